// `mocapd calibrate`: builds a subject model (skeleton + calibrated marker set) from the
// actor's labelled markers alone (one or more C3D takes, the marker set recognised from
// the labels), or, with --skeleton, from a BVH of the actor's motion and the C3D capture
// of the same take.
#pragma once

#include <ostream>
#include <string>
#include <vector>

#include "filters/calibration.hpp"
#include "filters/subject_calibration.hpp"

namespace mocapd {

struct CalibrateCommandOptions {
  std::string skeleton_bvh;              ///< Empty: calibrate from the markers alone.
  std::vector<std::string> markers_c3d;  ///< One take with a skeleton; any number without.
  std::string out_subject;
  std::string subject_name;  ///< Empty: the output file's stem.
  std::string bvh_units;     ///< Empty: guess.
  CalibrationOptions calibration;
  std::string marker_set = "auto";  ///< Markers alone: a set name, a set file, or auto.
  std::string report_json;          ///< Markers alone: the report as JSON (empty: none).
  /// Markers alone: interleaved subsets averaged with the whole take's solve (1: one solve).
  int interleaved_solves = SubjectCalibrationOptions{}.interleaved_solves;
  std::string actor = {};  ///< Of takes holding several actors' markers: whose (label prefix).
};

/// Runs the calibration, prints a per-marker report to out and writes the subject file.
/// Returns the number of accepted markers. Throws std::runtime_error (files, too few
/// markers accepted, frame counts that cannot be matched).
int RunCalibrateCommand(const CalibrateCommandOptions& options, std::ostream& out);

}  // namespace mocapd
