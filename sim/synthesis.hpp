// Synthesis of marker takes from skeletal motion: a marker set evaluated along the
// motion (resample it first with filters/resample.hpp).
#pragma once

#include <random>
#include <vector>

#include "filters/marker_model.hpp"
#include "filters/resample.hpp"
#include "formats/bvh.hpp"
#include "formats/c3d.hpp"

namespace mocapd {

/// Evaluates the markers on every pose and returns a C3D take in millimetres with the
/// markers' names. If noise_sigma_m > 0, adds isotropic Gaussian noise from rng.
C3dTake SynthesizeMarkers(const Skeleton& skeleton, const MarkerSet& markers,
                          const std::vector<Pose>& frames, double rate_hz,
                          double noise_sigma_m = 0.0, std::mt19937_64* rng = nullptr);

}  // namespace mocapd
