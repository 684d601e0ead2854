// Tests for the cleanup's options: validation names the field, and the option table
// (the one place bounds are written) agrees with the struct's defaults.
#include "filters/cleanup_options.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <string>

namespace mocapd {
namespace {

TEST(CleanupOptionsTest, ValidateNamesTheBadField) {
  CleanupOptions options;
  options.lookahead = -1;
  try {
    options.Validate();
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("lookahead"), std::string::npos);
  }
  options = CleanupOptions{};
  options.repaired_weight = 2.0;
  EXPECT_THROW(options.Validate(), std::invalid_argument);
}

TEST(CleanupOptionsTest, ValidateGivesTheBoundsAndTheValue) {
  CleanupOptions options;
  options.spike_m = 0.0;
  try {
    options.Validate();
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()), "CleanupOptions.spike_m: must be in [0.001, 100], got 0");
  }
  options = CleanupOptions{};
  options.fill_snap_release_s = std::nan("");
  EXPECT_THROW(options.Validate(), std::invalid_argument);
  options = CleanupOptions{};
  options.frozen_reference_motion_m = options.frozen_radius_m;
  EXPECT_THROW(options.Validate(), std::invalid_argument);
  // A motion memory too short ever to recall or test: refused, naming it; off is fine.
  options = CleanupOptions{};
  options.unseen_limb_memory_s = 1.0;
  try {
    options.Validate();
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()),
              "CleanupOptions.unseen_limb_memory_s: must be 0 (off) or at least 2.5 (time to "
              "recall and to test a recall), got 1");
  }
  options.unseen_limb_memory_s = 0.0;
  EXPECT_NO_THROW(options.Validate());
}

// The table is the one place the bounds are written: each option once, each default
// inside its bounds, each config key unique within its section.
TEST(CleanupOptionsTest, EveryOptionIsInTheTableOnceWithItsDefaultInBounds) {
  const CleanupOptions defaults;
  EXPECT_NO_THROW(defaults.Validate());
  std::set<std::string> names, keys;
  for (const CleanupOptionField& f : CleanupOptionFields()) {
    EXPECT_TRUE(names.insert(f.name).second) << f.name;
    EXPECT_TRUE(keys.insert(std::string(f.section ? f.section : "-") + "." + f.key).second)
        << f.key;
    EXPECT_LE(f.min, f.max) << f.name;
    EXPECT_GT(f.to_si, 0.0) << f.name;
    const double value =
        std::visit([&](auto member) { return static_cast<double>(defaults.*member); }, f.member);
    EXPECT_GE(value, f.min * f.to_si) << f.name;
    EXPECT_LE(value, f.max * f.to_si) << f.name;
  }
  EXPECT_EQ(names.size(), 53u);  // a new option must be added to the table (and this count)
}

TEST(CleanupOptionsTest, EveryPerFrameRuleMeansTheSameSpeedOrTimeAtEveryRate) {
  // The cleanup works per frame, but its rules are physical: a speed, an acceleration or
  // a time. Converted at 60 and at 240 Hz they must bound the same motion per second.
  CleanupOptions slow, fast;
  slow.rate_hz = 60.0;
  fast.rate_hz = 240.0;
  const CleanupFrameRules s = FrameRules(slow), f = FrameRules(fast);
  auto per_second = [](double per_frame, double rate) { return per_frame * rate; };
  EXPECT_NEAR(per_second(s.fill_anchor_radius_m, 60), per_second(f.fill_anchor_radius_m, 240),
              1e-12);
  EXPECT_NEAR(per_second(s.fill_anchor_radius_m, 60), slow.fill_anchor_speed_mps, 1e-12);
  EXPECT_NEAR(per_second(s.data_catchup_m, 60), per_second(f.data_catchup_m, 240), 1e-12);
  EXPECT_NEAR(per_second(s.data_catchup_max_m, 60), per_second(f.data_catchup_max_m, 240), 1e-12);
  // A share closed per frame: after one 60 Hz frame as much is left as after four at 240.
  EXPECT_NEAR(1.0 - s.data_catchup_share, std::pow(1.0 - f.data_catchup_share, 4), 1e-12);
  EXPECT_NEAR(per_second(s.unseen_limb_turn_rad, 60), per_second(f.unseen_limb_turn_rad, 240),
              1e-12);
  EXPECT_NEAR(per_second(s.unseen_limb_turn_rad, 60), slow.unseen_limb_turn_radps, 1e-12);
  EXPECT_NEAR(per_second(s.unseen_limb_recall_turn_rad, 60),
              per_second(f.unseen_limb_recall_turn_rad, 240), 1e-12);
  EXPECT_NEAR(per_second(s.unseen_limb_recall_turn_rad, 60), slow.unseen_limb_recall_turn_radps,
              1e-12);
  EXPECT_NEAR(per_second(s.unseen_limb_interpolation_radius_m, 60),
              per_second(f.unseen_limb_interpolation_radius_m, 240), 1e-12);
  EXPECT_NEAR(per_second(s.unseen_limb_interpolation_radius_m, 60),
              slow.unseen_limb_interpolation_speed_mps, 1e-12);
  EXPECT_NEAR(per_second(s.trim_slope_m, 60), per_second(f.trim_slope_m, 240), 1e-12);
  EXPECT_NEAR(per_second(s.max_offset_velocity_m, 60), per_second(f.max_offset_velocity_m, 240),
              1e-12);
  EXPECT_NEAR(s.data_motion_acceleration_m * 60 * 60, f.data_motion_acceleration_m * 240 * 240,
              1e-9);
  // Durations in whole frames: the same time to within half a frame at each rate.
  EXPECT_NEAR(s.frozen_frames / 60.0, slow.frozen_s, 0.5 / 60);
  EXPECT_NEAR(f.frozen_frames / 240.0, fast.frozen_s, 0.5 / 240);
  EXPECT_NEAR(s.fallen_frames / 60.0, slow.fallen_s, 0.5 / 60);
  EXPECT_NEAR(f.fallen_frames / 240.0, fast.fallen_s, 0.5 / 240);
  EXPECT_NEAR(s.frozen_backdate_frames / 60.0, slow.frozen_backdate_s, 0.5 / 60);
  EXPECT_NEAR(f.frozen_backdate_frames / 240.0, fast.frozen_backdate_s, 0.5 / 240);
  CleanupOptions slow_ease = slow, fast_ease = fast;  // the default, 0, holds at once
  slow_ease.fill_ease_s = fast_ease.fill_ease_s = 0.05;
  EXPECT_NEAR(FrameRules(slow_ease).fill_ease_frames / 60.0, 0.05, 0.5 / 60);
  EXPECT_NEAR(FrameRules(fast_ease).fill_ease_frames / 240.0, 0.05, 0.5 / 240);
  EXPECT_NEAR(s.fill_interpolation_horizon_frames / 60.0, slow.fill_interpolation_horizon_s,
              0.5 / 60);
  EXPECT_NEAR(f.fill_interpolation_horizon_frames / 240.0, fast.fill_interpolation_horizon_s,
              0.5 / 240);
  // A horizon shorter than a small gap would hide the small gap's end from its Hermite.
  CleanupOptions short_horizon = fast;
  short_horizon.fill_interpolation_horizon_s = 0.01;
  EXPECT_EQ(FrameRules(short_horizon).fill_interpolation_horizon_frames,
            FrameRules(short_horizon).small_gap_frames);
  // The weight ramp grows by the same factor per second.
  EXPECT_NEAR(60 * std::log(s.fill_weight_ramp), 240 * std::log(f.fill_weight_ramp), 1e-9);
}

}  // namespace
}  // namespace mocapd
