// Shared fixtures: the humanoid with its default marker set and synthesized motion.
#pragma once

#include <memory>
#include <vector>

#include "filters/marker_model.hpp"
#include "formats/c3d.hpp"

namespace mocapd::testing {

struct HumanoidFixture {
  std::shared_ptr<const Skeleton> skeleton;
  std::shared_ptr<const MarkerSet> markers;
  std::vector<Pose> motion;  ///< Ground truth.
  C3dTake take;              ///< Markers synthesized from the motion.
};

/// The built-in humanoid doing `motion` (walk|reach|turn|mixed) at rate_hz, with
/// Gaussian marker noise sigma noise_m from a fixed seed.
HumanoidFixture MakeHumanoidFixture(const char* motion, double seconds, double rate_hz,
                                    double noise_m = 0.0, uint64_t seed = 7);

/// A unique empty directory under the build tree for files a test writes.
std::string TempDir(const std::string& name);

/// The take with one more point under point's label, 30 cm beside it (every sample valid):
/// a label given to two points.
C3dTake WithALabelGivenTwice(const C3dTake& take, int point);

}  // namespace mocapd::testing
