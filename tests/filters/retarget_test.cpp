// Tests for retargeting: identical rigs give the identity, a uniformly scaled rig the
// same joint angles, planted feet do not slide, the map reports what matched, and a
// frame allocates nothing.
#include "filters/retarget.hpp"

#include <gtest/gtest.h>

#include "formats/bvh.hpp"
#include "formats/marker_layout.hpp"
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
    if (f < 5) continue;  // the warm start settles from the cold first frame
    worst = std::max(worst, MaxRotationDifferenceDeg(out, motion_[f]));
    worst_root = std::max(worst_root, (out.translation[0] - motion_[f].translation[0]).norm());
  }
  EXPECT_LT(worst, 2.0);
  EXPECT_LT(worst_root, 0.005);
}

// A character whose rest pose faces +X, or stands on +Z (as 3ds Max and Blender write
// some rigs): its hips and shoulders turn as the actor's do. The angle around each bone
// was measured from the world's axes, so such a character's thighs and shins came out
// turned 86 degrees about their bones, and one facing +X its whole body.
TEST_F(RetargetTest, ACharacterFacingAnotherWayOrStandingOnZTurnsAsTheActorDoes) {
  const HumanoidRoles roles = MatchHumanoidRoles(*source_);
  auto left_right = [&](const KinematicsWorkspace& ws, const char* l, const char* r) {
    return Vec3(ws.p_WJ[static_cast<size_t>(roles.joint_of_role.at(l))] -
                ws.p_WJ[static_cast<size_t>(roles.joint_of_role.at(r))])
        .normalized();
  };
  for (const Quat& turn : {Quat(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitY())),
                           Quat(Eigen::AngleAxisd(-M_PI / 2, Vec3::UnitX()))}) {
    std::vector<Joint> joints(source_->joints().begin(), source_->joints().end());
    joints[0].rest_rotation = turn * joints[0].rest_rotation;
    const auto turned = std::make_shared<const Skeleton>(std::move(joints));
    Retargeter r(source_, turned, MakeRetargetMap(*source_, {}, *turned, {}), NoContacts());
    KinematicsWorkspace actor(*source_), character(*turned);
    double worst_deg = 0.0;
    for (size_t f = 0; f < motion_.size(); ++f) {
      ForwardKinematics(*turned, r.Retarget(motion_[f]), &character);
      ForwardKinematics(*source_, motion_[f], &actor);
      if (f < 5) continue;
      for (const auto& [l, rr] : {std::pair{"thigh_l", "thigh_r"},
                                  {"upper_arm_l", "upper_arm_r"},
                                  {"shin_l", "shin_r"},
                                  {"forearm_l", "forearm_r"}})
        worst_deg = std::max(
            worst_deg, std::acos(std::clamp(
                           left_right(actor, l, rr).dot(left_right(character, l, rr)), -1.0, 1.0)) *
                           180.0 / M_PI);
    }
    EXPECT_LT(worst_deg, 10.0) << "rest turned " << turn.coeffs().transpose();
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
  EXPECT_LT(worst, 2.0);
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

TEST_F(RetargetTest, TheMapReportsWhatMatchedAndRefusesUnknownOverrides) {
  const RetargetMap map = MakeRetargetMap(*source_, {}, *source_, {});
  EXPECT_NE(map.report.find("hand_l: LeftHand -> LeftHand (position)"), std::string::npos)
      << map.report;
  EXPECT_NE(map.report.find("chest:"), std::string::npos) << map.report;
  EXPECT_THROW(MakeRetargetMap(*source_, {}, *source_, {}, {{"hand_l", "NoSuchJoint"}}),
               std::invalid_argument);
  EXPECT_THROW(MakeRetargetMap(*source_, {}, *source_, {}, {{"tail", "Hips"}}),
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
