// Take inspection for `mocap-sim info`.
#include "sim/take_info.hpp"

#include <algorithm>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include <boost/algorithm/string/case_conv.hpp>

#include "formats/bvh.hpp"
#include "formats/c3d.hpp"

namespace mocapd {

std::string FileExtension(const std::string& path) {
  const size_t dot = path.rfind('.');
  const size_t slash = path.find_last_of('/');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  return boost::algorithm::to_lower_copy(path.substr(dot + 1));
}

TakeInfo InspectTake(const std::string& path) {
  TakeInfo info;
  info.path = path;
  const std::string ext = FileExtension(path);
  if (ext == "c3d") {
    const C3dTake take = ReadC3d(path);
    info.format = "c3d";
    info.frames = take.num_frames;
    info.rate_hz = take.rate_hz;
    info.units = take.units;
    info.processor = take.processor;
    info.analog_channels = take.analog.labels;
    info.analog_samples_per_frame = take.analog.samples_per_frame;
    info.origin_samples_missing = take.origin_samples_missing;
    info.notes = take.notes;
    for (int p = 0; p < take.num_points(); ++p) {
      PointInfo pi;
      pi.label = take.labels[static_cast<size_t>(p)];
      pi.kind = take.is_marker(p) ? "marker" : take.model_output_kind[static_cast<size_t>(p)];
      int missing = 0, run = 0;
      for (int f = 0; f < take.num_frames; ++f) {
        if (!take.valid(f, p)) {
          ++missing;
          if (run == 0) ++pi.gaps;
          ++run;
          pi.longest_gap = std::max(pi.longest_gap, run);
        } else {
          run = 0;
        }
      }
      pi.missing_fraction =
          take.num_frames > 0 ? static_cast<double>(missing) / take.num_frames : 0.0;
      info.points.push_back(pi);
    }
  } else if (ext == "bvh") {
    const BvhTake take = ReadBvh(path);
    info.format = "bvh";
    info.frames = take.num_frames();
    info.rate_hz = take.rate_hz();
    info.units = take.units;
    for (const Joint& j : take.skeleton.joints())
      info.joints.push_back(j.name + " (" + to_string(j.type) + ")");
    info.end_sites = static_cast<int>(take.end_sites.size());
  } else {
    throw std::invalid_argument(path + ": unknown take format '." + ext +
                                "' (expected .c3d or .bvh)");
  }
  return info;
}

std::string FormatTakeInfo(const TakeInfo& info) {
  char line[256];
  std::string out;
  std::snprintf(line, sizeof(line),
                "%s\n  format  %s\n  frames  %d\n  rate    %.6g Hz (%.3f s)\n  units   %s\n",
                info.path.c_str(), info.format.c_str(), info.frames, info.rate_hz,
                info.rate_hz > 0 ? info.frames / info.rate_hz : 0.0, info.units.c_str());
  out += line;
  if (info.format == "c3d") {
    out += "  processor " + info.processor + "\n";
    if (!info.analog_channels.empty()) {
      std::snprintf(line, sizeof(line), "  analog  %zu channels x %d samples a frame (%.6g Hz):",
                    info.analog_channels.size(), info.analog_samples_per_frame,
                    info.rate_hz * info.analog_samples_per_frame);
      out += line;
      for (const std::string& label : info.analog_channels) out += " " + label;
      out += "\n";
    }
    for (const std::string& note : info.notes) out += "  note    " + note + "\n";
    if (info.origin_samples_missing > 0)
      out += "  " + std::to_string(info.origin_samples_missing) +
             " marker samples at exactly (0, 0, 0) read as missing (an exporter's gaps)\n";
    std::snprintf(line, sizeof(line), "  %-24s %-8s %9s %6s %12s\n", "label", "kind", "missing%",
                  "gaps", "longest gap");
    out += line;
    for (const PointInfo& p : info.points) {
      std::snprintf(line, sizeof(line), "  %-24s %-8s %8.2f%% %6d %12d\n", p.label.c_str(),
                    p.kind.c_str(), 100.0 * p.missing_fraction, p.gaps, p.longest_gap);
      out += line;
    }
  } else {
    out += "  joints  " + std::to_string(info.joints.size()) + " (+" +
           std::to_string(info.end_sites) + " end sites)\n";
    for (const std::string& j : info.joints) out += "    " + j + "\n";
  }
  return out;
}

nlohmann::json TakeInfoJson(const TakeInfo& info) {
  nlohmann::json j = {{"path", info.path},
                      {"format", info.format},
                      {"frames", info.frames},
                      {"rate_hz", info.rate_hz},
                      {"units", info.units}};
  if (info.format == "c3d") {
    j["processor"] = info.processor;
    j["analog"] = {{"channels", info.analog_channels},
                   {"samples_per_frame", info.analog_samples_per_frame}};
    j["origin_samples_missing"] = info.origin_samples_missing;
    j["notes"] = info.notes;
    j["points"] = nlohmann::json::array();
    for (const PointInfo& p : info.points)
      j["points"].push_back({{"label", p.label},
                             {"kind", p.kind},
                             {"missing_fraction", p.missing_fraction},
                             {"gaps", p.gaps},
                             {"longest_gap", p.longest_gap}});
  } else {
    j["joints"] = info.joints;
    j["end_sites"] = info.end_sites;
  }
  return j;
}

}  // namespace mocapd
