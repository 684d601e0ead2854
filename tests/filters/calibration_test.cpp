// Tests for marker calibration on synthesized takes with known attachments.
#include "filters/calibration.hpp"

#include <gtest/gtest.h>

#include <random>

#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

class CalibrationTest : public ::testing::Test {
 protected:
  CalibrationTest() : fixture_(testing::MakeHumanoidFixture("mixed", 9.0, 60.0)) {
    const Skeleton& sk = *fixture_.skeleton;
    fk_.assign(fixture_.motion.size(), KinematicsWorkspace(sk));
    for (size_t f = 0; f < fixture_.motion.size(); ++f)
      ForwardKinematics(sk, fixture_.motion[f], &fk_[f]);
    names_ = fixture_.take.labels;
    observed_ = fixture_.take.positions;
  }
  testing::HumanoidFixture fixture_;
  std::vector<KinematicsWorkspace> fk_;
  std::vector<std::string> names_;
  std::vector<Vec3> observed_;
};

TEST_F(CalibrationTest, FindsEveryMarkersJointAndOffset) {
  const auto result = CalibrateMarkers(*fixture_.skeleton, fk_, names_, observed_);
  ASSERT_EQ(result.size(), names_.size());
  for (size_t m = 0; m < result.size(); ++m) {
    const MarkerDefinition& truth = fixture_.markers->marker(static_cast<int>(m));
    const MarkerCalibration& got = result[m];
    ASSERT_TRUE(got.accepted) << got.name << ": " << got.reason;
    EXPECT_EQ(got.definition.num_attachments, truth.num_attachments) << got.name;
    EXPECT_EQ(got.definition.attachments[0].joint, truth.attachments[0].joint) << got.name;
    EXPECT_LT(got.rms_m, 1e-6) << got.name;
    // The offsets reproduce the marker within 1 mm on every frame (blend weights are a
    // convention; the positions they give are what must match).
    for (size_t f = 0; f < fk_.size(); f += 17)
      EXPECT_LT((EvaluateMarker(got.definition, fk_[f]) - EvaluateMarker(truth, fk_[f])).norm(),
                1e-3)
          << got.name;
    if (truth.num_attachments == 1) {
      EXPECT_LT((got.definition.attachments[0].offset - truth.attachments[0].offset).norm(), 1e-3);
    }
  }
}

TEST_F(CalibrationTest, RejectsMarkersThatFitNothing) {
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const size_t stride = names_.size();
  for (size_t f = 0; f < fk_.size(); ++f)
    observed_[f * stride + 3] = Vec3(u(rng), u(rng) + 1.0, u(rng));  // a stray
  for (size_t f = 0; f < fk_.size(); ++f)
    if (f > 5) observed_[f * stride + 4] = Vec3::Constant(kNaN);  // almost never seen
  const auto result = CalibrateMarkers(*fixture_.skeleton, fk_, names_, observed_);
  EXPECT_FALSE(result[3].accepted);
  EXPECT_NE(result[3].reason.find("mm RMS"), std::string::npos) << result[3].reason;
  EXPECT_FALSE(result[4].accepted);
  EXPECT_NE(result[4].reason.find("valid frames"), std::string::npos) << result[4].reason;
  EXPECT_TRUE(result[5].accepted);
}

TEST_F(CalibrationTest, ToleratesNoiseAndGaps) {
  std::mt19937_64 rng(4);
  std::normal_distribution<double> noise(0.0, 0.5e-3);
  for (size_t i = 0; i < observed_.size(); ++i) {
    if (i % 11 == 0)
      observed_[i] = Vec3::Constant(kNaN);
    else
      observed_[i] += Vec3(noise(rng), noise(rng), noise(rng));
  }
  const auto result = CalibrateMarkers(*fixture_.skeleton, fk_, names_, observed_);
  for (size_t m = 0; m < result.size(); ++m) {
    ASSERT_TRUE(result[m].accepted) << result[m].name;
    EXPECT_EQ(result[m].definition.attachments[0].joint,
              fixture_.markers->marker(static_cast<int>(m)).attachments[0].joint)
        << result[m].name;
    EXPECT_LT(result[m].rms_m, 1.5e-3);
  }
}

TEST_F(CalibrationTest, RejectsMismatchedSizes) {
  observed_.pop_back();
  EXPECT_THROW(CalibrateMarkers(*fixture_.skeleton, fk_, names_, observed_), std::invalid_argument);
}

}  // namespace
}  // namespace mocapd
