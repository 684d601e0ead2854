// Subject model files (TOML, format documented in config/subject.example.toml): a
// skeleton and the marker set attached to it, as written by `mocapd calibrate` and
// `mocap-sim synth --subject-out`, and read by everything that solves a subject.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "filters/marker_model.hpp"

namespace mocapd {

/// How a subject was calibrated from markers (absent for hand-made or skeleton-given
/// subjects): recorded in the subject file beside the model.
struct SubjectCalibrationRecord {
  std::string marker_set;
  int poses = 0;                    ///< Frames solved in the bundle adjustment.
  double median_residual_mm = 0.0;  ///< Per marker-sample, after calibration.
  /// Per joint (skeleton order): how its centre was found ("functional",
  /// "functional+prior", "prior", "root") and its uncertainty, mm.
  std::vector<std::string> joint_method;
  std::vector<double> joint_uncertainty_mm;
};

struct SubjectModel {
  std::string name;
  std::shared_ptr<const Skeleton> skeleton;
  std::shared_ptr<const MarkerSet> markers;
  /// Per marker, the calibration fit RMS in metres (NaN when unknown).
  std::vector<double> fit_rms_m;
  /// Length unit of the BVH files this subject's motion is written to (as its source).
  std::string bvh_units = "cm";
  std::optional<SubjectCalibrationRecord> calibration;
};

/// Parses a subject model. Throws std::runtime_error naming the file, line and field.
SubjectModel ParseSubjectModel(const std::string& text, const std::string& source_name);
SubjectModel ReadSubjectModel(const std::string& path);

/// Formats / writes a subject model (metres, quaternions w x y z).
std::string FormatSubjectModel(const SubjectModel& model);
void WriteSubjectModel(const std::string& path, const SubjectModel& model);

}  // namespace mocapd
