// IK accuracy evaluation: for each BVH take (the ../shared Bandai takes when present,
// else the built-in humanoid), checks the BVH write->read round trip, then synthesizes
// the default marker set at 120 Hz and solves every frame warm-started, clean and with
// 1 mm Gaussian noise. Prints a markdown table (see bench/README.md).
// Usage: ik_accuracy [--noise-mm S] [TAKE.bvh ...]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>

#include "bench/bench_takes.hpp"
#include "filters/ik_solver.hpp"
#include "filters/pose_error.hpp"
#include "formats/take_frames.hpp"
#include "sim/synthesis.hpp"

using namespace mocapd;

namespace {

double RoundTripErrorInFileUnits(const BvhTake& take) {
  const BvhTake again = ParseBvh(FormatBvh(take), "round-trip");
  KinematicsWorkspace a(take.skeleton), b(again.skeleton);
  double worst = 0.0;
  for (size_t f = 0; f < take.frames.size(); ++f) {
    ForwardKinematics(take.skeleton, take.frames[f], &a);
    ForwardKinematics(again.skeleton, again.frames[f], &b);
    for (size_t j = 0; j < a.p_WJ.size(); ++j)
      worst = std::max(worst, (a.p_WJ[j] - b.p_WJ[j]).norm() / take.metres_per_unit);
  }
  return worst;
}

struct Result {
  PoseErrorAccumulator errors;
  std::vector<double> times_us;
  double iterations = 0;
  int failures = 0;
};

Result Solve(const bench::BenchTake& take, double noise_m) {
  const Skeleton& sk = take.bvh.skeleton;
  std::mt19937_64 rng(42);
  const C3dTake c3d = SynthesizeMarkers(sk, *take.markers, take.motion, 120.0, noise_m, &rng);
  const TakeMarkerMap map(*take.markers, c3d);
  std::vector<Vec3> observed(static_cast<size_t>(take.markers->num_markers()));
  std::vector<double> weights(observed.size());
  IkState ik(sk, *take.markers);
  Result r{PoseErrorAccumulator(sk), {}, 0, 0};
  KinematicsWorkspace truth(sk);
  long iterations = 0;
  for (int f = 0; f < c3d.num_frames; ++f) {
    map.Observe(c3d, f, observed, weights);
    const auto t0 = std::chrono::steady_clock::now();
    const IkSummary s = SolveIk(sk, *take.markers, IkOptions{}, observed, weights, &ik);
    const auto t1 = std::chrono::steady_clock::now();
    if (f > 0) r.times_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    if (f > 0) iterations += s.iterations;
    if (s.status == IkStatus::kNumericalFailure) ++r.failures;
    ForwardKinematics(sk, take.motion[static_cast<size_t>(f)], &truth);
    r.errors.Add(truth, ik.kinematics());
  }
  r.iterations = static_cast<double>(iterations) / std::max(1, c3d.num_frames - 1);
  return r;
}

}  // namespace

int RunProgram(int argc, char** argv) {
  double noise_mm = 1.0;
  std::vector<std::string> paths;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--noise-mm") == 0 && i + 1 < argc)
      noise_mm = std::atof(argv[++i]);
    else
      paths.emplace_back(argv[i]);
  }
  if (paths.empty()) paths = bench::SharedBvhTakes();
  if (paths.empty()) paths.emplace_back("");  // the built-in humanoid
  std::printf(
      "| take | frames@120Hz | markers | DOF | BVH round trip (units) | clean: mean / max pos (mm) "
      "| clean: mean rot (deg) | "
      "%.1fmm noise: mean / max pos (mm) | noise: mean rot (deg) | noise: worst joint p99 rot "
      "(deg) | solve p50 / p99 (us) | iters |\n",
      noise_mm);
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  bool ok = true;
  for (const std::string& path : paths) {
    const bench::BenchTake take = bench::LoadBenchTake(path, 120.0);
    const double round_trip = RoundTripErrorInFileUnits(take.bvh);
    const Result clean = Solve(take, 0.0);
    const Result noisy = Solve(take, noise_mm * 1e-3);
    int worst = 0;
    const double p99 = noisy.errors.worst_joint_rotation_quantile_rad(0.99, &worst) * 180 / M_PI;
    std::printf(
        "| %s | %zu | %d | %d | %.2e | %.3f / %.3f | %.3f | %.3f / %.3f | %.3f | %.2f (%s) | %.1f "
        "/ %.1f | %.2f |\n",
        take.name.c_str(), take.motion.size(), take.markers->num_markers(),
        take.bvh.skeleton.num_dofs(), round_trip, clean.errors.mean_position_error_m() * 1e3,
        clean.errors.max_position_error_m() * 1e3,
        clean.errors.mean_rotation_error_rad() * 180 / M_PI,
        noisy.errors.mean_position_error_m() * 1e3, noisy.errors.max_position_error_m() * 1e3,
        noisy.errors.mean_rotation_error_rad() * 180 / M_PI, p99,
        take.bvh.skeleton.joint(worst).name.c_str(), Quantile(noisy.times_us, 0.5),
        Quantile(noisy.times_us, 0.99), noisy.iterations);
    std::fflush(stdout);
    ok = ok && round_trip < 1e-4 && clean.errors.mean_position_error_m() < 1e-3 &&
         clean.errors.max_position_error_m() < 5e-3 &&
         noisy.errors.mean_rotation_error_rad() * 180 / M_PI <= 2.0 && p99 <= 10.0 &&
         clean.failures == 0 && noisy.failures == 0;
  }
  std::printf(
      "\nacceptance (round trip < 1e-4, clean mean < 1 mm & max < 5 mm, noisy mean rot <= 2 deg & "
      "every joint p99 <= 10 deg): %s\n",
      ok ? "PASS" : "FAIL");
  return ok ? 0 : 1;
}

int main(int argc, char** argv) {
  return mocapd::bench::RunReportingErrors("ik_accuracy", RunProgram, argc, argv);
}
