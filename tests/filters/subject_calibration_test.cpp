// Tests for the markers-only bundle adjustment: from a template whose bones and marker
// offsets are wrong by centimetres, a range-of-motion take brings the joint centres back
// to the truth; directions the motion does not excite are reported as the prior's;
// bad input is a clear error.
#include "filters/subject_calibration.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "sim/humanoid.hpp"
#include "sim/synthesis.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

// The truth's markers as a template that is off: bones 8 % long, each marker 2 cm away.
CalibrationTemplate WrongTemplate(const Skeleton& truth, const MarkerSet& markers) {
  std::vector<Joint> joints(truth.joints().begin(), truth.joints().end());
  for (Joint& j : joints) j.offset *= 1.08;
  CalibrationTemplate t;
  t.skeleton = Skeleton(std::move(joints));
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 0.02 / std::sqrt(3.0));
  for (const MarkerDefinition& d : markers.markers()) {
    MarkerDefinition rigid;
    rigid.name = d.name;
    rigid.attachments[0] = {d.attachments[0].joint, 1.0,
                            d.attachments[0].offset + Vec3(n(rng), n(rng), n(rng))};
    t.markers.push_back(rigid);
  }
  for (int j = 0; j < truth.num_joints(); ++j) {
    const std::string name = truth.joint(j).name;
    std::string other = name;
    if (name.rfind("Left", 0) == 0) other = "Right" + name.substr(4);
    if (name.rfind("Right", 0) == 0) other = "Left" + name.substr(5);
    t.mirror.push_back(other != name ? t.skeleton.FindJoint(other)->value : -1);
  }
  return t;
}

// Rigid markers only (the default layout blends knee and elbow markers across the joint,
// which a rigid calibration cannot reproduce exactly).
std::shared_ptr<const MarkerSet> RigidMarkers(const Skeleton& skeleton, const MarkerSet& markers) {
  std::vector<MarkerDefinition> rigid;
  for (const MarkerDefinition& d : markers.markers()) {
    if (d.num_attachments != 1) continue;
    rigid.push_back(d);
  }
  return std::make_shared<const MarkerSet>(skeleton, std::move(rigid));
}

class SubjectCalibrationTest : public ::testing::Test {
 protected:
  void Calibrate(HumanoidMotion motion, double seconds) {
    truth_ = MakeHumanoidSkeleton();
    const auto fixture = testing::MakeHumanoidFixture("walk", 0.1, 120.0);
    markers_ = RigidMarkers(truth_, *fixture.markers);
    // 60 Hz, 100 poses and one solve keep the test quick under the sanitizers (the mean
    // of several solves: formats/subject_from_markers_test.cpp).
    motion_ = MakeHumanoidMotion(truth_, motion, seconds, 60.0);
    SynthesisNoise noise;
    noise.noise_sigma_m = 0.001;
    const C3dTake take = SynthesizeMarkers(truth_, *markers_, motion_, 60.0, noise);
    SubjectCalibrationOptions options;
    options.max_frames = 100;
    options.interleaved_solves = 1;
    result_ = CalibrateSubject(WrongTemplate(truth_, *markers_), take.positions, take.num_frames,
                               options);
  }
  // The calibrated joint's world position against the truth's, over every 10th frame.
  std::vector<double> CentreErrors(const char* joint) const {
    const Skeleton& sk = result_.skeleton;
    const MarkerSet calibrated(sk, result_.markers);
    IkState state(sk, calibrated);
    KinematicsWorkspace truth(truth_), solved(sk);
    const int j = truth_.FindJoint(joint)->value;
    std::vector<double> errors;
    std::vector<Vec3> targets(static_cast<size_t>(markers_->num_markers()));
    std::vector<double> weights(targets.size(), 1.0);
    for (size_t f = 0; f < motion_.size(); ++f) {
      ForwardKinematics(truth_, motion_[f], &truth);
      EvaluateMarkers(*markers_, truth, targets);
      (void)SolveIk(sk, calibrated, IkOptions{}, targets, weights, &state);
      if (f % 5 != 0 || f < 10) continue;
      ForwardKinematics(sk, state.pose(), &solved);
      errors.push_back(
          (solved.p_WJ[static_cast<size_t>(j)] - truth.p_WJ[static_cast<size_t>(j)]).norm());
    }
    return errors;
  }
  double Median(std::vector<double> v) const {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  }
  Skeleton truth_{{Joint{.name = "root", .parent = {}}}};
  std::shared_ptr<const MarkerSet> markers_;
  std::vector<Pose> motion_;
  SubjectCalibrationResult result_;
};

TEST_F(SubjectCalibrationTest, RangeOfMotionBringsTheJointCentresBackFromAWrongTemplate) {
  // The template's centres were 3-8 cm off. Ball joints the range of motion turns every
  // way come back to within a few mm; the hinges (knee, elbow) are determined across
  // their axis (no marker near them on this layout holds the axis direction).
  Calibrate(HumanoidMotion::kRom, 20.0);
  for (const char* joint :
       {"LeftUpLeg", "RightUpLeg", "LeftArm", "RightArm", "LeftHand", "RightHand"})
    EXPECT_LT(Median(CentreErrors(joint)), 0.003) << joint;
  for (const char* joint : {"LeftFoot", "RightFoot", "LeftForeArm", "RightForeArm"})
    EXPECT_LT(Median(CentreErrors(joint)), 0.006) << joint;
  for (const char* joint : {"LeftUpLeg", "RightArm", "LeftHand"}) {
    const int j = truth_.FindJoint(joint)->value;
    EXPECT_EQ(result_.joints[static_cast<size_t>(j)].method, "functional") << joint;
  }
  for (const char* joint : {"LeftForeArm", "RightHand", "LeftFoot"}) {
    const int j = truth_.FindJoint(joint)->value;
    EXPECT_NEAR(result_.skeleton.joint(j).offset.norm(), truth_.joint(j).offset.norm(),
                0.02 * truth_.joint(j).offset.norm())
        << joint;
  }
  EXPECT_LT(result_.median_residual_m, 0.002);
}

TEST_F(SubjectCalibrationTest, ADirectionTheMotionNeverExcitesIsLeftToThePrior) {
  // A walk bends knees and hips in one plane: the hip's centre is not determined in every
  // direction, and the report says so.
  Calibrate(HumanoidMotion::kWalk, 8.0);
  const int hip = truth_.FindJoint("LeftUpLeg")->value;
  const JointCalibrationReport& r = result_.joints[static_cast<size_t>(hip)];
  EXPECT_NE(r.method, "functional");
  EXPECT_LT(r.directions_covered, 3);
  EXPECT_LT(r.rotation_spread_deg[2], 10.0);
}

TEST(SubjectCalibrationInputTest, BadInputIsAClearError) {
  const Skeleton sk = MakeHumanoidSkeleton();
  const auto fixture = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  CalibrationTemplate t = WrongTemplate(sk, *fixture.markers);
  // NaN-only markers.
  std::vector<Vec3> nan(static_cast<size_t>(60 * fixture.markers->num_markers()),
                        Vec3::Constant(kNaN));
  EXPECT_THROW(CalibrateSubject(t, nan, 60), std::invalid_argument);
  // Sizes that do not match.
  EXPECT_THROW(CalibrateSubject(t, fixture.take.positions, 59), std::invalid_argument);
  try {
    CalibrateSubject(t, nan, 60);
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("frames see at least"), std::string::npos) << e.what();
  }
}

TEST(SubjectCalibrationInputTest, TheSameInputGivesTheSameSubjectBitForBit) {
  const Skeleton sk = MakeHumanoidSkeleton();
  const auto fixture = testing::MakeHumanoidFixture("mixed", 2.0, 30.0, 0.001);
  const auto markers = RigidMarkers(sk, *fixture.markers);
  const C3dTake take = SynthesizeMarkers(sk, *markers, fixture.motion, 30.0);
  const CalibrationTemplate t = WrongTemplate(sk, *markers);
  SubjectCalibrationOptions options;
  options.max_frames = 30;
  options.iterations = 4;
  const SubjectCalibrationResult a = CalibrateSubject(t, take.positions, take.num_frames, options);
  const SubjectCalibrationResult b = CalibrateSubject(t, take.positions, take.num_frames, options);
  for (int j = 0; j < sk.num_joints(); ++j)
    EXPECT_EQ(a.skeleton.joint(j).offset, b.skeleton.joint(j).offset);
  for (size_t m = 0; m < a.markers.size(); ++m)
    EXPECT_EQ(a.markers[m].attachments[0].offset, b.markers[m].attachments[0].offset);
}

}  // namespace
}  // namespace mocapd
