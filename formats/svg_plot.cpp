// SVG charts (see the header).
#include "formats/svg_plot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "filters/pose_error.hpp"

namespace mocapd::svg {
namespace {

constexpr double kLeft = 70, kRight = 20, kTitleHeight = 36, kAxisHeight = 42;
constexpr char kFont[] = "font-family=\"sans-serif\" font-size=\"12\"";

std::string Num(double v, int decimals = 2) {
  char b[40];
  std::snprintf(b, sizeof(b), "%.*f", decimals, v);
  return b;
}

// A "nice" tick step covering span in about n steps: 1, 2 or 5 times a power of ten.
double TickStep(double span, int n) {
  if (!(span > 0)) return 1.0;  // an empty or flat axis still gets finite ticks
  const double raw = span / std::max(1, n);
  const double power = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (m * power >= raw) return m * power;
  return 10.0 * power;
}

void Open(std::ostringstream& s, double w, double h, const std::string& title) {
  s << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << w << "\" height=\"" << h << "\" "
    << kFont << ">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n"
    << "<text x=\"" << w / 2 << "\" y=\"22\" text-anchor=\"middle\" font-size=\"15\">"
    << Escape(title) << "</text>\n";
}

// The time axis under a plot area: ticks in seconds (or minutes for long takes).
void TimeAxis(std::ostringstream& s, double left, double width, double y, double seconds) {
  const bool minutes = seconds > 600;
  const double span = minutes ? seconds / 60 : seconds;
  const double step = TickStep(span, 10);
  s << "<line x1=\"" << left << "\" y1=\"" << y << "\" x2=\"" << left + width << "\" y2=\"" << y
    << "\" stroke=\"#444\"/>\n";
  for (double t = 0; t <= span + 1e-9; t += step) {
    const double x = left + width * t / std::max(span, 1e-9);
    s << "<line x1=\"" << x << "\" y1=\"" << y << "\" x2=\"" << x << "\" y2=\"" << y + 4
      << "\" stroke=\"#444\"/><text x=\"" << x << "\" y=\"" << y + 16
      << "\" text-anchor=\"middle\">" << Num(t, step < 1 ? 1 : 0) << "</text>\n";
  }
  s << "<text x=\"" << left + width / 2 << "\" y=\"" << y + 34 << "\" text-anchor=\"middle\">"
    << (minutes ? "time (min)" : "time (s)") << "</text>\n";
}

}  // namespace

std::string Escape(const std::string& text) {
  std::string out;
  for (char c : text) {
    if (c == '<')
      out += "&lt;";
    else if (c == '>')
      out += "&gt;";
    else if (c == '&')
      out += "&amp;";
    else if (c == '"')
      out += "&quot;";
    else
      out += c;
  }
  return out;
}

std::string LineCharts(const std::string& title, double seconds_per_sample,
                       const std::vector<Panel>& panels, int width) {
  constexpr double kPanelHeight = 180, kGap = 26;
  const double w = width, plot_w = w - kLeft - kRight;
  const double h =
      kTitleHeight + static_cast<double>(panels.size()) * (kPanelHeight + kGap) + kAxisHeight;
  size_t samples = 0;
  for (const Panel& p : panels)
    for (const Series& series : p.series) samples = std::max(samples, series.y.size());
  const double seconds = static_cast<double>(samples) * seconds_per_sample;
  std::ostringstream s;
  Open(s, w, h, title);
  double top = kTitleHeight;
  for (const Panel& p : panels) {
    double y_max = p.y_max;
    if (y_max <= p.y_min) {
      for (const Series& series : p.series)
        for (double v : series.y)
          if (std::isfinite(v)) y_max = std::max(y_max, v);
      y_max = y_max > p.y_min ? y_max * 1.05 : p.y_min + 1.0;
    }
    const auto y_of = [&](double v) {
      return top +
             kPanelHeight * (1.0 - (std::clamp(v, p.y_min, y_max) - p.y_min) / (y_max - p.y_min));
    };
    s << "<rect x=\"" << kLeft << "\" y=\"" << top << "\" width=\"" << plot_w << "\" height=\""
      << kPanelHeight << "\" fill=\"#fafafa\" stroke=\"#bbb\"/>\n";
    const double step = TickStep(y_max - p.y_min, 4);
    for (double v = p.y_min; v <= y_max + 1e-9; v += step)
      s << "<line x1=\"" << kLeft << "\" x2=\"" << kLeft + plot_w << "\" y1=\"" << y_of(v)
        << "\" y2=\"" << y_of(v) << "\" stroke=\"#e4e4e4\"/><text x=\"" << kLeft - 6 << "\" y=\""
        << y_of(v) + 4 << "\" text-anchor=\"end\">" << Num(v, step < 1 ? 2 : 0) << "</text>\n";
    s << "<text x=\"14\" y=\"" << top + kPanelHeight / 2 << "\" transform=\"rotate(-90 14 "
      << top + kPanelHeight / 2 << ")\" text-anchor=\"middle\">" << Escape(p.y_label)
      << "</text>\n";
    double legend_x = kLeft + 8;
    for (const Series& series : p.series) {
      // Min and max per pixel column: every spike stays visible, the file stays small.
      const int columns = static_cast<int>(plot_w);
      std::string points;
      for (int c = 0; c < columns && !series.y.empty(); ++c) {
        const size_t a = static_cast<size_t>(c) * series.y.size() / static_cast<size_t>(columns);
        const size_t b = std::max(
            a + 1, static_cast<size_t>(c + 1) * series.y.size() / static_cast<size_t>(columns));
        double lo = std::numeric_limits<double>::infinity(), hi = -lo;
        for (size_t i = a; i < std::min(b, series.y.size()); ++i)
          if (std::isfinite(series.y[i])) {
            lo = std::min(lo, series.y[i]);
            hi = std::max(hi, series.y[i]);
          }
        if (!std::isfinite(lo)) {
          if (!points.empty())
            s << "<polyline points=\"" << points << "\" fill=\"none\" stroke=\"" << series.color
              << "\" stroke-width=\"1.2\"/>\n";
          points.clear();
          continue;
        }
        const double x = kLeft + c + 0.5;
        points += Num(x, 1) + "," + Num(y_of(lo), 1) + " ";
        if (hi > lo) points += Num(x, 1) + "," + Num(y_of(hi), 1) + " ";
      }
      if (!points.empty())
        s << "<polyline points=\"" << points << "\" fill=\"none\" stroke=\"" << series.color
          << "\" stroke-width=\"1.2\"/>\n";
      s << "<rect x=\"" << legend_x << "\" y=\"" << top + 7
        << "\" width=\"14\" height=\"4\" fill=\"" << series.color << "\"/><text x=\""
        << legend_x + 18 << "\" y=\"" << top + 13 << "\">" << Escape(series.name) << "</text>\n";
      legend_x += 30 + 7.0 * static_cast<double>(series.name.size());
    }
    top += kPanelHeight + kGap;
  }
  TimeAxis(s, kLeft, plot_w, top - kGap + 2, seconds);
  s << "</svg>\n";
  return s.str();
}

std::string Timeline(const std::string& title, double seconds_per_sample,
                     const std::vector<TimelineRow>& rows, const std::vector<Category>& categories,
                     int width) {
  constexpr double kRowHeight = 11, kLabelWidth = 90, kLegendLine = 18;
  const double w = width, left = kLabelWidth, plot_w = w - left - kRight;
  const double plot_h = kRowHeight * static_cast<double>(rows.size());
  size_t samples = 0;
  std::vector<uint64_t> totals(categories.size(), 0);
  for (const TimelineRow& r : rows) {
    samples = std::max(samples, r.category.size());
    for (uint8_t c : r.category)
      if (c < totals.size()) ++totals[c];
  }
  // Legend: the categories that occur, with their share of all cells, on as many lines as
  // the width needs.
  uint64_t all = 0;
  for (uint64_t n : totals) all += n;
  struct LegendEntry {
    size_t category;
    std::string label;
    double x, y;
  };
  std::vector<LegendEntry> legend;
  double x = left, legend_y = kTitleHeight;
  for (size_t c = 0; c < categories.size(); ++c) {
    if (totals[c] == 0) continue;
    const std::string label = categories[c].name + " " +
                              Num(100.0 * static_cast<double>(totals[c]) /
                                      static_cast<double>(std::max<uint64_t>(1, all)),
                                  1) +
                              "%";
    const double entry_w = 30 + 6.5 * static_cast<double>(label.size());
    if (x > left && x + entry_w > w - kRight) {
      x = left;
      legend_y += kLegendLine;
    }
    legend.push_back({c, label, x, legend_y});
    x += entry_w;
  }
  const double legend_h = legend_y - kTitleHeight + kLegendLine + 8;
  const double h = kTitleHeight + legend_h + plot_h + kAxisHeight;
  const double per_sample = plot_w / static_cast<double>(std::max<size_t>(1, samples));
  std::ostringstream s;
  Open(s, w, h, title);
  for (const LegendEntry& e : legend)
    s << "<rect x=\"" << e.x << "\" y=\"" << e.y << "\" width=\"12\" height=\"12\" fill=\""
      << categories[e.category].color << "\" stroke=\"#999\"/><text x=\"" << e.x + 16 << "\" y=\""
      << e.y + 10 << "\">" << Escape(e.label) << "</text>\n";
  const double top = kTitleHeight + legend_h;
  for (size_t r = 0; r < rows.size(); ++r) {
    const double y = top + kRowHeight * static_cast<double>(r);
    s << "<text x=\"" << left - 6 << "\" y=\"" << y + kRowHeight - 2
      << "\" text-anchor=\"end\" font-size=\"9\">" << Escape(rows[r].label) << "</text>\n";
    const auto& cells = rows[r].category;
    for (size_t a = 0; a < cells.size();) {
      size_t b = a + 1;
      while (b < cells.size() && cells[b] == cells[a]) ++b;
      if (cells[a] < categories.size())
        s << "<rect x=\"" << Num(left + per_sample * static_cast<double>(a), 2) << "\" y=\"" << y
          << "\" width=\"" << Num(per_sample * static_cast<double>(b - a), 2) << "\" height=\""
          << kRowHeight - 1 << "\" fill=\"" << categories[cells[a]].color << "\"/>\n";
      a = b;
    }
  }
  TimeAxis(s, left, plot_w, top + plot_h + 2, static_cast<double>(samples) * seconds_per_sample);
  s << "</svg>\n";
  return s.str();
}

std::string LogHistogram(const std::string& title, const std::string& x_label,
                         const std::vector<double>& values, double lo, double hi,
                         const std::vector<double>& quantiles, const std::string& unit) {
  constexpr int kBins = 48;
  std::vector<int> counts(kBins, 0);
  const auto position = [&](double v) {
    return std::log10(std::clamp(v, lo, hi) / lo) / std::log10(hi / lo);
  };
  for (double v : values)
    ++counts[static_cast<size_t>(std::min(kBins - 1, static_cast<int>(position(v) * kBins)))];
  const int peak = std::max(1, *std::max_element(counts.begin(), counts.end()));
  const double w = 760, h = 380, plot_w = w - kLeft - kRight;
  const double top = kTitleHeight + 4, plot_h = h - top - kAxisHeight - 6;
  std::ostringstream s;
  Open(s, w, h, title);
  s << "<rect x=\"" << kLeft << "\" y=\"" << top << "\" width=\"" << plot_w << "\" height=\""
    << plot_h << "\" fill=\"#fafafa\" stroke=\"#bbb\"/>\n";
  for (int b = 0; b < kBins; ++b) {
    const double bh = plot_h * counts[static_cast<size_t>(b)] / peak;
    s << "<rect x=\"" << kLeft + plot_w * b / kBins << "\" y=\"" << top + plot_h - bh
      << "\" width=\"" << plot_w / kBins - 1 << "\" height=\"" << bh
      << "\" fill=\"#2a7fc1\"><title>" << counts[static_cast<size_t>(b)] << "</title></rect>\n";
  }
  for (double decade = lo; decade <= hi * 1.0001; decade *= 10) {
    const double x = kLeft + plot_w * position(decade);
    s << "<line x1=\"" << x << "\" y1=\"" << top + plot_h << "\" x2=\"" << x << "\" y2=\""
      << top + plot_h + 4 << "\" stroke=\"#444\"/><text x=\"" << x << "\" y=\"" << top + plot_h + 16
      << "\" text-anchor=\"middle\">" << Num(decade, decade < 1 ? 2 : 0) << "</text>\n";
  }
  s << "<text x=\"" << kLeft + plot_w / 2 << "\" y=\"" << h - 10 << "\" text-anchor=\"middle\">"
    << Escape(x_label) << "</text>\n<text x=\"14\" y=\"" << top + plot_h / 2
    << "\" transform=\"rotate(-90 14 " << top + plot_h / 2
    << ")\" text-anchor=\"middle\">count</text>\n<text x=\"" << kLeft + 6 << "\" y=\"" << top + 14
    << "\">peak " << peak << ", " << values.size() << " in all</text>\n";
  for (size_t k = 0; k < quantiles.size() && !values.empty(); ++k) {
    const double v = Quantile(values, quantiles[k]);
    const double x = kLeft + plot_w * position(v);
    s << "<line x1=\"" << x << "\" y1=\"" << top << "\" x2=\"" << x << "\" y2=\"" << top + plot_h
      << "\" stroke=\"#c0392b\" stroke-dasharray=\"4 3\"/><text x=\"" << x + 3 << "\" y=\""
      << top + 30 + 14.0 * static_cast<double>(k) << "\" fill=\"#c0392b\">p"
      << Num(quantiles[k] * 100, quantiles[k] * 100 == std::floor(quantiles[k] * 100) ? 0 : 1)
      << " " << Num(v, 3) << " " << Escape(unit) << "</text>\n";
  }
  s << "</svg>\n";
  return s.str();
}

}  // namespace mocapd::svg
