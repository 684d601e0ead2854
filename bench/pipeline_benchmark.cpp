// Whole cleanup pipeline cost per subject-frame (detection, repair, the naive, robust and
// final solves): a take (../shared walk, or the humanoid) corrupted at medium severity,
// pushed frame by frame; reports p50/p99 per Push (pin it: `taskset -c 1`), in wall time
// and in the thread's CPU time (which leaves out the time this VM's vCPU was taken away:
// its wall-clock tail moves by tens of microseconds from run to run).
#include <benchmark/benchmark.h>

#include <time.h>

#include <chrono>
#include <random>

#include "bench/bench_takes.hpp"
#include "filters/cleanup_pipeline.hpp"
#include "filters/pose_error.hpp"
#include "formats/take_frames.hpp"
#include "sim/corruption.hpp"
#include "sim/synthesis.hpp"

namespace mocapd::bench {
namespace {

double ThreadCpuMicroseconds() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) * 1e6 + static_cast<double>(t.tv_nsec) * 1e-3;
}

void BM_CleanupPipelinePush(benchmark::State& state) {
  // Arg 2 picks the take: 0 the walk, 1 the dance (the hardest of the Bandai set).
  std::string path;
  for (const auto& p : SharedBvhTakes())
    if (p.find(state.range(2) == 0 ? "walk_normal" : "dance-short") != std::string::npos) path = p;
  const BenchTake take = LoadBenchTake(path, 120.0);
  std::mt19937_64 rng(1);
  const C3dTake clean =
      SynthesizeMarkers(take.bvh.skeleton, *take.markers, take.motion, 120.0, 0.0005, &rng);
  CorruptionOptions corruption;
  corruption.severity = static_cast<CorruptionSeverity>(state.range(0));
  const CorruptedTake bad = CorruptTake(clean, take.markers.get(), corruption);
  const TakeMarkerMap map(*take.markers, bad.take);
  CleanupOptions options;
  options.lookahead = static_cast<int>(state.range(1));
  auto skeleton = std::make_shared<const Skeleton>(take.bvh.skeleton);
  CleanupPipeline pipeline(skeleton, take.markers, options);
  std::vector<Vec3> observed(static_cast<size_t>(take.markers->num_markers()));
  std::vector<double> weights(observed.size());
  std::vector<double> times_us, cpu_times_us;
  times_us.reserve(1 << 20);
  cpu_times_us.reserve(1 << 20);
  int frame = 0;
  for (auto _ : state) {
    if (frame == bad.take.num_frames) {
      while (pipeline.Flush()) {
      }
      pipeline.Reset();
      frame = 0;
    }
    map.Observe(bad.take, frame, observed, weights);
    const double cpu0 = ThreadCpuMicroseconds();
    const auto t0 = std::chrono::steady_clock::now();
    benchmark::DoNotOptimize(pipeline.Push(observed));
    const auto t1 = std::chrono::steady_clock::now();
    const double cpu1 = ThreadCpuMicroseconds();
    // Skip each pass's cold start (the first K + 1 frames).
    if (frame > options.lookahead && times_us.size() < times_us.capacity()) {
      times_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
      cpu_times_us.push_back(cpu1 - cpu0);
    }
    ++frame;
  }
  state.counters["p50_us"] = Quantile(times_us, 0.5);
  state.counters["p99_us"] = Quantile(times_us, 0.99);
  state.counters["cpu_p50_us"] = Quantile(cpu_times_us, 0.5);
  state.counters["cpu_p99_us"] = Quantile(cpu_times_us, 0.99);
  state.counters["iterations_per_frame"] =
      static_cast<double>(pipeline.counters().solve_iterations) /
      static_cast<double>(pipeline.counters().frames_in);
  state.SetLabel(take.name);
}
// Args: severity (0 light, 1 medium, 2 heavy), lookahead K, take (0 walk, 1 dance).
BENCHMARK(BM_CleanupPipelinePush)
    ->Args({1, 12, 0})
    ->Args({1, 0, 0})
    ->Args({0, 12, 0})
    ->Args({1, 12, 1})
    ->Args({2, 12, 1})
    ->Unit(benchmark::kMicrosecond)
    ->MinTime(3.0);

}  // namespace
}  // namespace mocapd::bench

BENCHMARK_MAIN();
