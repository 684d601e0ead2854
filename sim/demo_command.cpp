// `mocapd demo` implementation.
#include "sim/demo_command.hpp"

#include <chrono>
#include <cstdio>
#include <random>
#include <vector>

#include "filters/ik_solver.hpp"
#include "filters/pose_error.hpp"
#include "formats/marker_layout.hpp"
#include "formats/take_frames.hpp"
#include "sim/humanoid.hpp"
#include "sim/synthesis.hpp"

namespace mocapd {

int RunDemoCommand(const DemoOptions& options, std::ostream& out) {
  const Skeleton skeleton = MakeHumanoidSkeleton(1.75);
  const HumanoidRoles roles = MatchHumanoidRoles(skeleton);
  const MarkerSet markers(skeleton, PlaceMarkers(skeleton, roles, DefaultMarkerLayout(), {}));
  const std::vector<Pose> truth = MakeHumanoidMotion(skeleton, ParseHumanoidMotion(options.motion),
                                                     options.seconds, options.rate_hz);
  std::mt19937_64 rng(options.seed);
  const C3dTake take =
      SynthesizeMarkers(skeleton, markers, truth, options.rate_hz, options.noise_mm * 1e-3, &rng);
  char line[256];
  std::snprintf(line, sizeof(line),
                "mocapd demo: %s motion, %.1f s at %.0f Hz (%d frames), %d joints / %d DOF, %d "
                "markers, %.1f mm noise\n",
                options.motion.c_str(), options.seconds, options.rate_hz, take.num_frames,
                skeleton.num_joints(), skeleton.num_dofs(), markers.num_markers(),
                options.noise_mm);
  out << line << std::flush;

  IkOptions ik_options;
  ik_options.Validate();
  IkState state(skeleton, markers);
  const TakeMarkerMap map(markers, take);
  std::vector<Vec3> observed(static_cast<size_t>(markers.num_markers()));
  std::vector<double> weights(observed.size());
  PoseErrorAccumulator errors(skeleton);
  KinematicsWorkspace truth_fk(skeleton);
  std::vector<double> solve_us;
  solve_us.reserve(static_cast<size_t>(take.num_frames));
  long iterations = 0;
  const int report_every = static_cast<int>(options.rate_hz * 2.0);
  for (int f = 0; f < take.num_frames; ++f) {
    map.Observe(take, f, observed, weights);
    const auto t0 = std::chrono::steady_clock::now();
    const IkSummary summary = SolveIk(skeleton, markers, ik_options, observed, weights, &state);
    const auto t1 = std::chrono::steady_clock::now();
    solve_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    iterations += summary.iterations;
    ForwardKinematics(skeleton, truth[static_cast<size_t>(f)], &truth_fk);
    errors.Add(truth_fk, state.kinematics());
    if (f % report_every == 0 || f + 1 == take.num_frames) {
      std::snprintf(line, sizeof(line),
                    "  frame %5d  t=%5.1fs  %-10s iters %2d  marker rms %5.2f mm  solve %6.1f us\n",
                    f, f / options.rate_hz, to_string(summary.status), summary.iterations,
                    summary.rms_residual_m * 1e3, solve_us.back());
      out << line << std::flush;
    }
  }
  // The first frame is a cold start; report it apart from the warm-started ones.
  const double cold_us = solve_us.front();
  std::vector<double> warm(solve_us.begin() + 1, solve_us.end());
  auto row = [&](const char* name, double value, int decimals) {
    std::snprintf(line, sizeof(line), "%-34s %10.*f\n", name, decimals, value);
    out << line;
  };
  out << "\n";
  row("joint position error mean (mm)", errors.mean_position_error_m() * 1e3, 3);
  row("joint position error max (mm)", errors.max_position_error_m() * 1e3, 3);
  row("joint rotation error mean (deg)", errors.mean_rotation_error_rad() * 180 / M_PI, 3);
  row("worst joint p99 rotation (deg)", errors.worst_joint_rotation_quantile_rad(0.99) * 180 / M_PI,
      3);
  row("warm solve p50 (us)", Quantile(warm, 0.5), 1);
  row("warm solve p99 (us)", Quantile(warm, 0.99), 1);
  row("cold first-frame solve (us)", cold_us, 1);
  row("mean LM iterations / frame", static_cast<double>(iterations) / take.num_frames, 2);
  return 0;
}

}  // namespace mocapd
