// Benchmark take loading.
#include "bench/bench_takes.hpp"

#include <algorithm>
#include <cstdlib>
#include <filesystem>

#include "formats/marker_layout.hpp"
#include "sim/humanoid.hpp"
#include "sim/synthesis.hpp"

namespace mocapd::bench {

std::vector<std::string> SharedBvhTakes() {
  const char* env = std::getenv("MOCAPD_SHARED_DATA");
  const std::filesystem::path data =
      env != nullptr ? std::filesystem::path(env)
                     : std::filesystem::path(MOCAPD_SOURCE_DIR) / ".." / "shared" / "data";
  std::vector<std::string> out;
  const auto dir = data / "bandai-namco-1";
  if (!std::filesystem::is_directory(dir)) return out;
  for (const auto& entry : std::filesystem::directory_iterator(dir))
    if (entry.path().extension() == ".bvh") out.push_back(entry.path().string());
  std::sort(out.begin(), out.end());
  return out;
}

BenchTake LoadBenchTake(const std::string& bvh_path, double rate_hz) {
  BenchTake take;
  if (bvh_path.empty()) {
    take.name = "humanoid-mixed";
    Skeleton sk = MakeHumanoidSkeleton();
    auto frames = MakeHumanoidMotion(sk, HumanoidMotion::kMixed, 20.0, 30.0);
    take.bvh = MakeBvhTake(std::move(sk), std::move(frames), 1.0 / 30.0);
  } else {
    take.name = std::filesystem::path(bvh_path).stem().string();
    take.bvh = ReadBvh(bvh_path);
  }
  take.motion = ResampleMotion(take.bvh.skeleton, take.bvh.frames, take.bvh.rate_hz(), rate_hz);
  take.markers = std::make_shared<const MarkerSet>(
      take.bvh.skeleton, PlaceMarkers(take.bvh.skeleton, MatchHumanoidRoles(take.bvh.skeleton),
                                      DefaultMarkerLayout(), take.bvh.end_sites));
  return take;
}

}  // namespace mocapd::bench
