// Tests for the LBS marker model: evaluation, validation and the analytic Jacobian.
#include "filters/marker_model.hpp"

#include <gtest/gtest.h>

#include <random>

#include "filters/rotation.hpp"

namespace mocapd {
namespace {

Skeleton MakeChain() {
  std::vector<Joint> joints(4);
  joints[0].name = "root";
  joints[0].type = JointType::kFree;
  joints[1].name = "a";
  joints[1].parent = JointIndex(0);
  joints[1].offset = Vec3(0, 0.4, 0);
  joints[2].name = "b";
  joints[2].parent = JointIndex(1);
  joints[2].offset = Vec3(0.3, 0, 0.05);
  joints[2].type = JointType::kHinge;
  joints[2].hinge_axis = Vec3(0, 0.6, 0.8);
  joints[3].name = "c";
  joints[3].parent = JointIndex(2);
  joints[3].offset = Vec3(0.25, -0.02, 0);
  return Skeleton(joints);
}

MarkerDefinition Rigid(const std::string& name, int joint, Vec3 offset) {
  MarkerDefinition m;
  m.name = name;
  m.attachments[0] = {joint, 1.0, offset};
  return m;
}

MarkerDefinition Blend(const std::string& name, int child, int parent, double parent_weight,
                       Vec3 child_offset, Vec3 parent_offset) {
  MarkerDefinition m;
  m.name = name;
  m.num_attachments = 2;
  m.attachments[0] = {child, 1.0 - parent_weight, child_offset};
  m.attachments[1] = {parent, parent_weight, parent_offset};
  return m;
}

TEST(MarkerModelTest, AnalyticJacobianMatchesFiniteDifferences) {
  const Skeleton skeleton = MakeChain();
  const MarkerSet dut(skeleton,
                      {Rigid("m0", 0, Vec3(0.1, 0, 0)), Rigid("m1", 1, Vec3(0.02, 0.1, 0.05)),
                       Rigid("m2", 2, Vec3(0.1, 0.04, -0.03)), Rigid("m3", 3, Vec3(0.2, 0.0, 0.06)),
                       Blend("m4", 2, 1, 0.4, Vec3(0.0, 0.05, 0.0), Vec3(0.3, 0.05, 0.05))});
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    Pose pose = RestPose(skeleton);
    for (auto& q : pose.rotation) q = ExpRotation(Vec3(u(rng), u(rng), u(rng)));
    pose.rotation[2] = ExpRotation(skeleton.joint(2).hinge_axis * u(rng));
    pose.translation[0] = Vec3(u(rng), u(rng), u(rng)) * 3.0;
    KinematicsWorkspace ws(skeleton);
    ForwardKinematics(skeleton, pose, &ws);
    const Eigen::MatrixXd J = MarkerJacobian(skeleton, dut, ws);
    const double h = 1e-6;
    for (int k = 0; k < skeleton.num_dofs(); ++k) {
      Eigen::VectorXd dq = Eigen::VectorXd::Zero(skeleton.num_dofs());
      dq[k] = h;
      Pose plus = pose, minus = pose;
      IntegratePose(skeleton, dq, &plus);
      IntegratePose(skeleton, -dq, &minus);
      KinematicsWorkspace wp(skeleton), wm(skeleton);
      ForwardKinematics(skeleton, plus, &wp);
      ForwardKinematics(skeleton, minus, &wm);
      for (int m = 0; m < dut.num_markers(); ++m) {
        const Vec3 fd =
            (EvaluateMarker(dut.marker(m), wp) - EvaluateMarker(dut.marker(m), wm)) / (2 * h);
        EXPECT_LT((J.block<3, 1>(3 * m, k) - fd).norm(), 1e-7) << "marker " << m << " dof " << k;
      }
    }
  }
}

TEST(MarkerModelTest, BlendInterpolatesTheTwoRigidPositions) {
  const Skeleton skeleton = MakeChain();
  const MarkerSet dut(skeleton, {Blend("k", 3, 2, 0.25, Vec3(0, 0.1, 0), Vec3(0.25, 0.1, 0))});
  Pose pose = RestPose(skeleton);
  pose.rotation[3] = ExpRotation(Vec3(0, 0, 0.8));
  KinematicsWorkspace ws(skeleton);
  ForwardKinematics(skeleton, pose, &ws);
  const Vec3 on_child = ws.R_WJ[3] * Vec3(0, 0.1, 0) + ws.p_WJ[3];
  const Vec3 on_parent = ws.R_WJ[2] * Vec3(0.25, 0.1, 0) + ws.p_WJ[2];
  EXPECT_LT((EvaluateMarker(dut.marker(0), ws) - (0.75 * on_child + 0.25 * on_parent)).norm(),
            1e-12);
}

TEST(MarkerModelTest, NormalisesBlendOrderToChildThenParent) {
  const Skeleton skeleton = MakeChain();
  const MarkerSet dut(skeleton,
                      {Blend("k", 1, 2, 0.5, Vec3::Zero(), Vec3::Zero())});  // listed parent first
  EXPECT_EQ(dut.marker(0).attachments[0].joint, 2);
  EXPECT_EQ(dut.marker(0).attachments[1].joint, 1);
}

TEST(MarkerModelTest, RejectsInvalidMarkerSets) {
  const Skeleton skeleton = MakeChain();
  auto expect_message = [&](std::vector<MarkerDefinition> defs, const std::string& text) {
    try {
      MarkerSet(skeleton, std::move(defs));
      FAIL() << "expected a throw mentioning " << text;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    }
  };
  expect_message({Rigid("x", 0, Vec3::Zero()), Rigid("x", 1, Vec3::Zero())}, "'x' is repeated");
  expect_message({Rigid("x", 9, Vec3::Zero())}, "joint index 9");
  expect_message({Blend("x", 3, 1, 0.5, Vec3::Zero(), Vec3::Zero())}, "not parent and child");
  MarkerDefinition bad_weights = Blend("w", 3, 2, 0.5, Vec3::Zero(), Vec3::Zero());
  bad_weights.attachments[1].weight = 0.7;
  expect_message({bad_weights}, "sum to");
  expect_message({Rigid("", 0, Vec3::Zero())}, "empty name");
}

}  // namespace
}  // namespace mocapd
