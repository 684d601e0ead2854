// Retargeting benchmark (issue "Live retargeting"): the ../shared BVH takes (or the
// built-in humanoid) at 120 Hz retargeted onto characters scaled 0.8x and 1.25x and onto
// one with another hierarchy (spine joints merged, scaled 1.1x). Reports per character:
// end-effector (hands, feet, head) position error normalised by the scale (cm), torso
// orientation error (pelvis and chest, deg), foot slide during contacts (cm per contact:
// the character's ankle's horizontal travel while the actor's foot is planted, contacts
// detected by the benchmark itself, not by the retargeter) and the
// per-frame retarget time (p50 / p99, us).
// Usage: retarget_accuracy [TAKE.bvh ...]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>

#include "bench/bench_takes.hpp"
#include "filters/pose_error.hpp"
#include "filters/retarget.hpp"
#include "formats/marker_layout.hpp"
#include "formats/retarget_map.hpp"

using namespace mocapd;

namespace {

std::shared_ptr<const Skeleton> Scaled(const Skeleton& sk, double factor) {
  std::vector<Joint> joints(sk.joints().begin(), sk.joints().end());
  for (Joint& j : joints) j.offset *= factor;
  return std::make_shared<const Skeleton>(std::move(joints));
}

// Merges every spine joint between the pelvis and the chest into one (the chest's
// children hang from the lowest spine joint, their offsets carried through the merged
// joints' rest transforms), then scales: a character with a shorter spine chain.
std::shared_ptr<const Skeleton> MergedSpine(const Skeleton& sk, double factor,
                                            std::string* description) {
  const HumanoidRoles roles = MatchHumanoidRoles(sk);
  if (roles.spine_chain.size() < 2) {
    *description = "spine already one joint; scaled only";
    return Scaled(sk, factor);
  }
  const int keep = roles.spine_chain.front();
  std::vector<int> removed(roles.spine_chain.begin() + 1, roles.spine_chain.end());
  std::vector<int> new_index(static_cast<size_t>(sk.num_joints()), -1);
  std::vector<Joint> joints;
  for (int j = 0; j < sk.num_joints(); ++j) {
    if (std::find(removed.begin(), removed.end(), j) != removed.end()) continue;
    Joint joint = sk.joint(j);
    // Walk up through removed parents, composing their rest transforms into the offset.
    int parent = joint.parent.value;
    while (parent >= 0 && std::find(removed.begin(), removed.end(), parent) != removed.end()) {
      const Joint& p = sk.joint(parent);
      joint.offset = p.offset + p.rest_rotation * joint.offset;
      joint.rest_rotation = p.rest_rotation * joint.rest_rotation;
      parent = p.parent.value;
    }
    joint.parent = parent >= 0 ? JointIndex{new_index[static_cast<size_t>(parent)]} : JointIndex{};
    joint.offset *= factor;
    new_index[static_cast<size_t>(j)] = static_cast<int>(joints.size());
    joints.push_back(joint);
  }
  *description =
      "merged " + std::to_string(removed.size()) + " spine joint(s) into " + sk.joint(keep).name;
  return std::make_shared<const Skeleton>(std::move(joints));
}

struct Scores {
  double effector_cm = 0, torso_deg = 0, slide_cm = 0;
  int contacts = 0, frames = 0;
  std::vector<double> times_us;
};

Mat3 RelativeToRest(const KinematicsWorkspace& now, const KinematicsWorkspace& rest, int j) {
  return now.R_WJ[static_cast<size_t>(j)] * rest.R_WJ[static_cast<size_t>(j)].transpose();
}

Scores Run(const bench::BenchTake& take, std::shared_ptr<const Skeleton> character, Scores* into) {
  auto source = std::make_shared<const Skeleton>(take.bvh.skeleton);
  const RetargetMap map = MakeRetargetMap(*source, take.bvh.end_sites, *character, {});
  RetargetOptions options;
  // Experiments without rebuilding: MOCAPD_EXP_<FIELD>=value.
  auto env = [](const char* name, double* field) {
    if (const char* v = std::getenv(name)) *field = std::atof(v);
  };
  env("MOCAPD_EXP_DAMPING", &options.damping);
  env("MOCAPD_EXP_CONTACT_HEIGHT", &options.contact_height_m);
  env("MOCAPD_EXP_CONTACT_SPEED", &options.contact_speed_m_s);
  env("MOCAPD_EXP_LIMB_WEIGHT", &options.limb_weight);
  env("MOCAPD_EXP_TORSO_WEIGHT", &options.torso_weight);
  env("MOCAPD_EXP_ROOT_WEIGHT", &options.root_weight);
  env("MOCAPD_EXP_CONTACT_GAIN", &options.contact_weight_gain);
  if (const char* v = std::getenv("MOCAPD_EXP_ITERS")) options.max_iterations = std::atoi(v);
  Retargeter retargeter(source, character, map, options);
  const HumanoidRoles sr = MatchHumanoidRoles(*source), tr = MatchHumanoidRoles(*character);
  std::vector<std::pair<int, int>> effectors;
  for (const char* role : {"hand_l", "hand_r", "foot_l", "foot_r", "head"})
    effectors.emplace_back(sr.joint_of_role.at(role), tr.joint_of_role.at(role));
  std::vector<std::pair<int, int>> torso = {
      {sr.joint_of_role.at("pelvis"), tr.joint_of_role.at("pelvis")}};
  if (sr.joint_of_role.count("chest") && tr.joint_of_role.count("chest"))
    torso.emplace_back(sr.joint_of_role.at("chest"), tr.joint_of_role.at("chest"));
  KinematicsWorkspace s_fk(*source), s_rest(*source), t_rest(*character);
  ForwardKinematics(*source, RestPose(*source), &s_rest);
  ForwardKinematics(*character, RestPose(*character), &t_rest);
  const double scale = retargeter.scale();
  std::array<bool, 2> was{false, false};
  std::array<Vec3, 2> start{Vec3::Zero(), Vec3::Zero()};
  std::array<double, 2> travel{0, 0};
  std::array<int, 2> length{0, 0};
  std::array<Vec3, 2> previous_source_ankle{Vec3::Zero(), Vec3::Zero()};
  std::array<double, 2> lowest_ankle{1e9, 1e9};
  for (const Pose& pose : take.motion) {
    ForwardKinematics(*source, pose, &s_fk);
    for (size_t sd = 0; sd < 2; ++sd)
      lowest_ankle[sd] =
          std::min(lowest_ankle[sd], s_fk.p_WJ[static_cast<size_t>(map.source_ankles[sd])].y());
  }
  Scores& s = *into;
  for (size_t f = 0; f < take.motion.size(); ++f) {
    const auto t0 = std::chrono::steady_clock::now();
    retargeter.Retarget(take.motion[f]);
    const auto t1 = std::chrono::steady_clock::now();
    if (f < 24) continue;  // the first 0.2 s settle the character from its rest pose
    s.times_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    ForwardKinematics(*source, take.motion[f], &s_fk);
    const KinematicsWorkspace& t_fk = retargeter.kinematics();
    double e = 0;
    for (const auto& [js, jt] : effectors)
      e += (t_fk.p_WJ[static_cast<size_t>(jt)] / scale - s_fk.p_WJ[static_cast<size_t>(js)]).norm();
    s.effector_cm += e / static_cast<double>(effectors.size()) * 100.0;
    double r = 0;
    for (const auto& [js, jt] : torso) {
      const Mat3 d =
          RelativeToRest(t_fk, t_rest, jt) * RelativeToRest(s_fk, s_rest, js).transpose();
      r += std::acos(std::clamp(0.5 * (d.trace() - 1.0), -1.0, 1.0));
    }
    s.torso_deg += r / static_cast<double>(torso.size()) * 180.0 / M_PI;
    ++s.frames;
    // Contacts as the benchmark sees them, independently of the retargeter's own
    // detector: the actor's ankle within 3 cm of its lowest height in the take and
    // moving slower than 0.2 m/s horizontally, for at least 6 frames.
    for (int side = 0; side < 2; ++side) {
      const auto sd = static_cast<size_t>(side);
      const auto ankle_s = static_cast<size_t>(map.source_ankles[sd]);
      Vec3 sv = s_fk.p_WJ[ankle_s] - previous_source_ankle[sd];
      sv.y() = 0;
      previous_source_ankle[sd] = s_fk.p_WJ[ankle_s];
      const bool planted =
          s_fk.p_WJ[ankle_s].y() < lowest_ankle[sd] + 0.03 && sv.norm() * 120.0 < 0.2;
      Vec3 ankle = t_fk.p_WJ[static_cast<size_t>(map.target_ankles[sd])];
      ankle.y() = 0;
      if (planted && !was[sd]) {
        start[sd] = ankle;
        travel[sd] = 0;
        length[sd] = 0;
      }
      if (planted) {
        travel[sd] = std::max(travel[sd], (ankle - start[sd]).norm());
        ++length[sd];
      }
      if (!planted && was[sd] && length[sd] >= 6) {
        s.slide_cm += travel[sd] * 100.0;
        ++s.contacts;
      }
      was[sd] = planted;
    }
  }
  return s;
}

}  // namespace

int RunBenchmark(int argc, char** argv) {
  std::vector<std::string> paths(argv + 1, argv + argc);
  for (const std::string& path : paths)
    if (path.starts_with("-")) {
      std::fputs("Usage: retarget_accuracy [TAKE.bvh ...]\n", path == "--help" ? stdout : stderr);
      return path == "--help" ? 0 : 2;
    }
  if (paths.empty()) paths = bench::SharedBvhTakes();
  if (paths.empty()) paths.emplace_back("");
  std::map<std::string, Scores> results;
  std::string merged_description;
  for (const std::string& path : paths) {
    const bench::BenchTake take = bench::LoadBenchTake(path, 120.0);
    const Skeleton& sk = take.bvh.skeleton;
    Run(take, Scaled(sk, 0.8), &results["scaled 0.8x"]);
    Run(take, Scaled(sk, 1.25), &results["scaled 1.25x"]);
    Run(take, MergedSpine(sk, 1.1, &merged_description), &results["merged spine, 1.1x"]);
  }
  std::printf("%zu takes at 120 Hz; different hierarchy: %s\n\n", paths.size(),
              merged_description.c_str());
  std::printf(
      "| character | end-effector error / scale (cm) | torso orientation (deg) | foot slide per "
      "contact (cm) | contacts | per-frame p50 / p99 (us) |\n");
  std::printf("|---|---|---|---|---|---|\n");
  for (const char* name : {"scaled 0.8x", "scaled 1.25x", "merged spine, 1.1x"}) {
    const Scores& s = results[name];
    std::printf("| %s | %.3f | %.2f | %.3f | %d | %.1f / %.1f |\n", name, s.effector_cm / s.frames,
                s.torso_deg / s.frames, s.contacts > 0 ? s.slide_cm / s.contacts : 0.0, s.contacts,
                Quantile(s.times_us, 0.5), Quantile(s.times_us, 0.99));
  }
  return 0;
}

int main(int argc, char** argv) {
  return mocapd::bench::RunReportingErrors("retarget_accuracy", RunBenchmark, argc, argv);
}
