// Tests for the seeded corruption injector and its ground-truth mask.
#include "sim/corruption.hpp"

#include <gtest/gtest.h>

#include <map>
#include <nlohmann/json.hpp>

#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

class CorruptionTest : public ::testing::Test {
 protected:
  CorruptionTest() : fixture_(testing::MakeHumanoidFixture("mixed", 20.0, 60.0)) {}
  testing::HumanoidFixture fixture_;
};

TEST_F(CorruptionTest, ReachesEachSeveritysTargetFraction) {
  for (auto severity :
       {CorruptionSeverity::kLight, CorruptionSeverity::kMedium, CorruptionSeverity::kHeavy}) {
    CorruptionOptions options;
    options.severity = severity;
    const CorruptedTake dut = CorruptTake(fixture_.take, fixture_.markers.get(), options);
    const double target = TargetCorruptedFraction(severity);
    EXPECT_GE(dut.corrupted_fraction, target);
    EXPECT_LT(dut.corrupted_fraction, target + 0.06);
  }
}

// An occlusion is the body's, not the camera's: the same motion captured at 60 and at
// 240 Hz loses stretches of the same length in seconds. (Counted in frames, a 60 Hz
// take's gaps averaged 28 % longer in time than a 240 Hz take's.)
TEST(CorruptionRateTest, GapsLastAsLongInSecondsAtAnyCaptureRate) {
  auto mean_gap_seconds = [](double rate_hz) {
    const testing::HumanoidFixture take = testing::MakeHumanoidFixture("mixed", 20.0, rate_hz);
    double seconds = 0.0;
    int gaps = 0;
    for (uint64_t seed = 1; seed <= 8; ++seed) {
      CorruptionOptions options;
      options.seed = seed;
      for (const CorruptionEvent& e : CorruptTake(take.take, take.markers.get(), options).events)
        if (e.kind == CorruptionKind::kGap && e.first_frame > 0 &&
            e.last_frame < take.take.num_frames - 1) {  // not cut short by the take's ends
          seconds += (e.last_frame - e.first_frame + 1) / rate_hz;
          ++gaps;
        }
    }
    return seconds / gaps;
  };
  const double at_60 = mean_gap_seconds(60.0), at_240 = mean_gap_seconds(240.0);
  EXPECT_NEAR(at_60 / at_240, 1.0, 0.1) << at_60 << " s at 60 Hz, " << at_240 << " s at 240 Hz";
}

TEST_F(CorruptionTest, ProducesEveryKindAndATruthThatMatchesTheData) {
  CorruptionOptions options;
  options.jitter_min_m = options.jitter_max_m = 0.0;  // so untouched samples are exact
  const CorruptedTake dut = CorruptTake(fixture_.take, fixture_.markers.get(), options);
  std::map<CorruptionKind, int> kinds;
  for (const CorruptionEvent& e : dut.events) ++kinds[e.kind];
  for (auto kind : {CorruptionKind::kGap, CorruptionKind::kSwap, CorruptionKind::kPop,
                    CorruptionKind::kFrozen, CorruptionKind::kFallenOff})
    EXPECT_GT(kinds[kind], 0) << to_string(kind);
  bool gap_at_end = false;
  for (int f = 0; f < dut.take.num_frames; ++f) {
    for (int p = 0; p < dut.take.num_points(); ++p) {
      const CorruptionKind truth = dut.at(f, p);
      if (truth == CorruptionKind::kNone) {
        ASSERT_TRUE(dut.take.valid(f, p));
        ASSERT_EQ(dut.take.at(f, p), fixture_.take.at(f, p)) << f << " " << p;
      } else if (truth == CorruptionKind::kGap) {
        ASSERT_FALSE(dut.take.valid(f, p));
        gap_at_end = gap_at_end || f == dut.take.num_frames - 1;
      } else {
        ASSERT_TRUE(dut.take.valid(f, p));
        ASSERT_GT((dut.take.at(f, p) - fixture_.take.at(f, p)).norm(), 1e-9)
            << to_string(truth) << " " << f << " " << p;
      }
    }
  }
  EXPECT_TRUE(gap_at_end);
}

TEST_F(CorruptionTest, PopsAreFiveToFiftyCentimetres) {
  CorruptionOptions options;
  options.jitter_min_m = options.jitter_max_m = 0.0;
  const CorruptedTake dut = CorruptTake(fixture_.take, fixture_.markers.get(), options);
  for (const CorruptionEvent& e : dut.events) {
    if (e.kind != CorruptionKind::kPop) continue;
    EXPECT_LE(e.last_frame - e.first_frame, 2);
    for (int f = e.first_frame; f <= e.last_frame; ++f) {
      if (dut.at(f, e.marker) != CorruptionKind::kPop) continue;
      const double d = (dut.take.at(f, e.marker) - fixture_.take.at(f, e.marker)).norm();
      EXPECT_GE(d, 0.05 - 1e-9);
      EXPECT_LE(d, 0.5 + 1e-9);
    }
  }
}

TEST_F(CorruptionTest, SameSeedSameTakeDifferentSeedDifferentTake) {
  CorruptionOptions options;
  const CorruptedTake a = CorruptTake(fixture_.take, fixture_.markers.get(), options);
  const CorruptedTake b = CorruptTake(fixture_.take, fixture_.markers.get(), options);
  options.seed = 2;
  const CorruptedTake c = CorruptTake(fixture_.take, fixture_.markers.get(), options);
  EXPECT_EQ(a.truth, b.truth);
  EXPECT_NE(a.truth, c.truth);
  const nlohmann::json j = CorruptionTruthJson(a, CorruptionOptions{});
  EXPECT_EQ(j["severity"], "medium");
  EXPECT_EQ(j["events"].size(), a.events.size());
}

TEST_F(CorruptionTest, RejectsBadInput) {
  EXPECT_THROW(ParseCorruptionSeverity("apocalyptic"), std::invalid_argument);
  CorruptionOptions options;
  options.up_axis = 3;
  EXPECT_THROW(CorruptTake(fixture_.take, nullptr, options), std::invalid_argument);
  C3dTake tiny;
  tiny.labels = {"A"};
  tiny.rate_hz = 100;
  tiny.Allocate(1);
  EXPECT_THROW(CorruptTake(tiny, nullptr, CorruptionOptions{}), std::invalid_argument);
}

}  // namespace
}  // namespace mocapd
