// Calibration from markers alone (issue "Subject calibration from markers alone"):
// marker takes synthesized on skeletons with known joint centres (the built-in humanoid
// at three heights doing a range of motion or walking; the ../shared Bandai takes when
// present), with 1 mm noise and soft-tissue wobble, calibrated from their labelled
// markers alone (the set recognised from the labels), then solved frame by frame. Reports
// per case the error of the anatomical joint centres (hips, knees, ankles, shoulders,
// elbows, wrists) of the solved skeleton against the truth, matched by role (median, p95,
// max over joint-frames), the worst bone-length error (thigh, shin, upper arm, forearm),
// the hip's error and the method the report gives it, the neck's and head's centres (no
// marker rides the link between them), how far the trunk's joints sit beside the midline
// in the calibrated rest pose, and the calibration's time.
// Usage: calibration_accuracy [--set NAME]... [--wobble-mm W]... [TAKE.bvh ...]
// MOCAPD_BENCH_ROLES=1 also prints each centre's median / p95 and each bone's length.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <string>

#include "bench/bench_takes.hpp"
#include "filters/pose_error.hpp"
#include "formats/marker_set.hpp"
#include "formats/subject_from_markers.hpp"
#include "sim/humanoid.hpp"
#include "sim/synthesis.hpp"

using namespace mocapd;

namespace {

const char* kCentres[] = {"thigh_l",   "thigh_r",   "shin_l",      "shin_r",
                          "foot_l",    "foot_r",    "upper_arm_l", "upper_arm_r",
                          "forearm_l", "forearm_r", "hand_l",      "hand_r"};
// The trunk's joints whose place is anatomical in any rig (the base of the neck, the base
// of the skull); reported on their own, not in the centres' figures above.
const char* kTrunkCentres[] = {"neck", "head"};
const char* kBones[] = {"shin_l",    "shin_r",    "foot_l", "foot_r",
                        "forearm_l", "forearm_r", "hand_l", "hand_r"};

struct Case {
  std::string name;
  Skeleton skeleton{{Joint{.name = "root", .parent = {}}}};
  std::vector<BvhEndSite> end_sites;
  std::vector<Pose> motion;  // 120 Hz
};

struct Outcome {
  std::vector<double> errors;  // per joint-frame, m
  std::map<std::string, std::vector<double>> by_role;
  double worst_bone_percent = 0.0;
  double hip_median_m = 0.0;
  std::string hip_method;
  double seconds = 0.0;
  double residual_mm = 0.0;
  std::vector<double> trunk_errors;  // neck and head centres, per frame, m
  double worst_midline_m = 0.0;
  std::string failure;
};

double Quant(std::vector<double> v, double q) {
  if (v.empty()) return kNaN;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())))];
}

Outcome Run(const Case& c, const MarkerSetDefinition& set, double wobble_m) {
  Outcome o;
  const HumanoidRoles truth_roles = MatchHumanoidRoles(c.skeleton);
  const MarkerSet markers(c.skeleton, PlaceMarkerSet(c.skeleton, truth_roles, set, c.end_sites));
  SynthesisNoise noise;
  noise.noise_sigma_m = 0.001;
  noise.soft_tissue_m = wobble_m;
  noise.seed = 3;
  const C3dTake take = SynthesizeMarkers(c.skeleton, markers, c.motion, 120.0, noise);
  const auto t0 = std::chrono::steady_clock::now();
  MarkersOnlyCalibration cal;
  try {
    cal = CalibrateFromMarkers(std::span<const C3dTake>(&take, 1), MarkersOnlyOptions{}, "bench");
  } catch (const std::exception& e) {
    o.failure = e.what();
    return o;
  }
  o.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  o.residual_mm = cal.solve.median_residual_m * 1e3;
  const Skeleton& sk = *cal.model.skeleton;
  const MarkerSet& calibrated = *cal.model.markers;
  // The calibrated markers in the take's point order.
  std::vector<int> point_of(static_cast<size_t>(calibrated.num_markers()));
  for (int m = 0; m < calibrated.num_markers(); ++m)
    point_of[static_cast<size_t>(m)] = take.FindLabel(calibrated.marker(m).name);
  IkState state(sk, calibrated);
  KinematicsWorkspace truth(c.skeleton), solved(sk);
  std::vector<Vec3> targets(static_cast<size_t>(calibrated.num_markers()));
  std::vector<double> weights(targets.size(), 1.0);
  std::vector<double> hip;
  for (int f = 0; f < take.num_frames; ++f) {
    for (size_t m = 0; m < targets.size(); ++m) targets[m] = take.at(f, point_of[m]);
    (void)SolveIk(sk, calibrated, IkOptions{}, targets, weights, &state);
    if (f < 30 || f % 4 != 0) continue;
    ForwardKinematics(c.skeleton, c.motion[static_cast<size_t>(f)], &truth);
    ForwardKinematics(sk, state.pose(), &solved);
    for (const char* role : kCentres) {
      const auto t = static_cast<size_t>(truth_roles.joint_of_role.at(role));
      const auto s = static_cast<size_t>(sk.FindJoint(role)->value);
      const double e = (solved.p_WJ[s] - truth.p_WJ[t]).norm();
      o.errors.push_back(e);
      o.by_role[role].push_back(e);
      if (std::string(role).rfind("thigh", 0) == 0) hip.push_back(e);
    }
    for (const char* role : kTrunkCentres) {
      const auto t = static_cast<size_t>(truth_roles.joint_of_role.at(role));
      const auto s = static_cast<size_t>(sk.FindJoint(role)->value);
      o.trunk_errors.push_back((solved.p_WJ[s] - truth.p_WJ[t]).norm());
      o.by_role[role].push_back(o.trunk_errors.back());
    }
  }
  o.hip_median_m = Quant(hip, 0.5);
  // How far a joint of the trunk (no mirror image) sits beside its parent's midline plane:
  // a body has its spine, neck and head on it.
  for (int j = 1; j < sk.num_joints(); ++j)
    if (MirrorRole(sk.joint(j).name).empty())
      o.worst_midline_m = std::max(o.worst_midline_m, std::abs(sk.joint(j).offset.x()));
  o.hip_method = cal.solve.joints[static_cast<size_t>(sk.FindJoint("thigh_l")->value)].method;
  // Bone lengths: the distance from a joint's parent centre to its own, both skeletons.
  KinematicsWorkspace truth_rest(c.skeleton);
  ForwardKinematics(c.skeleton, RestPose(c.skeleton), &truth_rest);
  for (const char* role : kBones) {
    const int t = truth_roles.joint_of_role.at(role);
    const std::string parent_role = sk.joint(sk.joint(sk.FindJoint(role)->value).parent.value).name;
    const int tp = truth_roles.joint_of_role.at(parent_role);
    const double true_length =
        (truth_rest.p_WJ[static_cast<size_t>(t)] - truth_rest.p_WJ[static_cast<size_t>(tp)]).norm();
    const double length = sk.joint(sk.FindJoint(role)->value).offset.norm();
    o.worst_bone_percent =
        std::max(o.worst_bone_percent, 100.0 * std::abs(length - true_length) / true_length);
    if (std::getenv("MOCAPD_BENCH_ROLES"))
      std::printf("    bone to %s: %.1f vs true %.1f mm\n", role, length * 1e3, true_length * 1e3);
  }
  return o;
}

}  // namespace

int RunProgram(int argc, char** argv) {
  std::vector<std::string> sets, paths;
  std::vector<double> wobbles;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--set") == 0 && i + 1 < argc)
      sets.emplace_back(argv[++i]);
    else if (std::strcmp(argv[i], "--wobble-mm") == 0 && i + 1 < argc)
      wobbles.push_back(std::atof(argv[++i]) * 1e-3);
    else
      paths.emplace_back(argv[i]);
  }
  if (sets.empty()) sets = {"plug-in-gait-full", "cmu-41"};
  if (wobbles.empty()) wobbles = {0.005, 0.015};
  if (paths.empty()) paths = bench::SharedBvhTakes();
  std::vector<Case> cases;
  for (double height : {1.60, 1.75, 1.90}) {
    for (const auto& [motion, name] :
         {std::pair{HumanoidMotion::kRom, "rom"}, std::pair{HumanoidMotion::kWalk, "walk"}}) {
      Case c;
      char label[64];
      std::snprintf(label, sizeof(label), "humanoid %.2f m %s 20 s", height, name);
      c.name = label;
      c.skeleton = MakeHumanoidSkeleton(height);
      c.motion = MakeHumanoidMotion(c.skeleton, motion, 20.0, 120.0);
      cases.push_back(std::move(c));
    }
  }
  for (const std::string& path : paths) {
    const bench::BenchTake t = bench::LoadBenchTake(path, 120.0);
    Case c;
    c.name = t.name;
    c.skeleton = t.bvh.skeleton;
    c.end_sites = t.bvh.end_sites;
    c.motion = t.motion;
    cases.push_back(std::move(c));
  }
  std::printf(
      "| take | set | wobble (mm) | centres median / p95 / max (mm) | worst bone (%%) | hip median "
      "(mm), method | neck & head median / max (mm) | trunk off midline (mm) | "
      "residual median (mm) | time (s) |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|\n");
  for (const std::string& set_name : sets) {
    const MarkerSetDefinition set = FindMarkerSet(set_name);
    for (double wobble : wobbles) {
      for (const Case& c : cases) {
        const Outcome o = Run(c, set, wobble);
        if (!o.failure.empty()) {
          std::printf("| %s | %s | %.0f | failed: %s | | | | | | |\n", c.name.c_str(),
                      set_name.c_str(), wobble * 1e3, o.failure.c_str());
          continue;
        }
        std::printf(
            "| %s | %s | %.0f | %.1f / %.1f / %.1f | %.1f | %.1f, %s | %.1f / %.1f | %.1f | %.1f | "
            "%.2f |\n",
            c.name.c_str(), set_name.c_str(), wobble * 1e3, Quant(o.errors, 0.5) * 1e3,
            Quant(o.errors, 0.95) * 1e3, Quant(o.errors, 1.0) * 1e3, o.worst_bone_percent,
            o.hip_median_m * 1e3, o.hip_method.c_str(), Quant(o.trunk_errors, 0.5) * 1e3,
            Quant(o.trunk_errors, 1.0) * 1e3, o.worst_midline_m * 1e3, o.residual_mm, o.seconds);
        if (std::getenv("MOCAPD_BENCH_ROLES")) {
          for (const auto& [role, e] : o.by_role)
            std::printf("    %s %.1f / %.1f mm\n", role.c_str(), Quant(e, 0.5) * 1e3,
                        Quant(e, 0.95) * 1e3);
        }
        std::fflush(stdout);
      }
    }
  }
  return 0;
}

int main(int argc, char** argv) {
  return mocapd::bench::RunReportingErrors("calibration_accuracy", RunProgram, argc, argv);
}
