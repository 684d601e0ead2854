// Tests for retargeting: identical rigs give the identity, a uniformly scaled rig the
// same joint angles, planted feet do not slide, the map reports what matched, and a
// frame allocates nothing.
#include "filters/retarget.hpp"

#include <gtest/gtest.h>

#include <random>

#include "formats/bvh.hpp"
#include "formats/marker_layout.hpp"
#include "formats/marker_set.hpp"
#include "formats/retarget_map.hpp"
#include "sim/humanoid.hpp"
#include "tests/support/allocation_counter.hpp"

namespace mocapd {
namespace {

std::shared_ptr<const Skeleton> Scaled(const Skeleton& sk, double factor) {
  std::vector<Joint> joints(sk.joints().begin(), sk.joints().end());
  for (Joint& j : joints) j.offset *= factor;
  return std::make_shared<const Skeleton>(std::move(joints));
}

double MaxRotationDifferenceDeg(const Pose& a, const Pose& b) {
  double worst = 0.0;
  for (size_t j = 0; j < a.rotation.size(); ++j)
    worst = std::max(worst, a.rotation[j].angularDistance(b.rotation[j]) * 180.0 / M_PI);
  return worst;
}

class RetargetTest : public ::testing::Test {
 protected:
  RetargetTest() : source_(std::make_shared<const Skeleton>(MakeHumanoidSkeleton())) {
    motion_ = MakeHumanoidMotion(*source_, HumanoidMotion::kWalk, 3.0, 120.0);
  }
  std::shared_ptr<const Skeleton> source_;
  std::vector<Pose> motion_;
};

// Contact locking off: the procedural walk's stance feet creep a little, which locking
// would (rightly) hold still on the character -- not the identity any more.
RetargetOptions NoContacts() {
  RetargetOptions o;
  o.contact_height_m = 0.0;
  return o;
}

TEST_F(RetargetTest, IdenticalRigsRetargetToTheIdentity) {
  Retargeter r(source_, source_, MakeRetargetMap(*source_, {}, *source_, {}), NoContacts());
  EXPECT_DOUBLE_EQ(r.scale(), 1.0);
  double worst = 0.0, worst_root = 0.0;
  for (size_t f = 0; f < motion_.size(); ++f) {
    const Pose& out = r.Retarget(motion_[f]);
    worst = std::max(worst, MaxRotationDifferenceDeg(out, motion_[f]));
    worst_root = std::max(worst_root, (out.translation[0] - motion_[f].translation[0]).norm());
  }
  // The solve's pull toward its last pose (RetargetOptions::prediction_velocity_gain 0)
  // lags the fastest joint: 2.8 deg.
  EXPECT_LT(worst, 3.2);
  EXPECT_LT(worst_root, 0.005);
}

// A fresh retargeter (a stream's start, a restart) meets the actor mid-motion, limbs
// far from their rest: its first frame is already the actor's pose, not eased in over
// the next frames (20 fixed settling passes left a CMU actor's forearm 15 cm off at
// frame 0, 10 cm at frame 1).
TEST_F(RetargetTest, AFirstFrameFarFromRestIsSettledAtOnce) {
  const auto rig = std::make_shared<const Skeleton>(MakeTemplateHumanoid(1.75));
  KinematicsWorkspace actor(*rig), character(*rig);
  double worst = 0.0;
  for (double twist_deg : {0.0, 60.0, 120.0, 150.0, 170.0}) {
    for (double bend_deg : {30.0, 90.0, 130.0}) {
      // Arms raised, turned about themselves, elbows bent: far from the rest's arms down.
      Pose pose = RestPose(*rig);
      pose.translation[0] = Vec3(0.3, 0.9, -0.2);
      for (const char* arm : {"upper_arm_l", "upper_arm_r"}) {
        const int a = rig->FindJoint(arm)->value;
        const Vec3 along = rig->joint(a + 1).offset.normalized();
        pose.rotation[static_cast<size_t>(a)] =
            Quat(Eigen::AngleAxisd(twist_deg * M_PI / 180.0, along)) *
            Quat(Eigen::AngleAxisd(bend_deg * M_PI / 180.0, Vec3::UnitZ()));
        pose.rotation[static_cast<size_t>(a + 1)] =
            Quat(Eigen::AngleAxisd(bend_deg * M_PI / 180.0, Vec3::UnitX()));
      }
      Retargeter r(rig, rig, MakeRetargetMap(*rig, {}, *rig, {}), NoContacts());
      ForwardKinematics(*rig, r.Retarget(pose), &character);
      ForwardKinematics(*rig, pose, &actor);
      for (size_t j = 0; j < actor.p_WJ.size(); ++j)
        worst = std::max(worst, (character.p_WJ[j] - actor.p_WJ[j]).norm());
    }
  }
  EXPECT_LT(worst, 0.005);  // 20 fixed passes: 2.4-26 cm
}

// A character whose rest pose faces +X, or stands on +Z (as 3ds Max and Blender write
// some rigs): its hips and shoulders turn as the actor's do, and it comes out in its own
// world, standing on the axis its rest pose stands on. The angle around each bone was
// measured from the world's axes, so such a character's thighs and shins came out turned
// 86 degrees about their bones, and one facing +X its whole body (now within 6 degrees:
// the solver's damping is not turned with the world); and a character
// standing on +Z came out in the actor's Y-up world, lying on its back in its own.
TEST_F(RetargetTest, ACharacterFacingAnotherWayOrStandingOnZTurnsAsTheActorDoes) {
  const HumanoidRoles roles = MatchHumanoidRoles(*source_);
  auto joint = [&](const KinematicsWorkspace& ws, const char* role) {
    return ws.p_WJ[static_cast<size_t>(roles.joint_of_role.at(role))];
  };
  auto left_right = [&](const KinematicsWorkspace& ws, const char* l, const char* r) {
    return Vec3(joint(ws, l) - joint(ws, r)).normalized();
  };
  const Quat facing_x(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitY()));
  const Quat standing_on_z(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitX()));
  for (const Quat& turn : {facing_x, standing_on_z}) {
    std::vector<Joint> joints(source_->joints().begin(), source_->joints().end());
    joints[0].rest_rotation = turn * joints[0].rest_rotation;
    const auto turned = std::make_shared<const Skeleton>(std::move(joints));
    Retargeter r(source_, turned, MakeRetargetMap(*source_, {}, *turned, {}), NoContacts());
    KinematicsWorkspace actor(*source_), character(*turned);
    double worst_deg = 0.0, worst_up_deg = 0.0;
    const Vec3 own_up = turn * Vec3::UnitY();
    for (size_t f = 0; f < motion_.size(); ++f) {
      ForwardKinematics(*turned, r.Retarget(motion_[f]), &character);
      ForwardKinematics(*source_, motion_[f], &actor);
      if (f < 5) continue;
      const Mat3& world = r.to_character_world();
      for (const auto& [l, rr] : {std::pair{"thigh_l", "thigh_r"},
                                  {"upper_arm_l", "upper_arm_r"},
                                  {"shin_l", "shin_r"},
                                  {"forearm_l", "forearm_r"}}) {
        const double cosine = (world * left_right(actor, l, rr)).dot(left_right(character, l, rr));
        worst_deg = std::max(worst_deg, std::acos(std::clamp(cosine, -1.0, 1.0)) * 180.0 / M_PI);
      }
      const Vec3 body = Vec3(joint(character, "head") - joint(character, "pelvis")).normalized();
      worst_up_deg =
          std::max(worst_up_deg, std::acos(std::clamp(body.dot(own_up), -1.0, 1.0)) * 180.0 / M_PI);
    }
    EXPECT_LT(worst_deg, 15.0) << "rest turned " << turn.coeffs().transpose();
    EXPECT_LT(worst_up_deg, 30.0) << "rest turned " << turn.coeffs().transpose();
  }
}

// A Vicon capture stands on +Z; a character file on +Y. The character comes out standing
// in its own world, as if the capture had stood on +Y, and the feet's contacts are found
// along the capture's up: it came out in the capture's world (lying on its back in the
// character's) and took a horizontal axis for the ankles' height.
TEST_F(RetargetTest, ACaptureStandingOnZDrivesACharacterStandingOnY) {
  const Mat3 to_z = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitX()).toRotationMatrix();
  std::vector<Pose> on_z = motion_;
  for (Pose& p : on_z) {
    p.rotation[0] = Quat(to_z) * p.rotation[0];
    p.translation[0] = to_z * p.translation[0];
  }
  Retargeter from_z(source_, source_, MakeRetargetMap(*source_, {}, *source_, {}), NoContacts());
  double worst_deg = 0.0, worst_root = 0.0;
  for (size_t f = 0; f < motion_.size(); ++f) {
    const Pose& out = from_z.Retarget(on_z[f]);
    if (f < 5) continue;
    worst_deg = std::max(worst_deg, MaxRotationDifferenceDeg(out, motion_[f]));
    worst_root = std::max(worst_root, (out.translation[0] - motion_[f].translation[0]).norm());
  }
  EXPECT_TRUE(from_z.to_character_world().isApprox(to_z.transpose(), 1e-9));
  EXPECT_LT(worst_deg, 3.2);  // the lag, as in IdenticalRigsRetargetToTheIdentity
  EXPECT_LT(worst_root, 0.005);
  // Contacts: the same frames planted as from the capture standing on +Y.
  Retargeter on_y_contacts(source_, source_, MakeRetargetMap(*source_, {}, *source_, {}),
                           RetargetOptions{});
  Retargeter on_z_contacts(source_, source_, MakeRetargetMap(*source_, {}, *source_, {}),
                           RetargetOptions{});
  int planted = 0, disagree = 0;
  for (size_t f = 0; f < motion_.size(); ++f) {
    on_y_contacts.Retarget(motion_[f]);
    on_z_contacts.Retarget(on_z[f]);
    for (size_t side = 0; side < 2; ++side) {
      planted += on_y_contacts.summary().planted[side];
      disagree += on_y_contacts.summary().planted[side] != on_z_contacts.summary().planted[side];
    }
  }
  // The procedural walk skates: its few true contacts (10 side-frames here) count, and
  // rounding at a threshold may flip a frame or two at their edges.
  EXPECT_GE(planted, 5);
  EXPECT_LE(disagree, planted / 4);
}

// A character with a spine joint no role names (Mixamo's Spine1, between Spine and
// Spine2): it holds its rest rotation, and the chest and head still turn as the actor's.
// Free and with no goal of its own, it traded rotation with its neighbours (Spine1 turned
// 165 degrees and Spine2 back: a candy-wrapper twist on a skinned mesh); and the head,
// tracked by its points' positions, flapped up to 50 cm a frame at its top.
TEST_F(RetargetTest, AnUntrackedSpineJointHoldsItsRestAndTheHeadTurnsAsTheActors) {
  std::vector<Joint> joints;
  std::vector<int> index_of(static_cast<size_t>(source_->num_joints()));
  for (int j = 0; j < source_->num_joints(); ++j) {
    Joint joint = source_->joint(j);
    if (joint.parent.is_valid())
      joint.parent = JointIndex(index_of[static_cast<size_t>(joint.parent.value)]);
    if (joint.name == "Chest") {
      Joint middle{.name = "Spine1", .parent = joint.parent, .offset = joint.offset / 2};
      joints.push_back(middle);
      joint.parent = JointIndex(static_cast<int>(joints.size()) - 1);
      joint.offset /= 2;
    }
    index_of[static_cast<size_t>(j)] = static_cast<int>(joints.size());
    joints.push_back(joint);
  }
  const auto three_spines = std::make_shared<const Skeleton>(std::move(joints));
  Retargeter r(source_, three_spines, MakeRetargetMap(*source_, {}, *three_spines, {}),
               NoContacts());
  const int middle = three_spines->FindJoint("Spine1")->value;
  const int actor_head = source_->FindJoint("Head")->value;
  const int character_head = three_spines->FindJoint("Head")->value;
  KinematicsWorkspace character(*three_spines), actor(*source_);
  double worst_middle_deg = 0.0, worst_head_deg = 0.0;
  for (size_t f = 0; f < motion_.size(); ++f) {
    const Pose& out = r.Retarget(motion_[f]);
    if (f < 5) continue;
    worst_middle_deg = std::max(
        worst_middle_deg,
        out.rotation[static_cast<size_t>(middle)].angularDistance(Quat::Identity()) * 180 / M_PI);
    ForwardKinematics(*three_spines, out, &character);
    ForwardKinematics(*source_, motion_[f], &actor);
    const Quat a(actor.R_WJ[static_cast<size_t>(actor_head)]);
    const Quat c(character.R_WJ[static_cast<size_t>(character_head)]);
    worst_head_deg = std::max(worst_head_deg, a.angularDistance(c) * 180 / M_PI);
  }
  EXPECT_LT(worst_middle_deg, 1e-6);
  EXPECT_LT(worst_head_deg, 5.0);
}

// Turning a posed skeleton's world turns every joint, whether the root moves or is a
// fixed floor-level root carrying the pelvis (Bandai's joint_Root).
TEST_F(RetargetTest, TurningAPoseTurnsEveryJointEvenUnderAFixedRoot) {
  std::vector<Joint> joints = {Joint{.name = "joint_Root",
                                     .parent = {},
                                     .offset = Vec3(0.1, 0, 0.2),
                                     .rest_rotation = Quat(Eigen::AngleAxisd(0.3, Vec3::UnitY())),
                                     .type = JointType::kFixed}};
  for (const Joint& j : source_->joints()) {
    Joint joint = j;
    joint.parent = JointIndex(j.parent.is_valid() ? j.parent.value + 1 : 0);
    joints.push_back(joint);
  }
  const Skeleton rooted(std::move(joints));
  const Mat3 world = Eigen::AngleAxisd(-M_PI / 2, Vec3::UnitX()).toRotationMatrix();
  for (const Skeleton* sk : {source_.get(), &rooted}) {
    Pose pose = RestPose(*sk);
    const size_t pelvis = sk == &rooted ? 1 : 0;
    pose.translation[pelvis] += Vec3(0.3, 0.05, -0.4);
    pose.rotation[pelvis] = Quat(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()));
    KinematicsWorkspace before(*sk), after(*sk);
    ForwardKinematics(*sk, pose, &before);
    TurnPoseWorld(*sk, world, &pose);
    ForwardKinematics(*sk, pose, &after);
    for (int j = sk == &rooted ? 1 : 0; j < sk->num_joints(); ++j) {
      const auto uj = static_cast<size_t>(j);
      EXPECT_LT((after.p_WJ[uj] - world * before.p_WJ[uj]).norm(), 1e-9) << sk->joint(j).name;
      EXPECT_TRUE(after.R_WJ[uj].isApprox(world * before.R_WJ[uj], 1e-9)) << sk->joint(j).name;
    }
  }
}

// The usual character file is one frame of its T-pose: read from such a file, the
// character's root must still translate with the actor's (it stood 2.3 m off).
TEST_F(RetargetTest, ACharacterFromAOneFrameFileFollowsTheRoot) {
  const BvhTake file = ParseBvh(
      FormatBvh(MakeBvhTake(*source_, {RestPose(*source_)}, 1.0 / 30.0, "cm")), "character.bvh");
  const auto character = std::make_shared<const Skeleton>(file.skeleton);
  Retargeter r(source_, character, MakeRetargetMap(*source_, {}, *character, file.end_sites),
               NoContacts());
  double worst_root = 0.0;
  for (size_t f = 0; f < motion_.size(); ++f) {
    const Pose& out = r.Retarget(motion_[f]);
    if (f >= 5)
      worst_root = std::max(worst_root, (out.translation[0] - motion_[f].translation[0]).norm());
  }
  EXPECT_LT(worst_root, 0.01);
}

// A one-frame character file with a floor-level root over a pelvis that has position
// channels (Bandai's joint_Root over its Hips): the reader types the top joint free, and
// the written character travelled on joint_Root, its Hips held metres from it. As a file
// character it travels on its pelvis, and the joint above stays at rest; a file with
// motion keeps the types its motion gave.
TEST_F(RetargetTest, AOneFrameCharacterUnderAFloorRootTravelsOnItsPelvis) {
  std::vector<Joint> joints = {
      Joint{.name = "joint_Root", .parent = {}, .offset = Vec3::Zero(), .type = JointType::kFree}};
  for (const Joint& j : source_->joints()) {
    Joint joint = j;
    joint.parent = JointIndex(j.parent.is_valid() ? j.parent.value + 1 : 0);
    joints.push_back(joint);
  }
  const Skeleton rig(std::move(joints));  // both joints free: written with 6 channels each
  const BvhTake file =
      ParseBvh(FormatBvh(MakeBvhTake(rig, {RestPose(rig)}, 1.0 / 30.0, "cm")), "tpose.bvh");
  ASSERT_EQ(file.skeleton.joint(0).type, JointType::kFree);
  ASSERT_NE(file.skeleton.joint(1).type, JointType::kFree);
  const auto character = std::make_shared<const Skeleton>(CharacterSkeleton(file));
  EXPECT_EQ(character->joint(1).type, JointType::kFree);
  Retargeter r(source_, character, MakeRetargetMap(*source_, {}, *character, file.end_sites),
               NoContacts());
  const Pose rest = RestPose(*character);
  double floor_moved = 0.0, pelvis_off = 0.0;
  KinematicsWorkspace ws(*character);
  for (size_t f = 5; f < motion_.size(); ++f) {
    const Pose& out = r.Retarget(motion_[f]);
    ForwardKinematics(*character, out, &ws);
    floor_moved = std::max(floor_moved, (out.translation[0] - rest.translation[0]).norm());
    pelvis_off = std::max(pelvis_off, (ws.p_WJ[1] - motion_[f].translation[0]).norm());
  }
  EXPECT_LT(floor_moved, 1e-9);
  EXPECT_LT(pelvis_off, 0.01);
  const BvhTake moving = ParseBvh(
      FormatBvh(MakeBvhTake(rig, {RestPose(rig), RestPose(rig)}, 1.0 / 30.0, "cm")), "two.bvh");
  EXPECT_EQ(CharacterSkeleton(moving).joint(1).type, moving.skeleton.joint(1).type);
}

// A character whose root only turns (a BVH root with rotation channels alone) cannot
// travel: it reached for the walking actor's positions metres away, its joints bent 46 cm
// out of the actor's pose. It now moves in place: the pose is the actor's (the same joint
// angles, as for the same rig with a free root), the root stays where it stands.
TEST_F(RetargetTest, ACharacterWhoseRootOnlyTurnsMovesInPlace) {
  std::vector<Joint> joints(source_->joints().begin(), source_->joints().end());
  joints[0].type = JointType::kBall;
  const auto fixed = std::make_shared<const Skeleton>(std::move(joints));
  ASSERT_FALSE(CharacterTravels(*fixed));
  ASSERT_TRUE(CharacterTravels(*source_));
  const RetargetMap map = MakeRetargetMap(*source_, {}, *fixed, {});
  EXPECT_NE(map.report.find("retargeted in place"), std::string::npos) << map.report;
  Retargeter r(source_, fixed, map, NoContacts());
  EXPECT_TRUE(r.in_place());
  const Vec3 start = r.kinematics().p_WJ[0];
  double worst_deg = 0.0, travelled_m = 0.0;
  for (size_t f = 0; f < motion_.size(); ++f) {
    const Pose& out = r.Retarget(motion_[f]);
    if (f >= 12) worst_deg = std::max(worst_deg, MaxRotationDifferenceDeg(out, motion_[f]));
    travelled_m = std::max(travelled_m, (r.kinematics().p_WJ[0] - start).norm());
  }
  // The same bound as the identical rigs' (the solve's pull lags the fastest joint).
  EXPECT_LT(worst_deg, 4.0);
  EXPECT_LT(travelled_m, 1e-9);
  // The actor walked far enough that reaching for it could not have kept the pose.
  EXPECT_GT((motion_.back().translation[0] - motion_.front().translation[0]).norm(), 1.0);
}

// A character file whose own frames never move its root (an idle on the spot) reads its
// root as a fixed frame, though the file gives it position channels: it could not travel,
// and was bent reaching for the actor. As a character it travels, to a file and on the wire. A rig
// whose root has rotation channels only stays in place.
TEST_F(RetargetTest, ACharacterWithRootPositionChannelsTravelsThoughItsFileNeverMovesIt) {
  // The actor's first frames with the pelvis held as it starts: the limbs move, the root
  // does not (read as a fixed frame, as Bandai's floor-level joint_Root is).
  std::vector<Pose> idle(motion_.begin(), motion_.begin() + 30);
  for (Pose& pose : idle) {
    pose.translation[0] = motion_.front().translation[0];
    pose.rotation[0] = motion_.front().rotation[0];
  }
  const BvhTake still =
      ParseBvh(FormatBvh(MakeBvhTake(*source_, idle, 1.0 / 30.0, "cm")), "idle.bvh");
  ASSERT_NE(still.skeleton.joint(0).type, JointType::kFree);
  for (const CharacterOutput output : {CharacterOutput::kFile, CharacterOutput::kWire}) {
    const Skeleton character = CharacterSkeleton(still, output);
    EXPECT_EQ(character.joint(0).type, JointType::kFree);
    EXPECT_TRUE(CharacterTravels(character));
  }
  std::vector<Joint> joints(source_->joints().begin(), source_->joints().end());
  joints[0].type = JointType::kBall;
  const Skeleton rotation_only(std::move(joints));
  const BvhTake in_place = ParseBvh(
      FormatBvh(MakeBvhTake(rotation_only, {RestPose(rotation_only), RestPose(rotation_only)},
                            1.0 / 30.0, "cm")),
      "in_place.bvh");
  EXPECT_FALSE(CharacterTravels(CharacterSkeleton(in_place)));
}

// The scale is the legs' length along their bones, wherever the file stood the pelvis:
// under a floor-level root joint (Bandai's joint_Root) its height was taken as the leg
// length, so a one-frame character file (the pelvis where the take starts) and the same
// rig with its animation (the pelvis at its OFFSET) got two scales (0.928 and 0.965).
TEST_F(RetargetTest, TheScaleIsTheLegsLengthWhereverThePelvisStands) {
  for (const double pelvis_height_m : {0.4, 0.9, 1.6}) {
    std::vector<Joint> joints;
    Joint floor;
    floor.name = "joint_Root";
    floor.type = JointType::kFixed;
    joints.push_back(floor);
    for (Joint j : source_->joints()) {
      j.parent = j.parent.is_valid() ? JointIndex(j.parent.value + 1) : JointIndex(0);
      joints.push_back(j);
    }
    joints[1].offset = Vec3(0.3, pelvis_height_m, -0.2);
    const Skeleton rig(std::move(joints));
    const RetargetMap map = MakeRetargetMap(*source_, {}, rig, {});
    EXPECT_NEAR(map.target_leg_length_m / map.source_leg_length_m, 1.0, 1e-9)
        << "pelvis at " << pelvis_height_m << " m";
  }
}

TEST_F(RetargetTest, AUniformlyScaledRigGetsTheSameJointAngles) {
  const auto big = Scaled(*source_, 1.25);
  Retargeter r(source_, big, MakeRetargetMap(*source_, {}, *big, {}), NoContacts());
  EXPECT_NEAR(r.scale(), 1.25, 1e-9);
  double worst = 0.0, worst_root = 0.0;
  for (size_t f = 0; f < motion_.size(); ++f) {
    const Pose& out = r.Retarget(motion_[f]);
    if (f < 5) continue;
    worst = std::max(worst, MaxRotationDifferenceDeg(out, motion_[f]));
    worst_root =
        std::max(worst_root, (out.translation[0] - 1.25 * motion_[f].translation[0]).norm());
  }
  EXPECT_LT(worst, 3.2);  // the lag of the pull toward the last pose, as above: 2.8 deg
  EXPECT_LT(worst_root, 0.01);
}

TEST_F(RetargetTest, APlantedFootDoesNotSlide) {
  // A character with longer legs but the same torso: scaled positions alone would not
  // keep its feet still.
  std::vector<Joint> joints(source_->joints().begin(), source_->joints().end());
  for (Joint& j : joints)
    if (j.name.find("Leg") != std::string::npos || j.name.find("Foot") != std::string::npos)
      j.offset *= 1.3;
  const auto leggy = std::make_shared<const Skeleton>(std::move(joints));
  Retargeter r(source_, leggy, MakeRetargetMap(*source_, {}, *leggy, {}), RetargetOptions{});
  const int ankle = leggy->FindJoint("LeftFoot")->value;
  Vec3 start = Vec3::Zero();
  double worst_slide = 0.0;
  int contacts = 0;
  bool was = false;
  for (size_t f = 0; f < motion_.size(); ++f) {
    r.Retarget(motion_[f]);
    // Contacts from 0.2 s on: the first frames settle the character from its rest pose.
    const bool planted = r.summary().planted[0] && f >= 24;
    const Vec3 ankle_at = r.kinematics().p_WJ[static_cast<size_t>(ankle)];
    if (planted && !was) {
      start = ankle_at;
      ++contacts;
    }
    if (planted)
      worst_slide =
          std::max(worst_slide, Vec3(ankle_at - start).cwiseProduct(Vec3(1, 0, 1)).norm());
    was = planted;
  }
  EXPECT_GE(contacts, 1);  // the procedural walk skates; its short true contacts count
  EXPECT_LT(worst_slide, 0.004);
}

// A character whose shoulders sit lower than the actor's, scaled (a short torso): its
// hands reach the actor's places from elsewhere, and turn no faster than the actor's do.
TEST_F(RetargetTest, AHandReachingFromOtherShouldersTurnsNoFasterThanTheActors) {
  std::vector<Joint> joints(source_->joints().begin(), source_->joints().end());
  for (Joint& j : joints)
    if (j.name == "Spine" || j.name == "Chest" || j.name == "Neck") j.offset *= 0.5;
  const auto short_torso = std::make_shared<const Skeleton>(std::move(joints));
  Retargeter r(source_, short_torso, MakeRetargetMap(*source_, {}, *short_torso, {}),
               RetargetOptions{});
  const std::vector<Pose> mixed = MakeHumanoidMotion(*source_, HumanoidMotion::kMixed, 20.0, 60.0);
  KinematicsWorkspace actor(*source_), actor_before(*source_), character_before(*short_torso);
  double worst_actor = 0.0, worst_character = 0.0;
  for (size_t f = 0; f < mixed.size(); ++f) {
    ForwardKinematics(*short_torso, r.pose(), &character_before);
    r.Retarget(mixed[f]);
    ForwardKinematics(*source_, mixed[f], &actor);
    for (const char* hand : {"LeftHand", "RightHand"}) {
      const auto a = static_cast<size_t>(source_->FindJoint(hand)->value);
      const auto c = static_cast<size_t>(short_torso->FindJoint(hand)->value);
      if (f >= 10) {
        worst_actor =
            std::max(worst_actor, Quat(actor.R_WJ[a]).angularDistance(Quat(actor_before.R_WJ[a])));
        worst_character =
            std::max(worst_character,
                     Quat(r.kinematics().R_WJ[c]).angularDistance(Quat(character_before.R_WJ[c])));
      }
    }
    actor_before = actor;
  }
  // On the old surface-point positions: 29.4 degrees a frame against the actor's 4.0.
  EXPECT_LT(worst_character, worst_actor + 5.0 * M_PI / 180.0)
      << "actor " << worst_actor * 180 / M_PI << " deg a frame";
}

// The same short torso: the actor's hand, scaled, is nearer the character's lower
// shoulder than the actor's own arm reaches, so reaching it the character must bend an
// elbow the actor keeps straighter, and a bent elbow's swivel is left to the arm's weak
// lever points (the CMU actor's characters flipped an upper arm 25 degrees a frame).
// Half the hand's goal is the actor's reach from the character's own shoulder: the
// elbow bends nearer the actor's.
TEST_F(RetargetTest, AnArmFromLowerShouldersBendsAsTheActorsDoes) {
  std::vector<Joint> joints(source_->joints().begin(), source_->joints().end());
  for (Joint& j : joints)
    if (j.name == "Spine" || j.name == "Chest" || j.name == "Neck") j.offset *= 0.5;
  const auto short_torso = std::make_shared<const Skeleton>(std::move(joints));
  const std::vector<Pose> mixed = MakeHumanoidMotion(*source_, HumanoidMotion::kMixed, 20.0, 60.0);
  auto elbow_bend = [](const Skeleton& rig, const KinematicsWorkspace& posed, const char* hand) {
    const int wrist = rig.FindJoint(hand)->value;
    const int elbow = rig.joint(wrist).parent.value, shoulder = rig.joint(elbow).parent.value;
    const Vec3 upper =
        posed.p_WJ[static_cast<size_t>(elbow)] - posed.p_WJ[static_cast<size_t>(shoulder)];
    const Vec3 lower =
        posed.p_WJ[static_cast<size_t>(wrist)] - posed.p_WJ[static_cast<size_t>(elbow)];
    return std::atan2(upper.cross(lower).norm(), upper.dot(lower));
  };
  auto worst_bend_difference = [&](double reach_share) {
    RetargetOptions options;
    options.hand_reach_share = reach_share;
    Retargeter r(source_, short_torso, MakeRetargetMap(*source_, {}, *short_torso, {}), options);
    KinematicsWorkspace actor(*source_);
    double worst = 0.0;
    for (size_t f = 0; f < mixed.size(); ++f) {
      r.Retarget(mixed[f]);
      ForwardKinematics(*source_, mixed[f], &actor);
      for (const char* hand : {"LeftHand", "RightHand"})
        worst = std::max(worst, std::abs(elbow_bend(*short_torso, r.kinematics(), hand) -
                                         elbow_bend(*source_, actor, hand)));
    }
    return worst * 180 / M_PI;
  };
  const double halfway = worst_bend_difference(RetargetOptions{}.hand_reach_share);
  const double scaled_only = worst_bend_difference(0.0);
  // Measured: 45 deg at half, 93 scaled alone, 1.7 on the reach alone.
  EXPECT_LT(halfway, 0.7 * scaled_only);
  EXPECT_LT(worst_bend_difference(1.0), 5.0);
}

// A character whose feet are built otherwise than the actor's (a toe twice as long, a
// foot shorter): no placement of its toe meets all of the actor's toe points, scaled, so
// its toe has two near-equal placements. With the solve's own velocity carried into the
// next frame it swung between them: here 35 degrees every frame while the actor stood
// still (on the CMU actor, Mixamo's toe turned 8-30 degrees a frame on a planted foot).
// Pulled toward its last pose, it stays, and a one-frame twitch of the actor's toe
// (0.1 rad) moves it out and back once.
TEST_F(RetargetTest, AWeaklyHeldToeStaysWhereTheActorsStays) {
  std::vector<Joint> joints(source_->joints().begin(), source_->joints().end());
  for (Joint& j : joints) {
    if (j.name.find("ToeBase") != std::string::npos) j.offset *= 2.0;
    if (j.name.find("Foot") != std::string::npos) j.offset *= 0.6;
  }
  const auto rig = std::make_shared<const Skeleton>(std::move(joints));
  const auto actor_toe = static_cast<size_t>(source_->FindJoint("LeftToeBase")->value);
  std::vector<Pose> still(90, motion_[0]);
  still[40].rotation[actor_toe] =
      (still[40].rotation[actor_toe] * Quat(Eigen::AngleAxisd(0.1, Vec3::UnitX()))).normalized();
  auto toe_travel_deg = [&](double gain) {
    RetargetOptions options;
    options.prediction_velocity_gain = gain;
    Retargeter r(source_, rig, MakeRetargetMap(*source_, {}, *rig, {}), options);
    KinematicsWorkspace before(*rig);
    const auto toe = static_cast<size_t>(rig->FindJoint("LeftToeBase")->value);
    double travelled = 0.0;
    for (size_t f = 0; f < still.size(); ++f) {
      ForwardKinematics(*rig, r.pose(), &before);
      r.Retarget(still[f]);
      if (f >= 10)
        travelled += Quat(r.kinematics().R_WJ[toe]).angularDistance(Quat(before.R_WJ[toe]));
    }
    return travelled * 180 / M_PI;
  };
  // Measured: 2800 deg at gain 1, 1500 at 0.25.
  EXPECT_LT(toe_travel_deg(RetargetOptions{}.prediction_velocity_gain), 3 * 5.73);
  EXPECT_GT(toe_travel_deg(1.0), 100.0);
}

// An actor standing still: the character's first frame is where the next frames go.
// The first frame was settled without the contact the second frame finds (a foot on
// the floor is planted only from the second frame, and then outweighs the rest) and
// without the solve's pull toward its last pose, which holds a weakly held toe where
// the settling left it: the CMU actor's Mixamo character turned its hips 7 degrees, a
// foot 11 and a toe 12 from frame 0 to frame 1, easing back over the next five.
TEST_F(RetargetTest, TheFirstFrameOfAStillActorIsWhereTheNextFramesStay) {
  std::vector<Joint> joints(source_->joints().begin(), source_->joints().end());
  for (Joint& j : joints) {
    if (j.name.find("ToeBase") != std::string::npos) j.offset *= 2.0;
    if (j.name.find("Foot") != std::string::npos) j.offset *= 0.6;
    if (j.name.find("UpLeg") != std::string::npos) j.offset *= 1.3;
  }
  const auto rig = std::make_shared<const Skeleton>(std::move(joints));
  Retargeter r(source_, rig, MakeRetargetMap(*source_, {}, *rig, {}), RetargetOptions{});
  const Pose first = r.Retarget(motion_[0]);
  double worst = 0.0;
  for (int f = 1; f < 10; ++f)
    worst = std::max(worst, MaxRotationDifferenceDeg(r.Retarget(motion_[0]), first));
  EXPECT_LT(worst, 1.0);  // 17 deg before
}

TEST_F(RetargetTest, TheMapReportsWhatMatchedAndRefusesUnknownOverrides) {
  const RetargetMap map = MakeRetargetMap(*source_, {}, *source_, {});
  EXPECT_NE(map.report.find("hand_l: LeftHand -> LeftHand (position)"), std::string::npos)
      << map.report;
  EXPECT_NE(map.report.find("chest:"), std::string::npos) << map.report;
  EXPECT_THROW(MakeRetargetMap(*source_, {}, *source_, {}, {{"hand_l", "NoSuchJoint"}}),
               std::invalid_argument);
  EXPECT_THROW(MakeRetargetMap(*source_, {}, *source_, {}, {{"tail", "Hips"}}),
               std::invalid_argument);
  // One joint, two roles: both hands on one joint, or a hand on the hips.
  EXPECT_THROW(MakeRetargetMap(*source_, {}, *source_, {}, {{"hand_r", "LeftHand"}}),
               std::invalid_argument);
  EXPECT_THROW(MakeRetargetMap(*source_, {}, *source_, {}, {{"hand_l", "Hips"}}),
               std::invalid_argument);
}

TEST_F(RetargetTest, ARetargetedFrameAllocatesNothing) {
  const auto big = Scaled(*source_, 0.8);
  Retargeter r(source_, big, MakeRetargetMap(*source_, {}, *big, {}), RetargetOptions{});
  for (size_t f = 0; f < 10; ++f) r.Retarget(motion_[f]);
  testing::ScopedAllocationCounter counter;
  for (size_t f = 10; f < 60; ++f) r.Retarget(motion_[f]);
  EXPECT_EQ(counter.count(), 0u);
}

}  // namespace
}  // namespace mocapd
