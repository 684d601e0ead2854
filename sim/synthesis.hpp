// Synthesis of marker takes from skeletal motion: a marker set evaluated along the
// motion (resample it first with filters/resample.hpp).
#pragma once

#include <cstdint>
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

/// What a synthesized capture adds to the model's markers.
struct SynthesisNoise {
  double noise_sigma_m = 0.0;  ///< Isotropic Gaussian noise per sample.
  /// Soft tissue: a marker on a fleshy segment (thigh, shin, upper arm, forearm, spine,
  /// chest) moves on its segment by up to about this much, a smooth function of the pose
  /// of the joint it rides and of that joint's child (a muscle bulging as the knee bends),
  /// fixed per marker by the seed. Bony landmarks (pelvis, head, hands, feet) stay put.
  double soft_tissue_m = 0.0;
  uint64_t seed = 1;
};

/// Evaluates the markers on every pose with noise and soft tissue, as a C3D take in
/// millimetres. Deterministic for a given seed.
C3dTake SynthesizeMarkers(const Skeleton& skeleton, const MarkerSet& markers,
                          const std::vector<Pose>& frames, double rate_hz,
                          const SynthesisNoise& noise);

}  // namespace mocapd
