// Tests for take summaries (mocap-sim info).
#include "sim/take_info.hpp"

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "formats/c3d.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

TEST(TakeInfoTest, CountsMissingSamplesAndGapsPerMarker) {
  C3dTake take;
  take.labels = {"A", "B"};
  take.rate_hz = 100.0;
  take.Allocate(10);
  take.model_output_kind[1] = "ANGLES";
  for (int f = 0; f < 10; ++f) {
    // A is missing at frames 2-3 and 7: two gaps, longest 2.
    if (f != 2 && f != 3 && f != 7) {
      take.at(f, 0) = Vec3(1, 2, 3);
      take.residuals[static_cast<size_t>(f) * 2] = 0.0f;
    }
    take.at(f, 1) = Vec3(0, 0, 0);
    take.residuals[static_cast<size_t>(f) * 2 + 1] = 0.0f;
  }
  const std::string path = testing::TempDir("info") + "/take.C3D";
  WriteC3d(path, take);
  const TakeInfo info = InspectTake(path);
  EXPECT_EQ(info.format, "c3d");
  EXPECT_EQ(info.frames, 10);
  ASSERT_EQ(info.points.size(), 2u);
  EXPECT_EQ(info.points[0].gaps, 2);
  EXPECT_EQ(info.points[0].longest_gap, 2);
  EXPECT_DOUBLE_EQ(info.points[0].missing_fraction, 0.3);
  EXPECT_EQ(info.points[1].kind, "ANGLES");
  const nlohmann::json j = TakeInfoJson(info);
  EXPECT_EQ(j["points"][0]["label"], "A");
  EXPECT_EQ(j["points"][0]["gaps"], 2);
  EXPECT_EQ(j["rate_hz"], 100.0);
  EXPECT_NE(FormatTakeInfo(info).find("30.00%"), std::string::npos);
}

// A C3D's analog channels are named with their rate (a take's force plates were invisible
// to `info`, and lost without a word by `process --out-c3d`).
TEST(TakeInfoTest, NamesAC3dsAnalogChannels) {
  C3dTake take;
  take.labels = {"A"};
  take.rate_hz = 100.0;
  take.Allocate(3);
  take.analog.labels = {"Fz1", "EMG1"};
  take.analog.descriptions = take.analog.units = {"", ""};
  take.analog.scale = {1.0, 1.0};
  take.analog.offset = {0.0, 0.0};
  take.analog.samples_per_frame = 10;
  take.analog.values.assign(3 * 2 * 10, 1.0f);
  const std::string path = testing::TempDir("info_analog") + "/analog.c3d";
  WriteC3d(path, take);
  const TakeInfo info = InspectTake(path);
  EXPECT_NE(
      FormatTakeInfo(info).find("analog  2 channels x 10 samples a frame (1000 Hz): Fz1 EMG1"),
      std::string::npos)
      << FormatTakeInfo(info);
  EXPECT_EQ(TakeInfoJson(info)["analog"]["samples_per_frame"], 10);
}

TEST(TakeInfoTest, DescribesBvhJoints) {
  const TakeInfo info = InspectTake(std::string(MOCAPD_TEST_DATA_DIR) + "/tiny_static_root.bvh");
  EXPECT_EQ(info.format, "bvh");
  EXPECT_EQ(info.frames, 3);
  ASSERT_EQ(info.joints.size(), 5u);
  EXPECT_EQ(info.joints[1], "Hips (free)");
  EXPECT_EQ(info.end_sites, 1);
  EXPECT_EQ(TakeInfoJson(info)["joints"][0], "joint_Root (fixed)");
}

TEST(TakeInfoTest, UnknownExtensionIsRejected) {
  EXPECT_THROW(InspectTake("take.fbx"), std::invalid_argument);
  EXPECT_EQ(FileExtension("/a.b/take"), "");
  EXPECT_EQ(FileExtension("x.BVH"), "bvh");
}

}  // namespace
}  // namespace mocapd
