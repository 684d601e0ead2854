// Tests for the streaming cleanup pipeline: delay and accounting, untouched samples kept
// bit for bit, each detector on a hand-made case (with the others made blind where they
// would catch it first), the Hermite repairs, the no-pop re-entry blend, and zero
// allocation per frame.
#include "filters/cleanup_pipeline.hpp"

#include <gtest/gtest.h>

#include <random>
#include <string>

#include "filters/pose_error.hpp"
#include "sim/synthesis.hpp"
#include "tests/support/allocation_counter.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

class CleanupPipelineTest : public ::testing::Test {
 protected:
  CleanupPipelineTest() : fixture_(testing::MakeHumanoidFixture("mixed", 8.0, 120.0)) {
    frames_.resize(static_cast<size_t>(fixture_.take.num_frames));
    for (int f = 0; f < fixture_.take.num_frames; ++f)
      for (int m = 0; m < fixture_.take.num_points(); ++m) frames_[static_cast<size_t>(f)].push_back(fixture_.take.at(f, m));
  }
  int Marker(const char* name) const { return fixture_.markers->FindMarker(name)->value; }
  Vec3& Sample(int frame, int marker) { return frames_[static_cast<size_t>(frame)][static_cast<size_t>(marker)]; }
  Vec3 Truth(int frame, int marker) const { return fixture_.take.at(frame, marker); }

  // Runs every frame through a pipeline and keeps every published frame.
  std::vector<CleanFrame> Run(const CleanupOptions& options) {
    CleanupPipeline dut(fixture_.skeleton, fixture_.markers, options);
    std::vector<CleanFrame> out;
    for (const auto& frame : frames_)
      if (dut.Push(frame)) out.push_back(dut.output());
    while (dut.Flush()) out.push_back(dut.output());
    counters_ = dut.counters();
    return out;
  }
  // How much further a published marker moved into frame f than the truth did, metres.
  double ExtraStep(const std::vector<CleanFrame>& out, int f, int m) const {
    const auto uf = static_cast<size_t>(f), um = static_cast<size_t>(m);
    return (out[uf].markers[um] - out[uf - 1].markers[um]).norm() - (Truth(f, m) - Truth(f - 1, m)).norm();
  }
  // How much further a joint of the published skeleton moved in one frame than it did in
  // `truth`, at worst over frames [from, to), metres.
  double WorstExtraJointStep(const std::vector<CleanFrame>& out, const std::vector<Pose>& truth, const char* joint_name, int from,
                             int to) const {
    const auto joint = static_cast<size_t>(fixture_.skeleton->FindJoint(joint_name)->value);
    KinematicsWorkspace t(*fixture_.skeleton), t_before(*fixture_.skeleton), e(*fixture_.skeleton), e_before(*fixture_.skeleton);
    double worst = 0.0;
    for (int f = from; f < to; ++f) {
      const auto uf = static_cast<size_t>(f);
      ForwardKinematics(*fixture_.skeleton, truth[uf - 1], &t_before);
      ForwardKinematics(*fixture_.skeleton, truth[uf], &t);
      ForwardKinematics(*fixture_.skeleton, out[uf - 1].pose, &e_before);
      ForwardKinematics(*fixture_.skeleton, out[uf].pose, &e);
      worst = std::max(worst, (e.p_WJ[joint] - e_before.p_WJ[joint]).norm() - (t.p_WJ[joint] - t_before.p_WJ[joint]).norm());
    }
    return worst;
  }
  static constexpr const char* kLeftForearm[] = {"LFRM1", "LFRM2", "LHND1", "LHND2", "LHND3"};
  // From frame 300 the left elbow bends a further 90 degrees over 100 frames while the
  // forearm and hand markers are occluded; they come back at frame 420 on the bent arm.
  // Returns the bent motion (the truth).
  std::vector<Pose> BendElbowWhileForearmIsOccluded() {
    std::vector<Pose> bent = fixture_.motion;
    const auto elbow = static_cast<size_t>(fixture_.skeleton->FindJoint("LeftForeArm")->value);
    for (size_t f = 300; f < bent.size(); ++f) {
      const double bend = M_PI / 2 * std::min(1.0, static_cast<double>(f - 300) / 100.0);
      bent[f].rotation[elbow] = bent[f].rotation[elbow] * Quat(Eigen::AngleAxisd(bend, Vec3::UnitZ()));
    }
    const C3dTake moved = SynthesizeMarkers(*fixture_.skeleton, *fixture_.markers, bent, 120.0);
    for (int f = 300; f < static_cast<int>(frames_.size()); ++f)
      for (const char* name : kLeftForearm) Sample(f, Marker(name)) = f < 420 ? Vec3::Constant(kNaN) : moved.at(f, Marker(name));
    return bent;
  }
  // RFOT2 stuck where it was at frame 699 for 60 frames, with Gaussian jitter of sigma
  // metres, the other detectors blind: how many of those frames come out as frozen.
  int FramesFoundFrozen(double jitter_sigma) {
    const int m = Marker("RFOT2");
    std::mt19937 rng(3);
    std::normal_distribution<double> jitter(0.0, jitter_sigma > 0.0 ? jitter_sigma : 1.0);
    for (int f = 700; f < 760; ++f)
      Sample(f, m) = Truth(699, m) + (jitter_sigma > 0.0 ? Vec3(jitter(rng), jitter(rng), jitter(rng)) : Vec3::Zero());
    CleanupOptions options = Blind();
    options.frozen_frames = 6;
    const auto out = Run(options);
    int frozen = 0;
    for (int f = 700; f < 760; ++f) frozen += out[static_cast<size_t>(f)].reason[static_cast<size_t>(m)] == MaskReason::kFrozen;
    return frozen;
  }
  // Options with every outlier detector made blind, to test one at a time.
  static CleanupOptions Blind() {
    CleanupOptions o;
    o.residual_floor_m = 10.0;
    o.disagreement_position_m = 10.0;
    o.disagreement_rotation_rad = 10.0;
    o.spike_m = 10.0;
    o.rigid_tolerance_m = 10.0;
    o.swap_margin_m = 10.0;
    o.frozen_frames = 100000;
    return o;
  }

  testing::HumanoidFixture fixture_;
  std::vector<std::vector<Vec3>> frames_;
  CleanupCounters counters_;
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
      ASSERT_EQ(out[f].status[m], MarkerStatus::kObserved) << f << " " << m << " " << to_string(out[f].reason[m]);
      ASSERT_EQ(out[f].markers[m], frames_[f][m]);  // bit for bit
    }
  }
}

TEST_F(CleanupPipelineTest, LongGapIsFilledAlongTheReferenceWithoutJumps) {
  const int m = Marker("LFRM1");
  for (int f = 200; f < 400; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  for (int f = 200; f < 400; ++f) {
    ASSERT_EQ(out[static_cast<size_t>(f)].status[static_cast<size_t>(m)], MarkerStatus::kRepaired);
    EXPECT_EQ(out[static_cast<size_t>(f)].reason[static_cast<size_t>(m)], MaskReason::kMissing);
    EXPECT_LT((out[static_cast<size_t>(f)].markers[static_cast<size_t>(m)] - Truth(f, m)).norm(), 0.01) << f;
  }
  // C0 at both ends: no step bigger than the marker's own motion allows.
  for (int f = 195; f < 405; ++f) {
    const double step = (out[static_cast<size_t>(f)].markers[static_cast<size_t>(m)] - out[static_cast<size_t>(f - 1)].markers[static_cast<size_t>(m)]).norm();
    EXPECT_LT(step, (Truth(f, m) - Truth(f - 1, m)).norm() + 0.003) << f;
  }
  EXPECT_EQ(counters_.repaired_by[static_cast<size_t>(MaskReason::kMissing)], 200);
}

TEST_F(CleanupPipelineTest, ShortGapGetsAPlainHermiteOnTheRawPath) {
  const int m = Marker("RTHI2");
  for (int f = 300; f < 303; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  for (int f = 300; f < 303; ++f) EXPECT_LT((out[static_cast<size_t>(f)].markers[static_cast<size_t>(m)] - Truth(f, m)).norm(), 0.001);
}

TEST_F(CleanupPipelineTest, ResidualDetectorCatchesAPop) {
  const int m = Marker("HED2");
  for (int f = 500; f < 502; ++f) Sample(f, m) += Vec3(0.0, 0.25, 0.0);
  CleanupOptions options = Blind();
  options.residual_floor_m = 0.012;
  const auto out = Run(options);
  for (int f = 500; f < 502; ++f) {
    EXPECT_EQ(out[static_cast<size_t>(f)].reason[static_cast<size_t>(m)], MaskReason::kResidual);
    EXPECT_LT((out[static_cast<size_t>(f)].markers[static_cast<size_t>(m)] - Truth(f, m)).norm(), 0.005);
  }
  EXPECT_EQ(out[499].status[static_cast<size_t>(m)], MarkerStatus::kObserved);
  EXPECT_EQ(out[502].status[static_cast<size_t>(m)], MarkerStatus::kObserved);
}

TEST_F(CleanupPipelineTest, SpikeDetectorCatchesAOneFrameJump) {
  const int m = Marker("LSHN1");
  Sample(600, m) += Vec3(0.06, 0.0, 0.0);
  CleanupOptions options = Blind();
  options.spike_m = 0.03;
  const auto out = Run(options);
  EXPECT_EQ(out[600].reason[static_cast<size_t>(m)], MaskReason::kSpike);
  EXPECT_EQ(out[601].status[static_cast<size_t>(m)], MarkerStatus::kObserved);  // the return is not a spike
}

TEST_F(CleanupPipelineTest, RigidDistanceDetectorBlamesTheMarkerThatMoved) {
  const int m = Marker("PEL2");
  for (int f = 400; f < 410; ++f) Sample(f, m) += Vec3(0.0, 0.0, 0.05);
  CleanupOptions options = Blind();
  options.rigid_tolerance_m = 0.03;
  const auto out = Run(options);
  for (int f = 400; f < 410; ++f) EXPECT_EQ(out[static_cast<size_t>(f)].reason[static_cast<size_t>(m)], MaskReason::kRigidDistance) << f;
  for (int f = 400; f < 410; ++f)
    EXPECT_EQ(out[static_cast<size_t>(f)].status[static_cast<size_t>(Marker("PEL1"))], MarkerStatus::kObserved);
}

TEST_F(CleanupPipelineTest, DisagreementDetectorMarksTheJointsMarkers) {
  // Two of the head's four markers displaced: the naive solve turns the head toward them,
  // the robust one does not; the displaced markers, skinned to the head, are marked.
  const int a = Marker("HED1"), b = Marker("HED3");
  for (int f = 300; f < 320; ++f) {
    Sample(f, a) += Vec3(0.0, 0.3, 0.0);
    Sample(f, b) += Vec3(0.0, 0.3, 0.0);
  }
  CleanupOptions options = Blind();
  options.disagreement_position_m = 0.05;
  options.disagreement_rotation_rad = 10.0 * M_PI / 180.0;
  const auto out = Run(options);
  int marked = 0;
  for (int f = 300; f < 320; ++f)
    marked += out[static_cast<size_t>(f)].reason[static_cast<size_t>(a)] == MaskReason::kDisagreement;
  EXPECT_GT(marked, 10);
  EXPECT_EQ(out[310].status[static_cast<size_t>(Marker("HED2"))], MarkerStatus::kObserved);
  EXPECT_EQ(out[290].status[static_cast<size_t>(a)], MarkerStatus::kObserved);
}

TEST_F(CleanupPipelineTest, SwapOnOneSegmentIsRelabelledExactly) {
  const int a = Marker("LHND1"), b = Marker("LHND2");
  for (int f = 300; f < 360; ++f) std::swap(Sample(f, a), Sample(f, b));
  const auto out = Run(CleanupOptions{});
  for (int f = 300; f < 360; ++f) {
    EXPECT_EQ(out[static_cast<size_t>(f)].reason[static_cast<size_t>(a)], MaskReason::kSwap) << f;
    EXPECT_EQ(out[static_cast<size_t>(f)].markers[static_cast<size_t>(a)], Truth(f, a)) << f;
    EXPECT_EQ(out[static_cast<size_t>(f)].markers[static_cast<size_t>(b)], Truth(f, b)) << f;
  }
  EXPECT_EQ(out[360].status[static_cast<size_t>(a)], MarkerStatus::kObserved);
}

TEST_F(CleanupPipelineTest, SwapAcrossSegmentsIsCaughtByContinuity) {
  // Two markers on different segments, swapped from a frame where they pass close.
  const int a = Marker("LELB"), b = Marker("LUPA3");
  int start = -1;
  for (int f = 50; f < 900 && start < 0; ++f)
    if ((Truth(f, a) - Truth(f, b)).norm() < 0.12) start = f;
  ASSERT_GE(start, 0);
  for (int f = start; f < start + 40; ++f) std::swap(Sample(f, a), Sample(f, b));
  const auto out = Run(CleanupOptions{});
  int right = 0;
  for (int f = start; f < start + 40; ++f) right += (out[static_cast<size_t>(f)].markers[static_cast<size_t>(a)] - Truth(f, a)).norm() < 0.01;
  EXPECT_GE(right, 36);
}

TEST_F(CleanupPipelineTest, FrozenMarkerIsDetected) {
  EXPECT_GT(FramesFoundFrozen(0.0), 40);
}

TEST_F(CleanupPipelineTest, FrozenMarkerUnderCaptureJitterIsDetected) {
  // A stuck marker still jitters by the capture's noise: millimetres per frame, more
  // than any per-frame "no motion" threshold allows.
  EXPECT_GT(FramesFoundFrozen(0.002), 40);
}

TEST_F(CleanupPipelineTest, StillMarkerIsNotFrozenWhenNoOtherMarkerShowsItsSegmentMoving) {
  // The foot's other markers are occluded: the reference's foot is a guess, so a marker
  // that stays put (a planted foot) may not be blamed for the guess moving away.
  const int m = Marker("RFOT2");
  for (int f = 700; f < 760; ++f) {
    Sample(f, m) = Truth(699, m);
    Sample(f, Marker("RFOT1")) = Vec3::Constant(kNaN);
    Sample(f, Marker("RFOT3")) = Vec3::Constant(kNaN);
  }
  CleanupOptions options = Blind();
  options.frozen_frames = 6;
  const auto out = Run(options);
  for (int f = 700; f < 760; ++f) EXPECT_NE(out[static_cast<size_t>(f)].reason[static_cast<size_t>(m)], MaskReason::kFrozen) << f;
}

TEST_F(CleanupPipelineTest, FallenOffMarkerIsClassifiedAndExcluded) {
  const int m = Marker("RUPA2");
  for (int f = 300; f < static_cast<int>(frames_.size()); ++f) Sample(f, m) = Vec3(Truth(299, m).x(), 0.0, Truth(299, m).z());
  const auto out = Run(CleanupOptions{});
  // At first it is only a marker that stopped (frozen) or fits badly (residual); lying
  // far off for long makes it fallen off.
  const MaskReason first = out[300].reason[static_cast<size_t>(m)];
  EXPECT_TRUE(first == MaskReason::kFrozen || first == MaskReason::kResidual) << to_string(first);
  EXPECT_EQ(out[500].reason[static_cast<size_t>(m)], MaskReason::kFallenOff);
  EXPECT_LT((out[800].markers[static_cast<size_t>(m)] - Truth(800, m)).norm(), 0.02);
}

TEST_F(CleanupPipelineTest, ReturningMarkerBlendsInWithoutAPop) {
  // A gap longer than the lookahead: its first frames go out one-sided, holding the
  // offset the marker had (+9 mm). It returns with another offset (-9 mm, both within
  // the detectors' tolerance): the output must ease over instead of jumping 18 mm.
  const int m = Marker("RFRM1");
  CleanupOptions options;
  options.lookahead = 4;
  for (int f = 0; f < 400; ++f) Sample(f, m) += Vec3(0.009, 0.0, 0.0);
  for (int f = 400; f < 460; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  for (int f = 460; f < static_cast<int>(frames_.size()); ++f) Sample(f, m) -= Vec3(0.009, 0.0, 0.0);
  const auto out = Run(options);
  double worst_extra_step = 0.0;
  for (int f = 440; f < 470; ++f) worst_extra_step = std::max(worst_extra_step, ExtraStep(out, f, m));
  EXPECT_LT(worst_extra_step, 0.008);
  EXPECT_EQ(out[460].status[static_cast<size_t>(m)], MarkerStatus::kObserved);
  EXPECT_EQ(out[460].markers[static_cast<size_t>(m)], Sample(460, m));  // the returning sample itself is untouched
}

TEST_F(CleanupPipelineTest, FillsRideThroughAReferenceThatSnapsBack) {
  // The whole lower leg is occluded for long: the reference guesses it, and when the toe
  // markers come back (the foot's markers still missing) it snaps to them. The foot's
  // fills must not jump with it (0.23 m without the rule), and the toes' re-entry spreads
  // the guess's error over the lookahead: no published marker moves more than 3.5 cm per
  // frame beyond its true motion.
  const char* leg[] = {"LKNE", "LSHN1", "LSHN2", "LFOT1", "LFOT2", "LFOT3", "LTOE1", "LTOE2"};
  for (int f = 300; f < 500; ++f)
    for (const char* name : leg)
      if (f < 480 || std::string(name).rfind("LTOE", 0) != 0) Sample(f, Marker(name)) = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  double worst_extra_step = 0.0;
  for (int f = 301; f < 510; ++f)
    for (const char* name : leg) worst_extra_step = std::max(worst_extra_step, ExtraStep(out, f, Marker(name)));
  EXPECT_LT(worst_extra_step, 0.035);
}

TEST_F(CleanupPipelineTest, OneSidedFillTakesUpAReferenceMotionItHeldBack) {
  // With the acceleration limit set so low that all of the hand's real motion counts as
  // snapping, the fill holds it back but takes it up a tenth per frame: it stays near
  // the true path instead of falling behind for the whole gap.
  const int m = Marker("LHND1");
  for (int f = 300; f < 560; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  CleanupOptions options;
  options.fill_reference_acceleration_mps2 = 0.5;
  auto worst_error = [&](double release) {
    options.fill_snap_release = release;
    const auto out = Run(options);
    double worst = 0.0;
    for (int f = 300; f < 540; ++f) worst = std::max(worst, (out[static_cast<size_t>(f)].markers[static_cast<size_t>(m)] - Truth(f, m)).norm());
    return worst;
  };
  EXPECT_LT(worst_error(0.1), 0.3);  // measured 0.15 m
  EXPECT_GT(worst_error(0.0), 1.0);  // held back for good: measured 2.6 m
}

TEST_F(CleanupPipelineTest, AFillGainsFinalSolveWeightGradually) {
  // A long gap: first one-sided fills (weak), then, once the return is in the lookahead,
  // interpolated fills (strong). The weight must climb by at most fill_weight_ramp per
  // frame, never jump from a guess's to data's.
  const int m = Marker("LSHN1");
  for (int f = 300; f < 420; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  CleanupOptions options;
  const auto out = Run(options);
  const auto um = static_cast<size_t>(m);
  EXPECT_DOUBLE_EQ(out[330].weight[um], options.repaired_weight);  // one-sided, mid-gap
  EXPECT_DOUBLE_EQ(out[299].weight[um], 1.0);                      // observed
  bool reached_full = false;
  for (int f = 301; f < 430; ++f) {
    const double before = out[static_cast<size_t>(f - 1)].weight[um], now = out[static_cast<size_t>(f)].weight[um];
    if (out[static_cast<size_t>(f)].status[um] == MarkerStatus::kRepaired) {
      EXPECT_LE(now, before * options.fill_weight_ramp + 1e-12) << f;
    }
    reached_full |= out[static_cast<size_t>(f)].status[um] == MarkerStatus::kRepaired && now > 0.5;
  }
  EXPECT_TRUE(reached_full);  // the interpolation near the return does get its weight
  options.fill_weight_ramp = 1.0;  // without the ramp the weight jumps
  const auto jumpy = Run(options);
  double biggest_jump = 0.0;
  for (int f = 301; f < 420; ++f)
    biggest_jump = std::max(biggest_jump, jumpy[static_cast<size_t>(f)].weight[um] / jumpy[static_cast<size_t>(f - 1)].weight[um]);
  EXPECT_GT(biggest_jump, 10.0);
}

TEST_F(CleanupPipelineTest, ReturningMarkerEasesIntoTheSkeletonWithoutLookahead) {
  // K = 0 without a catch-up target: the return cannot be seen coming, so the marker goes
  // from a guess straight to data. Its sample is published exactly as captured, but its
  // final-solve weight climbs from the guess's at most fill_weight_ramp per frame, so the
  // skeleton eases over.
  const int m = Marker("LSHN1");
  for (int f = 300; f < 420; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  CleanupOptions options;
  options.lookahead = 0;
  options.data_catchup_m = 0.0;
  const auto out = Run(options);
  const auto um = static_cast<size_t>(m);
  ASSERT_EQ(out[420].status[um], MarkerStatus::kObserved);
  EXPECT_EQ(out[420].markers[um], Sample(420, m));
  EXPECT_LE(out[420].weight[um], options.repaired_weight * options.fill_weight_ramp + 1e-12);
  for (int f = 421; f < 440; ++f)
    EXPECT_LE(out[static_cast<size_t>(f)].weight[um], out[static_cast<size_t>(f - 1)].weight[um] * options.fill_weight_ramp + 1e-12) << f;
  EXPECT_DOUBLE_EQ(out[450].weight[um], 1.0);
}

TEST_F(CleanupPipelineTest, ForearmThatBentWhileOccludedIsCaughtUpWithoutAPop) {
  // K = 0. While the forearm and hand are occluded the elbow bends a further 90 degrees:
  // the reference holds the old angle, so the fills are far off when the markers come
  // back. They are published as captured, and the skeleton's hand must close the gap
  // over several frames, not in a jump.
  const std::vector<Pose> bent = BendElbowWhileForearmIsOccluded();
  auto worst_extra_hand_step = [&](double catchup) {
    CleanupOptions options;
    options.lookahead = 0;
    options.data_catchup_m = catchup;
    return WorstExtraJointStep(Run(options), bent, "LeftHand", 400, 520);
  };
  EXPECT_LT(worst_extra_hand_step(CleanupOptions{}.data_catchup_m), 0.02);
  EXPECT_GT(worst_extra_hand_step(0.0), 0.03);  // the weight ramp alone: measured 0.22 m
  CleanupOptions options;
  options.lookahead = 0;
  const auto out = Run(options);
  for (const char* name : kLeftForearm) {
    const auto um = static_cast<size_t>(Marker(name));
    EXPECT_EQ(out[420].status[um], MarkerStatus::kObserved) << name;
    EXPECT_EQ(out[420].markers[um], Sample(420, Marker(name))) << name;  // published as captured
  }
}

TEST_F(CleanupPipelineTest, CapturedJumpTheDetectorsMissIsClosedOnNotFollowed) {
  // From frame 300 every left-hand marker is 10 cm off (a slipped cluster, or a swap no
  // detector caught: they are all blind here). The samples are published as captured,
  // but a jump is not motion: the skeleton's hand closes on them over several frames.
  for (int f = 300; f < static_cast<int>(frames_.size()); ++f)
    for (const char* name : {"LHND1", "LHND2", "LHND3"}) Sample(f, Marker(name)) += Vec3(0.1, 0.0, 0.0);
  auto worst_extra_hand_step = [&](double motion_acceleration) {
    CleanupOptions options = Blind();
    options.lookahead = 0;
    options.data_motion_acceleration_m = motion_acceleration;
    const auto out = Run(options);
    EXPECT_EQ(out[300].markers[static_cast<size_t>(Marker("LHND1"))], Sample(300, Marker("LHND1")));
    return WorstExtraJointStep(out, fixture_.motion, "LeftHand", 290, 340);
  };
  EXPECT_LT(worst_extra_hand_step(CleanupOptions{}.data_motion_acceleration_m), 0.02);  // measured 0.3 cm
  EXPECT_GT(worst_extra_hand_step(1.0), 0.04);  // the jump taken as motion: measured 4.6 cm
}

TEST_F(CleanupPipelineTest, GuessesPullTheSkeletonNoFurtherThanTheAnchorAllows) {
  // K = 12. While the forearm and hand are occluded the elbow bends a further 90 degrees;
  // the lookahead sees them come back far from the reference's guess, and the
  // interpolated fills bend onto the returning tracks within 12 frames, much faster than
  // the arm moves. The skeleton may follow those guesses only within the anchor's
  // radius of the pose the trusted samples give.
  const std::vector<Pose> bent = BendElbowWhileForearmIsOccluded();
  auto worst_extra_hand_step = [&](double radius) {
    CleanupOptions options;
    options.fill_anchor_radius_m = radius;
    return WorstExtraJointStep(Run(options), bent, "LeftHand", 380, 520);
  };
  const double anchored = worst_extra_hand_step(CleanupOptions{}.fill_anchor_radius_m), free = worst_extra_hand_step(0.0);
  EXPECT_LT(anchored, 0.02) << free;  // measured 1.1 cm
  EXPECT_GT(free, 0.03) << anchored;   // measured 5.6 cm
}

TEST_F(CleanupPipelineTest, UnseenLowerLegIsNotSwungByItsTurningThigh) {
  // From frame 300 the left thigh turns 60 degrees in 20 frames while the knee turns back
  // as much: the shin and foot keep their world orientation (a planted lower leg under a
  // turning thigh), and all their markers are occluded. Held relative to the thigh, the
  // guessed shin would swing the foot with it.
  std::vector<Pose> turned = fixture_.motion;
  const auto hip = static_cast<size_t>(fixture_.skeleton->FindJoint("LeftUpLeg")->value);
  const auto knee = static_cast<size_t>(fixture_.skeleton->FindJoint("LeftLeg")->value);
  for (size_t f = 300; f < turned.size(); ++f) {
    const Quat turn(Eigen::AngleAxisd(M_PI / 3 * std::min(1.0, static_cast<double>(f - 300) / 20.0), Vec3::UnitX()));
    turned[f].rotation[hip] = turned[f].rotation[hip] * turn;
    turned[f].rotation[knee] = turn.inverse() * turned[f].rotation[knee];
  }
  const C3dTake moved = SynthesizeMarkers(*fixture_.skeleton, *fixture_.markers, turned, 120.0);
  for (int f = 0; f < static_cast<int>(frames_.size()); ++f)
    for (int m = 0; m < fixture_.markers->num_markers(); ++m) Sample(f, m) = moved.at(f, m);
  for (int f = 280; f < 420; ++f)
    for (const char* name : {"LKNE", "LSHN1", "LSHN2", "LFOT1", "LFOT2", "LFOT3", "LTOE1", "LTOE2"}) Sample(f, Marker(name)) = Vec3::Constant(kNaN);
  auto worst_extra_ankle_step = [&](bool hold) {
    CleanupOptions options;
    options.lookahead = 0;
    options.anchor_holds_unseen_limbs = hold;
    return WorstExtraJointStep(Run(options), turned, "LeftFoot", 290, 330);
  };
  const double held = worst_extra_ankle_step(true), swung = worst_extra_ankle_step(false);
  EXPECT_LT(held, 0.01) << swung;  // measured 0.4 cm
  EXPECT_GT(swung, 0.02) << held;  // measured 3.4 cm
}

TEST_F(CleanupPipelineTest, MarkerNeverSeenIsUnrecoverableNotInvented) {
  const int m = Marker("LTOE1");
  for (auto& frame : frames_) frame[static_cast<size_t>(m)] = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  EXPECT_EQ(out[100].status[static_cast<size_t>(m)], MarkerStatus::kUnrecoverable);
  EXPECT_FALSE(out[100].markers[static_cast<size_t>(m)].allFinite());
  EXPECT_EQ(counters_.unrecoverable, static_cast<int64_t>(frames_.size()));
}

TEST_F(CleanupPipelineTest, StraySampleLeavesTheReferenceOfAnOccludedSegment) {
  // The foot is occluded and RTOE1 carries another marker's track 50 cm away (a swap
  // whose partner is hidden). Kept in the robust solve, it drags the guessed foot's
  // reference after it until RTOE2, which is fine, no longer fits and is thrown out too.
  const int stray = Marker("RTOE1"), good = Marker("RTOE2");
  for (int f = 300; f < 420; ++f) {
    Sample(f, stray) += Vec3(0.0, 0.5, 0.0);
    for (const char* name : {"RFOT1", "RFOT2", "RFOT3"}) Sample(f, Marker(name)) = Vec3::Constant(kNaN);
  }
  auto good_marker_rejected = [&](int stray_frames) {
    CleanupOptions options;
    options.stray_frames = stray_frames;
    const auto out = Run(options);
    int rejected = 0;
    for (int f = 330; f < 420; ++f) rejected += out[static_cast<size_t>(f)].status[static_cast<size_t>(good)] != MarkerStatus::kObserved;
    return rejected;
  };
  EXPECT_LT(good_marker_rejected(CleanupOptions{}.stray_frames), 5);  // measured 0 of 90 frames
  EXPECT_GT(good_marker_rejected(100000), 20);                       // without the rule: 90
}

TEST_F(CleanupPipelineTest, ArmThatMovedWhileOccludedIsReacquired) {
  // While the whole left arm is occluded the shoulder turns 90 degrees and the elbow
  // bends 150 more: its markers come back far from the reference's guess (they would be
  // outliers and, after 12 frames, strays, if judged one by one). They agree with each
  // other, so the reference must come round to them and publish them as observed.
  std::vector<Pose> bent = fixture_.motion;
  const auto shoulder = static_cast<size_t>(fixture_.skeleton->FindJoint("LeftArm")->value);
  const auto elbow = static_cast<size_t>(fixture_.skeleton->FindJoint("LeftForeArm")->value);
  for (size_t f = 300; f < bent.size(); ++f) {
    bent[f].rotation[shoulder] = bent[f].rotation[shoulder] * Quat(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitX()));
    bent[f].rotation[elbow] = bent[f].rotation[elbow] * Quat(Eigen::AngleAxisd(150.0 * M_PI / 180.0, Vec3::UnitZ()));
  }
  const C3dTake moved = SynthesizeMarkers(*fixture_.skeleton, *fixture_.markers, bent, 120.0);
  const char* arm[] = {"LUPA1", "LUPA2", "LUPA3", "LELB", "LFRM1", "LFRM2", "LHND1", "LHND2", "LHND3"};
  ASSERT_GT((moved.at(330, Marker("LHND1")) - Truth(330, Marker("LHND1"))).norm(), 0.3);  // far from the old path
  for (int f = 250; f < static_cast<int>(frames_.size()); ++f)
    for (const char* name : arm) Sample(f, Marker(name)) = f < 330 ? Vec3::Constant(kNaN) : moved.at(f, Marker(name));
  const auto out = Run(CleanupOptions{});
  int observed = 0;
  for (int f = 360; f < 500; ++f)
    for (const char* name : arm) observed += out[static_cast<size_t>(f)].status[static_cast<size_t>(Marker(name))] == MarkerStatus::kObserved;
  EXPECT_GT(observed, 9 * 140 * 95 / 100);
}

TEST_F(CleanupPipelineTest, SolvedSkeletonStaysAccurateThroughRepairs) {
  for (int f = 200; f < 320; ++f) Sample(f, Marker("LHND1")) = Vec3::Constant(kNaN);
  for (int f = 500; f < 503; ++f) Sample(f, Marker("RSHN2")) += Vec3(0.3, 0.0, 0.0);
  const auto out = Run(CleanupOptions{});
  PoseErrorAccumulator errors(*fixture_.skeleton);
  KinematicsWorkspace truth(*fixture_.skeleton), est(*fixture_.skeleton);
  for (const CleanFrame& frame : out) {
    ForwardKinematics(*fixture_.skeleton, fixture_.motion[static_cast<size_t>(frame.frame)], &truth);
    ForwardKinematics(*fixture_.skeleton, frame.pose, &est);
    errors.Add(truth, est);
  }
  EXPECT_LT(errors.mean_position_error_m(), 0.003);
  EXPECT_LT(errors.max_position_error_m(), 0.03);
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

}  // namespace
}  // namespace mocapd
