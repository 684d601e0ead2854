// Role matching between an actor's and a character's skeletons.
#include "formats/retarget_map.hpp"

#include <algorithm>
#include <array>
#include <optional>
#include <set>
#include <stdexcept>
#include <tuple>

#include "formats/marker_layout.hpp"

namespace mocapd {
namespace {

struct RoleSpec {
  const char* role;
  RetargetRegion region;
  int foot_side;
};

// Every role that can carry surface points, and what it tracks.
constexpr RoleSpec kRoles[] = {
    {"pelvis", RetargetRegion::kTorso, -1},       {"spine", RetargetRegion::kTorso, -1},
    {"chest", RetargetRegion::kTorso, -1},        {"neck", RetargetRegion::kLimb, -1},
    {"head", RetargetRegion::kTorso, -1},         {"clavicle_l", RetargetRegion::kLimb, -1},
    {"clavicle_r", RetargetRegion::kLimb, -1},    {"upper_arm_l", RetargetRegion::kLimb, -1},
    {"upper_arm_r", RetargetRegion::kLimb, -1},   {"forearm_l", RetargetRegion::kLimb, -1},
    {"forearm_r", RetargetRegion::kLimb, -1},     {"hand_l", RetargetRegion::kEndEffector, -1},
    {"hand_r", RetargetRegion::kEndEffector, -1}, {"thigh_l", RetargetRegion::kLimb, -1},
    {"thigh_r", RetargetRegion::kLimb, -1},       {"shin_l", RetargetRegion::kLimb, -1},
    {"shin_r", RetargetRegion::kLimb, -1},        {"foot_l", RetargetRegion::kEndEffector, 0},
    {"foot_r", RetargetRegion::kEndEffector, 1},  {"toe_l", RetargetRegion::kEndEffector, 0},
    {"toe_r", RetargetRegion::kEndEffector, 1},
};

const char* RegionName(RetargetRegion r) {
  return r == RetargetRegion::kEndEffector ? "position"
         : r == RetargetRegion::kTorso     ? "normals (torso)"
                                           : "normals (limb)";
}

// The leg's length along its bones, hip to ankle, averaged over both legs.
double LegLength(const Skeleton& sk, const HumanoidRoles& roles, const char* which) {
  double total = 0.0;
  int legs = 0;
  for (const auto& [hip_role, ankle_role] :
       {std::pair{"thigh_l", "foot_l"}, {"thigh_r", "foot_r"}}) {
    const auto hip = roles.joint_of_role.find(hip_role);
    const auto ankle = roles.joint_of_role.find(ankle_role);
    if (hip == roles.joint_of_role.end() || ankle == roles.joint_of_role.end()) continue;
    double length = 0.0;
    int j = ankle->second;
    while (j > hip->second) {
      length += sk.joint(j).offset.norm();
      j = sk.joint(j).parent;
    }
    if (j != hip->second) continue;  // the ankle is not below that hip
    total += length;
    ++legs;
  }
  if (legs == 0 || !(total > 0.0))
    throw std::invalid_argument(std::string("retarget: the ") + which +
                                " has no leg from a hip (thigh) down to an ankle (foot)");
  return total / legs;
}

// The pelvis's rest height above the lowest joint below it, or below a foot with no toe
// joint its End Site: hip drop, leg and ankle height, what the pelvis stands at. Only the
// pelvis's own subtree counts: a joint above it (Bandai's joint_Root at the floor origin)
// is no part of a leg, and counting it made this the pelvis's height above that origin,
// wherever the file put it (a one-frame character file: where the take starts; the same
// rig animated: its OFFSET). A toe's End Site does not count: the ball of the foot is
// what stands, and a tip a file (or NominalLeafEndSites, continuing the foot's slope) puts
// lower would make one rig stand at two heights, with End Sites and without. A foot with
// no End Site stands on the one a BVH writer gives it (NominalLeafEndSites), for the same
// reason.
double StandingHeight(const Skeleton& sk, const HumanoidRoles& roles,
                      const KinematicsWorkspace& rest, std::span<const BvhEndSite> end_sites,
                      const Vec3& up) {
  const int pelvis = roles.joint_of_role.at("pelvis");
  std::vector<uint8_t> below(static_cast<size_t>(sk.num_joints()), 0);
  below[static_cast<size_t>(pelvis)] = 1;
  double lowest = rest.p_WJ[static_cast<size_t>(pelvis)].dot(up);
  for (int j = pelvis + 1; j < sk.num_joints(); ++j) {  // parents come before children
    const JointIndex parent = sk.joint(j).parent;
    if (!parent.is_valid() || !below[static_cast<size_t>(parent.value)]) continue;
    below[static_cast<size_t>(j)] = 1;
    lowest = std::min(lowest, rest.p_WJ[static_cast<size_t>(j)].dot(up));
  }
  auto is_foot_leaf = [&](int j) {
    for (const char* foot : {"foot_l", "foot_r"})
      if (const auto f = roles.joint_of_role.find(foot);
          f != roles.joint_of_role.end() && f->second == j && below[static_cast<size_t>(j)] &&
          sk.children(j).empty())
        return true;
    return false;
  };
  std::vector<BvhEndSite> soles;
  for (const BvhEndSite& e : end_sites)
    if (is_foot_leaf(e.parent)) soles.push_back(e);
  for (const BvhEndSite& nominal : NominalLeafEndSites(sk))
    if (is_foot_leaf(nominal.parent) &&
        std::none_of(end_sites.begin(), end_sites.end(),
                     [&](const BvhEndSite& e) { return e.parent == nominal.parent; }))
      soles.push_back(nominal);
  for (const BvhEndSite& e : soles)
    lowest = std::min(lowest, Vec3(rest.R_WJ[static_cast<size_t>(e.parent)] * e.offset +
                                   rest.p_WJ[static_cast<size_t>(e.parent)])
                                  .dot(up));
  return rest.p_WJ[static_cast<size_t>(pelvis)].dot(up) - lowest;
}

// The scale of the actor's positions onto the character, as two lengths. Where both rigs
// stand in their rest poses, the pelvis's standing height (hip drop and ankle height
// included: the pelvis is placed at the actor's scaled by it, and with the legs alone a
// character with proportionally longer legs stood on overstretched ones and its planted
// feet slid 7 mm). A rest pose need not stand (Bandai's, all rotations zero, folds its
// legs to 6.5 cm): then both are measured along the legs' bones, hip to ankle.
std::pair<double, double> ScaleLengths(const Skeleton& source, const HumanoidRoles& source_roles,
                                       const KinematicsWorkspace& source_rest,
                                       std::span<const BvhEndSite> source_end_sites,
                                       const Vec3& source_up, const Skeleton& target,
                                       const HumanoidRoles& target_roles,
                                       const KinematicsWorkspace& target_rest,
                                       std::span<const BvhEndSite> target_end_sites,
                                       const Vec3& target_up) {
  const double source_legs = LegLength(source, source_roles, "actor");
  const double target_legs = LegLength(target, target_roles, "character");
  const double source_standing =
      StandingHeight(source, source_roles, source_rest, source_end_sites, source_up);
  const double target_standing =
      StandingHeight(target, target_roles, target_rest, target_end_sites, target_up);
  // Standing: the pelvis at least as high above its lowest point as the legs are long
  // (less 10 %, for a rig whose knees are a little bent at rest).
  if (source_standing >= 0.9 * source_legs && target_standing >= 0.9 * target_legs)
    return {source_standing, target_standing};
  return {source_legs, target_legs};
}

// The body's forward and left in a rig's rest pose, from a left-right pair of joints and
// the way up from one joint to another: left x up, with Y up and X left, is forward (+Z).
// Empty where the pair or the way up is missing or they are parallel.
std::optional<std::pair<Vec3, Vec3>> BodyAxes(const HumanoidRoles& roles,
                                              const KinematicsWorkspace& rest,
                                              const char* left_role, const char* right_role,
                                              const char* low_role,
                                              std::initializer_list<const char*> high_roles) {
  auto at = [&](const char* role) -> std::optional<Vec3> {
    const auto r = roles.joint_of_role.find(role);
    if (r == roles.joint_of_role.end()) return std::nullopt;
    return rest.p_WJ[static_cast<size_t>(r->second)];
  };
  const auto l = at(left_role), r = at(right_role), low = at(low_role);
  std::optional<Vec3> high;
  for (const char* role : high_roles)
    if (!high) high = at(role);
  if (!l || !r || !low || !high) return std::nullopt;
  const Vec3 up = *high - *low;
  if (up.norm() < 1e-6) return std::nullopt;
  const Vec3 up_unit = up.normalized();
  Vec3 left = *l - *r;
  left -= left.dot(up_unit) * up_unit;
  if (left.norm() < 1e-6) return std::nullopt;
  left.normalize();
  return std::pair{left.cross(up_unit), left};
}

// Forward and left for each half of a rig: the hips' (pelvis, spine, legs) and the
// shoulders' (chest, neck, head, arms). A rig's joints need not agree on which way is
// forward at rest (Bandai's, all rotations zero: its hips face +Z and its chest +Y), so
// each bone takes its own half's; either half stands in for a missing other, and the
// world's axes for both.
std::array<std::pair<Vec3, Vec3>, 2> HalfBodyAxes(const HumanoidRoles& roles,
                                                  const KinematicsWorkspace& rest) {
  auto lower = BodyAxes(roles, rest, "thigh_l", "thigh_r", "pelvis", {"spine", "chest", "neck"});
  auto upper = BodyAxes(roles, rest, "upper_arm_l", "upper_arm_r", "chest", {"neck", "head"});
  const std::pair<Vec3, Vec3> world{Vec3::UnitZ(), Vec3::UnitX()};
  return {lower ? *lower : upper ? *upper : world, upper ? *upper : lower ? *lower : world};
}

// The hips' way up in a rig's rest pose (toward the spine, neck or head), world frame.
Vec3 HipsUp(const HumanoidRoles& roles, const KinematicsWorkspace& rest) {
  const Vec3& pelvis = rest.p_WJ[static_cast<size_t>(roles.joint_of_role.at("pelvis"))];
  for (const char* role : {"spine", "chest", "neck", "head"})
    if (const auto r = roles.joint_of_role.find(role); r != roles.joint_of_role.end()) {
      const Vec3 up = rest.p_WJ[static_cast<size_t>(r->second)] - pelvis;
      if (up.norm() > 1e-6) return up.normalized();
    }
  return Vec3::UnitY();
}

// The world axis a rig stands on in its rest pose: its hips' way up, snapped to the
// nearest axis, where both legs hang the other way from it; +Y (BVH's convention) where
// they do not (Bandai's rest pose, all rotations zero, lays its legs along the spine).
Vec3 RestUp(const HumanoidRoles& roles, const KinematicsWorkspace& rest) {
  const Vec3 hips_up = HipsUp(roles, rest);
  for (const auto& [hip, ankle] : {std::pair{"thigh_l", "foot_l"}, {"thigh_r", "foot_r"}}) {
    const auto h = roles.joint_of_role.find(hip), a = roles.joint_of_role.find(ankle);
    if (h == roles.joint_of_role.end() || a == roles.joint_of_role.end()) return Vec3::UnitY();
    const Vec3 leg =
        rest.p_WJ[static_cast<size_t>(a->second)] - rest.p_WJ[static_cast<size_t>(h->second)];
    if (!(leg.norm() > 1e-6) || leg.normalized().dot(hips_up) > -0.8) return Vec3::UnitY();
  }
  return NearestAxis(hips_up);
}

bool InUpperBody(const std::string& role) {
  for (const char* prefix :
       {"spine", "chest", "neck", "head", "clavicle", "upper_arm", "forearm", "hand"})
    if (role.rfind(prefix, 0) == 0) return true;
  return false;
}

// The rest pose's extent along the way it stands, for nominal end-segment lengths (along
// +Y, a rig standing on +Z measured its width, and its hands and head came out another
// length than the same rig's standing on +Y).
double Height(const KinematicsWorkspace& rest, const Vec3& up) {
  double lo = 1e9, hi = -1e9;
  for (const Vec3& p : rest.p_WJ) {
    lo = std::min(lo, p.dot(up));
    hi = std::max(hi, p.dot(up));
  }
  return std::clamp(hi - lo, 0.5, 2.5);
}

}  // namespace

RetargetMap MakeRetargetMap(const Skeleton& source, std::span<const BvhEndSite> source_end_sites,
                            const Skeleton& target, std::span<const BvhEndSite> target_end_sites,
                            const std::map<std::string, std::string>& overrides) {
  const HumanoidRoles source_roles = MatchHumanoidRoles(source);
  HumanoidRoles target_roles = MatchHumanoidRoles(target);
  std::set<std::string> known;
  for (const RoleSpec& r : kRoles) known.insert(r.role);
  for (const auto& [role, joint] : overrides) {
    if (!known.count(role))
      throw std::invalid_argument("retarget joint map: unknown role '" + role + "'");
    const auto j = target.FindJoint(joint);
    if (!j)
      throw std::invalid_argument("retarget joint map: the character has no joint '" + joint +
                                  "' (for role " + role + ")");
    target_roles.joint_of_role[role] = j->value;
  }
  // One character joint plays one role: two would pull it two ways (a joint map giving
  // both hands one joint, or a hand the hips, was accepted without a word).
  std::map<int, std::string> role_of_joint;
  for (const RoleSpec& spec : kRoles) {
    const auto t = target_roles.joint_of_role.find(spec.role);
    if (t == target_roles.joint_of_role.end()) continue;
    const auto [it, fresh] = role_of_joint.emplace(t->second, spec.role);
    if (!fresh)
      throw std::invalid_argument("retarget joint map: the character's joint '" +
                                  target.joint(t->second).name + "' is given two roles, " +
                                  it->second + " and " + spec.role);
  }
  KinematicsWorkspace source_rest(source), target_rest(target);
  ForwardKinematics(source, RestPose(source), &source_rest);
  ForwardKinematics(target, RestPose(target), &target_rest);
  const auto source_axes = HalfBodyAxes(source_roles, source_rest);
  const auto target_axes = HalfBodyAxes(target_roles, target_rest);

  RetargetMap map;
  map.source_root = source_roles.joint_of_role.at("pelvis");
  map.target_root = target_roles.joint_of_role.at("pelvis");
  const Vec3 source_up = RestUp(source_roles, source_rest);
  map.target_up = RestUp(target_roles, target_rest);
  map.source_hips_up = source_rest.R_WJ[static_cast<size_t>(map.source_root)].transpose() *
                       HipsUp(source_roles, source_rest);
  const double source_height = Height(source_rest, source_up);
  const double target_height = Height(target_rest, map.target_up);
  std::tie(map.source_leg_length_m, map.target_leg_length_m) =
      ScaleLengths(source, source_roles, source_rest, source_end_sites, source_up, target,
                   target_roles, target_rest, target_end_sites, map.target_up);
  map.source_ankles = {source_roles.joint_of_role.at("foot_l"),
                       source_roles.joint_of_role.at("foot_r")};
  map.target_ankles = {target_roles.joint_of_role.at("foot_l"),
                       target_roles.joint_of_role.at("foot_r")};
  std::set<int> covered;
  std::string matched, missing;
  for (const RoleSpec& spec : kRoles) {
    const auto s = source_roles.joint_of_role.find(spec.role);
    const auto t = target_roles.joint_of_role.find(spec.role);
    if (s == source_roles.joint_of_role.end() || t == target_roles.joint_of_role.end()) {
      missing += std::string(missing.empty() ? "" : ", ") + spec.role;
      continue;
    }
    RetargetBone bone;
    bone.role = spec.role;
    bone.source_joint = s->second;
    bone.target_joint = t->second;
    bool source_nominal = false, target_nominal = false;
    bone.source_bone = SegmentBoneWorld(source, source_roles, source_rest, source_end_sites,
                                        spec.role, s->second, source_height, &source_nominal);
    bone.target_bone = SegmentBoneWorld(target, target_roles, target_rest, target_end_sites,
                                        spec.role, t->second, target_height, &target_nominal);
    // An end segment one rig's file closes with an End Site and the other's leaves open
    // (a subject has none, a character file has them): the open one is as long as the
    // closed one, scaled. Its nominal length would place the end effector's surface
    // points off the other rig's, and the IK pulls the hand or head after them (a
    // character written with End Sites and read back stood 1.3 cm off the same rig).
    const double scale = map.target_leg_length_m / map.source_leg_length_m;
    if (source_nominal && !target_nominal)
      bone.source_bone = bone.source_bone.normalized() * (bone.target_bone.norm() / scale);
    if (target_nominal && !source_nominal)
      bone.target_bone = bone.target_bone.normalized() * (bone.source_bone.norm() * scale);
    const size_t half = InUpperBody(spec.role) ? 1 : 0;
    std::tie(bone.source_forward, bone.source_left) = source_axes[half];
    std::tie(bone.target_forward, bone.target_left) = target_axes[half];
    bone.region = spec.region;
    bone.foot_side = spec.foot_side;
    map.bones.push_back(bone);
    covered.insert(t->second);
    matched += "  " + std::string(spec.role) + ": " + source.joint(s->second).name + " -> " +
               target.joint(t->second).name + " (" + RegionName(spec.region) + ")\n";
  }
  std::string uncovered;
  for (int j = 0; j < target.num_joints(); ++j)
    if (!covered.count(j))
      uncovered += std::string(uncovered.empty() ? "" : ", ") + target.joint(j).name;
  char scale[128];
  std::snprintf(scale, sizeof(scale), "leg length %.3f m -> %.3f m (scale %.3f)\n",
                map.source_leg_length_m, map.target_leg_length_m,
                map.target_leg_length_m / map.source_leg_length_m);
  map.report =
      "retarget map: " + std::to_string(map.bones.size()) + " bones matched, " + scale + matched +
      (missing.empty() ? "" : "  roles on only one rig (not tracked): " + missing + "\n") +
      (uncovered.empty() ? ""
                         : "  character joints without surface points (solved, not tracked): " +
                               uncovered + "\n") +
      (CharacterTravels(target) ? ""
                                : "  the character has no joint that translates (its root only "
                                  "turns): retargeted in place, the actor's travel left out\n");
  return map;
}

namespace {

bool HasPositionChannels(const BvhTake& character, int joint) {
  if (joint < 0 || static_cast<size_t>(joint) >= character.channels.size()) return false;
  const auto& channels = character.channels[static_cast<size_t>(joint)];
  return std::count_if(channels.begin(), channels.end(), [](BvhChannel c) {
           return c == BvhChannel::kXposition || c == BvhChannel::kYposition ||
                  c == BvhChannel::kZposition;
         }) == 3;
}

// The one-frame file's types: a pelvis with position channels under a floor-level root
// travels.
Skeleton TypedFromOneFrame(const BvhTake& character) {
  const Skeleton& sk = character.skeleton;
  if (character.frames.size() >= 2) return sk;  // typed by its motion
  int pelvis = -1;
  try {
    pelvis = MatchHumanoidRoles(sk).joint_of_role.at("pelvis");
  } catch (const std::exception&) {
    return sk;  // MakeRetargetMap says what is missing
  }
  // A take built by hand may carry no channel list; its joints keep the skeleton's types.
  if (pelvis < 0 || static_cast<size_t>(pelvis) >= character.channels.size()) return sk;
  if (sk.joint(pelvis).type == JointType::kFree) return sk;
  bool translates_above = false;
  for (int a = sk.joint(pelvis).parent.value; a >= 0; a = sk.joint(a).parent.value)
    translates_above = translates_above || sk.joint(a).type == JointType::kFree;
  const auto& channels = character.channels[static_cast<size_t>(pelvis)];
  if (!translates_above || !HasPositionChannels(character, pelvis) || channels.size() != 6)
    return sk;
  std::vector<Joint> joints(sk.joints().begin(), sk.joints().end());
  joints[static_cast<size_t>(pelvis)].type = JointType::kFree;
  return Skeleton(std::move(joints));
}

}  // namespace

Skeleton CharacterSkeleton(const BvhTake& character, CharacterOutput output) {
  Skeleton sk =
      output == CharacterOutput::kFile ? TypedFromOneFrame(character) : character.skeleton;
  if (CharacterTravels(sk)) return sk;
  // A file whose own motion never moves the root (an idle, a T-pose held for a few frames)
  // typed it a ball, and the character could not travel, though the file gives it position
  // channels: the first joint that has them (the root, or a pelvis under it; on the wire
  // only the root) travels. A rig with none at all is retargeted in place.
  const int last =
      output == CharacterOutput::kFile ? sk.num_joints() : std::min(1, sk.num_joints());
  for (int j = 0; j < last; ++j) {
    if (!HasPositionChannels(character, j)) continue;
    std::vector<Joint> joints(sk.joints().begin(), sk.joints().end());
    joints[static_cast<size_t>(j)].type = JointType::kFree;
    return Skeleton(std::move(joints));
  }
  return sk;
}

}  // namespace mocapd
