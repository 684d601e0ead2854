// Retargeting an actor's solved pose onto a character (thesis ch. 4).
#include "filters/retarget.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace mocapd {
namespace {

constexpr int kAlong = 4;   // candidate rings along each bone
constexpr int kAround = 8;  // candidate points around each ring

struct Capsule {
  Vec3 origin, axis, e1, e2;
  double length = 0, radius = 0;
};

// The capsule of a bone in the rest pose's world frame. The angle around the bone is
// measured from the body's forward (from its left for bones that point forward), so both
// rigs agree on it whichever way each rest pose faces. Measured from the world's axes, a
// character facing another way, standing on +Z, or whose rest pose faces its chest and
// hips different ways (Bandai's, all rotations zero) had its chest turned 90 degrees.
Capsule MakeCapsule(const Vec3& origin, const Vec3& bone, double radius_fraction,
                    const Vec3& forward, const Vec3& left) {
  Capsule c;
  c.origin = origin;
  c.length = std::max(bone.norm(), 1e-4);
  c.axis = bone / c.length;
  const Vec3 reference = std::abs(c.axis.dot(forward)) < 0.9 ? forward : left;
  c.e1 = (reference - reference.dot(c.axis) * c.axis).normalized();
  c.e2 = c.axis.cross(c.e1);
  c.radius = std::clamp(radius_fraction * c.length, 0.02, 0.12);
  return c;
}

Vec3 CandidateNormal(const Capsule& c, int k) {
  const double angle = 2.0 * M_PI * (k % kAround) / kAround;
  return std::cos(angle) * c.e1 + std::sin(angle) * c.e2;
}

double CandidateAlong(int k) { return 0.2 + 0.6 * (k / kAround) / (kAlong - 1.0); }

Vec3 CandidatePoint(const Capsule& c, int k) {
  return c.origin + CandidateAlong(k) * c.length * c.axis + c.radius * CandidateNormal(c, k);
}

// Farthest-point sampling (thesis Algorithm 5) of the candidates: each next point is the
// one farthest from those already chosen, which spreads them evenly over the surface.
std::vector<int> FarthestPoints(const Capsule& c, int count) {
  std::vector<int> chosen = {0};
  std::vector<double> distance(kAlong * kAround, 1e300);
  while (static_cast<int>(chosen.size()) < std::min(count, kAlong * kAround)) {
    const Vec3 last = CandidatePoint(c, chosen.back());
    int best = -1;
    for (int k = 0; k < kAlong * kAround; ++k) {
      distance[static_cast<size_t>(k)] =
          std::min(distance[static_cast<size_t>(k)], (CandidatePoint(c, k) - last).squaredNorm());
      if (best < 0 || distance[static_cast<size_t>(k)] > distance[static_cast<size_t>(best)])
        best = k;
    }
    chosen.push_back(best);
  }
  return chosen;
}

double Smoothstep(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x * x * (3.0 - 2.0 * x);
}

// The character as the solve moves it. A joint no surface point tracks, between two that
// are (a middle spine joint, a roll bone), holds its rest rotation, and so do the joints
// above a free pelvis (a floor-level root). With no goal of their own they only traded
// rotation with their neighbours: a Mixamo rig's Spine1 turned 165 degrees and its Spine2
// back, and a one-frame character's root wandered under the pelvis it carried.
std::shared_ptr<const Skeleton> SolvedCharacter(std::shared_ptr<const Skeleton> target,
                                                const RetargetMap& map) {
  const int n = target->num_joints();
  if (map.target_root < 0 || map.target_root >= n) return target;  // the constructor says so
  std::vector<uint8_t> tracked(static_cast<size_t>(n), 0), above(tracked), below(tracked);
  for (const RetargetBone& bone : map.bones)
    if (bone.target_joint >= 0 && bone.target_joint < n)
      tracked[static_cast<size_t>(bone.target_joint)] = 1;
  for (int j = 0; j < n; ++j) {  // parents come before children
    const int parent = target->joint(j).parent.value;
    if (parent >= 0)
      above[static_cast<size_t>(j)] =
          above[static_cast<size_t>(parent)] || tracked[static_cast<size_t>(parent)];
  }
  for (int j = n - 1; j > 0; --j) {
    const int parent = target->joint(j).parent.value;
    if (below[static_cast<size_t>(j)] || tracked[static_cast<size_t>(j)])
      below[static_cast<size_t>(parent)] = 1;
  }
  std::vector<Joint> joints(target->joints().begin(), target->joints().end());
  bool changed = false;
  for (int j = 0; j < n; ++j) {
    const auto uj = static_cast<size_t>(j);
    if (!tracked[uj] && above[uj] && below[uj] && joints[uj].type != JointType::kFixed) {
      joints[uj].type = JointType::kFixed;
      changed = true;
    }
  }
  if (joints[static_cast<size_t>(map.target_root)].type == JointType::kFree)
    for (int a = joints[static_cast<size_t>(map.target_root)].parent.value; a >= 0;
         a = joints[static_cast<size_t>(a)].parent.value)
      if (joints[static_cast<size_t>(a)].type != JointType::kFixed) {
        joints[static_cast<size_t>(a)].type = JointType::kFixed;
        changed = true;
      }
  return changed ? std::make_shared<const Skeleton>(std::move(joints)) : target;
}

}  // namespace

bool CharacterTravels(const Skeleton& character) {
  // A free joint under one that turns (a stretchy bone, a prop) does not carry the body.
  for (int j = 0; j < character.num_joints(); ++j) {
    if (character.joint(j).type != JointType::kFree) continue;
    bool carried_by_fixed = true;
    for (int a = character.joint(j).parent.value; a >= 0; a = character.joint(a).parent.value)
      carried_by_fixed = carried_by_fixed && character.joint(a).type == JointType::kFixed;
    if (carried_by_fixed) return true;
  }
  return false;
}

void RetargetOptions::Validate() const {
  auto require = [](bool ok, const char* field, const char* rule) {
    if (!ok)
      throw std::invalid_argument(std::string("retarget option ") + field + " must be " + rule);
  };
  require(rate_hz > 0 && std::isfinite(rate_hz), "rate_hz", "> 0");
  require(points_per_bone >= 1 && points_per_bone <= kAlong * kAround, "points_per_bone",
          "in [1, 32]");
  require(surface_radius_fraction > 0 && surface_radius_fraction < 1, "surface_radius_fraction",
          "in (0, 1)");
  require(normal_lever_m > 0 && normal_lever_m < 1, "normal_lever_m", "in (0, 1) m");
  require(end_effector_weight >= 0 && torso_weight >= 0 && limb_weight >= 0 && root_weight >= 0,
          "weights", ">= 0");
  require(damping >= 0 && std::isfinite(damping), "damping", ">= 0");
  require(max_iterations >= 1 && max_iterations <= 100, "max_iterations", "in [1, 100]");
  require(prediction_velocity_gain >= 0 && prediction_velocity_gain <= 1,
          "prediction_velocity_gain", "in [0, 1]");
  require(hand_reach_share >= 0 && hand_reach_share <= 1, "hand_reach_share", "in [0, 1]");
  require(contact_height_m >= 0 && contact_speed_m_s >= 0, "contact_height_m / contact_speed_m_s",
          ">= 0");
  require(release_s > 0 && std::isfinite(release_s), "release_s", "> 0");
  require(contact_weight_gain >= 1, "contact_weight_gain", ">= 1");
  require(first_frame_passes >= 0 && first_frame_passes <= 1000, "first_frame_passes",
          "in [0, 1000]");
  require(first_frame_settled_m >= 0 && std::isfinite(first_frame_settled_m),
          "first_frame_settled_m", ">= 0");
}

Retargeter::Retargeter(std::shared_ptr<const Skeleton> source,
                       std::shared_ptr<const Skeleton> target, RetargetMap map,
                       const RetargetOptions& options)
    : source_(std::move(source)),
      target_(SolvedCharacter(std::move(target), map)),
      map_(std::move(map)),
      options_(options),
      state_(*target_,
             MarkerSet(*target_, {MarkerDefinition{
                                     "root", 1, {MarkerAttachment{0, 1.0, Vec3::Zero()}, {}}}})),
      source_fk_(*source_) {
  options_.Validate();
  if (map_.bones.empty()) throw std::invalid_argument("retarget: no corresponding bones");
  auto check = [](int j, const Skeleton& sk, const std::string& what) {
    if (j < 0 || j >= sk.num_joints())
      throw std::invalid_argument("retarget: " + what + " joint index out of range");
  };
  check(map_.source_root, *source_, "source root");
  check(map_.target_root, *target_, "target root");
  scale_ = map_.target_leg_length_m / map_.source_leg_length_m;
  if (!(scale_ > 0 && std::isfinite(scale_)))
    throw std::invalid_argument("retarget: leg lengths must be positive");

  KinematicsWorkspace source_rest(*source_), target_rest(*target_);
  ForwardKinematics(*source_, RestPose(*source_), &source_rest);
  ForwardKinematics(*target_, RestPose(*target_), &target_rest);
  source_root_rest_ = source_rest.R_WJ[static_cast<size_t>(map_.source_root)];
  in_place_ = !CharacterTravels(*target_);
  target_root_rest_ = target_rest.p_WJ[static_cast<size_t>(map_.target_root)];
  std::vector<MarkerDefinition> defs;
  std::vector<double> region_weight;
  for (size_t b = 0; b < map_.bones.size(); ++b) {
    const RetargetBone& bone = map_.bones[b];
    check(bone.source_joint, *source_, bone.role);
    check(bone.target_joint, *target_, bone.role);
    const auto js = static_cast<size_t>(bone.source_joint),
               jt = static_cast<size_t>(bone.target_joint);
    const Capsule cs =
        MakeCapsule(source_rest.p_WJ[js], bone.source_bone, options_.surface_radius_fraction,
                    bone.source_forward, bone.source_left);
    const Capsule ct =
        MakeCapsule(target_rest.p_WJ[jt], bone.target_bone, options_.surface_radius_fraction,
                    bone.target_forward, bone.target_left);
    const bool end_effector = bone.region == RetargetRegion::kEndEffector;
    const double bone_weight = end_effector ? options_.end_effector_weight
                               : bone.region == RetargetRegion::kTorso ? options_.torso_weight
                                                                       : options_.limb_weight;
    const double weight = bone_weight / options_.points_per_bone;
    // A hand goes where the actor's goes, scaled, from its joint origin (the wrist), and
    // its surface points turn it about that origin as the actor's turns, as a limb's do.
    // Tracking its surface points' positions let a character whose shoulders sit elsewhere
    // than the actor's, scaled, spin its hand 30-55 degrees a frame about its axis: the
    // twist its points could not hold against their position error, on every character
    // a CMU actor drove. Feet and toes keep their surface points' positions: turned about
    // their origins the same way, the knees swung aside (the knee's swivel off the
    // actor's, Bandai onto Mixamo: median 8 -> 24 degrees).
    const bool hand = end_effector && bone.foot_side < 0;
    if (hand) {
      SurfacePoint p;
      p.bone = static_cast<int>(b);
      p.position = true;
      p.source_offset = p.source_normal = p.source_axis = Vec3::Zero();
      // The arm's lengths, shoulder to wrist along the rest pose's straight line: a rest
      // pose with a bent elbow gives a shorter arm on that rig, as its reach is.
      const size_t underscore = bone.role.find('_');  // "hand_l": "_l"
      const std::string side = underscore == std::string::npos ? "" : bone.role.substr(underscore);
      for (const RetargetBone& upper : map_.bones) {
        if (upper.role != "upper_arm" + side) continue;
        const double source_arm =
            (source_rest.p_WJ[js] - source_rest.p_WJ[static_cast<size_t>(upper.source_joint)])
                .norm();
        const double target_arm =
            (target_rest.p_WJ[jt] - target_rest.p_WJ[static_cast<size_t>(upper.target_joint)])
                .norm();
        if (!(source_arm > 1e-6 && target_arm > 1e-6)) break;
        p.shoulder_source = upper.source_joint;
        p.shoulder_target = upper.target_joint;
        p.arm_ratio = target_arm / source_arm;
      }
      p.marker = static_cast<int>(defs.size());
      MarkerDefinition def;
      def.name = bone.role + "_origin";
      def.attachments[0] = {bone.target_joint, 1.0, Vec3::Zero()};
      defs.push_back(def);
      region_weight.push_back(bone_weight);
      points_.push_back(p);
    }
    const bool positions = end_effector && !hand;
    for (int k : FarthestPoints(cs, options_.points_per_bone)) {
      SurfacePoint p;
      p.bone = static_cast<int>(b);
      p.position = positions;
      p.source_offset = source_rest.R_WJ[js].transpose() * (CandidatePoint(cs, k) - cs.origin);
      p.source_normal = source_rest.R_WJ[js].transpose() * CandidateNormal(cs, k);
      p.source_axis = source_rest.R_WJ[js].transpose() * cs.axis;
      p.target_along_m = CandidateAlong(k) * ct.length;
      // A normal-tracked point is represented on the target by a lever point: as far
      // along the bone's axis as the surface point, one lever out along its normal.
      const Vec3 world = positions ? CandidatePoint(ct, k)
                                   : Vec3(ct.origin + p.target_along_m * ct.axis +
                                          options_.normal_lever_m * CandidateNormal(ct, k));
      p.marker = static_cast<int>(defs.size());
      MarkerDefinition def;
      def.name = bone.role + "_" + std::to_string(k);
      def.attachments[0] = {bone.target_joint, 1.0,
                            target_rest.R_WJ[jt].transpose() * (world - ct.origin)};
      defs.push_back(def);
      region_weight.push_back(weight);
      points_.push_back(p);
    }
  }
  root_marker_ = static_cast<int>(defs.size());
  MarkerDefinition root;
  root.name = "root";
  root.attachments[0] = {map_.target_root, 1.0, Vec3::Zero()};
  defs.push_back(root);
  region_weight.push_back(options_.root_weight);
  markers_ = std::make_unique<MarkerSet>(*target_, std::move(defs));
  state_ = IkState(*target_, *markers_);
  weights_ = region_weight;
  base_weights_ = region_weight;
  goals_.assign(weights_.size(), Vec3::Zero());
  source_origin_before_.assign(static_cast<size_t>(source_->num_joints()), Vec3::Zero());
  settle_before_.assign(static_cast<size_t>(target_->num_joints()), Vec3::Zero());
  ik_.max_iterations = options_.max_iterations;
  ik_.temporal_weight = options_.damping * options_.damping;
  ik_.min_markers = 1;
  ik_.prediction_velocity_gain = options_.prediction_velocity_gain;
  settle_ik_ = ik_;
  settle_ik_.max_iterations = 10;
  // The settling keeps the solve's pull toward its last pose: each pass re-centres it, so
  // it slows nothing that the data holds, and a weakly held joint (a long toe on a short
  // foot) ends where the next frames' solve leaves it. Without it the toe settled 12 deg
  // from there and eased back over five frames.
  settle_ik_.predict_constant_velocity = false;
}

void Retargeter::Reset() {
  ForgetMotion();
  to_character_world_ = Mat3::Identity();
  world_found_ = false;
}

void Retargeter::ForgetMotion() {
  state_.Reset();
  planted_ = {false, false};
  since_release_ = {1 << 20, 1 << 20};
  foot_correction_ = release_correction_ = lock_ = {Vec3::Zero(), Vec3::Zero()};
  floor_height_ = 1e9;
  frames_ = 0;
}

Vec3 NearestAxis(const Vec3& direction) {
  Eigen::Index axis = 0;
  direction.cwiseAbs().maxCoeff(&axis);
  return direction[axis] > 0 ? Vec3::Unit(axis) : Vec3(-Vec3::Unit(axis));
}

std::string AxisName(const Vec3& direction) {
  Eigen::Index axis = 0;
  direction.cwiseAbs().maxCoeff(&axis);
  return std::string(direction[axis] > 0 ? "+" : "-") + "xyz"[axis];
}

Mat3 CaptureToTargetWorld(const RetargetMap& map, const KinematicsWorkspace& source_posed) {
  const Vec3 up = source_posed.R_WJ[static_cast<size_t>(map.source_root)] * map.source_hips_up;
  return Quat::FromTwoVectors(NearestAxis(up), map.target_up).toRotationMatrix();
}

void TurnPoseWorld(const Skeleton& skeleton, const Mat3& world, Pose* pose) {
  if (world.isIdentity()) return;
  const Quat turn(world);
  if (skeleton.joint(0).type != JointType::kFixed) {
    pose->rotation[0] = (turn * pose->rotation[0]).normalized();
    pose->translation[0] = world * pose->translation[0];
    return;
  }
  // A fixed root (Bandai's joint_Root at the floor origin) stays: the joints it carries
  // turn about the world's origin, as seen through it.
  const Quat root = pose->rotation[0];
  const Vec3 at = pose->translation[0];
  for (int j : skeleton.children(0)) {
    const auto uj = static_cast<size_t>(j);
    pose->rotation[uj] = (root.conjugate() * turn * root * pose->rotation[uj]).normalized();
    pose->translation[uj] =
        root.conjugate() * (world * Vec3(at + root * pose->translation[uj]) - at);
  }
}

void Retargeter::FindCharacterWorld() {
  const Mat3& pelvis = source_fk_.R_WJ[static_cast<size_t>(map_.source_root)];
  if (pelvis.isApprox(source_root_rest_, 1e-12)) return;
  to_character_world_ = CaptureToTargetWorld(map_, source_fk_);
  world_found_ = true;
  // Frames at rest came before in another world: the solve starts afresh in this one.
  // In the same world it carries on (a restart from rest mid-take would be a jump).
  if (frames_ > 0 && !to_character_world_.isIdentity()) ForgetMotion();
}

void Retargeter::ComputeGoals(bool predict) {
  const KinematicsWorkspace& warm = state_.kinematics();
  for (const SurfacePoint& p : points_) {
    const RetargetBone& bone = map_.bones[static_cast<size_t>(p.bone)];
    const auto js = static_cast<size_t>(bone.source_joint);
    const Vec3 source_point = source_fk_.R_WJ[js] * p.source_offset + source_fk_.p_WJ[js];
    Vec3& goal = goals_[static_cast<size_t>(p.marker)];
    if (p.position) {
      Vec3 tracked = scale_ * source_point;
      const double reach_share = options_.hand_reach_share;
      if (p.shoulder_source >= 0 && reach_share > 0.0) {
        // The character's shoulder as the lever anchors take a joint: last solution's,
        // moved by the actor's own scaled motion since.
        const auto ss = static_cast<size_t>(p.shoulder_source),
                   st = static_cast<size_t>(p.shoulder_target);
        const Vec3 shoulder =
            warm.p_WJ[st] + (predict
                                 ? Vec3(scale_ * (source_fk_.p_WJ[ss] - source_origin_before_[ss]))
                                 : Vec3::Zero());
        const Vec3 reach = shoulder + p.arm_ratio * (source_point - source_fk_.p_WJ[ss]);
        tracked = (1.0 - reach_share) * tracked + reach_share * reach;
      }
      // A foot in contact keeps its horizontal place: every point of that foot moves by
      // the same correction, so the foot still rolls heel to toe but does not slide.
      goal = bone.foot_side < 0
                 ? tracked
                 : Vec3(tracked + foot_correction_[static_cast<size_t>(bone.foot_side)]);
      // A planted foot outweighs the rest, so that the lock holds against other pulls.
      weights_[static_cast<size_t>(p.marker)] =
          base_weights_[static_cast<size_t>(p.marker)] *
          (bone.foot_side >= 0 && planted_[static_cast<size_t>(bone.foot_side)]
               ? options_.contact_weight_gain
               : 1.0);
    } else {
      // Where the lever point belongs: from the target joint's origin along the actor's
      // bone axis, then out along the actor's normal -- zero residual exactly when the
      // target bone points and turns like the actor's, whatever either rest pose is. The
      // origin is the last solution's, moved by the actor's own (scaled) motion since the
      // last frame: no lag, and no feedback of the solve's velocity into its goals.
      const auto jt = static_cast<size_t>(bone.target_joint);
      const Vec3 anchor =
          warm.p_WJ[jt] + (predict
                               ? Vec3(scale_ * (source_fk_.p_WJ[js] - source_origin_before_[js]))
                               : Vec3::Zero());
      goal = anchor + p.target_along_m * (source_fk_.R_WJ[js] * p.source_axis) +
             options_.normal_lever_m * (source_fk_.R_WJ[js] * p.source_normal);
    }
  }
  goals_[static_cast<size_t>(root_marker_)] =
      scale_ * source_fk_.p_WJ[static_cast<size_t>(map_.source_root)];
}

const Pose& Retargeter::Retarget(const Pose& source_pose) {
  ForwardKinematics(*source_, source_pose, &source_fk_);
  if (!world_found_) FindCharacterWorld();
  if (!to_character_world_.isIdentity()) {
    // Everything below happens in the character's world, the one its file stands in.
    for (size_t j = 0; j < source_fk_.p_WJ.size(); ++j) {
      source_fk_.p_WJ[j] = to_character_world_ * source_fk_.p_WJ[j];
      source_fk_.R_WJ[j] = to_character_world_ * source_fk_.R_WJ[j];
    }
  }
  if (in_place_) {
    // A character that cannot travel reached for the actor's scaled world positions
    // metres away and bent every joint trying: the actor is moved so that its scaled
    // pelvis stays where the character's stands, and the body moves about it. A walking
    // foot then slides back under the body, faster than a contact, so it is not planted.
    const Vec3 shift =
        target_root_rest_ / scale_ - source_fk_.p_WJ[static_cast<size_t>(map_.source_root)];
    for (Vec3& p : source_fk_.p_WJ) p += shift;
  }
  const Vec3& up = map_.target_up;
  // Contacts: the actor's ankles against the lowest ankle height seen so far.
  std::array<bool, 2> planted_now = planted_;
  for (int side = 0; side < 2; ++side) {
    const int ankle = map_.source_ankles[static_cast<size_t>(side)];
    if (ankle < 0) continue;
    const Vec3& p = source_fk_.p_WJ[static_cast<size_t>(ankle)];
    floor_height_ = std::min(floor_height_, p.dot(up));
    Vec3 moved = p - previous_ankle_[static_cast<size_t>(side)];
    moved -= moved.dot(up) * up;
    const double speed = frames_ > 0 ? moved.norm() * options_.rate_hz : 0.0;
    const double height = p.dot(up) - floor_height_;
    // Hysteresis: leaving contact needs clearly more than entering it. The first frame,
    // with no speed yet, may plant a foot on the floor (settled unplanted, the first pose
    // moved when the second frame planted the foot and weighted it: hips 7 deg, a foot
    // 11 deg in one frame at a take's start); the second judges that plant again as a
    // touch-down, now that the foot's speed is known.
    const bool was = planted_[static_cast<size_t>(side)] && frames_ != 1;
    planted_now[static_cast<size_t>(side)] =
        was ? height < 1.5 * options_.contact_height_m && speed < 1.5 * options_.contact_speed_m_s
            : height < options_.contact_height_m && speed < options_.contact_speed_m_s;
    previous_ankle_[static_cast<size_t>(side)] = p;
  }
  for (int side = 0; side < 2; ++side) {
    const auto sd = static_cast<size_t>(side);
    const int ankle = map_.source_ankles[sd];
    if (ankle < 0) continue;
    Vec3 reference = scale_ * source_fk_.p_WJ[static_cast<size_t>(ankle)];
    reference -= reference.dot(up) * up;
    if (planted_now[sd] && !planted_[sd]) {
      // Touch-down: the character's foot stays where it is now (horizontally); on the
      // first frame, before any solution, where the actor's scaled ankle is.
      const int held = frames_ > 0 ? map_.target_ankles[sd] : -1;
      lock_[sd] = held >= 0 ? state_.kinematics().p_WJ[static_cast<size_t>(held)]
                            : Vec3(reference + foot_correction_[sd]);
      lock_[sd] -= lock_[sd].dot(up) * up;
    }
    if (planted_now[sd]) {
      foot_correction_[sd] = lock_[sd] - reference;
      release_correction_[sd] = foot_correction_[sd];
    } else {
      // Lifted: ease the correction away over release_s (at least one frame).
      const double blend = Smoothstep(static_cast<double>(since_release_[sd] + 1) /
                                      std::max(1.0, options_.release_s * options_.rate_hz));
      foot_correction_[sd] = (1.0 - blend) * release_correction_[sd];
    }
  }
  for (int side = 0; side < 2; ++side) {
    const auto s = static_cast<size_t>(side);
    since_release_[s] = planted_now[s] ? 0 : planted_[s] ? 0 : since_release_[s] + 1;
  }
  planted_ = planted_now;
  ComputeGoals(/*predict=*/frames_ > 0);
  summary_.ik = SolveIk(*target_, *markers_, ik_, goals_, weights_, &state_);
  if (frames_ == 0) {
    // The first frame starts from the rest pose, where the normal anchors are wrong:
    // re-anchor on each solution until no joint moves (once, not per frame). The anchors
    // converge slowly where a limb must turn far from its rest: a fixed 20 passes left a
    // forearm 15 cm off that the next frames eased in, a slide the stage saw at start.
    // The passes converge geometrically, so the distance still to go is estimated from
    // the last two steps (step x r / (1 - r)): a small step of a slow convergence is not
    // yet settled.
    double last_moved = kNaN;
    for (int pass = 0; pass < options_.first_frame_passes; ++pass) {
      std::copy(state_.kinematics().p_WJ.begin(), state_.kinematics().p_WJ.end(),
                settle_before_.begin());
      ComputeGoals(false);
      summary_.ik = SolveIk(*target_, *markers_, settle_ik_, goals_, weights_, &state_);
      double moved = 0.0;
      for (size_t j = 0; j < settle_before_.size(); ++j)
        moved = std::max(moved, (state_.kinematics().p_WJ[j] - settle_before_[j]).norm());
      const double rate = moved / last_moved;  // NaN on the first pass
      const double to_go = rate < 1.0 ? moved * rate / (1.0 - rate) : kNaN;
      if (moved < options_.first_frame_settled_m &&
          (pass == 0 || to_go < options_.first_frame_settled_m))
        break;
      last_moved = moved;
    }
  }
  summary_.planted = planted_;
  std::copy(source_fk_.p_WJ.begin(), source_fk_.p_WJ.end(), source_origin_before_.begin());
  ++frames_;
  return state_.pose();
}

}  // namespace mocapd
