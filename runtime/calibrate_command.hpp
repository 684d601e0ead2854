// `mocapd calibrate`: builds a subject model (skeleton + calibrated marker set) from a
// BVH of the actor's motion and the C3D marker capture of the same take.
#pragma once

#include <ostream>
#include <string>

#include "filters/calibration.hpp"

namespace mocapd {

struct CalibrateCommandOptions {
  std::string skeleton_bvh;
  std::string markers_c3d;
  std::string out_subject;
  std::string subject_name;  ///< Empty: the output file's stem.
  std::string bvh_units;     ///< Empty: guess.
  CalibrationOptions calibration;
};

/// Runs the calibration, prints a per-marker report to out and writes the subject file.
/// Returns the number of accepted markers. Throws std::runtime_error (files, too few
/// markers accepted, frame counts that cannot be matched).
int RunCalibrateCommand(const CalibrateCommandOptions& options, std::ostream& out);

}  // namespace mocapd
