// Per-frame IK cost: the warm-started solve on real (or procedural) motion at 120 Hz,
// clean and with 1 mm marker noise, reporting p50/p99 per-frame time and LM iterations;
// and forward kinematics plus marker evaluation alone.
#include <benchmark/benchmark.h>

#include <chrono>
#include <random>

#include "bench/bench_takes.hpp"
#include "filters/ik_solver.hpp"
#include "filters/pose_error.hpp"
#include "formats/take_frames.hpp"
#include "sim/synthesis.hpp"

namespace mocapd::bench {
namespace {

const BenchTake& Take() {
  static const BenchTake take = [] {
    const auto shared = SharedBvhTakes();
    // The longest walk when ../shared is present: real motion, ~1.6 s at 30 Hz.
    std::string path;
    for (const auto& p : shared)
      if (p.find("walk_normal") != std::string::npos) path = p;
    return LoadBenchTake(path, 120.0);
  }();
  return take;
}

void BM_IkSolveWarmStarted(benchmark::State& state) {
  const BenchTake& take = Take();
  const Skeleton& sk = take.bvh.skeleton;
  const MarkerSet& markers = *take.markers;
  std::mt19937_64 rng(1);
  const double noise_m = static_cast<double>(state.range(0)) * 1e-3;
  const C3dTake c3d = SynthesizeMarkers(sk, markers, take.motion, 120.0, noise_m, &rng);
  const TakeMarkerMap map(markers, c3d);
  std::vector<Vec3> observed(static_cast<size_t>(markers.num_markers()));
  std::vector<double> weights(observed.size());
  IkState ik(sk, markers);
  const IkOptions options;
  ik.Reset(take.motion[0]);
  std::vector<double> times_us;
  times_us.reserve(1 << 20);
  long iterations = 0;
  int frame = 1;
  for (auto _ : state) {
    if (frame == c3d.num_frames) {
      // Wrap around without a cold start: seed the first frame as if just solved.
      ik.Reset(take.motion[0]);
      frame = 1;
    }
    map.Observe(c3d, frame, observed, weights);
    const auto t0 = std::chrono::steady_clock::now();
    const IkSummary summary = SolveIk(sk, markers, options, observed, weights, &ik);
    const auto t1 = std::chrono::steady_clock::now();
    benchmark::DoNotOptimize(summary);
    if (times_us.size() < times_us.capacity())
      times_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    iterations += summary.iterations;
    ++frame;
  }
  state.counters["p50_us"] = Quantile(times_us, 0.5);
  state.counters["p99_us"] = Quantile(times_us, 0.99);
  state.counters["iterations"] =
      static_cast<double>(iterations) / static_cast<double>(state.iterations());
  state.counters["markers"] = markers.num_markers();
  state.counters["dofs"] = sk.num_dofs();
  state.SetLabel(take.name + (noise_m > 0 ? " +noise" : " clean"));
}
BENCHMARK(BM_IkSolveWarmStarted)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond)->MinTime(2.0);

void BM_ForwardKinematicsAndMarkers(benchmark::State& state) {
  const BenchTake& take = Take();
  const Skeleton& sk = take.bvh.skeleton;
  KinematicsWorkspace ws(sk);
  std::vector<Vec3> p(static_cast<size_t>(take.markers->num_markers()));
  size_t frame = 0;
  for (auto _ : state) {
    ForwardKinematics(sk, take.motion[frame], &ws);
    EvaluateMarkers(*take.markers, ws, p);
    benchmark::DoNotOptimize(p.data());
    frame = (frame + 1) % take.motion.size();
  }
  state.SetLabel(take.name);
}
BENCHMARK(BM_ForwardKinematicsAndMarkers)->Unit(benchmark::kNanosecond);

}  // namespace
}  // namespace mocapd::bench

BENCHMARK_MAIN();
