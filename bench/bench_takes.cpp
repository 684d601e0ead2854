// Benchmark take loading.
#include "bench/bench_takes.hpp"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <exception>
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

C3dTake FillGaps(const C3dTake& in, bool cubic) {
  C3dTake out = in;
  for (int p = 0; p < in.num_points(); ++p) {
    int f = 0;
    while (f < in.num_frames) {
      if (in.valid(f, p)) {
        ++f;
        continue;
      }
      const int s = f - 1;
      int e = f;
      while (e < in.num_frames && !in.valid(e, p)) ++e;
      for (int g = f; g < e; ++g) {
        Vec3 v;
        if (s < 0 && e >= in.num_frames) break;
        if (s < 0)
          v = in.at(e, p);
        else if (e >= in.num_frames)
          v = in.at(s, p);
        else {
          const double u = static_cast<double>(g - s) / (e - s);
          const Vec3 a = in.at(s, p), b = in.at(e, p);
          if (!cubic) {
            v = (1 - u) * a + u * b;
          } else {
            const Vec3 ma = (s > 0 && in.valid(s - 1, p))
                                ? Vec3((b - in.at(s - 1, p)) * 0.5 * (e - s) / (e - s + 1.0))
                                : Vec3(b - a);
            const Vec3 mb = (e + 1 < in.num_frames && in.valid(e + 1, p))
                                ? Vec3((in.at(e + 1, p) - a) * 0.5 * (e - s) / (e - s + 1.0))
                                : Vec3(b - a);
            const double u2 = u * u, u3 = u2 * u;
            v = (2 * u3 - 3 * u2 + 1) * a + (u3 - 2 * u2 + u) * ma + (-2 * u3 + 3 * u2) * b +
                (u3 - u2) * mb;
          }
        }
        out.at(g, p) = v;
        out.residuals[static_cast<size_t>(g) * static_cast<size_t>(in.num_points()) +
                      static_cast<size_t>(p)] = 0.0f;
      }
      f = e;
    }
  }
  return out;
}

int RunReportingErrors(const char* program, int (*body)(int, char**), int argc, char** argv) {
  try {
    return body(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n", program, e.what());
    return 1;
  }
}

}  // namespace mocapd::bench
