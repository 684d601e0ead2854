// Resampling skeletal motion to another rate: what lets a 30 Hz BVH drive a 120 Hz
// capture's calibration, and a benchmark run any take at any capture rate.
#pragma once

#include <vector>

#include "filters/skeleton.hpp"

namespace mocapd {

/// Writes into out the pose a fraction alpha of the way from a to b: every joint's rotation
/// slerped (shortest arc), every translation lerped. a and b must have the same size.
void InterpolatePose(const Pose& a, const Pose& b, double alpha, Pose* out);

/// Resamples poses from src_rate to dst_rate over the same duration: frame k of the
/// result is at time k / dst_rate; rotations are slerped, translations lerped. Throws
/// std::invalid_argument for non-positive rates or an empty input. Allocates the result.
std::vector<Pose> ResampleMotion(const Skeleton& skeleton, const std::vector<Pose>& frames,
                                 double src_rate_hz, double dst_rate_hz);

}  // namespace mocapd
