// Tests for the exponential/logarithm maps.
#include "filters/rotation.hpp"

#include <gtest/gtest.h>

#include <random>

namespace mocapd {
namespace {

TEST(RotationTest, ExpThenLogReturnsTheRotationVector) {
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < 1000; ++i) {
    Vec3 v(u(rng), u(rng), u(rng));
    v *= (3.1 * u(rng)) / std::max(v.norm(), 1e-9);  // angle in (-3.1, 3.1)
    const Vec3 back = LogRotation(ExpRotation(v));
    EXPECT_LT((back - v).norm(), 1e-9) << v.transpose();
  }
}

TEST(RotationTest, ExpMatchesAngleAxis) {
  const Vec3 v(0.3, -0.2, 0.9);
  const Quat expected(Eigen::AngleAxisd(v.norm(), v.normalized()));
  EXPECT_LT(AngleBetween(ExpRotation(v), expected), 1e-12);
}

TEST(RotationTest, TinyRotationsStayExact) {
  const Vec3 v(1e-9, -2e-9, 3e-10);
  EXPECT_LT((LogRotation(ExpRotation(v)) - v).norm(), 1e-20);
}

TEST(RotationTest, LogTakesTheShortestArc) {
  const Quat q = ExpRotation(Vec3(0.0, 0.0, 0.5));
  const Quat negated(-q.w(), -q.x(), -q.y(), -q.z());  // the same rotation
  EXPECT_NEAR(LogRotation(negated).z(), 0.5, 1e-12);
}

TEST(RotationTest, SkewMatchesCrossProduct) {
  const Vec3 a(1, 2, 3), b(-4, 0.5, 2);
  EXPECT_LT((Skew(a) * b - a.cross(b)).norm(), 1e-15);
}

}  // namespace
}  // namespace mocapd
