// Synthesis of marker takes from skeletal motion: resampling (slerp for rotations,
// linear for translations) and evaluating a marker set along the motion.
#pragma once

#include <random>
#include <vector>

#include "filters/marker_model.hpp"
#include "sim/bvh.hpp"
#include "sim/c3d.hpp"

namespace mocapd {

/// Resamples poses from src_rate to dst_rate over the same duration: frame k of the
/// result is at time k / dst_rate; rotations are slerped, translations lerped. Throws
/// std::invalid_argument for non-positive rates or an empty input.
std::vector<Pose> ResampleMotion(const Skeleton& skeleton, const std::vector<Pose>& frames, double src_rate_hz,
                                 double dst_rate_hz);

/// Evaluates the markers on every pose and returns a C3D take in millimetres with the
/// markers' names. If noise_sigma_m > 0, adds isotropic Gaussian noise from rng.
C3dTake SynthesizeMarkers(const Skeleton& skeleton, const MarkerSet& markers, const std::vector<Pose>& frames,
                          double rate_hz, double noise_sigma_m = 0.0, std::mt19937_64* rng = nullptr);

}  // namespace mocapd
