// End-to-end test of `mocapd process` on a synthesized, corrupted take in real files.
#include "runtime/process_command.hpp"

#include "runtime/calibrate_command.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "filters/pose_error.hpp"
#include "formats/bvh.hpp"
#include "formats/c3d.hpp"
#include "formats/subject_file.hpp"
#include "sim/corruption.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

// The fixture's own skeleton and markers as a subject file: the true model of its take.
void WriteFixtureSubject(const testing::HumanoidFixture& f, const std::string& path) {
  SubjectModel subject;
  subject.name = "actor";
  subject.skeleton = f.skeleton;
  subject.markers = f.markers;
  WriteSubjectModel(path, subject);
}

// The subject actor.toml and the take take.c3d in dir, the solve to dir/out_bvh.
ProcessCommandOptions OptionsIn(const std::string& dir, const std::string& out_bvh = "o.bvh") {
  ProcessCommandOptions options;
  options.subject = dir + "/actor.toml";
  options.input_c3d = dir + "/take.c3d";
  options.output_bvh = dir + "/" + out_bvh;
  return options;
}

// The solved BVH's mean joint position error against the fixture's true motion, frame for
// frame.
double MeanJointErrorM(const testing::HumanoidFixture& f, const BvhTake& solved) {
  PoseErrorAccumulator errors(solved.skeleton);
  KinematicsWorkspace truth(*f.skeleton), est(solved.skeleton);
  for (int fr = 0; fr < solved.num_frames(); ++fr) {
    ForwardKinematics(*f.skeleton, f.motion[static_cast<size_t>(fr)], &truth);
    ForwardKinematics(solved.skeleton, solved.frames[static_cast<size_t>(fr)], &est);
    errors.Add(truth, est);
  }
  return errors.mean_position_error_m();
}

// A take's analog channels (force plates, EMG) are in the cleaned C3D as they came: the
// cleaned file held none of them, with no word.
TEST(ProcessCommandTest, TheCleanedC3dKeepsTheTakesAnalogChannels) {
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 120.0);
  const std::string dir = testing::TempDir("process_analog");
  WriteFixtureSubject(f, dir + "/actor.toml");
  C3dTake take = f.take;
  C3dTake::Analog& analog = take.analog;
  analog.labels = {"Fz1", "Fz2"};
  analog.descriptions = analog.units = {"", ""};
  analog.scale = {0.5, 0.5};
  analog.offset = {0.0, 0.0};
  analog.samples_per_frame = 10;
  for (size_t i = 0; i < static_cast<size_t>(take.num_frames) * 20; ++i)
    analog.values.push_back(static_cast<float>(i % 977));
  WriteC3d(dir + "/take.c3d", take);
  ProcessCommandOptions options = OptionsIn(dir);
  options.output_c3d = dir + "/cleaned.c3d";
  std::ostringstream out;
  (void)RunProcessCommand(options, out);
  const C3dTake cleaned = ReadC3d(dir + "/cleaned.c3d");
  EXPECT_EQ(cleaned.analog.labels, analog.labels);
  EXPECT_EQ(cleaned.analog.samples_per_frame, 10);
  EXPECT_EQ(cleaned.analog.values, analog.values);
}

// The command fails with an error containing why (and names, if given) and writes no BVH.
void ExpectRefusedWritingNothing(const ProcessCommandOptions& options, const std::string& why,
                                 const std::string& names = "") {
  std::ostringstream out;
  try {
    RunProcessCommand(options, out);
    ADD_FAILURE() << "expected an error containing: " << why;
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(names), std::string::npos) << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(options.output_bvh));
}

TEST(ProcessCommandTest, CleansATakeAndWritesAlignedBvhCleanedC3dAndReport) {
  const auto f = testing::MakeHumanoidFixture("mixed", 6.0, 120.0);
  const std::string dir = testing::TempDir("process");
  WriteFixtureSubject(f, dir + "/actor.toml");
  CorruptionOptions corruption;
  CorruptedTake bad = CorruptTake(f.take, f.markers.get(), corruption);
  // A marker 15 cm off its place from the take's first frame for 0.5 s: judged bad with
  // nothing before it to repair from, unrecoverable.
  for (int fr = 0; fr < 60; ++fr)
    if (bad.take.valid(fr, 10)) bad.take.at(fr, 10) += Vec3(0.15, 0.0, 0.0);
  WriteC3d(dir + "/take.c3d", bad.take);

  ProcessCommandOptions options = OptionsIn(dir, "solved.bvh");
  options.output_c3d = dir + "/cleaned.c3d";
  options.report_json = dir + "/report.json";
  std::ostringstream out;
  const ProcessSummary summary = RunProcessCommand(options, out);
  EXPECT_EQ(summary.counters.frames_in, f.take.num_frames);
  EXPECT_EQ(summary.counters.frames_out, f.take.num_frames);
  EXPECT_NE(out.str().find("repaired (missing"), std::string::npos) << out.str();

  // The BVH lines up frame for frame with the truth and is accurate.
  const BvhTake solved = ReadBvh(dir + "/solved.bvh");
  ASSERT_EQ(solved.num_frames(), f.take.num_frames);
  EXPECT_NEAR(solved.rate_hz(), 120.0, 1e-6);
  EXPECT_LT(MeanJointErrorM(f, solved), 0.01);

  // Samples the pipeline left alone are the input's bit for bit (no float round trip
  // through metres); the ones it repaired moved for real.
  const C3dTake input = ReadC3d(dir + "/take.c3d");
  const C3dTake cleaned = ReadC3d(dir + "/cleaned.c3d");
  ASSERT_EQ(cleaned.labels, input.labels);
  int false_positives = 0, identical = 0, missing_out = 0, removed = 0;
  for (int fr = 0; fr < input.num_frames; ++fr) {
    for (int p = 0; p < input.num_points(); ++p) {
      missing_out += !cleaned.valid(fr, p);
      removed += input.valid(fr, p) && !cleaned.valid(fr, p);
      if (!input.valid(fr, p) || !cleaned.valid(fr, p)) continue;
      const double moved = (cleaned.at(fr, p) - input.at(fr, p)).norm();
      ASSERT_TRUE(moved == 0.0 || moved > 1e-6) << fr << " " << p << " moved by " << moved;
      identical += moved == 0.0;
      if (bad.at(fr, p) == CorruptionKind::kNone && moved > 0.0) ++false_positives;
    }
  }
  EXPECT_GT(identical, input.num_frames * input.num_points() * 8 / 10);
  // What the report calls unrecoverable is missing in the cleaned take, and nothing else:
  // captured samples judged bad with nothing to repair them from were written back as
  // captured.
  EXPECT_GT(removed, 0);  // the displaced marker's, at least
  EXPECT_EQ(missing_out, summary.counters.unrecoverable);
  EXPECT_LT(false_positives, input.num_frames * input.num_points() * 3 / 100);

  std::ifstream report_file(dir + "/report.json");
  const nlohmann::json report = nlohmann::json::parse(report_file);
  EXPECT_EQ(report["frames_in"], f.take.num_frames);
  EXPECT_EQ(report["frames_out"], f.take.num_frames);
  EXPECT_GT(report["repaired_samples_by_reason"]["missing"].get<int>(), 0);
}

TEST(ProcessCommandTest, RefusesATakeWithoutTheSubjectsMarkers) {
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  const std::string dir = testing::TempDir("process_mismatch");
  WriteFixtureSubject(f, dir + "/actor.toml");
  C3dTake other;
  other.labels = {"X", "Y"};
  other.rate_hz = 60;
  other.Allocate(10);
  WriteC3d(dir + "/take.c3d", other);
  ProcessCommandOptions options = OptionsIn(dir);
  std::ostringstream out;
  try {
    RunProcessCommand(options, out);
    FAIL() << "no error";
  } catch (const std::invalid_argument& e) {
    // Which take and which subject: the message named neither.
    EXPECT_EQ(std::string(e.what()).rfind(options.input_c3d + ": take has 0 of the subject's ", 0),
              0u)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("(subject " + options.subject + ")"), std::string::npos)
        << e.what();
    EXPECT_EQ(std::string(e.what()).find("carry no labels"), std::string::npos) << e.what();
  }
  // A file without POINT:LABELS: its points read as unlabeled_N, and the refusal says so
  // (it listed the subject's markers as missing, nothing more).
  other.labels = {"", ""};
  WriteC3d(dir + "/take.c3d", other);
  try {
    RunProcessCommand(options, out);
    FAIL() << "no error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("the take's 2 points carry no labels: its POINT:LABELS "
                                         "is missing or empty"),
              std::string::npos)
        << e.what();
  }
}

// A Vicon capture stands on +Z; its solve is written standing as the subject's rest pose
// does (+Y, as BVH readers expect), so it matches the motion captured on +Y. It was written
// in the capture's world, lying on its back in a tool reading the BVH.
TEST(ProcessCommandTest, ACaptureStandingOnZIsWrittenStandingAsTheSubjectsRestPoseDoes) {
  const auto f = testing::MakeHumanoidFixture("walk", 2.0, 60.0);
  const std::string dir = testing::TempDir("process_z_up");
  WriteFixtureSubject(f, dir + "/actor.toml");
  const Mat3 to_z = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitX()).toRotationMatrix();
  C3dTake on_z = f.take;
  for (int fr = 0; fr < on_z.num_frames; ++fr)
    for (int p = 0; p < on_z.num_points(); ++p)
      if (on_z.valid(fr, p)) on_z.at(fr, p) = to_z * on_z.at(fr, p);
  WriteC3d(dir + "/take.c3d", on_z);
  ProcessCommandOptions options = OptionsIn(dir);
  std::ostringstream out;
  EXPECT_TRUE(RunProcessCommand(options, out).solve_turned);
  EXPECT_NE(out.str().find("the capture stands on +z"), std::string::npos) << out.str();
  const BvhTake solved = ReadBvh(options.output_bvh);
  EXPECT_LT(MeanJointErrorM(f, solved), 0.01);
  // The same capture on +Y is written as it is.
  WriteC3d(dir + "/take.c3d", f.take);
  EXPECT_FALSE(RunProcessCommand(options, out).solve_turned);
  // ...and so is one that opens bent 60 degrees over and straightens within half a second:
  // judged on its first frame, the whole upright take was written turned onto its side.
  C3dTake leaning = f.take;
  const int lean_frames = 30;
  for (int fr = 0; fr < lean_frames; ++fr) {
    Vec3 centre = Vec3::Zero();
    int seen = 0;
    for (int p = 0; p < leaning.num_points(); ++p)
      if (leaning.valid(fr, p)) {
        centre += leaning.at(fr, p);
        ++seen;
      }
    centre /= seen;
    const Mat3 lean =
        Eigen::AngleAxisd(M_PI / 3 * (1.0 - static_cast<double>(fr) / lean_frames), Vec3::UnitX())
            .toRotationMatrix();
    for (int p = 0; p < leaning.num_points(); ++p)
      if (leaning.valid(fr, p)) leaning.at(fr, p) = centre + lean * (leaning.at(fr, p) - centre);
  }
  WriteC3d(dir + "/take.c3d", leaning);
  std::ostringstream leaning_out;
  EXPECT_FALSE(RunProcessCommand(options, leaning_out).solve_turned) << leaning_out.str();
}

// Fewer than half the subject's markers labelled in the take is most likely the wrong
// subject or marker set: refused unless asked for (4 of 59 matched solved with exit 0, 93 %
// of the samples unrecoverable and the 4's fit looking excellent).
TEST(ProcessCommandTest, RefusesATakeLabellingFewerThanHalfTheSubjectsMarkers) {
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  const std::string dir = testing::TempDir("process_partial");
  WriteFixtureSubject(f, dir + "/actor.toml");
  C3dTake partial = f.take;
  const int kept = static_cast<int>(partial.labels.size()) * 2 / 5;
  for (size_t p = static_cast<size_t>(kept); p < partial.labels.size(); ++p)
    partial.labels[p] = "OTHER" + std::to_string(p);
  WriteC3d(dir + "/take.c3d", partial);
  ProcessCommandOptions options = OptionsIn(dir);
  std::ostringstream out;
  try {
    RunProcessCommand(options, out);
    ADD_FAILURE() << "a take labelling " << kept << " markers was solved";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("only " + std::to_string(kept) + " of the subject's " +
                                         std::to_string(f.markers->num_markers()) + " markers"),
              std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("--allow-partial"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(options.output_bvh));
  options.allow_partial = true;
  RunProcessCommand(options, out);
  EXPECT_TRUE(std::filesystem::exists(options.output_bvh));
}

// An output that cannot be written and a character that cannot be used fail before the
// take is solved: they failed after it, the solved BVH already written.
TEST(ProcessCommandTest, AnUnwritableOutputOrAnUnusableCharacterFailsBeforeSolving) {
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  const std::string dir = testing::TempDir("process_outputs");
  WriteFixtureSubject(f, dir + "/actor.toml");
  WriteC3d(dir + "/take.c3d", f.take);
  const auto expect_refused = [](const ProcessCommandOptions& options, const std::string& why) {
    ExpectRefusedWritingNothing(options, why);
  };
  ProcessCommandOptions no_folder = OptionsIn(dir);
  no_folder.output_c3d = dir + "/missing/cleaned.c3d";
  expect_refused(no_folder, "--out-c3d " + dir + "/missing/cleaned.c3d: the folder");
  ProcessCommandOptions plot_file = OptionsIn(dir);
  plot_file.plot_dir = dir + "/take.c3d";
  expect_refused(plot_file, "is a file, not a folder");
  const Skeleton stick({Joint{.name = "root", .parent = {}, .type = JointType::kFree},
                        Joint{.name = "tip", .parent = JointIndex(0), .offset = Vec3(0, 0.3, 0)}});
  WriteBvh(dir + "/stick.bvh", MakeBvhTake(stick, {RestPose(stick)}, 1.0 / 30.0));
  ProcessCommandOptions stick_character = OptionsIn(dir);
  stick_character.retarget_bvh = dir + "/stick.bvh";
  expect_refused(stick_character, dir + "/stick.bvh: not a recognisable humanoid");
  // The character's motion goes beside the solved BVH unless told otherwise.
  ProcessCommandOptions beside = OptionsIn(dir, "solved.bvh");
  beside.retarget_bvh = dir + "/character.bvh";
  EXPECT_EQ(CharacterOutputPath(beside), dir + "/solved.character.bvh");
}

TEST(ProcessCommandTest, AnOutputOverTheTakeOrAnotherOutputIsRefusedAndTheTakeKept) {
  // A mistyped --out-c3d once replaced the raw capture with its cleaned copy, exit 0.
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  const std::string dir = testing::TempDir("process_overwrite");
  WriteFixtureSubject(f, dir + "/actor.toml");
  WriteC3d(dir + "/take.c3d", f.take);
  const auto bytes = [](const std::string& path) {
    std::ifstream file(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(file), {});
  };
  const std::string raw = bytes(dir + "/take.c3d");
  ProcessCommandOptions over_take = OptionsIn(dir);
  over_take.output_c3d = dir + "/take.c3d";
  ExpectRefusedWritingNothing(over_take,
                              "--out-c3d " + dir + "/take.c3d: is the same file as --in");
  ProcessCommandOptions report_over_subject = OptionsIn(dir);
  report_over_subject.report_json = dir + "/./actor.toml";
  ExpectRefusedWritingNothing(report_over_subject, "is the same file as --subject");
  ProcessCommandOptions two_outputs = OptionsIn(dir, "both.bvh");
  two_outputs.output_c3d = dir + "/both.bvh";
  ExpectRefusedWritingNothing(two_outputs, "is the same file as --out-bvh");
  EXPECT_EQ(bytes(dir + "/take.c3d"), raw);
  EXPECT_FALSE(std::filesystem::exists(dir + "/both.bvh"));
}

// A take the subject cannot be solved from at all gets an error naming the file, never a
// rest-pose BVH reported as a success.
TEST(ProcessCommandTest, RefusesATakeWithNoFramesNoSeenMarkerOrAnUnusableRate) {
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  const std::string dir = testing::TempDir("process_empty");
  WriteFixtureSubject(f, dir + "/actor.toml");
  ProcessCommandOptions options = OptionsIn(dir);
  const auto expect_refused = [&](const C3dTake& take, const std::string& why) {
    WriteC3d(options.input_c3d, take);
    ExpectRefusedWritingNothing(options, why, "take.c3d");
  };
  C3dTake unseen = f.take;
  unseen.Allocate(f.take.num_frames);  // every sample missing
  expect_refused(unseen, "no frame of 60 shows enough");
  C3dTake empty = f.take;
  empty.Allocate(0);
  expect_refused(empty, "no frames");
  // A rate the cleanup cannot run at is said of the take (it named CleanupOptions.rate_hz).
  C3dTake glacial = f.take;
  glacial.rate_hz = 1e-30;
  expect_refused(glacial, "a capture rate of 1e-30 Hz; the cleanup runs at 1 to 10000 Hz");
}

TEST(ProcessCommandTest, WarnsOfALabelGivenToTwoPointsOrMatchingTwoSubjects) {
  const auto f = testing::MakeHumanoidFixture("walk", 1.0, 60.0);
  const std::string dir = testing::TempDir("process_duplicate");
  WriteFixtureSubject(f, dir + "/actor.toml");
  C3dTake doubled = testing::WithALabelGivenTwice(f.take, 3);
  WriteC3d(dir + "/take.c3d", doubled);
  ProcessCommandOptions options = OptionsIn(dir);
  std::ostringstream out;
  RunProcessCommand(options, out);
  EXPECT_NE(out.str().find("warning: 1 of the subject's markers label more than one point of the "
                           "take; the first point is used for: " +
                           f.take.labels[3] + "\n"),
            std::string::npos)
      << out.str();
  // Two subjects' copies of a label: neither is this subject's, and the warning says why
  // the marker stays missing.
  doubled.labels[3] = "Dan:" + f.take.labels[3];
  doubled.labels.back() = "Eve:" + f.take.labels[3];
  WriteC3d(dir + "/take.c3d", doubled);
  std::ostringstream ambiguous;
  RunProcessCommand(options, ambiguous);
  EXPECT_NE(ambiguous.str().find("match several of the take's labels, so none is used and they "
                                 "stay missing: " +
                                 f.take.labels[3] + " (Dan:" + f.take.labels[3] +
                                 ", Eve:" + f.take.labels[3] + ")"),
            std::string::npos)
      << ambiguous.str();
}

// Offline, the frames before the subject comes into view hold its first solved pose
// (the live path's rest pose at the origin would be a jump across the stage in the
// file), and the summary says so.
TEST(ProcessCommandTest, FramesBeforeTheSubjectIsSeenHoldItsFirstSolvedPose) {
  const auto f = testing::MakeHumanoidFixture("walk", 2.0, 60.0);
  const std::string dir = testing::TempDir("process_late");
  WriteFixtureSubject(f, dir + "/actor.toml");
  C3dTake late = f.take;
  constexpr int kBlank = 20;
  for (int fr = 0; fr < kBlank; ++fr)
    for (int p = 0; p < late.num_points(); ++p) {
      late.at(fr, p) = Vec3::Constant(kNaN);
      late.residuals[static_cast<size_t>(fr) * static_cast<size_t>(late.num_points()) +
                     static_cast<size_t>(p)] = -1.0f;
    }
  WriteC3d(dir + "/take.c3d", late);
  ProcessCommandOptions options = OptionsIn(dir);
  std::ostringstream out;
  const ProcessSummary summary = RunProcessCommand(options, out);
  // The lookahead's frames before the first samples are filled from them; the ones
  // further back have nothing to solve.
  const int unsolved = kBlank - options.lookahead;
  EXPECT_EQ(summary.frames_before_first_solve, unsolved);
  EXPECT_EQ(summary.unsolved_frames, unsolved);
  EXPECT_NE(out.str().find("warning: " + std::to_string(unsolved) + " frames could not be solved"),
            std::string::npos)
      << out.str();
  const BvhTake solved = ReadBvh(options.output_bvh);
  ASSERT_EQ(solved.num_frames(), f.take.num_frames);
  KinematicsWorkspace first(solved.skeleton), held(solved.skeleton), truth(*f.skeleton);
  ForwardKinematics(solved.skeleton, solved.frames[static_cast<size_t>(unsolved)], &first);
  ForwardKinematics(*f.skeleton, f.motion[static_cast<size_t>(kBlank)], &truth);
  EXPECT_LT((first.p_WJ[0] - truth.p_WJ[0]).norm(), 0.05);
  for (int fr = 0; fr < unsolved; ++fr) {
    ForwardKinematics(solved.skeleton, solved.frames[static_cast<size_t>(fr)], &held);
    EXPECT_LT((held.p_WJ[0] - first.p_WJ[0]).norm(), 1e-4) << "frame " << fr;
  }
}

// --plot draws what the cleanup did: every marker's row with the repairs it made, the
// solve over time, and with the truth (what mocap-sim synth --truth-bvh writes) the
// joint error over time, reported too.
// A truth written in inches (mocap-sim synth writes it in the subject's bvh_units) is
// read in inches when told: from its bones alone an inch file looks like centimetres,
// and the error against it was 127 cm.
// A 120 Hz fixture's subject and take in dir, and its motion as the truth written at
// truth_rate_hz in units.
ProcessCommandOptions OptionsWithTruth(const std::string& dir, double seconds, double truth_rate_hz,
                                       const std::string& units) {
  const auto f = testing::MakeHumanoidFixture("walk", seconds, 120.0);
  WriteFixtureSubject(f, dir + "/actor.toml");
  WriteC3d(dir + "/take.c3d", f.take);
  WriteBvh(dir + "/truth.bvh", MakeBvhTake(*f.skeleton, f.motion, 1.0 / truth_rate_hz, units));
  ProcessCommandOptions options = OptionsIn(dir);
  options.truth_bvh = dir + "/truth.bvh";
  return options;
}

TEST(ProcessCommandTest, ATruthInInchesIsReadInInchesWhenTold) {
  ProcessCommandOptions options =
      OptionsWithTruth(testing::TempDir("process_truth_units"), 2.0, 120.0, "in");
  std::ostringstream out;
  EXPECT_GT(RunProcessCommand(options, out).truth_mean_cm, 10.0);  // guessed as cm
  options.truth_units = "in";
  EXPECT_LT(RunProcessCommand(options, out).truth_mean_cm, 1.0);
  options.truth_units = "furlongs";
  EXPECT_THROW(RunProcessCommand(options, out), BvhError);
}

// A truth of the same length at another rate is another moment in every frame but the
// first: refused, naming both rates (it was scored frame by frame without a word).
TEST(ProcessCommandTest, ATruthAtAnotherRateIsRefused) {
  const ProcessCommandOptions options =
      OptionsWithTruth(testing::TempDir("process_truth_rate"), 1.0, 30.0, "cm");
  std::ostringstream out;
  try {
    RunProcessCommand(options, out);
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()),
              options.truth_bvh + " is at 30 Hz, the take at 120 Hz: not the truth of this take");
  }
}

TEST(ProcessCommandTest, PlotsShowEveryMarkerTheSolveAndTheErrorAgainstTheTruth) {
  const auto f = testing::MakeHumanoidFixture("walk", 4.0, 120.0);
  const std::string dir = testing::TempDir("process_plot");
  WriteFixtureSubject(f, dir + "/actor.toml");
  CorruptedTake bad = CorruptTake(f.take, f.markers.get(), CorruptionOptions{});
  bad.take.first_frame = 245;  // a trimmed take: its numbers are not its indices
  WriteC3d(dir + "/take.c3d", bad.take);
  // The truth moved 40 cm at one frame: that frame is the worst, whatever the cleanup does.
  std::vector<Pose> truth = f.motion;
  constexpr int kMovedIndex = 300;
  const auto root = static_cast<size_t>(0);
  truth[kMovedIndex].translation[root] += Vec3(0.4, 0.0, 0.0);
  WriteBvh(dir + "/truth.bvh", MakeBvhTake(*f.skeleton, truth, 1.0 / 120.0, "cm"));

  ProcessCommandOptions options = OptionsIn(dir, "solved.bvh");
  options.plot_dir = dir + "/plots";
  options.truth_bvh = dir + "/truth.bvh";
  std::ostringstream out;
  const ProcessSummary summary = RunProcessCommand(options, out);
  ASSERT_TRUE(summary.has_truth);
  EXPECT_LT(summary.truth_mean_cm, 1.0);
  EXPECT_GE(summary.truth_p999_cm, summary.truth_mean_cm);
  EXPECT_GE(summary.truth_worst_cm, summary.truth_p999_cm);
  // The worst frame is named as a user looks it up: by the take's numbering (and its
  // time), with its joint.
  EXPECT_EQ(summary.truth_worst_index, kMovedIndex);
  EXPECT_EQ(summary.truth_worst_frame, 245 + kMovedIndex);
  EXPECT_NEAR(summary.truth_worst_cm, 40.0, 2.0);
  EXPECT_TRUE(f.skeleton->FindJoint(summary.truth_worst_joint).has_value())
      << summary.truth_worst_joint;
  EXPECT_NE(out.str().find("against the truth"), std::string::npos) << out.str();
  EXPECT_NE(out.str().find("(frame 545, 2.500 s, " + summary.truth_worst_joint + ")"),
            std::string::npos)
      << out.str();
  const nlohmann::json report = ProcessSummaryJson(summary, options);
  EXPECT_EQ(report["truth_joint_error_cm"]["worst_frame"], 545);
  EXPECT_EQ(report["truth_joint_error_cm"]["worst_frame_index"], kMovedIndex);
  EXPECT_EQ(report["truth_joint_error_cm"]["worst_joint"], summary.truth_worst_joint);
  EXPECT_DOUBLE_EQ(report["truth_joint_error_cm"]["frame_p999"].get<double>(),
                   summary.truth_p999_cm);
  const auto read = [](const std::string& path) {
    std::ifstream in(path);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  };
  const std::string markers = read(dir + "/plots/markers.svg");
  ASSERT_FALSE(markers.empty());
  for (int m = 0; m < f.markers->num_markers(); ++m)
    EXPECT_NE(markers.find(">" + f.markers->marker(m).name + "<"), std::string::npos);
  EXPECT_NE(markers.find("gap filled"), std::string::npos);  // the corruption's gaps, filled
  EXPECT_NE(markers.find("observed"), std::string::npos);
  EXPECT_NE(read(dir + "/plots/solve.svg").find("LM iterations"), std::string::npos);
  EXPECT_NE(read(dir + "/plots/joint_error.svg").find("worst joint"), std::string::npos);
  // A truth of another take is refused, naming it.
  WriteBvh(dir + "/short.bvh",
           MakeBvhTake(*f.skeleton, std::vector<Pose>(f.motion.begin(), f.motion.begin() + 10),
                       1.0 / 120.0, "cm"));
  options.truth_bvh = dir + "/short.bvh";
  try {
    RunProcessCommand(options, out);
    ADD_FAILURE() << "a 10-frame truth was taken";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("short.bvh: 10 frames, the take has"), std::string::npos)
        << e.what();
  }
}

// A label whose every sample is invalid and a run of frames with no marker at all came
// out as "repaired (missing)" like any short gap, with no word that nothing was seen.
TEST(ProcessCommandTest, SaysWhatTheTakeNeverCapturesAndWhichRepairsAreOneSidedGuesses) {
  const auto f = testing::MakeHumanoidFixture("walk", 3.0, 60.0);
  const std::string dir = testing::TempDir("process_coverage");
  WriteFixtureSubject(f, dir + "/actor.toml");
  C3dTake take = f.take;
  const auto P = static_cast<size_t>(take.num_points());
  const int lost = 4;
  for (int fr = 0; fr < take.num_frames; ++fr)
    for (size_t p = 0; p < P; ++p)
      if (static_cast<int>(p) == lost || (fr >= 60 && fr < 90))
        take.residuals[static_cast<size_t>(fr) * P + p] = -1.0f;
  WriteC3d(dir + "/take.c3d", take);
  ProcessCommandOptions options = OptionsIn(dir);
  options.lookahead = 6;
  options.report_json = dir + "/report.json";
  std::ostringstream out;
  const ProcessSummary summary = RunProcessCommand(options, out);
  const std::string lost_name = take.labels[static_cast<size_t>(lost)];
  ASSERT_EQ(summary.never_captured, std::vector<std::string>{lost_name}) << out.str();
  EXPECT_NE(out.str().find("captured in no frame: never published (unrecoverable), and the "
                           "solve goes without them: " +
                           lost_name),
            std::string::npos)
      << out.str();
  EXPECT_EQ(summary.blank_frames, 30);
  EXPECT_EQ(summary.longest_blank_run, 30);
  EXPECT_NE(out.str().find("30 frames capture none of the subject's markers (the longest run "
                           "30 frames, 0.5 s)"),
            std::string::npos)
      << out.str();
  // A 30-frame hole seen 6 frames ahead: its first 24 frames are guessed from one side.
  EXPECT_GE(summary.repaired_extrapolated, 24 * (f.markers->num_markers() - 1));
  EXPECT_GT(summary.repaired_interpolated, 0);
  EXPECT_NE(out.str().find("; --lookahead 30 or more bridges the longest between captured "
                           "frames"),
            std::string::npos)
      << out.str();
  {
    // As it says: seen 30 frames ahead, the hole is filled between the frames either side
    // (the horizon a fill turns toward its return within passes over a run of frames with
    // nothing seen). Before, only its last 0.1 s was.
    ProcessCommandOptions bridged = OptionsIn(dir);
    bridged.lookahead = 30;
    std::ostringstream bridged_out;
    const ProcessSummary across = RunProcessCommand(bridged, bridged_out);
    EXPECT_LT(across.repaired_extrapolated, (f.markers->num_markers() - 1)) << bridged_out.str();
    EXPECT_EQ(bridged_out.str().find("or more bridges"), std::string::npos) << bridged_out.str();
  }
  int64_t repaired = 0;
  for (const int64_t n : summary.counters.repaired_by) repaired += n;
  EXPECT_EQ(
      summary.repaired_captured + summary.repaired_interpolated + summary.repaired_extrapolated,
      repaired);
  std::ifstream report_file(dir + "/report.json");
  const nlohmann::json report = nlohmann::json::parse(report_file);
  EXPECT_EQ(report["markers_never_captured"][0], lost_name);
  EXPECT_EQ(report["frames_capturing_no_marker"], 30);
  EXPECT_EQ(report["repaired_samples_by_source"]["extrapolated"], summary.repaired_extrapolated);
}

// A subject calibrated from markers alone names its joints by role; the truth that
// mocap-sim writes names them its own way. The limb joints are matched by role.
TEST(ProcessCommandTest, ATruthWithOtherJointNamesIsMatchedByRoleOnTheLimbs) {
  const auto f = testing::MakeHumanoidFixture("mixed", 9.0, 60.0, 0.001);
  const std::string dir = testing::TempDir("process_truth_roles");
  WriteC3d(dir + "/take.c3d", f.take);
  WriteBvh(dir + "/truth.bvh", MakeBvhTake(*f.skeleton, f.motion, 1.0 / 60.0, "cm"));
  CalibrateCommandOptions calibrate;
  calibrate.markers_c3d = {dir + "/take.c3d"};
  calibrate.out_subject = dir + "/actor.toml";
  calibrate.interleaved_solves = 1;  // quick under the sanitizers
  std::ostringstream calibrate_out;
  ASSERT_GT(RunCalibrateCommand(calibrate, calibrate_out), 0) << calibrate_out.str();

  ProcessCommandOptions options = OptionsIn(dir, "solved.bvh");
  options.truth_bvh = dir + "/truth.bvh";
  std::ostringstream out;
  const ProcessSummary summary = RunProcessCommand(options, out);
  ASSERT_TRUE(summary.has_truth) << out.str();
  // Calibrated from 9 s of walking and reaching with the project's layout (measured:
  // 4.1 cm mean over the limb joints): centimetres, not the metres of unmatched joints.
  EXPECT_LT(summary.truth_mean_cm, 8.0) << out.str();
  EXPECT_NE(out.str().find("12 joints matched by humanoid role"), std::string::npos) << out.str();
}

// A character file of one frame whose floor-level root (Bandai's joint_Root) sits over a
// pelvis with position channels of its own: the written character travelled on joint_Root,
// its Hips held metres from it (global positions right, the rig's own takes moving the
// Hips). Now the Hips travel and the floor root stays where the file has it.
TEST(ProcessCommandTest, AOneFrameCharacterUnderAFloorRootIsWrittenTravellingOnItsPelvis) {
  const auto f = testing::MakeHumanoidFixture("walk", 3.0, 120.0);
  const std::string dir = testing::TempDir("process_floor_root");
  WriteFixtureSubject(f, dir + "/actor.toml");
  WriteC3d(dir + "/take.c3d", f.take);
  std::vector<Joint> joints = {
      Joint{.name = "joint_Root", .parent = {}, .offset = Vec3::Zero(), .type = JointType::kFree}};
  for (const Joint& j : f.skeleton->joints()) {
    Joint joint = j;
    joint.parent = JointIndex(j.parent.is_valid() ? j.parent.value + 1 : 0);
    joints.push_back(joint);
  }
  const Skeleton rig(std::move(joints));
  WriteBvh(dir + "/tpose.bvh", MakeBvhTake(rig, {RestPose(rig)}, 1.0 / 30.0, "cm"));
  ProcessCommandOptions options = OptionsIn(dir, "solved.bvh");
  options.retarget_bvh = dir + "/tpose.bvh";
  std::ostringstream out;
  RunProcessCommand(options, out);
  const BvhTake written = ReadBvh(CharacterOutputPath(options));
  ASSERT_EQ(written.num_frames(), f.take.num_frames);
  EXPECT_NE(written.skeleton.joint(0).type, JointType::kFree);  // read back from its motion
  EXPECT_EQ(written.skeleton.joint(1).type, JointType::kFree);
  KinematicsWorkspace ws(written.skeleton);
  double pelvis_off = 0.0;
  for (int fr = 5; fr < written.num_frames(); ++fr) {
    ForwardKinematics(written.skeleton, written.frames[static_cast<size_t>(fr)], &ws);
    pelvis_off = std::max(pelvis_off,
                          (ws.p_WJ[1] - f.motion[static_cast<size_t>(fr)].translation[0]).norm());
  }
  EXPECT_LT(pelvis_off, 0.02);
}

}  // namespace
}  // namespace mocapd
