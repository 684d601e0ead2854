// End-to-end test of `mocapd calibrate` on a synthesized take written to real files.
#include "runtime/calibrate_command.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>

#include <sstream>

#include "formats/bvh.hpp"
#include "formats/subject_file.hpp"
#include "formats/subject_from_markers.hpp"
#include "sim/humanoid.hpp"
#include "sim/synthesis.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

// Every marker of the calibrated model lands within 1 mm of the truth's, at every 97th pose.
void ExpectMarkersMatchTheTruth(const testing::HumanoidFixture& f, const SubjectModel& model,
                                const std::vector<Pose>& motion) {
  KinematicsWorkspace truth(*f.skeleton), got(*model.skeleton);
  for (size_t fr = 0; fr < motion.size(); fr += 97) {
    ForwardKinematics(*f.skeleton, motion[fr], &truth);
    ForwardKinematics(*model.skeleton, motion[fr], &got);
    for (int m = 0; m < f.markers->num_markers(); ++m) {
      const auto idx = model.markers->FindMarker(f.markers->marker(m).name);
      ASSERT_TRUE(idx.has_value());
      EXPECT_LT((EvaluateMarker(model.markers->marker(idx->value), got) -
                 EvaluateMarker(f.markers->marker(m), truth))
                    .norm(),
                1e-3)
          << f.markers->marker(m).name << " at frame " << fr;
    }
  }
}

// A genlocked capture: the BVH labelled 119.88 Hz, the C3D 120 Hz, the same frames. It was
// resampled, drifting half a frame over the take, and markers went to the wrong joint.
TEST(CalibrateCommandTest, PairsANtscLabelledSkeletonTakeFrameForFrame) {
  const auto f = testing::MakeHumanoidFixture("mixed", 0.1, 120.0);
  const std::string dir = testing::TempDir("calibrate_ntsc");
  const std::vector<Pose> motion =
      MakeHumanoidMotion(*f.skeleton, HumanoidMotion::kMixed, 4.0, 120.0);
  WriteBvh(dir + "/skel.bvh", MakeBvhTake(*f.skeleton, motion, 1001.0 / 120000.0, "cm"));
  WriteC3d(dir + "/take.c3d", SynthesizeMarkers(*f.skeleton, *f.markers, motion, 120.0));
  CalibrateCommandOptions options;
  options.skeleton_bvh = dir + "/skel.bvh";
  options.markers_c3d = {dir + "/take.c3d"};
  options.out_subject = dir + "/actor.toml";
  std::ostringstream out;
  EXPECT_EQ(RunCalibrateCommand(options, out), f.markers->num_markers()) << out.str();
  EXPECT_EQ(out.str().find("resampling"), std::string::npos) << out.str();
  EXPECT_NE(out.str().find("paired frame for frame"), std::string::npos) << out.str();
  ExpectMarkersMatchTheTruth(f, ReadSubjectModel(dir + "/actor.toml"), motion);
}

TEST(CalibrateCommandTest, WritesASubjectWhoseMarkersMatchTheTruth) {
  const auto f = testing::MakeHumanoidFixture("mixed", 0.1, 120.0);
  const std::string dir = testing::TempDir("calibrate");
  // The skeleton's BVH at 30 Hz, the markers at 120 Hz: the command must resample.
  const std::vector<Pose> motion30 =
      MakeHumanoidMotion(*f.skeleton, HumanoidMotion::kMixed, 9.0, 30.0);
  const std::vector<Pose> motion = ResampleMotion(*f.skeleton, motion30, 30.0, 120.0);
  WriteBvh(dir + "/skel.bvh", MakeBvhTake(*f.skeleton, motion30, 1.0 / 30.0, "cm"));
  const C3dTake clean = SynthesizeMarkers(*f.skeleton, *f.markers, motion, 120.0);
  C3dTake take;
  take.labels = clean.labels;
  take.labels.push_back("STRAY");  // a marker riding on nothing
  take.rate_hz = 120.0;
  take.Allocate(clean.num_frames);
  for (int fr = 0; fr < clean.num_frames; ++fr) {
    for (int p = 0; p < take.num_points(); ++p) {
      take.at(fr, p) = p < clean.num_points()
                           ? clean.at(fr, p)
                           : Vec3(std::sin(fr * 0.37), 1.0 + std::cos(fr * 0.11), 0.0);
      take.residuals[static_cast<size_t>(fr) * static_cast<size_t>(take.num_points()) +
                     static_cast<size_t>(p)] = 0.0f;
    }
  }
  WriteC3d(dir + "/take.c3d", take);

  CalibrateCommandOptions options;
  options.skeleton_bvh = dir + "/skel.bvh";
  options.markers_c3d = {dir + "/take.c3d"};
  options.out_subject = dir + "/actor.toml";
  std::ostringstream out;
  const int accepted = RunCalibrateCommand(options, out);
  EXPECT_EQ(accepted, f.markers->num_markers()) << out.str();
  EXPECT_NE(out.str().find("STRAY"), std::string::npos);
  EXPECT_NE(out.str().find("REJECTED"), std::string::npos);
  EXPECT_NE(out.str().find("resampling"), std::string::npos);

  const SubjectModel model = ReadSubjectModel(dir + "/actor.toml");
  EXPECT_EQ(model.name, "actor");
  ExpectMarkersMatchTheTruth(f, model, motion);
}

// The command's error, or "no error".
std::string ErrorOf(const CalibrateCommandOptions& options) {
  std::ostringstream out;
  try {
    RunCalibrateCommand(options, out);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "no error";
}

TEST(CalibrateCommandTest, RefusesTakesOfDifferentLengths) {
  const auto f = testing::MakeHumanoidFixture("walk", 2.0, 60.0);
  const std::string dir = testing::TempDir("calibrate_mismatch");
  WriteBvh(dir + "/skel.bvh",
           MakeBvhTake(*f.skeleton, std::vector<Pose>(f.motion.begin(), f.motion.begin() + 50),
                       1.0 / 60.0));
  WriteC3d(dir + "/take.c3d", f.take);
  CalibrateCommandOptions options{
      dir + "/skel.bvh", {dir + "/take.c3d"}, dir + "/out.toml", "", "", {}, "auto", ""};
  std::ostringstream out;
  try {
    RunCalibrateCommand(options, out);
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("not the same take"), std::string::npos) << e.what();
  }
}

// A skeleton read in the wrong units fits almost no marker: the command must fail and
// write nothing, never a subject made of the few markers that happened to fit.
TEST(CalibrateCommandTest, FailsWithoutWritingWhenMostMarkersDoNotFit) {
  const auto f = testing::MakeHumanoidFixture("mixed", 3.0, 60.0);
  const std::string dir = testing::TempDir("calibrate_units");
  WriteBvh(dir + "/skel.bvh", MakeBvhTake(*f.skeleton, f.motion, 1.0 / 60.0, "cm"));
  WriteC3d(dir + "/take.c3d", f.take);
  CalibrateCommandOptions options;
  options.skeleton_bvh = dir + "/skel.bvh";
  options.markers_c3d = {dir + "/take.c3d"};
  options.out_subject = dir + "/out.toml";
  options.bvh_units = "mm";  // a cm file read as mm: the skeleton is 10x too small
  std::ostringstream out;
  try {
    RunCalibrateCommand(options, out);
    FAIL() << out.str();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("markers fit the skeleton"), std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("No subject written"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(dir + "/out.toml"));
}

TEST(CalibrateCommandTest, AnOutputOverATakeIsRefusedAndTheTakeKept) {
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  const std::string dir = testing::TempDir("calibrate_overwrite");
  WriteC3d(dir + "/take.c3d", f.take);
  WriteC3d(dir + "/other.c3d", f.take);
  const auto size_before = std::filesystem::file_size(dir + "/other.c3d");
  CalibrateCommandOptions options;
  options.markers_c3d = {dir + "/take.c3d", dir + "/other.c3d"};
  options.out_subject = dir + "/other.c3d";
  const std::string error = ErrorOf(options);
  EXPECT_NE(error.find("--out " + dir + "/other.c3d: is the same file as --markers " + dir +
                       "/other.c3d"),
            std::string::npos)
      << error;
  EXPECT_EQ(std::filesystem::file_size(dir + "/other.c3d"), size_before);
  EXPECT_NO_THROW(ReadC3d(dir + "/other.c3d"));
}

// The same take given twice (however its path is written) weighed its frames double and
// moved the result with no word: refused, naming both spellings.
TEST(CalibrateCommandTest, TheSameTakeGivenTwiceIsRefused) {
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  const std::string dir = testing::TempDir("calibrate_twice");
  WriteC3d(dir + "/take.c3d", f.take);
  CalibrateCommandOptions options;
  options.markers_c3d = {dir + "/take.c3d", dir + "/./take.c3d"};
  options.out_subject = dir + "/s.toml";
  const std::string error = ErrorOf(options);
  EXPECT_NE(error.find("--markers " + dir + "/./take.c3d is the take given before as " + dir +
                       "/take.c3d"),
            std::string::npos)
      << error;
  EXPECT_FALSE(std::filesystem::exists(dir + "/s.toml"));
}

// A take with no frames is named (of several, which), and one too short to place a marker
// says so instead of blaming the skeleton ("is it the same take, in the units guessed?").
TEST(CalibrateCommandTest, ATakeWithNoOrTooFewFramesIsNamedAsSuch) {
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  const std::string dir = testing::TempDir("calibrate_short");
  C3dTake empty = f.take;
  empty.Allocate(0);
  WriteC3d(dir + "/empty.c3d", empty);
  WriteC3d(dir + "/take.c3d", f.take);
  CalibrateCommandOptions markers_only;
  markers_only.markers_c3d = {dir + "/take.c3d", dir + "/empty.c3d"};
  markers_only.out_subject = dir + "/out.toml";
  EXPECT_EQ(ErrorOf(markers_only), dir + "/empty.c3d: the take has no frames (" +
                                       std::to_string(empty.num_points()) +
                                       " points labelled): nothing to calibrate from");
  const std::vector<Pose> first(f.motion.begin(), f.motion.begin() + 1);
  WriteBvh(dir + "/one.bvh", MakeBvhTake(*f.skeleton, first, 1.0 / 60.0, "cm"));
  C3dTake one = f.take;
  one.num_frames = 1;
  one.positions.resize(one.labels.size());
  one.residuals.resize(one.labels.size());
  WriteC3d(dir + "/one.c3d", one);
  CalibrateCommandOptions with_skeleton;
  with_skeleton.skeleton_bvh = dir + "/one.bvh";
  with_skeleton.markers_c3d = {dir + "/one.c3d"};
  with_skeleton.out_subject = dir + "/out.toml";
  EXPECT_NE(ErrorOf(with_skeleton).find("the take has 1 frames; a marker's placement needs"),
            std::string::npos)
      << ErrorOf(with_skeleton);
  EXPECT_FALSE(std::filesystem::exists(dir + "/out.toml"));
  // A take standing still: which of the takes given (the message named none).
  C3dTake still = f.take;
  for (int fr = 1; fr < still.num_frames; ++fr)
    for (int p = 0; p < still.num_points(); ++p) {
      still.at(fr, p) = still.at(0, p);
      still.residuals[static_cast<size_t>(fr * still.num_points() + p)] =
          still.residuals[static_cast<size_t>(p)];
    }
  WriteC3d(dir + "/still.c3d", still);
  markers_only.markers_c3d = {dir + "/still.c3d"};
  EXPECT_EQ(
      ErrorOf(markers_only).rfind("calibrate: " + dir + "/still.c3d: the take shows no motion", 0),
      0u)
      << ErrorOf(markers_only);
}

// A capture whose labels belong to no set (here the default layout's markers renamed
// P0, P1, ... and the world turned Z-up): the command places them by clustering, says so,
// lists where each marker went, and writes a subject that fits them.
// Two points under one label: the calibration takes the first, and says so.
TEST(CalibrateCommandTest, WarnsOfALabelGivenToTwoPoints) {
  const auto f = testing::MakeHumanoidFixture("mixed", 12.0, 60.0, 0.001);
  const std::string dir = testing::TempDir("calibrate_duplicate");
  C3dTake doubled = testing::WithALabelGivenTwice(f.take, 3);
  WriteC3d(dir + "/take.c3d", doubled);
  CalibrateCommandOptions options;
  options.markers_c3d = {dir + "/take.c3d"};
  options.out_subject = dir + "/actor.toml";
  options.interleaved_solves = 1;  // quick under the sanitizers
  std::ostringstream out;
  RunCalibrateCommand(options, out);
  EXPECT_NE(out.str().find("warning: " + dir + "/take.c3d: 2 points are labelled " +
                           f.take.labels[3] + "; the first is used"),
            std::string::npos)
      << out.str();
}

TEST(CalibrateCommandTest, LabelsOfNoSetAreCalibratedByClusteringAlone) {
  const auto f = testing::MakeHumanoidFixture("mixed", 12.0, 60.0, 0.001);
  const std::string dir = testing::TempDir("calibrate_clustering");
  C3dTake renamed = f.take;
  const Mat3 z_up = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitX()).toRotationMatrix();
  for (int p = 0; p < renamed.num_points(); ++p) {
    renamed.labels[static_cast<size_t>(p)] = "P" + std::to_string(p);
    for (int fr = 0; fr < renamed.num_frames; ++fr) renamed.at(fr, p) = z_up * f.take.at(fr, p);
  }
  WriteC3d(dir + "/take.c3d", renamed);
  CalibrateCommandOptions options;
  options.markers_c3d = {dir + "/take.c3d"};
  options.out_subject = dir + "/actor.toml";
  options.report_json = dir + "/report.json";
  // Two subsets (not the default four) keep the test quick under the sanitizers.
  options.interleaved_solves = 2;
  std::ostringstream out;
  const int accepted = RunCalibrateCommand(options, out);
  EXPECT_GE(accepted * 10, f.markers->num_markers() * 9) << out.str();
  EXPECT_NE(out.str().find("the labels match no known marker set"), std::string::npos) << out.str();
  EXPECT_NE(out.str().find("up nearest +z"), std::string::npos) << out.str();
  EXPECT_NE(out.str().find("  thigh_l: "), std::string::npos) << out.str();
  const SubjectModel model = ReadSubjectModel(dir + "/actor.toml");
  ASSERT_TRUE(model.calibration.has_value());
  EXPECT_EQ(model.calibration->marker_set, "none (rigid clusters)");
  // The body looks much the same from behind; the walk must still put every marker on
  // its own side.
  const HumanoidRoles roles = MatchHumanoidRoles(*f.skeleton);
  for (int p = 0; p < f.markers->num_markers(); ++p) {
    const auto placed = model.markers->FindMarker("P" + std::to_string(p));
    if (!placed) continue;
    std::string truth;
    for (const auto& [role, joint] : roles.joint_of_role)
      if (joint == f.markers->primary_joint(p)) truth = role;
    const std::string got = model.skeleton->joint(model.markers->primary_joint(placed->value)).name;
    EXPECT_FALSE(got != truth && MirrorRole(got) == truth)
        << "P" << p << " " << truth << " " << got;
  }
  EXPECT_LT(model.calibration->median_residual_mm, 6.0) << out.str();
  std::ifstream report(dir + "/report.json");
  const std::string text((std::istreambuf_iterator<char>(report)),
                         std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("placed_by_clustering"), std::string::npos);
  EXPECT_NE(out.str().find("the mean of 3 solves"), std::string::npos) << out.str();
  EXPECT_NE(text.find("\"solves\": 3"), std::string::npos) << text;
}

}  // namespace
}  // namespace mocapd
