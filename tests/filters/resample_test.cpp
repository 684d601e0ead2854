// Tests for slerp/lerp motion resampling.
#include "filters/resample.hpp"

#include <gtest/gtest.h>

#include "filters/rotation.hpp"
#include "sim/humanoid.hpp"

namespace mocapd {
namespace {

TEST(ResampleTest, ResampleKeepsDurationAndSlerpsBetweenFrames) {
  const Skeleton sk = MakeHumanoidSkeleton();
  std::vector<Pose> frames(3, RestPose(sk));
  frames[1].rotation[1] = ExpRotation(Vec3(0, 0, 0.4));
  frames[2].rotation[1] = ExpRotation(Vec3(0, 0, 0.8));
  frames[2].translation[0] += Vec3(0.3, 0, 0);
  const auto dut = ResampleMotion(sk, frames, 30.0, 120.0);
  ASSERT_EQ(dut.size(), 9u);  // 2 intervals of 1/30 s at 120 Hz, plus the last frame
  EXPECT_NEAR(LogRotation(dut[2].rotation[1]).z(), 0.2, 1e-12);
  EXPECT_NEAR(LogRotation(dut[6].rotation[1]).z(), 0.6, 1e-12);
  EXPECT_NEAR(dut[6].translation[0].x() - frames[0].translation[0].x(), 0.15, 1e-12);
  EXPECT_TRUE(dut[8].rotation[1].isApprox(frames[2].rotation[1]));
  EXPECT_THROW(ResampleMotion(sk, {}, 30, 120), std::invalid_argument);
  EXPECT_THROW(ResampleMotion(sk, frames, 0, 120), std::invalid_argument);
}

}  // namespace
}  // namespace mocapd
