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
  EXPECT_EQ(names.size(), 43u);  // a new option must be added to the table (and this count)
}

}  // namespace
}  // namespace mocapd
