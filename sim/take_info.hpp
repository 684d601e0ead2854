// Summaries of take files for `mocap-sim info`: frames, rate, units, labels or joints,
// and for C3D each marker's missing fraction and gap count.
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace mocapd {

struct PointInfo {
  std::string label;
  std::string kind;  ///< "marker" or the model-output group (ANGLES, POWERS ...)
  double missing_fraction = 0.0;
  int gaps = 0;         ///< Runs of consecutive missing frames.
  int longest_gap = 0;  ///< Frames.
};

struct TakeInfo {
  std::string path;
  std::string format;  ///< "c3d" or "bvh"
  int frames = 0;
  double rate_hz = 0.0;
  std::string units;
  std::string processor;                     ///< C3D only
  std::vector<std::string> analog_channels;  ///< C3D only: the analog channels' labels.
  int analog_samples_per_frame = 0;          ///< C3D only.
  std::vector<PointInfo> points;             ///< C3D only
  int64_t origin_samples_missing = 0;        ///< C3D only: samples at (0, 0, 0) read as missing
  std::vector<std::string> notes;            ///< C3D only: the reader's notes (C3dTake::notes)
  std::vector<std::string> joints;           ///< BVH only: "name (type)"
  int end_sites = 0;
};

/// Reads a take (by extension .c3d / .bvh, case-insensitive) and summarises it. Throws
/// the reader's errors, or std::invalid_argument for an unknown extension.
TakeInfo InspectTake(const std::string& path);
std::string FormatTakeInfo(const TakeInfo& info);
nlohmann::json TakeInfoJson(const TakeInfo& info);

/// Lower-cased file extension without the dot ("" if none).
std::string FileExtension(const std::string& path);

}  // namespace mocapd
