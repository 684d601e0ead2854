// Tests for the unseen-knee rule: which chains are legs, what a leg learns where its
// thigh and shin are seen, and the turn that takes an unseen knee back to its side.
#include "filters/knee_swivel.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <string>

#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

class KneeSwivelTest : public ::testing::Test {
 protected:
  KneeSwivelTest() : fixture_(testing::MakeHumanoidFixture("walk", 4.0, 60.0)) {}

  const Skeleton& skeleton() const { return straight_toes_ ? *straight_toes_ : *fixture_.skeleton; }
  const MarkerSet& markers() const { return *fixture_.markers; }

  // Model markers of a pose: what a perfect capture sees.
  std::vector<Vec3> MarkersOf(const Pose& pose) const {
    KinematicsWorkspace ws(skeleton());
    ForwardKinematics(skeleton(), pose, &ws);
    std::vector<Vec3> out(static_cast<size_t>(markers().num_markers()));
    EvaluateMarkers(markers(), ws, out);
    return out;
  }
  // Weights with the leg's thigh and shin markers unseen.
  std::vector<double> ThighAndShinUnseen(const LegChain& leg) const {
    std::vector<double> w(static_cast<size_t>(markers().num_markers()), 1.0);
    for (int m = 0; m < markers().num_markers(); ++m)
      if (markers().primary_joint(m) == leg.hip || markers().primary_joint(m) == leg.knee)
        w[static_cast<size_t>(m)] = 0.0;
    return w;
  }
  // The knee's bend in a pose, radians.
  double Bend(const Pose& pose, const LegChain& leg) const {
    KinematicsWorkspace ws(skeleton());
    ForwardKinematics(skeleton(), pose, &ws);
    const Vec3 thigh =
        ws.p_WJ[static_cast<size_t>(leg.knee)] - ws.p_WJ[static_cast<size_t>(leg.hip)];
    const Vec3 shin =
        ws.p_WJ[static_cast<size_t>(leg.ankle)] - ws.p_WJ[static_cast<size_t>(leg.knee)];
    return std::acos(std::clamp(thigh.normalized().dot(shin.normalized()), -1.0, 1.0));
  }
  // The pose with the leg swung by angle about its hip-ankle line, the foot's world
  // orientation kept: the other side of the circle the foot leaves the knee on.
  Pose Swung(const Pose& pose, const LegChain& leg, double angle) const {
    KinematicsWorkspace ws(skeleton());
    ForwardKinematics(skeleton(), pose, &ws);
    const auto at = [](int j) { return static_cast<size_t>(j); };
    const Vec3 line = (ws.p_WJ[at(leg.ankle)] - ws.p_WJ[at(leg.hip)]).normalized();
    const Mat3 turn = Eigen::AngleAxisd(angle, line).toRotationMatrix();
    const Mat3 R_WP = ws.R_WJ[at(skeleton().joint(leg.hip).parent.value)];
    const Mat3 R_WH = turn * ws.R_WJ[at(leg.hip)];
    const Mat3 R_WK = R_WH * pose.rotation[at(leg.knee)].toRotationMatrix();
    Pose out = pose;
    out.rotation[at(leg.hip)] = Quat(R_WP.transpose() * R_WH);
    out.rotation[at(leg.ankle)] = Quat(R_WK.transpose() * ws.R_WJ[at(leg.ankle)]);
    return out;
  }
  // The frame of the walk where the leg's knee is bent most.
  int MostBentFrame(const LegChain& leg) const {
    int best = 0;
    for (int f = 0; f < static_cast<int>(fixture_.motion.size()); ++f)
      if (Bend(fixture_.motion[static_cast<size_t>(f)], leg) >
          Bend(fixture_.motion[static_cast<size_t>(best)], leg))
        best = f;
    return best;
  }
  // Learns from every frame of the walk, every marker seen.
  void LearnFromTheWalk(KneeSwivel* swivel) const {
    const std::vector<double> all(static_cast<size_t>(markers().num_markers()), 1.0);
    KinematicsWorkspace ws(skeleton());
    for (const Pose& truth : fixture_.motion) {
      Pose pose = truth;
      ForwardKinematics(skeleton(), pose, &ws);
      EXPECT_EQ(swivel->Update(skeleton(), MarkersOf(truth), all, 0.785, 0.0, &pose, &ws), 0);
    }
  }

  // From here on the skeleton is the humanoid with each toe bone along its leg at rest
  // (as in some BVH exports): a rest pose that says nothing of which way the knees bend.
  void StraightenTheToes() {
    std::vector<Joint> joints(fixture_.skeleton->joints().begin(),
                              fixture_.skeleton->joints().end());
    KinematicsWorkspace rest(*fixture_.skeleton);
    ForwardKinematics(*fixture_.skeleton, RestPose(*fixture_.skeleton), &rest);
    for (const LegChain& leg : FindLegChains(*fixture_.skeleton)) {
      const auto at = [](int j) { return static_cast<size_t>(j); };
      const Vec3 down = (rest.p_WJ[at(leg.ankle)] - rest.p_WJ[at(leg.hip)]).normalized();
      Joint& toe = joints[at(leg.toe)];
      toe.offset = rest.R_WJ[at(leg.ankle)].transpose() * down * toe.offset.norm();
    }
    straight_toes_ = std::make_unique<Skeleton>(std::move(joints));
  }

  testing::HumanoidFixture fixture_;
  std::unique_ptr<Skeleton> straight_toes_;
};

TEST_F(KneeSwivelTest, FindsTheTwoLegsAndNotTheArms) {
  const std::vector<LegChain> legs = FindLegChains(skeleton());
  ASSERT_EQ(legs.size(), 2u);
  for (const LegChain& leg : legs) {
    EXPECT_NE(skeleton().joint(leg.hip).name.find("UpLeg"), std::string::npos);
    EXPECT_TRUE(skeleton().children(leg.toe).empty());
  }
}

TEST(KneeSwivelLegsTest, LegsWhoseHipsHangFromJointsOfTheirOwnShareThePelvis) {
  // CMU-style: Hips -> LHipJoint -> LeftUpLeg -> LeftLeg -> LeftFoot -> LeftToeBase. Each
  // leg's hip has a parent of its own, but both chains branch from Hips, which is the
  // frame a leg that never showed its knee borrows the other's axis in.
  std::vector<Joint> joints;
  auto add = [&](const char* name, int parent, Vec3 offset) {
    Joint j;
    j.name = name;
    if (parent >= 0) j.parent = JointIndex(parent);
    j.offset = offset;
    joints.push_back(j);
    return static_cast<int>(joints.size()) - 1;
  };
  const int hips = add("Hips", -1, Vec3::Zero());
  add("Spine", hips, Vec3(0, 0, 0.1));
  for (const double side : {1.0, -1.0}) {
    int j = add(side > 0 ? "LHipJoint" : "RHipJoint", hips, Vec3(0.1 * side, 0, 0));
    for (const char* part : {"UpLeg", "Leg", "Foot", "ToeBase"})
      j = add((std::string(side > 0 ? "Left" : "Right") + part).c_str(), j, Vec3(0, 0, -0.4));
  }
  const std::vector<LegChain> legs = FindLegChains(Skeleton(joints));
  ASSERT_EQ(legs.size(), 2u);
  for (const LegChain& leg : legs) {
    EXPECT_EQ(leg.pelvis, hips);
    EXPECT_NE(joints[static_cast<size_t>(leg.hip)].parent.value, hips);
  }
}

TEST_F(KneeSwivelTest, AKneeSwungBehindItsUnseenLegIsTurnedBackWithTheFootKept) {
  KneeSwivel swivel(skeleton(), markers());
  ASSERT_EQ(swivel.num_legs(), 2);
  LearnFromTheWalk(&swivel);
  for (int i = 0; i < swivel.num_legs(); ++i) {
    const LegChain& leg = swivel.leg(i);
    ASSERT_GT(swivel.AxisInFoot(i).norm(), 0.99);
    const Pose& truth = fixture_.motion[static_cast<size_t>(MostBentFrame(leg))];
    ASSERT_GT(Bend(truth, leg), 0.5);
    Pose pose = Swung(truth, leg, 2.6);  // 150 degrees round: the knee behind the leg
    KinematicsWorkspace ws(skeleton()), truth_ws(skeleton());
    ForwardKinematics(skeleton(), pose, &ws);
    ForwardKinematics(skeleton(), truth, &truth_ws);
    const auto at = [](int j) { return static_cast<size_t>(j); };
    const double knee_off_before = (ws.p_WJ[at(leg.knee)] - truth_ws.p_WJ[at(leg.knee)]).norm();
    ASSERT_GT(knee_off_before, 0.2);
    EXPECT_EQ(swivel.Update(skeleton(), MarkersOf(truth), ThighAndShinUnseen(leg), 0.785, 0.0,
                            &pose, &ws),
              1);
    // Turned to the 45-degree tolerance of an axis the walk shows within a few degrees.
    const double knee_off_after = (ws.p_WJ[at(leg.knee)] - truth_ws.p_WJ[at(leg.knee)]).norm();
    EXPECT_LT(knee_off_after, 0.5 * knee_off_before);
    EXPECT_LT((ws.p_WJ[at(leg.ankle)] - truth_ws.p_WJ[at(leg.ankle)]).norm(), 1e-9);
    EXPECT_LT((ws.R_WJ[at(leg.ankle)] - truth_ws.R_WJ[at(leg.ankle)]).norm(), 1e-9);
    EXPECT_LT((ws.p_WJ[at(leg.toe)] - truth_ws.p_WJ[at(leg.toe)]).norm(), 1e-9);
  }
}

TEST_F(KneeSwivelTest, ALegThatNeverShowedItsKneeBorrowsTheOtherLegsAxisInThePelvis) {
  // Toes along the leg at rest, and one leg's thigh and shin never seen: that leg has no
  // axis of its own, but the other leg's, taken in the pelvis, says which way it bends.
  StraightenTheToes();
  KneeSwivel swivel(skeleton(), markers());
  ASSERT_EQ(swivel.num_legs(), 2);
  const LegChain& unseen = swivel.leg(0);
  for (int i = 0; i < swivel.num_legs(); ++i) EXPECT_EQ(swivel.AxisInFoot(i).norm(), 0.0);
  KinematicsWorkspace ws(skeleton());
  for (const Pose& truth : fixture_.motion) {
    Pose pose = truth;
    ForwardKinematics(skeleton(), pose, &ws);
    swivel.Update(skeleton(), MarkersOf(truth), ThighAndShinUnseen(unseen), 0.0, 0.0, &pose, &ws);
  }
  EXPECT_EQ(swivel.AxisInFoot(0).norm(), 0.0);
  EXPECT_GT(swivel.AxisInFoot(1).norm(), 0.99);
  ASSERT_GT(swivel.BorrowedAxisInPelvis(0).norm(), 0.99);

  const Pose& truth = fixture_.motion[static_cast<size_t>(MostBentFrame(unseen))];
  Pose pose = Swung(truth, unseen, 2.6);  // the knee behind the leg
  KinematicsWorkspace truth_ws(skeleton());
  ForwardKinematics(skeleton(), pose, &ws);
  ForwardKinematics(skeleton(), truth, &truth_ws);
  const auto knee = static_cast<size_t>(unseen.knee);
  const double knee_off_before = (ws.p_WJ[knee] - truth_ws.p_WJ[knee]).norm();
  ASSERT_GT(knee_off_before, 0.2);
  EXPECT_EQ(swivel.Update(skeleton(), MarkersOf(truth), ThighAndShinUnseen(unseen), 0.785, 0.0,
                          &pose, &ws),
            1);
  EXPECT_LT((ws.p_WJ[knee] - truth_ws.p_WJ[knee]).norm(), 0.5 * knee_off_before);
}

// On the very first solve (a take whose one leg is unseen from its first frame) the
// other leg's axis, learned in that same solve, already says which way the unseen knee
// bends: every seen leg learns before any unseen one is turned. The unseen leg came first
// and was passed over, and a Bandai run's knee stayed 30 cm off.
TEST_F(KneeSwivelTest, OnItsFirstSolveAnUnseenLegBorrowsTheAxisTheOtherLegShowsThere) {
  StraightenTheToes();
  KneeSwivel swivel(skeleton(), markers());
  ASSERT_EQ(swivel.num_legs(), 2);
  const LegChain& unseen = swivel.leg(0);
  // Both knees bent (a straight seen leg shows no axis): the unseen leg's most bent frame,
  // with the seen leg's local rotations from its own.
  const LegChain& seen = swivel.leg(1);
  Pose truth = fixture_.motion[static_cast<size_t>(MostBentFrame(unseen))];
  const Pose& seen_bent = fixture_.motion[static_cast<size_t>(MostBentFrame(seen))];
  for (const int j : {seen.hip, seen.knee, seen.ankle})
    truth.rotation[static_cast<size_t>(j)] = seen_bent.rotation[static_cast<size_t>(j)];
  Pose pose = Swung(truth, unseen, 2.6);  // the knee behind the leg
  KinematicsWorkspace ws(skeleton()), truth_ws(skeleton());
  ForwardKinematics(skeleton(), pose, &ws);
  ForwardKinematics(skeleton(), truth, &truth_ws);
  const auto knee = static_cast<size_t>(unseen.knee);
  const double knee_off_before = (ws.p_WJ[knee] - truth_ws.p_WJ[knee]).norm();
  EXPECT_EQ(swivel.Update(skeleton(), MarkersOf(truth), ThighAndShinUnseen(unseen), 0.785, 0.0,
                          &pose, &ws),
            1);
  EXPECT_LT((ws.p_WJ[knee] - truth_ws.p_WJ[knee]).norm(), 0.5 * knee_off_before);
}

TEST_F(KneeSwivelTest, ATurnIsBoundedPerSolveAndASeenOrStraightKneeIsLeftAlone) {
  KneeSwivel swivel(skeleton(), markers());
  LearnFromTheWalk(&swivel);
  const LegChain& leg = swivel.leg(0);
  const Pose& truth = fixture_.motion[static_cast<size_t>(MostBentFrame(leg))];
  const Pose swung = Swung(truth, leg, 2.6);
  const auto at = [](int j) { return static_cast<size_t>(j); };
  KinematicsWorkspace ws(skeleton());

  // At most 0.1 rad per solve: the hip turns by 0.1 rad, no more.
  Pose pose = swung;
  ForwardKinematics(skeleton(), pose, &ws);
  EXPECT_EQ(
      swivel.Update(skeleton(), MarkersOf(truth), ThighAndShinUnseen(leg), 0.785, 0.1, &pose, &ws),
      1);
  EXPECT_NEAR(pose.rotation[at(leg.hip)].angularDistance(swung.rotation[at(leg.hip)]), 0.1, 1e-6);
  // The solve's previous pose is turned alike: the turn is no motion to predict on with.
  Pose previous = swung;
  pose = swung;
  ForwardKinematics(skeleton(), pose, &ws);
  swivel.Update(skeleton(), MarkersOf(truth), ThighAndShinUnseen(leg), 0.785, 0.1, &pose, &ws,
                &previous);
  EXPECT_TRUE(previous.rotation[at(leg.hip)].isApprox(pose.rotation[at(leg.hip)], 1e-12));
  EXPECT_TRUE(previous.rotation[at(leg.ankle)].isApprox(pose.rotation[at(leg.ankle)], 1e-12));

  // A thigh or shin marker seen decides where the knee is.
  std::vector<double> one_seen = ThighAndShinUnseen(leg);
  for (int m = 0; m < markers().num_markers(); ++m)
    if (markers().primary_joint(m) == leg.knee) one_seen[static_cast<size_t>(m)] = 1.0;
  pose = swung;
  ForwardKinematics(skeleton(), pose, &ws);
  EXPECT_EQ(swivel.Update(skeleton(), MarkersOf(truth), one_seen, 0.785, 0.0, &pose, &ws), 0);
  EXPECT_TRUE(pose.rotation[at(leg.hip)].isApprox(swung.rotation[at(leg.hip)]));

  // A straight leg has no side to be on.
  pose = RestPose(skeleton());
  pose.translation = truth.translation;
  ForwardKinematics(skeleton(), pose, &ws);
  const Pose rest = pose;
  swivel.Update(skeleton(), MarkersOf(rest), ThighAndShinUnseen(leg), 0.785, 0.0, &pose, &ws);
  EXPECT_TRUE(pose.rotation[at(leg.hip)].isApprox(rest.rotation[at(leg.hip)]));

  // Off: nothing turns.
  pose = swung;
  ForwardKinematics(skeleton(), pose, &ws);
  EXPECT_EQ(
      swivel.Update(skeleton(), MarkersOf(truth), ThighAndShinUnseen(leg), 0.0, 0.0, &pose, &ws),
      0);
}

}  // namespace
}  // namespace mocapd
