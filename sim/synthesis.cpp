// Virtual marker synthesis.
#include "sim/synthesis.hpp"

#include "filters/rotation.hpp"
#include "formats/marker_layout.hpp"

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

C3dTake SynthesizeMarkers(const Skeleton& skeleton, const MarkerSet& markers,
                          const std::vector<Pose>& frames, double rate_hz,
                          const SynthesisNoise& noise) {
  std::mt19937_64 rng(noise.seed);
  C3dTake take = SynthesizeMarkers(skeleton, markers, frames, rate_hz, noise.noise_sigma_m, &rng);
  if (noise.soft_tissue_m <= 0.0) return take;
  // Which joints are fleshy segments (all of them if the skeleton is not a humanoid).
  std::vector<uint8_t> fleshy(static_cast<size_t>(skeleton.num_joints()), 1);
  try {
    const HumanoidRoles roles = MatchHumanoidRoles(skeleton);
    std::fill(fleshy.begin(), fleshy.end(), 0);
    for (const auto& [role, joint] : roles.joint_of_role)
      for (const char* soft : {"thigh", "shin", "upper_arm", "forearm", "spine", "chest"})
        if (role.rfind(soft, 0) == 0) fleshy[static_cast<size_t>(joint)] = 1;
  } catch (const std::invalid_argument&) {
  }
  // Per marker, a fixed mixing of the two joints' rotation vectors into a displacement.
  std::normal_distribution<double> normal(0.0, 1.0);
  const auto M = static_cast<size_t>(markers.num_markers());
  std::vector<Eigen::Matrix<double, 3, 6>> mix(M);
  for (auto& w : mix) {
    for (int c = 0; c < 6; ++c) {
      const Vec3 column(normal(rng), normal(rng), normal(rng));
      w.col(c) = column.normalized() / std::sqrt(2.0);
    }
  }
  const Pose rest = RestPose(skeleton);
  KinematicsWorkspace ws(skeleton);
  for (size_t f = 0; f < frames.size(); ++f) {
    ForwardKinematics(skeleton, frames[f], &ws);
    for (size_t m = 0; m < M; ++m) {
      const int joint = markers.primary_joint(static_cast<int>(m));
      const auto uj = static_cast<size_t>(joint);
      if (!fleshy[uj]) continue;
      Eigen::Matrix<double, 6, 1> v = Eigen::Matrix<double, 6, 1>::Zero();
      v.head<3>() = LogRotation(rest.rotation[uj].conjugate() * frames[f].rotation[uj]);
      const auto& children = skeleton.children(joint);
      if (!children.empty()) {
        const auto uc = static_cast<size_t>(children.front());
        v.tail<3>() = LogRotation(rest.rotation[uc].conjugate() * frames[f].rotation[uc]);
      }
      const Vec3 local = noise.soft_tissue_m * (mix[m] * v.array().sin().matrix());
      take.at(static_cast<int>(f), static_cast<int>(m)) += ws.R_WJ[uj] * local;
    }
  }
  return take;
}

}  // namespace mocapd
