// Tests for gap repair: Hermite fills along the reference (two-sided, one-sided, short
// gaps on the raw path), fills riding through reference snaps, the no-pop re-entry
// blend, and the stage driven alone on a hand-made window.
#include "filters/gap_repair.hpp"

#include <gtest/gtest.h>

#include <functional>

#include "tests/filters/cleanup_fixture.hpp"

namespace mocapd {
namespace {

class GapRepairTest : public CleanupFixture {};

TEST_F(GapRepairTest, LongGapIsFilledAlongTheReferenceWithoutJumps) {
  const int m = Marker("LFRM1");
  for (int f = 200; f < 400; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  for (int f = 200; f < 400; ++f) {
    ASSERT_EQ(out[static_cast<size_t>(f)].status[static_cast<size_t>(m)], MarkerStatus::kRepaired);
    EXPECT_EQ(out[static_cast<size_t>(f)].reason[static_cast<size_t>(m)], MaskReason::kMissing);
    EXPECT_LT((out[static_cast<size_t>(f)].markers[static_cast<size_t>(m)] - Truth(f, m)).norm(),
              0.01)
        << f;
  }
  // C0 at both ends: no step bigger than the marker's own motion allows.
  for (int f = 195; f < 405; ++f) {
    const double step = (out[static_cast<size_t>(f)].markers[static_cast<size_t>(m)] -
                         out[static_cast<size_t>(f - 1)].markers[static_cast<size_t>(m)])
                            .norm();
    EXPECT_LT(step, (Truth(f, m) - Truth(f - 1, m)).norm() + 0.003) << f;
  }
  EXPECT_EQ(counters_.repaired_by[static_cast<size_t>(MaskReason::kMissing)], 200);
}

TEST_F(GapRepairTest, ShortGapGetsAPlainHermiteOnTheRawPath) {
  const int m = Marker("RTHI2");
  for (int f = 300; f < 303; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  for (int f = 300; f < 303; ++f)
    EXPECT_LT((out[static_cast<size_t>(f)].markers[static_cast<size_t>(m)] - Truth(f, m)).norm(),
              0.001);
}

TEST_F(GapRepairTest, ReturningMarkerBlendsInWithoutAPop) {
  // A gap longer than the lookahead: its first frames go out one-sided, holding the
  // offset the marker had (+9 mm). It returns with another offset (-9 mm, both within
  // the detectors' tolerance): the output must ease over instead of jumping 18 mm.
  const int m = Marker("RFRM1");
  CleanupOptions options;
  options.lookahead = 4;
  for (int f = 0; f < 400; ++f) Sample(f, m) += Vec3(0.009, 0.0, 0.0);
  for (int f = 400; f < 460; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  for (int f = 460; f < static_cast<int>(frames_.size()); ++f)
    Sample(f, m) -= Vec3(0.009, 0.0, 0.0);
  const auto out = Run(options);
  double worst_extra_step = 0.0;
  for (int f = 440; f < 470; ++f)
    worst_extra_step = std::max(worst_extra_step, ExtraStep(out, f, m));
  EXPECT_LT(worst_extra_step, 0.008);
  EXPECT_EQ(out[460].status[static_cast<size_t>(m)], MarkerStatus::kObserved);
  EXPECT_EQ(out[460].markers[static_cast<size_t>(m)],
            Sample(460, m));  // the returning sample itself is untouched
}

TEST_F(GapRepairTest, FillsRideThroughAReferenceThatSnapsBack) {
  // The whole lower leg is occluded for long: the reference guesses it, and when the toe
  // markers come back (the foot's markers still missing) it snaps to them. The foot's
  // fills must not jump with it (0.23 m without the rule), and the toes' re-entry spreads
  // the guess's error over the lookahead: no published marker moves more than 3.5 cm per
  // frame beyond its true motion.
  const char* leg[] = {"LKNE", "LSHN1", "LSHN2", "LFOT1", "LFOT2", "LFOT3", "LTOE1", "LTOE2"};
  for (int f = 300; f < 500; ++f)
    for (const char* name : leg)
      if (f < 480 || std::string(name).rfind("LTOE", 0) != 0)
        Sample(f, Marker(name)) = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  double worst_extra_step = 0.0;
  for (int f = 301; f < 510; ++f)
    for (const char* name : leg)
      worst_extra_step = std::max(worst_extra_step, ExtraStep(out, f, Marker(name)));
  EXPECT_LT(worst_extra_step, 0.035);
}

TEST_F(GapRepairTest, OneSidedFillTakesUpAReferenceMotionItHeldBack) {
  // With the acceleration limit set so low that all of the hand's real motion counts as
  // snapping, the fill holds it back but takes it up over 80 ms: it stays near
  // the true path instead of falling behind for the whole gap.
  const int m = Marker("LHND1");
  for (int f = 300; f < 560; ++f) Sample(f, m) = Vec3::Constant(kNaN);
  CleanupOptions options;
  options.fill_reference_acceleration_mps2 = 0.5;
  auto worst_error = [&](double release_s) {
    options.fill_snap_release_s = release_s;
    const auto out = Run(options);
    double worst = 0.0;
    for (int f = 300; f < 540; ++f)
      worst = std::max(
          worst,
          (out[static_cast<size_t>(f)].markers[static_cast<size_t>(m)] - Truth(f, m)).norm());
    return worst;
  };
  EXPECT_LT(worst_error(0.079), 0.3);  // measured 0.15 m
  EXPECT_GT(worst_error(1e3), 1.0);    // held back for good: measured 2.6 m
}

TEST_F(GapRepairTest, MarkerNeverSeenIsUnrecoverableNotInvented) {
  const int m = Marker("LTOE1");
  for (auto& frame : frames_) frame[static_cast<size_t>(m)] = Vec3::Constant(kNaN);
  const auto out = Run(CleanupOptions{});
  EXPECT_EQ(out[100].status[static_cast<size_t>(m)], MarkerStatus::kUnrecoverable);
  EXPECT_FALSE(out[100].markers[static_cast<size_t>(m)].allFinite());
  EXPECT_EQ(counters_.unrecoverable, static_cast<int64_t>(frames_.size()));
}

// The repair alone on one marker whose reference moves at 1 cm per frame along x and
// whose captured samples sit at a fixed offset from it: what each kind of fill gives is
// known exactly.
class GapRepairAloneTest : public ::testing::Test {
 protected:
  static Vec3 Line(int t) { return Vec3(0.01 * t, 1.0, 0.0); }
  Vec3 Reference(int t) const { return Line(t) + bump_(t); }
  // Runs frames [0, frames) through a window of K + 3, the sample of frame t being
  // Reference(t) + offset(t), or missing where offset(t) is NaN; returns every output.
  std::vector<CleanFrame> Run(int lookahead, int frames, const std::function<Vec3(int)>& offset) {
    options_.lookahead = lookahead;
    CleanupWindow window(1, lookahead + 3);
    GapRepair dut(1, options_);
    std::vector<CleanFrame> out;
    auto publish = [&](int tau, int newest) {
      CleanFrame f;
      f.frame = tau;
      f.markers.assign(1, Vec3::Zero());
      f.status.assign(1, MarkerStatus::kObserved);
      f.reason.assign(1, MaskReason::kNone);
      f.source.assign(1, SampleSource::kNone);
      dut.Repair(window, tau, newest, &f, &counters_);
      out.push_back(f);
    };
    for (int t = 0; t < frames; ++t) {
      WindowFrame& s = window.at(t);
      s.frame = t;
      s.raw[0] = Line(t) + offset(t);
      s.valid[0] = s.raw[0].allFinite();
      s.mask[0] = s.valid[0] ? MaskReason::kNone : MaskReason::kMissing;
      s.reference[0] = Reference(t);
      s.reference_solved = true;  // a reference solved from data
      if (t >= lookahead) publish(t - lookahead, t);
    }
    for (int tau = std::max(0, frames - lookahead); tau < frames; ++tau) publish(tau, frames - 1);
    return out;
  }
  CleanupOptions options_;
  CleanupCounters counters_;
  std::function<Vec3(int)> bump_ = [](int) -> Vec3 {
    return Vec3::Zero();
  };  // the reference's own deviation
};

TEST_F(GapRepairAloneTest, TwoSidedFillRidesTheReferenceAtTheOffsetOfBothEnds) {
  const Vec3 offset(0.02, 0.0, 0.0);
  const auto out =
      Run(12, 60, [&](int t) -> Vec3 { return t >= 20 && t < 30 ? Vec3::Constant(kNaN) : offset; });
  ASSERT_EQ(out.size(), 60u);
  for (int t = 20; t < 30; ++t) {
    const CleanFrame& f = out[static_cast<size_t>(t)];
    EXPECT_EQ(f.status[0], MarkerStatus::kRepaired);
    EXPECT_EQ(f.reason[0], MaskReason::kMissing);
    EXPECT_EQ(f.source[0], SampleSource::kInterpolated);
    EXPECT_LT((f.markers[0] - (Reference(t) + offset)).norm(), 1e-12) << t;
  }
  EXPECT_EQ(out[30].source[0], SampleSource::kCaptured);
  EXPECT_EQ(out[30].markers[0], Reference(30) + offset);  // untouched
  EXPECT_EQ(counters_.repaired_by[static_cast<size_t>(MaskReason::kMissing)], 10);
}

TEST_F(GapRepairAloneTest, TwoSidedFillMovesBetweenDifferentEndOffsetsWithoutJumps) {
  const auto out = Run(12, 60, [&](int t) -> Vec3 {
    return t < 20 ? Vec3(0.02, 0, 0) : t < 30 ? Vec3::Constant(kNaN) : Vec3(0.05, 0, 0);
  });
  double previous = 0.02;
  for (int t = 20; t < 30; ++t) {
    const double o = (out[static_cast<size_t>(t)].markers[0] - Reference(t)).x();
    EXPECT_GT(o, previous - 1e-12) << t;            // monotone from one end's offset to the other's
    EXPECT_LT(o - previous, 0.03 / 10 * 1.6) << t;  // no step much beyond the even share
    previous = o;
  }
  EXPECT_LT(previous, 0.05);
}

TEST_F(GapRepairAloneTest, OneSidedFillHoldsTheLastOffsetWhileTheGapIsOpen) {
  const Vec3 offset(0.0, 0.0, 0.03);
  const auto out =
      Run(2, 60, [&](int t) -> Vec3 { return t >= 20 && t < 40 ? Vec3::Constant(kNaN) : offset; });
  for (int t = 20; t < 37; ++t) {  // the end is not in the 2-frame lookahead yet
    const CleanFrame& f = out[static_cast<size_t>(t)];
    EXPECT_EQ(f.source[0], SampleSource::kExtrapolated) << t;
    EXPECT_LT((f.markers[0] - (Reference(t) + offset)).norm(), 1e-12) << t;
  }
}

// An offline user raising the lookahead must not get worse fills: the reference carries
// a long gap, and the return pulls the fill only within fill_interpolation_horizon_s; the
// one-sided fill eases its start velocity out over fill_ease_s, not over the lookahead.
TEST_F(GapRepairAloneTest, ALongGapIsFilledTheSameWithALongerLookahead) {
  options_.rate_hz = 120.0;
  auto offset = [](int t) -> Vec3 {  // drifting before the gap, a different offset after
    return t < 20 ? Vec3(0.001 * t, 0, 0) : t < 140 ? Vec3::Constant(kNaN) : Vec3(0.05, 0, 0);
  };
  const auto near = Run(12, 200, offset);
  const auto far = Run(240, 200, offset);
  ASSERT_EQ(near.size(), far.size());
  const int horizon = FrameRules(options_).fill_interpolation_horizon_frames;
  for (int t = 20; t < 140; ++t) {
    const auto f = static_cast<size_t>(t);
    EXPECT_LT((near[f].markers[0] - far[f].markers[0]).norm(), 1e-12) << t;
    EXPECT_EQ(far[f].source[0],
              140 - t <= horizon ? SampleSource::kInterpolated : SampleSource::kExtrapolated)
        << t;
  }
}

TEST_F(GapRepairAloneTest, OneSidedFillHoldsTheLastOffsetOfADriftingMarker) {
  // The marker drifts from its reference by 1 mm a frame before the gap; the fill does
  // not carry the drift on (fill_ease_s = 0), nor ring about the offset it holds.
  const auto out = Run(2, 60, [&](int t) -> Vec3 {
    return t < 20 ? Vec3(0.001 * t, 0, 0) : t < 40 ? Vec3::Constant(kNaN) : Vec3(0.019, 0, 0);
  });
  const Vec3 held = out[19].markers[0] - Reference(19);
  for (int t = 20; t < 37; ++t)
    EXPECT_LT((out[static_cast<size_t>(t)].markers[0] - (Reference(t) + held)).norm(), 1e-12) << t;
}

TEST_F(GapRepairAloneTest, AMarkerNotSeenYetRidesItsFirstOffsetAsFarAsTheLookaheadShows) {
  // Occluded from the take's start: nothing to bend toward the return, so the horizon
  // does not apply, and every frame the lookahead reaches is filled.
  const Vec3 offset(0.0, 0.02, 0.0);
  const auto out =
      Run(60, 120, [&](int t) -> Vec3 { return t < 50 ? Vec3::Constant(kNaN) : offset; });
  for (int t = 0; t < 50; ++t) {
    const CleanFrame& f = out[static_cast<size_t>(t)];
    EXPECT_EQ(f.status[0], MarkerStatus::kRepaired) << t;
    EXPECT_LT((f.markers[0] - (Reference(t) + offset)).norm(), 1e-12) << t;
  }
}

TEST_F(GapRepairAloneTest, ShortGapIsAPlainHermiteOnTheRawPath) {
  // The raw path bends; during the gap alone the reference bulges up to 8 mm away from
  // it (slowly enough that no snap rule hides it). A short gap interpolates the raw path
  // itself and ignores the bulge: an offset fill onto the reference would be 8 mm off.
  bump_ = [](int t) -> Vec3 {
    return Vec3(0.0, t == 31 ? 0.008 : t == 30 || t == 32 ? 0.004 : 0.0, 0.0);
  };
  auto bend = [](int t) -> Vec3 { return Vec3(0.0, 0.0, 0.0001 * t * t); };
  const auto out = Run(
      12, 60, [&](int t) -> Vec3 { return t >= 30 && t < 33 ? Vec3::Constant(kNaN) : bend(t); });
  for (int t = 30; t < 33; ++t)
    EXPECT_EQ(out[static_cast<size_t>(t)].source[0], SampleSource::kInterpolated);
  EXPECT_LT((out[30].markers[0] - (Line(30) + bend(30))).norm(), 0.001);
}

TEST_F(GapRepairAloneTest, MarkerNeverSeenIsUnrecoverable) {
  const auto out = Run(4, 20, [](int) -> Vec3 { return Vec3::Constant(kNaN); });
  for (const CleanFrame& f : out) {
    EXPECT_EQ(f.status[0], MarkerStatus::kUnrecoverable);
    EXPECT_EQ(f.source[0], SampleSource::kNone);
    EXPECT_FALSE(f.markers[0].allFinite());
  }
  EXPECT_EQ(counters_.unrecoverable, 20);
}

}  // namespace
}  // namespace mocapd
