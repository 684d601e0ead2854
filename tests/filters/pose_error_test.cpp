// Tests for the joint error statistics: a frame's error is its worst joint's, so one bad
// joint in one frame shows in the worst frame and the high quantiles, not in the median.
#include "filters/pose_error.hpp"

#include <gtest/gtest.h>

#include "sim/humanoid.hpp"

namespace mocapd {
namespace {

TEST(PoseErrorTest, AFramesErrorIsItsWorstJointAndTheWorstFrameIsFound) {
  const Skeleton skeleton = MakeHumanoidSkeleton();
  const Pose rest = RestPose(skeleton);
  KinematicsWorkspace truth(skeleton), estimate(skeleton);
  ForwardKinematics(skeleton, rest, &truth);
  PoseErrorAccumulator errors(skeleton);
  EXPECT_EQ(errors.worst_frame(), -1);
  const int last = skeleton.num_joints() - 1;
  for (int f = 0; f < 2000; ++f) {
    estimate = truth;
    // Every frame 1 mm off on one joint; frame 1500 has one joint 5 cm off.
    estimate.p_WJ[static_cast<size_t>(f % skeleton.num_joints())] += Vec3(0.001, 0, 0);
    if (f == 1500) estimate.p_WJ[static_cast<size_t>(last)] += Vec3(0, 0.05, 0);
    errors.Add(truth, estimate);
  }
  int joint = -1;
  EXPECT_EQ(errors.worst_frame(&joint), 1500);
  EXPECT_EQ(joint, last);
  EXPECT_NEAR(errors.frame_position_error_quantile_m(0.5), 0.001, 1e-12);
  EXPECT_NEAR(errors.frame_position_error_quantile_m(1.0), 0.05, 1e-3);
  // One bad frame in 2000 sits above the 99.9th percentile's rank (the 1998th).
  EXPECT_NEAR(errors.frame_position_error_quantile_m(0.999), 0.001, 1e-12);
}

TEST(PoseErrorTest, TheFramesAtOrAboveAnErrorAreListedWithTheirWorstJoint) {
  const Skeleton skeleton = MakeHumanoidSkeleton();
  KinematicsWorkspace truth(skeleton), estimate(skeleton);
  ForwardKinematics(skeleton, RestPose(skeleton), &truth);
  PoseErrorAccumulator errors(skeleton);
  const int last = skeleton.num_joints() - 1;
  for (int f = 0; f < 10; ++f) {
    estimate = truth;
    // Joint 1: f mm off (its rest position is 0 along x, so the error is exactly that
    // double and the threshold below is met with equality by frame 8).
    estimate.p_WJ[1] += Vec3(0.001 * f, 0, 0);
    if (f == 3) estimate.p_WJ[static_cast<size_t>(last)] += Vec3(0, 0, 0.02);
    errors.Add(truth, estimate);
  }
  const auto tail = errors.frames_at_least(0.008);
  ASSERT_EQ(tail.size(), 3u);  // frames 3 (2 cm, the last joint), 8 and 9
  EXPECT_EQ(tail[0].frame, 3);
  EXPECT_EQ(tail[0].joint, last);
  EXPECT_NEAR(tail[0].error_m, 0.02, 1e-12);
  EXPECT_EQ(tail[1].frame, 8);
  EXPECT_EQ(tail[1].joint, 1);
  EXPECT_EQ(tail[2].frame, 9);
  EXPECT_NEAR(tail[2].error_m, 0.009, 1e-12);
  EXPECT_TRUE(errors.frames_at_least(0.05).empty());
}

}  // namespace
}  // namespace mocapd
