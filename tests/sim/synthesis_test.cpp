// Tests for marker synthesis.
#include "sim/synthesis.hpp"

#include <gtest/gtest.h>

#include <algorithm>

#include "sim/humanoid.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

TEST(SynthesisTest, MarkersFollowTheModel) {
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  ASSERT_EQ(f.take.num_frames, 60);
  ASSERT_EQ(f.take.num_points(), f.markers->num_markers());
  KinematicsWorkspace ws(*f.skeleton);
  for (int frame : {0, 31, 59}) {
    ForwardKinematics(*f.skeleton, f.motion[static_cast<size_t>(frame)], &ws);
    for (int m = 0; m < f.markers->num_markers(); ++m) {
      EXPECT_TRUE(f.take.valid(frame, m));
      EXPECT_LT((f.take.at(frame, m) - EvaluateMarker(f.markers->marker(m), ws)).norm(), 1e-12);
    }
  }
}

TEST(SynthesisTest, NoiseHasTheRequestedSpread) {
  const auto clean = testing::MakeHumanoidFixture("walk", 2.0, 120.0, 0.0);
  const auto noisy = testing::MakeHumanoidFixture("walk", 2.0, 120.0, 2e-3);
  double sum_sq = 0.0;
  for (size_t i = 0; i < clean.take.positions.size(); ++i)
    sum_sq += (clean.take.positions[i] - noisy.take.positions[i]).squaredNorm();
  const double sigma = std::sqrt(sum_sq / (3.0 * static_cast<double>(clean.take.positions.size())));
  EXPECT_NEAR(sigma, 2e-3, 1e-4);
}

TEST(SynthesisTest, HumanoidMotionIsFiniteAndMoves) {
  const Skeleton sk = MakeHumanoidSkeleton();
  for (auto motion : {HumanoidMotion::kWalk, HumanoidMotion::kReach, HumanoidMotion::kTurn,
                      HumanoidMotion::kMixed}) {
    const auto frames = MakeHumanoidMotion(sk, motion, 3.0, 60.0);
    ASSERT_EQ(frames.size(), 180u);
    double travelled = 0.0;
    for (size_t f = 1; f < frames.size(); ++f) {
      travelled += (frames[f].translation[0] - frames[f - 1].translation[0]).norm();
      for (const Quat& q : frames[f].rotation) ASSERT_TRUE(q.coeffs().allFinite());
    }
    if (motion != HumanoidMotion::kReach) {
      EXPECT_GT(travelled, 0.5);
    }
  }
  EXPECT_THROW(ParseHumanoidMotion("moonwalk"), std::invalid_argument);
}

// The README's 120 s walk went straight on to 156 m, past the default capture volume
// (100 m): every marker was gated as missing and the replay reported 982 cm of error. Any
// motion of any length stays on a stage, and the walk's first 20 s are a straight walk.
TEST(SynthesisTest, HumanoidMotionOfAnyLengthStaysOnAStage) {
  const Skeleton sk = MakeHumanoidSkeleton();
  for (auto motion : {HumanoidMotion::kWalk, HumanoidMotion::kTurn, HumanoidMotion::kMixed}) {
    const auto frames = MakeHumanoidMotion(sk, motion, 300.0, 30.0);
    double farthest = 0.0;
    for (const Pose& pose : frames) {
      Vec3 away = pose.translation[0] - frames.front().translation[0];
      away.y() = 0.0;
      farthest = std::max(farthest, away.norm());
    }
    EXPECT_LT(farthest, 35.0) << static_cast<int>(motion);
    if (motion == HumanoidMotion::kWalk) {
      EXPECT_GT(farthest, 25.0);  // it still walks somewhere
      const Vec3 at_20s = frames[600].translation[0] - frames.front().translation[0];
      EXPECT_LT(std::abs(at_20s.x()), 0.05);  // straight along +z until then
    }
  }
}

}  // namespace
}  // namespace mocapd
