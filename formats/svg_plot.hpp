// Small SVG charts for a person to read at a glance, all in one look: stacked line charts
// over time (series drawn min/max per pixel column, so an hour of frames stays a small
// file), a timeline with one row per item coloured by category (a take's markers by
// status), and a histogram on a log axis (the replay's latency). Used by `mocapd process
// --plot` and `mocap-sim replay --plot`.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace mocapd::svg {

struct Series {
  std::string name;
  std::string color;      ///< CSS colour, e.g. "#2a7fc1".
  std::vector<double> y;  ///< One value per sample; NaN leaves a gap.
};

struct Panel {
  std::string y_label;
  std::vector<Series> series;
  double y_min = 0.0;
  double y_max = 0.0;  ///< 0: from the data.
};

/// Panels stacked over one time axis: sample i is at x = i * seconds_per_sample.
std::string LineCharts(const std::string& title, double seconds_per_sample,
                       const std::vector<Panel>& panels, int width = 1100);

struct Category {
  std::string name;
  std::string color;
};

struct TimelineRow {
  std::string label;
  std::vector<uint8_t> category;  ///< Index into the categories, one per sample.
};

/// One row per item, each sample a cell coloured by its category (runs merged), with a
/// legend of the categories that occur and the share of samples in each.
std::string Timeline(const std::string& title, double seconds_per_sample,
                     const std::vector<TimelineRow>& rows, const std::vector<Category>& categories,
                     int width = 1100);

/// Values binned on a log axis from lo to hi (outside: the end bins), with dashed lines
/// and labels at the given quantiles.
std::string LogHistogram(const std::string& title, const std::string& x_label,
                         const std::vector<double>& values, double lo, double hi,
                         const std::vector<double>& quantiles, const std::string& unit);

/// Text safe inside SVG.
std::string Escape(const std::string& text);

}  // namespace mocapd::svg
