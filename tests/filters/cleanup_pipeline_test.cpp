// Tests for the streaming cleanup pipeline as a whole: delay and accounting, untouched
// samples kept bit for bit, accuracy through repairs, and zero allocation per frame.
#include "filters/cleanup_pipeline.hpp"

#include <gtest/gtest.h>

#include <limits>
#include <random>
#include <utility>

#include "filters/pose_error.hpp"
#include "tests/filters/cleanup_fixture.hpp"
#include "tests/support/allocation_counter.hpp"

namespace mocapd {
namespace {

class CleanupPipelineTest : public CleanupFixture {
 protected:
  // The published skeletons' errors against the fixture's motion.
  PoseErrorAccumulator Errors(const std::vector<CleanFrame>& out) const {
    PoseErrorAccumulator errors(*fixture_.skeleton);
    KinematicsWorkspace truth(*fixture_.skeleton), est(*fixture_.skeleton);
    for (const CleanFrame& frame : out) {
      ForwardKinematics(*fixture_.skeleton, fixture_.motion[static_cast<size_t>(frame.frame)],
                        &truth);
      ForwardKinematics(*fixture_.skeleton, frame.pose, &est);
      errors.Add(truth, est);
    }
    return errors;
  }
};

TEST_F(CleanupPipelineTest, PublishesEveryFrameKFramesLateWithUntouchedSamplesBitForBit) {
  CleanupOptions options;
  options.lookahead = 12;
  CleanupPipeline dut(fixture_.skeleton, fixture_.markers, options);
  for (int f = 0; f < 12; ++f) EXPECT_FALSE(dut.Push(frames_[static_cast<size_t>(f)]));
  ASSERT_TRUE(dut.Push(frames_[12]));
  EXPECT_EQ(dut.output().frame, 0);
  const auto out = Run(options);
  ASSERT_EQ(out.size(), frames_.size());
  EXPECT_EQ(counters_.frames_in, counters_.frames_out);
  for (size_t f = 0; f < out.size(); ++f) {
    ASSERT_EQ(out[f].frame, static_cast<int64_t>(f));
    for (size_t m = 0; m < frames_[f].size(); ++m) {
      ASSERT_EQ(out[f].status[m], MarkerStatus::kObserved)
          << f << " " << m << " " << to_string(out[f].reason[m]);
      ASSERT_EQ(out[f].markers[m], frames_[f][m]);  // bit for bit
    }
  }
}

TEST_F(CleanupPipelineTest, SolvedSkeletonStaysAccurateThroughRepairs) {
  for (int f = 200; f < 320; ++f) Sample(f, Marker("LHND1")) = Vec3::Constant(kNaN);
  for (int f = 500; f < 503; ++f) Sample(f, Marker("RSHN2")) += Vec3(0.3, 0.0, 0.0);
  const PoseErrorAccumulator errors = Errors(Run(CleanupOptions{}));
  EXPECT_LT(errors.mean_position_error_m(), 0.003);
  EXPECT_LT(errors.max_position_error_m(), 0.03);
}

// Capture noise (1 mm) shakes the skeleton less when the final solve fits each captured
// sample smoothed over the frames around it, while the published samples stay as
// captured; and on noiseless motion the centred smoothing costs next to nothing.
TEST_F(CleanupPipelineTest, TheSkeletonFitsSmoothedSamplesAndThePublishedOnesStayAsCaptured) {
  auto mean_errors = [&](const std::vector<CleanFrame>& out) {
    const PoseErrorAccumulator errors = Errors(out);
    return std::pair{errors.mean_position_error_m(), errors.mean_rotation_error_rad()};
  };
  CleanupOptions unsmoothed;
  unsmoothed.solve_smoothing_s = 0.0;
  const auto noiseless = mean_errors(Run(CleanupOptions{}));
  const auto noiseless_unsmoothed = mean_errors(Run(unsmoothed));
  EXPECT_LT(noiseless.first, noiseless_unsmoothed.first + 0.0005);
  EXPECT_LT(noiseless.second, noiseless_unsmoothed.second + 0.002);

  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.001);
  for (auto& frame : frames_)
    for (auto& p : frame) p += Vec3(noise(rng), noise(rng), noise(rng));
  const auto out = Run(CleanupOptions{});
  const auto smoothed = mean_errors(out);
  const auto as_captured = mean_errors(Run(unsmoothed));
  EXPECT_LT(smoothed.second, 0.8 * as_captured.second);
  EXPECT_LT(smoothed.first, as_captured.first);
  int not_as_captured = 0;
  for (size_t f = 0; f < out.size(); ++f)
    for (size_t m = 0; m < frames_[f].size(); ++m)
      not_as_captured +=
          out[f].status[m] == MarkerStatus::kObserved && out[f].markers[m] != frames_[f][m];
  EXPECT_EQ(not_as_captured, 0);
}

// A thigh and shin occluded for 5 s while the foot stays seen: the knee may sit anywhere
// on a circle about the hip-ankle line and no marker tells the places apart. The unseen-
// knee rule keeps it on the side the leg showed before (KneeSwivel; the rule switched off
// is the comparison).
TEST_F(CleanupPipelineTest, AnUnseenKneeUnderASeenFootKeepsToItsSide) {
  const int hip = fixture_.skeleton->FindJoint("LeftUpLeg")->value;
  const int knee = fixture_.skeleton->FindJoint("LeftLeg")->value;
  for (int m = 0; m < fixture_.markers->num_markers(); ++m)
    if (fixture_.markers->primary_joint(m) == hip || fixture_.markers->primary_joint(m) == knee)
      for (int f = 200; f < 800; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  CleanupOptions off;
  off.unseen_knee_tolerance_rad = 0.0;
  const double with_rule = WorstJointError(Run(CleanupOptions{}), "LeftLeg", 200, 800);
  const double without = WorstJointError(Run(off), "LeftLeg", 200, 800);
  EXPECT_LT(with_rule, 0.7 * without) << with_rule << " " << without;  // 13 against 27 cm
}

// A take that starts mid-motion: its fastest-moving foot is where its markers are from
// the first frame. Each captured sample's catch-up took its motion as zero until then and
// ramped up at the acceleration limit: a Bandai run's foot lagged 3-4 cm for 20 frames.
TEST_F(CleanupPipelineTest, ATakeStartingMidStrideHasItsFootWithItsMarkersFromTheFirstFrame) {
  const auto toe = static_cast<size_t>(fixture_.skeleton->FindJoint("LeftToeBase")->value);
  KinematicsWorkspace now(*fixture_.skeleton), before(*fixture_.skeleton);
  int start = 1;
  double fastest = 0.0;
  for (int f = 1; f < 240; ++f) {
    ForwardKinematics(*fixture_.skeleton, fixture_.motion[static_cast<size_t>(f - 1)], &before);
    ForwardKinematics(*fixture_.skeleton, fixture_.motion[static_cast<size_t>(f)], &now);
    const double step = (now.p_WJ[toe] - before.p_WJ[toe]).norm();
    if (step > fastest) {
      fastest = step;
      start = f;
    }
  }
  frames_.erase(frames_.begin(), frames_.begin() + start);
  const std::vector<Pose> truth(fixture_.motion.begin() + start, fixture_.motion.end());
  const double worst = WorstJointError(Run(CleanupOptions{}), truth, "LeftToeBase", 0, 40);
  EXPECT_LT(worst, 0.008) << "the take starts at a toe speed of " << fastest * 120.0 << " m/s";
}

TEST_F(CleanupPipelineTest, PushAndFlushAllocateNothingAfterWarmUp) {
  for (int f = 100; f < 160; ++f) Sample(f, Marker("HED1")) = Vec3::Constant(kNaN);
  for (int f = 120; f < 122; ++f) Sample(f, Marker("PEL1")) += Vec3(0.2, 0, 0);
  CleanupPipeline dut(fixture_.skeleton, fixture_.markers, CleanupOptions{});
  for (int f = 0; f < 60; ++f) dut.Push(frames_[static_cast<size_t>(f)]);
  size_t allocations = 0;
  {
    testing::ScopedAllocationCounter counter;
    for (int f = 60; f < 400; ++f) dut.Push(frames_[static_cast<size_t>(f)]);
    while (dut.Flush()) {
    }
    allocations = counter.count();
  }
  EXPECT_EQ(allocations, 0u);
}

// One absurd frame (every marker at 1e30, or FLT_MAX) is not a position: it is missing,
// it enters no solver's history, and not one good sample after it changes.
TEST_F(CleanupPipelineTest, AnAbsurdFrameHarmsNoGoodSampleAfterIt) {
  const auto clean = Run(CleanupOptions{});
  for (const double absurd : {1e30, static_cast<double>(std::numeric_limits<float>::max())}) {
    for (auto& p : frames_[300]) p = Vec3::Constant(absurd);
    const auto out = Run(CleanupOptions{});
    EXPECT_EQ(counters_.samples_out_of_volume, fixture_.markers->num_markers());
    for (size_t m = 0; m < frames_[300].size(); ++m)
      EXPECT_NE(out[300].status[m], MarkerStatus::kObserved) << m;
    int changed = 0;
    for (size_t f = 301; f < 420; ++f)
      for (size_t m = 0; m < frames_[f].size(); ++m)
        changed +=
            out[f].status[m] != MarkerStatus::kObserved || out[f].markers[m] != clean[f].markers[m];
    EXPECT_EQ(changed, 0) << absurd;
    for (size_t m = 0; m < frames_[300].size(); ++m)
      frames_[300][m] = Truth(300, static_cast<int>(m));
  }
}

// A take whose first frames hold no marker (the subject not yet tracked, an exporter's
// empty first frame): once the markers appear the skeleton is where they are, and the
// frames before them that the lookahead reaches hold the first samples seen. They rode
// the template's rest pose, wherever it stood, and the skeleton then caught up from there
// at data_catchup_mps: a CMU capture with an empty first frame was 1-2 m off for 4 s.
TEST_F(CleanupPipelineTest, ATakeThatStartsWithNoMarkersIsTrackedFromItsFirstSamples) {
  const int lookahead = CleanupOptions{}.lookahead;
  for (const int empty : {1, 5, 30}) {
    const std::vector<std::vector<Vec3>> saved(frames_.begin(), frames_.begin() + empty);
    for (int f = 0; f < empty; ++f)
      for (Vec3& p : frames_[static_cast<size_t>(f)]) p = Vec3::Constant(kNaN);
    const auto out = Run(CleanupOptions{});
    const std::vector<CleanFrame> seen(out.begin() + empty, out.end());
    EXPECT_LT(Errors(seen).max_position_error_m(), 0.03) << empty << " empty frames";
    for (int f = std::max(0, empty - lookahead); f < empty; ++f)
      for (size_t m = 0; m < frames_[0].size(); ++m)
        EXPECT_LT(
            (out[static_cast<size_t>(f)].markers[m] - Truth(empty, static_cast<int>(m))).norm(),
            0.001)
            << empty << " empty frames, frame " << f << ", marker " << m;
    std::copy(saved.begin(), saved.end(), frames_.begin());
  }
  // One marker comes three frames after the rest: its fill rode the step from the rest
  // pose to the first solve as a snap to hold out, and its first frames were published
  // where the rest pose stood (a CMU capture's finger 1.6 m off).
  for (const int empty : {1, 30}) {
    const auto saved = frames_;
    for (int f = 0; f < empty + 3; ++f)
      for (size_t m = 0; m < frames_[0].size(); ++m)
        if (f < empty || m == 7) frames_[static_cast<size_t>(f)][m] = Vec3::Constant(kNaN);
    const auto out = Run(CleanupOptions{});
    for (int f = empty; f < empty + 3; ++f)
      EXPECT_LT((out[static_cast<size_t>(f)].markers[7] - Truth(f, 7)).norm(), 0.05)
          << empty << " empty frames, frame " << f;
    frames_ = saved;
  }
}

// A take whose first frame shows three markers (tracking locking on): no reference is
// solved on them (robust_ik.cold_start_min_fraction), so nothing rides a pose three
// markers cannot place. Solved on them, the reference put a CMU capture's hands 68 cm
// off, and the skeleton took 2 s to come back.
TEST_F(CleanupPipelineTest, ATakeThatOpensWithThreeMarkersIsNotSolvedOnThem) {
  for (size_t m = 3; m < frames_[0].size(); ++m) frames_[0][m] = Vec3::Constant(kNaN);
  CleanupOptions options;
  const auto out = Run(options);
  const std::vector<CleanFrame> after(out.begin() + 1, out.end());
  EXPECT_LT(Errors(after).max_position_error_m(), 0.03);
  options.robust_ik.cold_start_min_fraction = 0.0;  // the reference solved on three
  const auto on_three = Run(options);
  EXPECT_GT(Errors({on_three.begin() + 1, on_three.end()}).max_position_error_m(), 0.1);
}

// A take that labels fewer markers than its subject has (20 of 59, for good): the
// reference waits for half the set only reference_cold_start_wait_s, then starts on what
// there is, and the samples there are published as they came (waiting for ever, none
// was: every one masked against the rest pose and unrecoverable).
TEST_F(CleanupPipelineTest, ATakeWithFewerMarkersThanItsSubjectIsStillCleaned) {
  for (auto& frame : frames_)
    for (size_t m = 20; m < frame.size(); ++m) frame[m] = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  int observed = 0, samples = 0;
  for (size_t f = 60; f < out.size(); ++f)
    for (size_t m = 0; m < 20; ++m, ++samples)
      observed += out[f].status[m] == MarkerStatus::kObserved;
  EXPECT_GT(observed, samples * 95 / 100);
  EXPECT_NE(out[60].final_solve.status, IkStatus::kTooFewMarkers);
}

// Every marker missing for 10 frames (83 ms, inside the lookahead): the skeleton follows
// the gaps' interpolations through it and is on the markers when they return. Held to
// last frame's skeleton (nothing trusted to solve an anchor on), it stood still, and the
// returning samples, taken as still on their first frame back, held it back further: a
// CMU capture's hand 23 cm behind its markers for 0.3 s.
TEST_F(CleanupPipelineTest, TheSkeletonFollowsThroughAFrameDropoutInsideTheLookahead) {
  for (int f = 500; f < 510; ++f)
    for (Vec3& p : frames_[static_cast<size_t>(f)]) p = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  // Through it, the interpolations' error; after it, none of the catching up.
  const std::vector<CleanFrame> through(out.begin() + 500, out.begin() + 510),
      after(out.begin() + 510, out.begin() + 600);
  EXPECT_LT(Errors(through).max_position_error_m(), 0.04);
  EXPECT_LT(Errors(after).max_position_error_m(), 0.01);
}

// Every marker missing for longer than the lookahead (a feed outage bridged by inserted
// frames): nothing leads the skeleton to where the body comes back, so at the return it
// takes the markers at once. Caught up at the catch-up speed, it was 5-47 cm behind them
// for a third of a second, published as tracking, and the model was called suspect.
TEST_F(CleanupPipelineTest, TheSkeletonMeetsTheMarkersBackFromAnOutageLongerThanTheLookahead) {
  for (const int length : {36, 120, 228}) {
    SCOPED_TRACE(length);
    std::vector<std::vector<Vec3>> saved = frames_;
    for (int f = 400; f < 400 + length; ++f)
      for (Vec3& p : frames_[static_cast<size_t>(f)]) p = Vec3::Constant(kNaN);
    const auto out = Run(CleanupOptions{});
    const auto back = out.begin() + 400 + length;
    EXPECT_LT(Errors({back, back + 1}).max_position_error_m(), 0.02);
    EXPECT_LT(Errors({back, back + 60}).mean_position_error_m(), 0.005);
    frames_ = std::move(saved);
  }
  // A frame lost within the lookahead is interpolated, the skeleton already on the markers
  // coming back: solved warm, no cold start (its hidden limbs would jump).
  Run(CleanupOptions{});
  const int64_t cold_starts = counters_.cold_starts;
  for (const int lost : {450, 600, 601})
    for (Vec3& p : frames_[static_cast<size_t>(lost)]) p = Vec3::Constant(kNaN);
  Run(CleanupOptions{});
  EXPECT_EQ(counters_.cold_starts, cold_starts);
}

// Every marker missing for 100 frames (0.83 s at 120 Hz) within a take replayed with a
// lookahead that holds the whole stretch (`mocapd process` at a large K): where the body
// was is known at both ends, and the fills take it across. Each fill turned toward its
// return only fill_interpolation_horizon_s before it, a horizon for a limb hidden while
// the body is seen (its reference then knows the body's motion); with nothing seen the
// reference knows nothing, and the skeleton froze, then crossed to the return in 0.1 s.
TEST_F(CleanupPipelineTest, ABlindStretchWithinTheLookaheadIsCrossedNotFrozen) {
  for (int f = 400; f < 500; ++f)
    for (Vec3& p : frames_[static_cast<size_t>(f)]) p = Vec3::Constant(kNaN);
  for (const int lookahead : {120, 200}) {
    CleanupOptions options;
    options.lookahead = lookahead;
    const auto out = Run(options);
    const std::vector<CleanFrame> through(out.begin() + 400, out.begin() + 500);
    // Before: the hips frozen, then 18 cm beyond the truth's step in one frame; the
    // joints 49 cm off on average over the stretch (a walk that curves: a path between
    // the two ends misses it too, by 19 cm).
    EXPECT_LT(WorstExtraJointStep(out, fixture_.motion, "Hips", 400, 520), 0.03) << lookahead;
    EXPECT_LT(Errors(through).mean_position_error_m(), 0.3) << lookahead;
  }
}

// Frames lost at regular intervals before the daemon (bridged with inserted frames that
// hold no sample at all): every received sample sits between two such frames, which are
// no gap in its track. Taken for small tracks, nearly every received sample was thrown
// away and the skeleton guessed (root 68 cm off losing every other frame, 6 cm off losing
// one in three, 96 % of the samples discarded losing one in ten); kept, each was caught up
// from rest after its lost frame, 2.5 cm behind.
TEST_F(CleanupPipelineTest, FramesLostAtRegularIntervalsCostNoReceivedSample) {
  const double clean = Errors(Run(CleanupOptions{})).mean_position_error_m();
  for (const int period : {2, 3, 5, 10}) {
    SCOPED_TRACE(period);
    std::vector<std::vector<Vec3>> saved = frames_;
    for (size_t f = 1; f < frames_.size(); f += static_cast<size_t>(period))
      for (Vec3& p : frames_[f]) p = Vec3::Constant(kNaN);
    const auto out = Run(CleanupOptions{});
    EXPECT_EQ(counters_.repaired_by[static_cast<size_t>(MaskReason::kSmallTrack)], 0);
    const PoseErrorAccumulator errors = Errors(out);
    EXPECT_LT(errors.mean_position_error_m(), clean + 0.001);
    EXPECT_LT(errors.max_position_error_m(), 0.01);
    frames_ = std::move(saved);
  }
}

// A frame whose every marker is shifted 10 m is a capture glitch: never published as
// observed; the frames after it are.
TEST_F(CleanupPipelineTest, AWholeFrameJumpIsAGlitchNotObserved) {
  for (auto& p : frames_[300]) p += Vec3(10.0, 0.0, 0.0);
  const auto out = Run(CleanupOptions{});
  EXPECT_EQ(counters_.glitch_frames, 1);
  EXPECT_EQ(counters_.resyncs, 0);
  for (size_t m = 0; m < frames_[300].size(); ++m) {
    EXPECT_NE(out[300].status[m], MarkerStatus::kObserved) << m;
    EXPECT_EQ(out[305].status[m], MarkerStatus::kObserved) << m;
  }
}

// A jump that persists is the world frame moving (a re-synchronisation): taken after
// glitch_resync_s, the solves starting afresh, and the subject tracked where it now is.
TEST_F(CleanupPipelineTest, AJumpThatPersistsIsAResynchronisation) {
  for (size_t f = 300; f < frames_.size(); ++f)
    for (auto& p : frames_[f]) p += Vec3(10.0, 0.0, 0.0);
  const auto out = Run(CleanupOptions{});
  EXPECT_EQ(counters_.resyncs, 1);
  EXPECT_EQ(counters_.glitch_frames, 12);  // 0.1 s at 120 Hz
  KinematicsWorkspace truth(*fixture_.skeleton), solved(*fixture_.skeleton);
  ForwardKinematics(*fixture_.skeleton, fixture_.motion[500], &truth);
  ForwardKinematics(*fixture_.skeleton, out[500].pose, &solved);
  EXPECT_LT((solved.p_WJ[0] - (truth.p_WJ[0] + Vec3(10.0, 0.0, 0.0))).norm(), 0.01);
}

// A jump that persists but is small enough to pass for motion once a few frames have gone
// by (40 m/s times their time): still a re-synchronisation. Judged against the last frame
// taken alone, 2 m passed after 6 gated frames at 120 Hz, and the skeleton then chased
// the markers at the catch-up speed for 0.4 s, half a metre off with every sample
// "observed".
TEST_F(CleanupPipelineTest, AJumpThatPersistsPastItsAllowanceIsStillAResynchronisation) {
  const auto uncorrupted = frames_;
  for (const double jump_m : {0.6, 1.0, 2.0}) {
    SCOPED_TRACE(jump_m);
    frames_ = uncorrupted;
    for (size_t f = 300; f < frames_.size(); ++f)
      for (auto& p : frames_[f]) p += Vec3(jump_m, 0.0, 0.0);
    const auto out = Run(CleanupOptions{});
    EXPECT_EQ(counters_.resyncs, 1);
    EXPECT_EQ(counters_.glitch_frames, 12);
    double worst_root_m = 0.0;
    KinematicsWorkspace truth(*fixture_.skeleton), solved(*fixture_.skeleton);
    for (size_t f = 312; f < 400; ++f) {
      ForwardKinematics(*fixture_.skeleton, fixture_.motion[f], &truth);
      ForwardKinematics(*fixture_.skeleton, out[f].pose, &solved);
      worst_root_m = std::max(worst_root_m,
                              (solved.p_WJ[0] - (truth.p_WJ[0] + Vec3(jump_m, 0.0, 0.0))).norm());
    }
    EXPECT_LT(worst_root_m, 0.02);
    // Through the glitch's frames the skeleton holds where it was: no glide toward the
    // jump (the fills there stop at the re-synchronisation, the markers' "return").
    double glide_m = 0.0;
    for (size_t f = 300; f < 312; ++f) {
      ForwardKinematics(*fixture_.skeleton, fixture_.motion[f], &truth);
      ForwardKinematics(*fixture_.skeleton, out[f].pose, &solved);
      glide_m = std::max(glide_m, (solved.p_WJ[0] - truth.p_WJ[0]).norm());
    }
    EXPECT_LT(glide_m, 0.15);
  }
}

// Every marker missing for 0.4 s, then back where the walk took them: no glitch. Judged by
// the time of the last frame taken (the dropout's), markers back had one frame's allowance
// for 0.4 s of walking; their first frame back was gated, and the frames after it, nearer
// it than the markers' last samples, carried the glitch on into a resync.
TEST_F(CleanupPipelineTest, MarkersBackFromADropoutAreNoGlitch) {
  for (size_t f = 300; f < 348; ++f)
    for (auto& p : frames_[f]) p = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  EXPECT_EQ(counters_.glitch_frames, 0);
  EXPECT_EQ(counters_.resyncs, 0);
  int observed = 0;
  for (size_t m = 0; m < frames_[348].size(); ++m)
    observed += out[350].status[m] == MarkerStatus::kObserved;
  EXPECT_GT(observed, static_cast<int>(frames_[348].size()) * 9 / 10);
}

}  // namespace
}  // namespace mocapd
