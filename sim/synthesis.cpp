// Virtual marker synthesis.
#include "sim/synthesis.hpp"

#include <cmath>
#include <stdexcept>

namespace mocapd {

C3dTake SynthesizeMarkers(const Skeleton& skeleton, const MarkerSet& markers,
                          const std::vector<Pose>& frames, double rate_hz, double noise_sigma_m,
                          std::mt19937_64* rng) {
  C3dTake take;
  for (const MarkerDefinition& m : markers.markers()) take.labels.push_back(m.name);
  take.rate_hz = rate_hz;
  take.units = "mm";
  take.metres_per_unit = 1e-3;
  take.Allocate(static_cast<int>(frames.size()));
  KinematicsWorkspace ws(skeleton);
  std::normal_distribution<double> noise(0.0, std::max(noise_sigma_m, 1e-12));
  const bool add_noise = noise_sigma_m > 0.0 && rng != nullptr;
  for (size_t f = 0; f < frames.size(); ++f) {
    ForwardKinematics(skeleton, frames[f], &ws);
    for (int m = 0; m < markers.num_markers(); ++m) {
      Vec3 p = EvaluateMarker(markers.marker(m), ws);
      if (add_noise) p += Vec3(noise(*rng), noise(*rng), noise(*rng));
      take.at(static_cast<int>(f), m) = p;
      take.residuals[f * static_cast<size_t>(markers.num_markers()) + static_cast<size_t>(m)] =
          0.0f;
    }
  }
  return take;
}

}  // namespace mocapd
