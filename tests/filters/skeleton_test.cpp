// Tests for skeleton validation, forward kinematics and pose updates.
#include "filters/skeleton.hpp"

#include <gtest/gtest.h>

#include "filters/rotation.hpp"

namespace mocapd {
namespace {

Joint MakeJoint(const std::string& name, int parent, Vec3 offset,
                JointType type = JointType::kBall) {
  Joint j;
  j.name = name;
  j.parent = JointIndex(parent);
  j.offset = offset;
  j.type = type;
  return j;
}

// root (free) -> upper (ball, 1 m up) -> lower (hinge about z, 1 m along x)
Skeleton MakeArm() {
  Joint hinge = MakeJoint("lower", 1, Vec3(1, 0, 0), JointType::kHinge);
  hinge.hinge_axis = Vec3::UnitZ();
  return Skeleton({MakeJoint("root", -1, Vec3::Zero(), JointType::kFree),
                   MakeJoint("upper", 0, Vec3(0, 1, 0)), hinge});
}

TEST(SkeletonTest, CountsDofsPerJointType) {
  const Skeleton dut = MakeArm();
  EXPECT_EQ(dut.num_dofs(), 6 + 3 + 1);
  EXPECT_EQ(dut.dof_offset(0), 0);
  EXPECT_EQ(dut.dof_offset(1), 6);
  EXPECT_EQ(dut.dof_offset(2), 9);
  EXPECT_EQ(dut.children(0), std::vector<int>{1});
  EXPECT_TRUE(dut.IsAncestorOrSelf(0, 2));
  EXPECT_FALSE(dut.IsAncestorOrSelf(2, 1));
}

TEST(SkeletonTest, RejectsInvalidSkeletons) {
  EXPECT_THROW(Skeleton({}), std::invalid_argument);
  try {
    Skeleton({MakeJoint("a", -1, Vec3::Zero()), MakeJoint("a", 0, Vec3::Zero())});
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("'a' is repeated"), std::string::npos);
  }
  try {
    Skeleton({MakeJoint("a", -1, Vec3::Zero()), MakeJoint("b", 2, Vec3::Zero()),
              MakeJoint("c", 0, Vec3::Zero())});
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("'b' has parent index 2"), std::string::npos);
  }
  EXPECT_THROW(Skeleton({MakeJoint("a", -1, Vec3::Zero()), MakeJoint("b", -1, Vec3::Zero())}),
               std::invalid_argument);
  Joint bad_hinge = MakeJoint("h", 0, Vec3::Zero(), JointType::kHinge);
  bad_hinge.hinge_axis = Vec3(1, 1, 0);
  EXPECT_THROW(Skeleton({MakeJoint("a", -1, Vec3::Zero()), bad_hinge}), std::invalid_argument);
}

TEST(SkeletonTest, ForwardKinematicsComposesParentTransforms) {
  const Skeleton dut = MakeArm();
  Pose pose = RestPose(dut);
  pose.translation[0] = Vec3(5, 0, 0);
  pose.rotation[0] = Quat(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()));  // root yaw 90 deg about z
  pose.rotation[2] = Quat(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()));
  KinematicsWorkspace ws(dut);
  ForwardKinematics(dut, pose, &ws);
  // upper: root + Rz(90) * (0,1,0) = (5,0,0) + (-1,0,0)
  EXPECT_LT((ws.p_WJ[1] - Vec3(4, 0, 0)).norm(), 1e-12);
  // lower: upper + Rz(90) * (1,0,0) = (4,0,0) + (0,1,0)
  EXPECT_LT((ws.p_WJ[2] - Vec3(4, 1, 0)).norm(), 1e-12);
  EXPECT_LT((ws.R_WJ[2] - Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitZ()))).norm(), 1e-12);
}

TEST(SkeletonTest, PoseDifferenceInvertsIntegratePose) {
  const Skeleton dut = MakeArm();
  const Pose a = RestPose(dut);
  Eigen::VectorXd dq(dut.num_dofs());
  dq << 0.1, -0.2, 0.3, 0.4, -0.5, 0.6, -0.7, 0.8, 0.2, -0.9;
  Pose b = a;
  IntegratePose(dut, dq, &b);
  Eigen::VectorXd back(dut.num_dofs());
  PoseDifference(dut, a, b, back);
  EXPECT_LT((back - dq).norm(), 1e-12);
}

TEST(SkeletonTest, JointLimitsClampTheAngleFromRest) {
  Joint limited = MakeJoint("b", 0, Vec3::UnitY());
  limited.max_angle_rad = 0.5;
  const Skeleton dut({MakeJoint("a", -1, Vec3::Zero()), limited});
  Pose pose = RestPose(dut);
  pose.rotation[1] = ExpRotation(Vec3(0, 0, 1.2));
  ApplyJointLimits(dut, &pose);
  EXPECT_NEAR(LogRotation(pose.rotation[1]).z(), 0.5, 1e-12);
  pose.rotation[1] = ExpRotation(Vec3(0, 0.3, 0));
  ApplyJointLimits(dut, &pose);
  EXPECT_NEAR(LogRotation(pose.rotation[1]).y(), 0.3, 1e-12);  // inside the limit: untouched
}

}  // namespace
}  // namespace mocapd
