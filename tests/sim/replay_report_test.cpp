// Tests for the replay report's accuracy tail: the frames over the p99.9 grouped by the
// joint that made them worst, with separate episodes told apart per subject.
#include "sim/replay_report.hpp"

#include <gtest/gtest.h>

#include <algorithm>

#include "sim/humanoid.hpp"

namespace mocapd {
namespace {

TEST(ReplayReportTest, TailFramesAreGroupedByJointAndEpisodesAreSplitByGapAndSubject) {
  const Skeleton skeleton = MakeHumanoidSkeleton();
  const int toe = skeleton.FindJoint("RightToeBase")->value;
  const int hand = skeleton.FindJoint("LeftHand")->value;
  // Two subjects' frames interleave as received: subject 0 frames 100.., subject 1 frames
  // 100.. too (the same frame numbers: another subject is another episode).
  std::vector<std::pair<size_t, uint64_t>> scored;
  for (uint64_t n = 100; n < 1000; ++n) {
    scored.push_back({0, n});
    scored.push_back({1, n});
  }
  auto index = [](size_t subject, uint64_t frame_number) {
    return static_cast<int>(2 * (frame_number - 100) + subject);
  };
  std::vector<PoseErrorAccumulator::FrameError> tail;
  // Toe: subject 0 frames 200-204, 206 and 216 (one episode: each at most the 10-frame
  // gap after the one before), then 227 (11 after: a second) and 400 (a third); subject 1
  // frame 202 (a fourth). Hand: subject 1 frame 300.
  for (uint64_t n : {200, 201, 202, 203, 204, 206, 216, 227, 400})
    tail.push_back({index(0, n), toe, 0.05 + 0.001 * static_cast<double>(n % 10)});
  tail.push_back({index(1, 202), toe, 0.2});
  tail.push_back({index(1, 300), hand, 0.3});
  std::sort(tail.begin(), tail.end(),
            [](const auto& a, const auto& b) { return a.frame < b.frame; });
  const std::vector<std::string> names = {"actor1", "actor2"};
  const auto summary = SummarizeTail(tail, scored, names, skeleton, 10);
  ASSERT_EQ(summary.size(), 2u);
  EXPECT_EQ(summary[0].joint, "RightToeBase");  // most frames first
  EXPECT_EQ(summary[0].frames, 10u);
  EXPECT_EQ(summary[0].episodes, 4u);
  EXPECT_NEAR(summary[0].worst_cm, 20.0, 1e-9);
  EXPECT_EQ(summary[0].worst_subject, "actor2");
  EXPECT_EQ(summary[0].worst_frame_number, 202u);
  EXPECT_EQ(summary[1].joint, "LeftHand");
  EXPECT_EQ(summary[1].frames, 1u);
  EXPECT_EQ(summary[1].episodes, 1u);
  EXPECT_NEAR(summary[1].worst_cm, 30.0, 1e-9);
  EXPECT_EQ(summary[1].worst_subject, "actor2");
  EXPECT_EQ(summary[1].worst_frame_number, 300u);
}

TEST(ReplayReportTest, AFrameReceivedOutOfOrderDoesNotSplitAnEpisode) {
  const Skeleton skeleton = MakeHumanoidSkeleton();
  const int toe = skeleton.FindJoint("RightToeBase")->value;
  const std::vector<std::pair<size_t, uint64_t>> scored = {{0, 100}, {0, 102}, {0, 101}, {0, 103}};
  std::vector<PoseErrorAccumulator::FrameError> tail;
  for (int f = 0; f < 4; ++f) tail.push_back({f, toe, 0.1});
  const std::vector<std::string> names = {"actor1"};
  const auto summary = SummarizeTail(tail, scored, names, skeleton, 2);
  ASSERT_EQ(summary.size(), 1u);
  EXPECT_EQ(summary[0].frames, 4u);
  EXPECT_EQ(summary[0].episodes, 1u);
}

TEST(ReplayReportTest, TheTailIsInTheJsonAndTheTable) {
  ReplayReport report;
  report.listened = true;  // the table shows accuracy only for a measured output
  report.has_truth = true;
  report.p999_tail = {{"RightToeBase", 12, 2, 18.8, "actor3", 35501},
                      {"LeftLeg", 3, 1, 9.5, "actor1", 7}};
  const nlohmann::json j = report.ToJson();
  ASSERT_EQ(j["accuracy"]["p999_tail"].size(), 2u);
  EXPECT_EQ(j["accuracy"]["p999_tail"][0]["joint"], "RightToeBase");
  EXPECT_EQ(j["accuracy"]["p999_tail"][0]["episodes"], 2);
  EXPECT_EQ(j["accuracy"]["p999_tail"][0]["worst_subject"], "actor3");
  EXPECT_EQ(j["accuracy"]["p999_tail"][0]["worst_frame_number"], 35501);
  const std::string table = report.FormatTable();
  EXPECT_NE(table.find("RightToeBase 12 (2 episodes, worst 18.8 at actor3 frame 35501)"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("LeftLeg 3 (1 episode, worst 9.5 at actor1 frame 7)"), std::string::npos)
      << table;
}

// A take sent at another rate than it was captured at is played faster or slower, not
// resampled (its frames still say the capture's rate): the summary printed "1 x 240 Hz"
// for a 120 Hz C3D sent at --rate 240.
TEST(ReplayReportTest, ATakeSentAtAnotherRateSaysItIsNotResampled) {
  ReplayReport report;
  report.subjects = 1;
  report.rate_hz = 240;
  report.capture_rate_hz = 120;
  EXPECT_NE(report.FormatTable().find(
                "1 x 120 Hz (sent at 240 frames/s, 2.00x the take's rate, not resampled)"),
            std::string::npos)
      << report.FormatTable();
  EXPECT_EQ(report.ToJson()["capture_rate_hz"], 120.0);
  report.rate_hz = 120;
  EXPECT_EQ(report.FormatTable().find("not resampled"), std::string::npos);
}

// A reload that changed a subject's lookahead shows as its Ks in turn; a replay that did
// not listen (--from "") says nothing of K (it printed "lookahead K = 0").
TEST(ReplayReportTest, TheLookaheadIsGivenPerSubjectWhenItVariesAndNotAtAllUnmeasured) {
  ReplayReport report;
  report.subjects = 2;
  report.rate_hz = report.capture_rate_hz = 120;
  report.listened = true;
  report.lookahead = 12;
  EXPECT_NE(report.FormatTable().find("lookahead K = 12"), std::string::npos);
  report.lookahead_by_subject = {{"actor1", {12, 20}}, {"actor2", {12}}};
  EXPECT_NE(report.FormatTable().find("lookahead K = actor1 12 -> 20, actor2 12"),
            std::string::npos)
      << report.FormatTable();
  EXPECT_EQ(report.ToJson()["lookahead_frames_by_subject"]["actor1"], nlohmann::json({12, 20}));
  report.listened = false;
  EXPECT_EQ(report.FormatTable().find("lookahead"), std::string::npos) << report.FormatTable();
}

}  // namespace
}  // namespace mocapd
