// Tests for the final solve: catch-up targets, weight ramps, the anchor and its held
// limbs, so that nothing moves the published skeleton faster than real motion.
#include "filters/final_solve.hpp"

#include <gtest/gtest.h>

#include "filters/pose_error.hpp"
#include "tests/filters/cleanup_fixture.hpp"

namespace mocapd {
namespace {

class FinalSolveTest : public CleanupFixture {
 protected:
  // The take becomes `motion`'s markers, with the left shin and foot occluded over
  // frames [from, to).
  void CaptureWithLeftLowerLegOccluded(const std::vector<Pose>& motion, int from, int to) {
    const C3dTake moved = SynthesizeMarkers(*fixture_.skeleton, *fixture_.markers, motion, 120.0);
    for (int f = 0; f < static_cast<int>(frames_.size()); ++f)
      for (int m = 0; m < fixture_.markers->num_markers(); ++m) Sample(f, m) = moved.at(f, m);
    for (int f = from; f < to; ++f)
      for (const char* name :
           {"LKNE", "LSHN1", "LSHN2", "LFOT1", "LFOT2", "LFOT3", "LTOE1", "LTOE2"})
        Sample(f, Marker(name)) = Vec3::Constant(kNaN);
  }
  // The take solved at K = 0 (no lookahead) with one catch-up option set.
  std::vector<CleanFrame> RunWithoutLookahead(double CleanupOptions::*option, double value) {
    CleanupOptions options;
    options.lookahead = 0;
    options.*option = value;
    return Run(options);
  }
};

TEST_F(FinalSolveTest, AFillGainsFinalSolveWeightGradually) {
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
    const double before = out[static_cast<size_t>(f - 1)].weight[um],
                 now = out[static_cast<size_t>(f)].weight[um];
    if (out[static_cast<size_t>(f)].status[um] == MarkerStatus::kRepaired) {
      EXPECT_LE(now, before * FrameRules(options).fill_weight_ramp + 1e-12) << f;
    }
    reached_full |= out[static_cast<size_t>(f)].status[um] == MarkerStatus::kRepaired && now > 0.5;
  }
  EXPECT_TRUE(reached_full);               // the interpolation near the return does get its weight
  options.fill_weight_growth_per_s = 0.0;  // without the ramp the weight jumps
  const auto jumpy = Run(options);
  double biggest_jump = 0.0;
  for (int f = 301; f < 420; ++f)
    biggest_jump = std::max(biggest_jump, jumpy[static_cast<size_t>(f)].weight[um] /
                                              jumpy[static_cast<size_t>(f - 1)].weight[um]);
  EXPECT_GT(biggest_jump, 10.0);
}

TEST_F(FinalSolveTest, ReturningMarkerEasesIntoTheSkeletonWithoutLookahead) {
  // K = 0 without a catch-up target: the return cannot be seen coming, so the marker goes
  // from a guess straight to data. Its sample is published exactly as captured, but its
  // final-solve weight climbs from the guess's at most fill_weight_ramp per frame, so the
  // skeleton eases over.
  const int m = Marker("LSHN1");
  for (int f = 300; f < 420; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  CleanupOptions options;
  options.lookahead = 0;
  options.data_catchup_mps = 0.0;
  const auto out = Run(options);
  const auto um = static_cast<size_t>(m);
  ASSERT_EQ(out[420].status[um], MarkerStatus::kObserved);
  EXPECT_EQ(out[420].markers[um], Sample(420, m));
  EXPECT_LE(out[420].weight[um],
            options.repaired_weight * FrameRules(options).fill_weight_ramp + 1e-12);
  for (int f = 421; f < 440; ++f)
    EXPECT_LE(
        out[static_cast<size_t>(f)].weight[um],
        out[static_cast<size_t>(f - 1)].weight[um] * FrameRules(options).fill_weight_ramp + 1e-12)
        << f;
  EXPECT_DOUBLE_EQ(out[450].weight[um], 1.0);
}

TEST_F(FinalSolveTest, ForearmThatBentWhileOccludedIsCaughtUpWithoutAPop) {
  // K = 0. While the forearm and hand are occluded the elbow bends a further 90 degrees:
  // the reference holds the old angle, so the fills are far off when the markers come
  // back. They are published as captured, and the skeleton's hand must close the gap
  // over several frames, not in a jump.
  const std::vector<Pose> bent = BendElbowWhileForearmIsOccluded();
  auto worst_extra_hand_step = [&](double catchup) {
    return WorstExtraJointStep(RunWithoutLookahead(&CleanupOptions::data_catchup_mps, catchup),
                               bent, "LeftHand", 400, 520);
  };
  EXPECT_LT(worst_extra_hand_step(CleanupOptions{}.data_catchup_mps), 0.02);
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

TEST_F(FinalSolveTest, AHandBackFarFromTheSkeletonIsReachedInAFractionOfASecond) {
  // K = 0, the elbow bent 90 degrees while the forearm and hand were occluded: their
  // markers come back about 30 cm from the skeleton's. At a fixed 0.6 m/s the hand stays
  // tens of cm off for half a second; closing a share of the distance each frame (at most
  // data_catchup_max_mps) it is within 5 cm in a quarter of a second, with no pop.
  const std::vector<Pose> bent = BendElbowWhileForearmIsOccluded();
  const auto closed = RunWithoutLookahead(&CleanupOptions::data_catchup_time_s,
                                          CleanupOptions{}.data_catchup_time_s);
  const auto fixed_speed = RunWithoutLookahead(&CleanupOptions::data_catchup_time_s, 0.0);
  const int quarter_second_later = 420 + 30;
  EXPECT_GT(WorstJointError(fixed_speed, bent, "LeftHand", 420, 421), 0.2);  // how far back it came
  EXPECT_LT(WorstJointError(closed, bent, "LeftHand", quarter_second_later, 480), 0.05);
  EXPECT_GT(WorstJointError(fixed_speed, bent, "LeftHand", quarter_second_later, 480), 0.1);
  EXPECT_LT(WorstExtraJointStep(closed, bent, "LeftHand", 400, 520), 0.02);  // no pop
}

TEST_F(FinalSolveTest, ForearmOccludedThroughABendIsLedToItsReturningMarkers) {
  // K = 12. The elbow bends 90 degrees while the forearm and hand are occluded. Once the
  // lookahead sees the markers come back, their fills are interpolations of real data on
  // a limb the anchor can only guess: they may lead the skeleton there faster than a
  // guess may drag it, so the hand meets its clean markers nearer where they are. The
  // limb is unseen whether or not the anchor holds it.
  const std::vector<Pose> bent = BendElbowWhileForearmIsOccluded();
  for (const bool hold : {true, false}) {
    auto run = [&](double interpolation_speed) {
      CleanupOptions options;
      options.anchor_holds_unseen_limbs = hold;
      options.unseen_limb_interpolation_speed_mps = interpolation_speed;
      return Run(options);
    };
    const auto led = run(CleanupOptions{}.unseen_limb_interpolation_speed_mps);
    const auto dragged = run(CleanupOptions{}.fill_anchor_speed_mps);
    const double led_error = WorstJointError(led, bent, "LeftHand", 420, 421),
                 dragged_error = WorstJointError(dragged, bent, "LeftHand", 420, 421);
    // Held, measured 32.5 against 35.1 cm: the fills' weight ramp and the solve's pull
    // toward its prediction leave less than the speed allows; the rest is the catch-up's.
    EXPECT_LT(led_error, dragged_error - 0.015) << hold << " " << led_error << " " << dragged_error;
    EXPECT_LT(WorstExtraJointStep(led, bent, "LeftHand", 400, 520), 0.02) << hold;  // no pop
  }
}

TEST_F(FinalSolveTest, InterpolationsOnALimbWithATrustedSampleOnlyNudgeIt) {
  // As above, but one hand marker stays captured: the hand and forearm are seen, their
  // anchor is data, and their interpolated fills pull no faster than any fill. The
  // faster speed must change nothing.
  const std::vector<Pose> bent = BendElbowWhileForearmIsOccluded();
  const C3dTake moved = SynthesizeMarkers(*fixture_.skeleton, *fixture_.markers, bent, 120.0);
  for (int f = 300; f < 420; ++f) Sample(f, Marker("LHND1")) = moved.at(f, Marker("LHND1"));
  auto run = [&](double interpolation_speed) {
    CleanupOptions options;
    options.unseen_limb_interpolation_speed_mps = interpolation_speed;
    return Run(options);
  };
  const auto fast = run(10.0), slow = run(CleanupOptions{}.fill_anchor_speed_mps);
  int interpolated = 0;
  for (int f = 300; f < 430; ++f) {
    const auto uf = static_cast<size_t>(f);
    interpolated +=
        fast[uf].source[static_cast<size_t>(Marker("LHND2"))] == SampleSource::kInterpolated;
    ASSERT_EQ(fast[uf].pose.rotation.size(), slow[uf].pose.rotation.size());
    for (size_t j = 0; j < fast[uf].pose.rotation.size(); ++j)
      ASSERT_TRUE(fast[uf].pose.rotation[j].coeffs() == slow[uf].pose.rotation[j].coeffs())
          << f << " " << j;
  }
  EXPECT_GT(interpolated, 0);  // the interpolations were there to pull
}

TEST_F(FinalSolveTest, InterpolationsLeadAHiddenElbowWhoseHandIsSeen) {
  // K = 12. The upper arm and forearm are occluded while the arm turns 60 degrees about
  // its shoulder-wrist line; the hand stays captured. The hand fixes where the forearm
  // ends, not where the elbow swings: the anchor keeps the old swivel, so the upper arm's
  // and forearm's interpolated fills lead the skeleton to where their markers come back,
  // as on a limb with nothing seen (kick 60 Hz medium: held to the anchor, a knee stayed
  // 5-7 cm off while its shin's fills were 0.7-2.6 cm off).
  std::vector<Pose> swivelled = fixture_.motion;
  const Skeleton& skeleton = *fixture_.skeleton;
  const auto shoulder = static_cast<size_t>(skeleton.FindJoint("LeftArm")->value);
  const auto elbow = static_cast<size_t>(skeleton.FindJoint("LeftForeArm")->value);
  const auto wrist = static_cast<size_t>(skeleton.FindJoint("LeftHand")->value);
  for (size_t f = 300; f < swivelled.size(); ++f) {
    Pose& pose = swivelled[f];
    // The shoulder-wrist line in the upper arm's frame: turning about it leaves the wrist
    // where it was.
    const Vec3 to_wrist = skeleton.joint(static_cast<int>(elbow)).offset +
                          pose.rotation[elbow] * skeleton.joint(static_cast<int>(wrist)).offset;
    const double angle = M_PI / 3 * std::min(1.0, static_cast<double>(f - 300) / 100.0);
    const Quat turn(Eigen::AngleAxisd(angle, to_wrist.normalized()));
    pose.rotation[shoulder] = pose.rotation[shoulder] * turn;
    // The hand keeps its orientation in the world: it says nothing about the swivel.
    pose.rotation[wrist] = pose.rotation[elbow].inverse() * turn.inverse() * pose.rotation[elbow] *
                           pose.rotation[wrist];
  }
  const C3dTake moved = SynthesizeMarkers(skeleton, *fixture_.markers, swivelled, 120.0);
  for (int f = 0; f < static_cast<int>(frames_.size()); ++f)
    for (int m = 0; m < fixture_.markers->num_markers(); ++m) Sample(f, m) = moved.at(f, m);
  for (int f = 300; f < 420; ++f)
    for (const char* name : {"LUPA1", "LUPA2", "LUPA3", "LELB", "LFRM1", "LFRM2"})
      Sample(f, Marker(name)) = Vec3::Constant(kNaN);
  auto elbow_error_on_return = [&](double interpolation_speed) {
    CleanupOptions options;
    options.unseen_limb_interpolation_speed_mps = interpolation_speed;
    return WorstJointError(Run(options), swivelled, "LeftForeArm", 419, 420);
  };
  const double led = elbow_error_on_return(CleanupOptions{}.unseen_limb_interpolation_speed_mps),
               dragged = elbow_error_on_return(CleanupOptions{}.fill_anchor_speed_mps);
  EXPECT_GT(dragged, 0.02) << led;            // the anchor's old swivel
  EXPECT_LT(led, dragged - 0.01) << dragged;  // measured 2.0 against 3.3 cm
}

TEST_F(FinalSolveTest, CapturedJumpTheDetectorsMissIsClosedOnNotFollowed) {
  // From frame 300 every left-hand marker is 10 cm off (a slipped cluster, or a swap no
  // detector caught: they are all blind here). The samples are published as captured,
  // but a jump is not motion: the skeleton's hand closes on them over several frames.
  for (int f = 300; f < static_cast<int>(frames_.size()); ++f)
    for (const char* name : {"LHND1", "LHND2", "LHND3"})
      Sample(f, Marker(name)) += Vec3(0.1, 0.0, 0.0);
  auto worst_extra_hand_step = [&](double motion_acceleration) {
    CleanupOptions options = Blind();
    options.lookahead = 0;
    options.data_motion_acceleration_mps2 = motion_acceleration;
    const auto out = Run(options);
    EXPECT_EQ(out[300].markers[static_cast<size_t>(Marker("LHND1"))], Sample(300, Marker("LHND1")));
    return WorstExtraJointStep(out, fixture_.motion, "LeftHand", 290, 340);
  };
  EXPECT_LT(worst_extra_hand_step(CleanupOptions{}.data_motion_acceleration_mps2),
            0.02);                                  // measured 0.3 cm
  EXPECT_GT(worst_extra_hand_step(14400.0), 0.04);  // the jump taken as motion: measured 4.6 cm
}

TEST_F(FinalSolveTest, GuessesPullTheSkeletonNoFurtherThanTheAnchorAllows) {
  // K = 12. While the forearm and hand are occluded the elbow bends a further 90 degrees;
  // the lookahead sees them come back far from the reference's guess, and the
  // interpolated fills bend onto the returning tracks within 12 frames, much faster than
  // the arm moves. The skeleton may follow those guesses only within the anchor's
  // radius of the pose the trusted samples give (here both fill speeds are that radius).
  const std::vector<Pose> bent = BendElbowWhileForearmIsOccluded();
  auto worst_extra_hand_step = [&](double speed) {
    CleanupOptions options;
    options.fill_anchor_speed_mps = speed;
    options.unseen_limb_interpolation_speed_mps = speed;
    return WorstExtraJointStep(Run(options), bent, "LeftHand", 380, 520);
  };
  const double anchored = worst_extra_hand_step(CleanupOptions{}.fill_anchor_speed_mps),
               free = worst_extra_hand_step(0.0);
  EXPECT_LT(anchored, 0.02) << free;  // measured 1.1 cm
  EXPECT_GT(free, 0.03) << anchored;  // measured 5.6 cm
}

TEST_F(FinalSolveTest, UnseenLowerLegIsNotSwungByItsTurningThigh) {
  // From frame 300 the left thigh turns 60 degrees in 20 frames while the knee turns back
  // as much: the shin and foot keep their world orientation (a planted lower leg under a
  // turning thigh), and all their markers are occluded. Held relative to the thigh, the
  // guessed shin would swing the foot with it.
  std::vector<Pose> turned = fixture_.motion;
  const auto hip = static_cast<size_t>(fixture_.skeleton->FindJoint("LeftUpLeg")->value);
  const auto knee = static_cast<size_t>(fixture_.skeleton->FindJoint("LeftLeg")->value);
  for (size_t f = 300; f < turned.size(); ++f) {
    const Quat turn(Eigen::AngleAxisd(M_PI / 3 * std::min(1.0, static_cast<double>(f - 300) / 20.0),
                                      Vec3::UnitX()));
    turned[f].rotation[hip] = turned[f].rotation[hip] * turn;
    turned[f].rotation[knee] = turn.inverse() * turned[f].rotation[knee];
  }
  CaptureWithLeftLowerLegOccluded(turned, 280, 420);
  auto worst_extra_ankle_step = [&](bool hold) {
    CleanupOptions options;
    options.lookahead = 0;
    options.anchor_holds_unseen_limbs = hold;
    options.unseen_limb_memory_s = 0.0;  // the hold alone (recalls: below)
    return WorstExtraJointStep(Run(options), turned, "LeftFoot", 290, 330);
  };
  const double held = worst_extra_ankle_step(true), swung = worst_extra_ankle_step(false);
  EXPECT_LT(held, 0.01) << swung;  // measured 0.2 cm
  EXPECT_GT(swung, 0.02) << held;  // measured 2.8 cm
}

TEST_F(FinalSolveTest, AnUnseenLowerLegKeepsWalkingAsTheSubjectsOwnStepsRecallIt) {
  // The left shin and foot occluded for a second in mid-walk, with no lookahead: held,
  // the guessed foot stays behind while the real one keeps stepping; recalled from the
  // walk's earlier steps (the rest of the body says where in its step the leg is), it
  // steps on.
  CaptureWithLeftLowerLegOccluded(fixture_.motion, 420, 540);
  auto worst_foot_error = [&](double memory_s) {
    CleanupOptions options;
    options.lookahead = 0;
    options.unseen_limb_memory_s = memory_s;
    return WorstJointError(Run(options), "LeftFoot", 420, 540);
  };
  const double recalled = worst_foot_error(CleanupOptions{}.unseen_limb_memory_s),
               held = worst_foot_error(0.0);
  EXPECT_LT(recalled, 0.5 * held) << held;  // measured 7.1 cm against 24.3 cm
}

TEST_F(FinalSolveTest, LongUnseenLowerLegGoesWhereItsSlowlyTurningThighTakesIt) {
  // From frame 280 the left hip, knee, ankle and toe keep their angles, except that from
  // frame 300 the thigh turns 45 degrees over one second (slower than
  // unseen_limb_turn_radps): the whole leg swings, its shin and foot markers occluded for
  // 1.5 s. Held in the world for as long as it is unseen, the guessed lower leg would
  // stay behind.
  std::vector<Pose> swung = fixture_.motion;
  const auto hip = static_cast<size_t>(fixture_.skeleton->FindJoint("LeftUpLeg")->value);
  for (const char* joint : {"LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase"}) {
    const auto j = static_cast<size_t>(fixture_.skeleton->FindJoint(joint)->value);
    for (size_t f = 280; f < swung.size(); ++f) swung[f].rotation[j] = swung[279].rotation[j];
  }
  for (size_t f = 300; f < swung.size(); ++f) {
    const Quat turn(Eigen::AngleAxisd(
        M_PI / 4 * std::min(1.0, static_cast<double>(f - 300) / 120.0), Vec3::UnitX()));
    swung[f].rotation[hip] = swung[f].rotation[hip] * turn;
  }
  CaptureWithLeftLowerLegOccluded(swung, 280, 460);
  auto worst_ankle_error = [&](double turn_radps) {
    CleanupOptions options;
    options.lookahead = 0;
    options.unseen_limb_turn_radps = turn_radps;
    return WorstJointError(Run(options), swung, "LeftFoot", 290, 460);
  };
  const double carried = worst_ankle_error(CleanupOptions{}.unseen_limb_turn_radps),
               kept = worst_ankle_error(0.0);
  EXPECT_LT(carried, 0.02) << kept;  // measured 0.4 cm
  EXPECT_GT(kept, 0.05) << carried;  // measured 9.5 cm
}

// The final solve alone, on frames whose every sample the repair marked captured.
class FinalSolveAloneTest : public CleanupFixture {
 protected:
  CleanFrame Frame(int t) const {
    CleanFrame f;
    f.frame = t;
    const auto m = static_cast<size_t>(fixture_.markers->num_markers());
    f.markers = frames_[static_cast<size_t>(t)];
    f.status.assign(m, MarkerStatus::kObserved);
    f.reason.assign(m, MaskReason::kNone);
    f.source.assign(m, SampleSource::kCaptured);
    f.weight.assign(m, 0.0);
    f.pose = RestPose(*fixture_.skeleton);
    return f;
  }
};

TEST_F(FinalSolveAloneTest, CapturedSamplesWeighFullyAndTheSkeletonFitsThem) {
  FinalSolve dut(*fixture_.skeleton, *fixture_.markers, CleanupOptions{});
  CleanupCounters counters;
  PoseErrorAccumulator errors(*fixture_.skeleton);
  KinematicsWorkspace truth(*fixture_.skeleton), solved(*fixture_.skeleton);
  for (int t = 0; t < 200; ++t) {
    CleanFrame f = Frame(t);
    dut.Solve(&f, &counters);
    for (double w : f.weight) ASSERT_EQ(w, 1.0);
    if (t < 20) continue;  // the cold start settles
    ForwardKinematics(*fixture_.skeleton, fixture_.motion[static_cast<size_t>(t)], &truth);
    ForwardKinematics(*fixture_.skeleton, f.pose, &solved);
    errors.Add(truth, solved);
  }
  EXPECT_LT(errors.mean_position_error_m(), 0.002);
  EXPECT_EQ(counters.solve_failures, 0);
}

TEST_F(FinalSolveAloneTest, WeightsFollowWhereTheSampleCameFrom) {
  CleanupOptions options;
  FinalSolve dut(*fixture_.skeleton, *fixture_.markers, options);
  CleanupCounters counters;
  for (int t = 0; t < 10; ++t) {
    CleanFrame f = Frame(t);
    dut.Solve(&f, &counters);
  }
  CleanFrame f = Frame(10);
  f.status[0] = MarkerStatus::kUnrecoverable;
  f.source[0] = SampleSource::kNone;
  f.markers[0] = Vec3::Constant(kNaN);
  f.status[1] = f.status[2] = MarkerStatus::kRepaired;
  f.source[1] = SampleSource::kExtrapolated;
  f.source[2] = SampleSource::kInterpolated;
  dut.Solve(&f, &counters);
  EXPECT_EQ(f.weight[0], 0.0);
  EXPECT_EQ(f.weight[1], options.repaired_weight);
  EXPECT_EQ(f.weight[2], options.interpolated_weight);
  EXPECT_TRUE(f.pose.rotation[1].coeffs().allFinite());
}

}  // namespace
}  // namespace mocapd
