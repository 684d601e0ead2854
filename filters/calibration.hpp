// Marker calibration: given a skeleton's motion and marker trajectories of the same
// take, finds the joint each marker rides on (or a blend of a joint and its parent)
// and its local offset by linear least squares over the take.
//
// Rigid fit on joint J: minimise sum_f |R_WJ(f) o + p_WJ(f) - y_f|^2, whose solution is
// o = mean_f R_WJ(f)' (y_f - p_WJ(f)) since R'R = I. Blend of child C and parent P: the
// LBS position (1-w)(R_C o_C + p_C) + w(R_P o_P + p_P) equals R_C a + R_P b + p_P for
// free a, b (the weight is not identifiable from motion), a 6-unknown linear problem;
// the result is expressed at a conventional weight.
#pragma once

#include <span>
#include <string>
#include <vector>

#include "filters/marker_model.hpp"

namespace mocapd {

struct CalibrationOptions {
  double max_rms_m = 0.01;  ///< A marker whose best fit is worse than this is rejected.
  /// A blend replaces the best rigid fit only if it lowers the RMS below this fraction of it.
  double blend_improvement = 0.5;
  double min_rigid_rms_for_blend_m = 0.0005;  ///< Rigid fits better than this are kept as they are.
  double blend_parent_weight = 0.5;           ///< Conventional weight for blended markers.
  int min_frames = 10;                        ///< Fewer valid samples: rejected.
  void Validate() const;
};

struct MarkerCalibration {
  std::string name;
  bool accepted = false;
  MarkerDefinition definition;  ///< Valid when accepted.
  double rms_m = 0.0;           ///< Fit residual of the chosen attachment.
  int frames_used = 0;
  std::string reason;  ///< Why it was rejected (empty when accepted).
};

/// Calibrates every marker. joint_frames[f] is FK of the skeleton at frame f;
/// observed holds positions frame-major (observed[f * names.size() + m], metres, NaN when
/// missing). Allocates; offline. Throws std::invalid_argument on mismatched sizes.
std::vector<MarkerCalibration> CalibrateMarkers(const Skeleton& skeleton,
                                                std::span<const KinematicsWorkspace> joint_frames,
                                                std::span<const std::string> names,
                                                std::span<const Vec3> observed,
                                                const CalibrationOptions& options = {});

}  // namespace mocapd
