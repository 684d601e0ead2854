// The cleanup with a subject calibrated from markers alone, against the same cleanup given
// the true skeleton (issue "Subject calibration from markers alone", the markers-only row):
// BVH takes (the ../shared Bandai takes when present, else the built-in humanoid) at
// 120 Hz with an industry marker set placed on the true skeleton; the subject is
// calibrated from the clean take's markers alone (the calibration take), then both
// subjects clean the same corrupted markers at K = 12. Reported per row: the mean
// joint-centre position error against the truth, joints matched by role (cm; for the true
// skeleton, its own joints), and the cleaned-marker RMSE on corrupted samples (mm).
// Usage: markers_only_accuracy [--set NAME] [--severity light|medium|heavy] [--seeds N]
// [--lookahead K] [TAKE.bvh ...]
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "bench/bench_takes.hpp"
#include "filters/cleanup_pipeline.hpp"
#include "formats/subject_from_markers.hpp"
#include "sim/corruption.hpp"
#include "sim/synthesis.hpp"

using namespace mocapd;

namespace {

struct RowScore {
  double position_sum_m = 0.0;
  long positions = 0;
  std::vector<double> joint_sum_m;  ///< Per subject joint (MOCAPD_BENCH_ROLES=1 prints them).
  std::vector<long> joint_count;
  double marker_sum_sq = 0.0;
  long markers = 0;
  void Merge(const RowScore& o) {
    position_sum_m += o.position_sum_m;
    positions += o.positions;
    marker_sum_sq += o.marker_sum_sq;
    markers += o.markers;
    joint_sum_m.resize(std::max(joint_sum_m.size(), o.joint_sum_m.size()), 0.0);
    joint_count.resize(joint_sum_m.size(), 0);
    for (size_t j = 0; j < o.joint_sum_m.size(); ++j) {
      joint_sum_m[j] += o.joint_sum_m[j];
      joint_count[j] += o.joint_count[j];
    }
  }
  double position_cm() const { return positions ? position_sum_m / positions * 100 : NAN; }
  double marker_mm() const { return markers ? std::sqrt(marker_sum_sq / markers) * 1e3 : NAN; }
};

// Cleans the corrupted take with a subject; point_of_marker maps the subject's markers to
// the take's points; joint_of_truth maps the subject's joints to the truth's (-1: unmatched).
RowScore Clean(const SubjectModel& subject, const std::vector<int>& point_of_marker,
               const std::vector<int>& joint_of_truth, const Skeleton& truth,
               const std::vector<Pose>& motion, const C3dTake& clean, const CorruptedTake& bad,
               double rate, int lookahead) {
  CleanupOptions options;
  options.rate_hz = rate;
  options.lookahead = lookahead;
  CleanupPipeline pipeline(subject.skeleton, subject.markers, options);
  KinematicsWorkspace solved(*subject.skeleton), truth_ws(truth);
  RowScore score;
  score.joint_sum_m.assign(joint_of_truth.size(), 0.0);
  score.joint_count.assign(joint_of_truth.size(), 0);
  const size_t markers = point_of_marker.size();
  std::vector<Vec3> frame(markers);
  auto take = [&] {
    const CleanFrame& out = pipeline.output();
    const auto f = static_cast<int>(out.frame);
    ForwardKinematics(*subject.skeleton, out.pose, &solved);
    ForwardKinematics(truth, motion[static_cast<size_t>(f)], &truth_ws);
    for (size_t j = 0; j < joint_of_truth.size(); ++j) {
      if (joint_of_truth[j] < 0) continue;
      const double error =
          (solved.p_WJ[j] - truth_ws.p_WJ[static_cast<size_t>(joint_of_truth[j])]).norm();
      score.position_sum_m += error;
      ++score.positions;
      score.joint_sum_m[j] += error;
      ++score.joint_count[j];
    }
    for (size_t m = 0; m < markers; ++m) {
      const int p = point_of_marker[m];
      if (bad.at(f, p) == CorruptionKind::kNone || !out.markers[m].allFinite()) continue;
      score.marker_sum_sq += (out.markers[m] - clean.at(f, p)).squaredNorm();
      ++score.markers;
    }
  };
  for (int f = 0; f < bad.take.num_frames; ++f) {
    for (size_t m = 0; m < markers; ++m) {
      const int p = point_of_marker[m];
      frame[m] = bad.take.valid(f, p) ? bad.take.at(f, p) : Vec3::Constant(NAN);
    }
    if (pipeline.Push(frame)) take();
  }
  while (pipeline.Flush()) take();
  return score;
}

}  // namespace

int RunProgram(int argc, char** argv) {
  std::string set_name = "plug-in-gait-full";
  std::string severity = "medium";
  int seeds = 2, lookahead = 12;
  std::vector<std::string> paths;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--set") && i + 1 < argc)
      set_name = argv[++i];
    else if (!std::strcmp(argv[i], "--severity") && i + 1 < argc)
      severity = argv[++i];
    else if (!std::strcmp(argv[i], "--seeds") && i + 1 < argc)
      seeds = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--lookahead") && i + 1 < argc)
      lookahead = std::atoi(argv[++i]);
    else if (argv[i][0] != '-')
      paths.emplace_back(argv[i]);
    else {
      std::fprintf(stderr,
                   "usage: markers_only_accuracy [--set NAME] [--severity S] [--seeds N] "
                   "[--lookahead K] [TAKE.bvh ...]\n");
      return 2;
    }
  }
  if (paths.empty()) paths = bench::SharedBvhTakes();
  if (paths.empty()) paths.emplace_back("");  // the built-in humanoid
  const double rate = 120.0;
  const MarkerSetDefinition set = FindMarkerSet(set_name);
  RowScore given_all, calibrated_all;
  std::printf(
      "| take | true skeleton: joints cm / markers mm | markers only: joints cm / markers mm |\n");
  std::printf("|---|---|---|\n");
  for (const std::string& path : paths) {
    const bench::BenchTake take = bench::LoadBenchTake(path, rate);
    const Skeleton& truth = take.bvh.skeleton;
    const HumanoidRoles roles = MatchHumanoidRoles(truth);
    SubjectModel given;
    given.skeleton = std::make_shared<const Skeleton>(truth);
    given.markers = std::make_shared<const MarkerSet>(
        truth, PlaceMarkerSet(truth, roles, set, take.bvh.end_sites));
    SynthesisNoise noise;
    noise.noise_sigma_m = 0.0005;
    const C3dTake clean = SynthesizeMarkers(truth, *given.markers, take.motion, rate, noise);

    // The calibration take: the clean markers alone.
    MarkersOnlyOptions options;
    options.marker_set = set_name;
    const MarkersOnlyCalibration calibration =
        CalibrateFromMarkers(std::span<const C3dTake>(&clean, 1), options, "actor");
    std::vector<int> calibrated_points, given_points;
    for (const std::string& label : calibration.markers)
      calibrated_points.push_back(clean.FindLabel(label));
    for (int p = 0; p < clean.num_points(); ++p) given_points.push_back(p);
    std::vector<int> calibrated_joints, given_joints;
    for (int j = 0; j < calibration.model.skeleton->num_joints(); ++j) {
      const auto found = roles.joint_of_role.find(calibration.model.skeleton->joint(j).name);
      calibrated_joints.push_back(found == roles.joint_of_role.end() ? -1 : found->second);
    }
    // The true skeleton is scored on the same roles.
    given_joints.assign(static_cast<size_t>(truth.num_joints()), -1);
    for (int j : calibrated_joints)
      if (j >= 0) given_joints[static_cast<size_t>(j)] = j;

    RowScore given_take, calibrated_take;
    for (int seed = 1; seed <= seeds; ++seed) {
      CorruptionOptions co;
      co.severity = ParseCorruptionSeverity(severity);
      co.seed = static_cast<uint64_t>(seed);
      const CorruptedTake bad = CorruptTake(clean, given.markers.get(), co);
      given_take.Merge(Clean(given, given_points, given_joints, truth, take.motion, clean, bad,
                             rate, lookahead));
      calibrated_take.Merge(Clean(calibration.model, calibrated_points, calibrated_joints, truth,
                                  take.motion, clean, bad, rate, lookahead));
    }
    std::printf("| %s | %.2f / %.1f | %.2f / %.1f |\n", take.name.c_str(), given_take.position_cm(),
                given_take.marker_mm(), calibrated_take.position_cm(), calibrated_take.marker_mm());
    std::fflush(stdout);
    given_all.Merge(given_take);
    calibrated_all.Merge(calibrated_take);
  }
  if (std::getenv("MOCAPD_BENCH_ROLES")) {
    // Per role, markers only (the calibrated skeleton's joints are named by role).
    const Skeleton templ = MakeTemplateHumanoid();
    for (size_t j = 0; j < calibrated_all.joint_sum_m.size(); ++j)
      if (calibrated_all.joint_count[j] > 0)
        std::printf("  %-12s %.2f cm\n", templ.joint(static_cast<int>(j)).name.c_str(),
                    calibrated_all.joint_sum_m[j] / calibrated_all.joint_count[j] * 100);
  }
  std::printf("| all (%s, %s, K = %d, %d seeds) | %.2f / %.1f | %.2f / %.1f |\n", set_name.c_str(),
              severity.c_str(), lookahead, seeds, given_all.position_cm(), given_all.marker_mm(),
              calibrated_all.position_cm(), calibrated_all.marker_mm());
  return 0;
}

int main(int argc, char** argv) {
  return mocapd::bench::RunReportingErrors("markers_only_accuracy", RunProgram, argc, argv);
}
