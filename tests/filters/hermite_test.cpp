// Tests for the cubic Hermite segment of the gap repair: it meets its end values and
// derivatives (C0 and C1 with what surrounds a gap) and reproduces any cubic exactly.
#include "filters/hermite.hpp"

#include <gtest/gtest.h>

namespace mocapd {
namespace {

TEST(HermiteTest, MeetsItsEndValuesAndDerivatives) {
  const HermiteSegment dut{Vec3(1, 2, 3), Vec3(0.1, -0.2, 0.3), Vec3(-1, 0, 5),
                           Vec3(0.4, 0.0, -0.1), 7.0};
  EXPECT_LT((dut.Value(0.0) - dut.p0).norm(), 1e-12);
  EXPECT_LT((dut.Value(7.0) - dut.p1).norm(), 1e-12);
  EXPECT_LT((dut.Derivative(0.0) - dut.m0).norm(), 1e-12);
  EXPECT_LT((dut.Derivative(7.0) - dut.m1).norm(), 1e-12);
}

TEST(HermiteTest, ReproducesACubicFromItsEndValuesAndSlopes) {
  // p(x) = a + b x + c x^2 + d x^3 per axis.
  const Vec3 a(0.5, -1, 2), b(0.3, 0.1, -0.2), c(-0.05, 0.02, 0.01), d(0.004, -0.001, 0.002);
  auto p = [&](double x) { return Vec3(a + b * x + c * x * x + d * x * x * x); };
  auto dp = [&](double x) { return Vec3(b + 2 * c * x + 3 * d * x * x); };
  const double length = 5.0;
  const HermiteSegment dut{p(0), dp(0), p(length), dp(length), length};
  for (double x = 0.0; x <= length; x += 0.25) {
    EXPECT_LT((dut.Value(x) - p(x)).norm(), 1e-12) << x;
    EXPECT_LT((dut.Derivative(x) - dp(x)).norm(), 1e-12) << x;
  }
}

TEST(HermiteTest, EqualEndsWithZeroSlopesStayPut) {
  const HermiteSegment dut{Vec3(0.2, 0.3, 0.4), Vec3::Zero(), Vec3(0.2, 0.3, 0.4), Vec3::Zero(),
                           13.0};
  for (double x = 0.0; x <= 13.0; x += 1.0) EXPECT_LT((dut.Value(x) - dut.p0).norm(), 1e-15) << x;
}

}  // namespace
}  // namespace mocapd
