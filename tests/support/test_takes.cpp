// Shared humanoid fixtures for tests.
#include "tests/support/test_takes.hpp"

#include <unistd.h>
#include <algorithm>
#include <filesystem>
#include <random>

#include "formats/marker_layout.hpp"
#include "sim/humanoid.hpp"
#include "sim/synthesis.hpp"

namespace mocapd::testing {

HumanoidFixture MakeHumanoidFixture(const char* motion, double seconds, double rate_hz,
                                    double noise_m, uint64_t seed) {
  HumanoidFixture f;
  f.skeleton = std::make_shared<const Skeleton>(MakeHumanoidSkeleton());
  f.markers = std::make_shared<const MarkerSet>(
      *f.skeleton,
      PlaceMarkers(*f.skeleton, MatchHumanoidRoles(*f.skeleton), DefaultMarkerLayout(), {}));
  f.motion = MakeHumanoidMotion(*f.skeleton, ParseHumanoidMotion(motion), seconds, rate_hz);
  std::mt19937_64 rng(seed);
  f.take = SynthesizeMarkers(*f.skeleton, *f.markers, f.motion, rate_hz, noise_m, &rng);
  return f;
}

std::string TempDir(const std::string& name) {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("mocapd_test_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir.string();
}

C3dTake WithALabelGivenTwice(const C3dTake& take, int point) {
  C3dTake doubled = take;
  doubled.labels.push_back(take.labels[static_cast<size_t>(point)]);
  doubled.Allocate(take.num_frames);
  for (int fr = 0; fr < take.num_frames; ++fr) {
    for (int p = 0; p < take.num_points(); ++p) doubled.at(fr, p) = take.at(fr, p);
    doubled.at(fr, take.num_points()) = take.at(fr, point) + Vec3(0.3, 0.0, 0.0);
  }
  std::fill(doubled.residuals.begin(), doubled.residuals.end(), 0.0f);
  return doubled;
}

}  // namespace mocapd::testing
