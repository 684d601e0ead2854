// Tests for the daemon's per-subject frame accounting and sequencing, without sockets:
// every frame in is published or dropped with a reason, gaps in the frame numbers are
// filled, restarts re-synchronise, and nothing for another model is ever applied.
#include "runtime/subject_runner.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <map>

#include "formats/marker_layout.hpp"
#include "formats/take_frames.hpp"
#include "runtime/daemon.hpp"
#include "runtime/live_view.hpp"
#include "sim/humanoid.hpp"
#include "sim/humanoid_subject.hpp"
#include "tests/support/allocation_counter.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

// Decodes what the runner sends, by topic.
class RecordingSink : public OutputSink {
 public:
  void Send(std::string_view topic, std::span<const uint8_t> message) override {
    if (topic.starts_with("skeleton/")) {
      protocol::SkeletonFrameMessage m;
      EXPECT_EQ(protocol::DecodeSkeletonFrame(message, &m), protocol::DecodeStatus::kOk);
      skeletons.push_back(m);
    } else if (topic.starts_with("cleaned/")) {
      protocol::CleanedMarkersMessage m;
      EXPECT_EQ(protocol::DecodeCleanedMarkers(message, &m), protocol::DecodeStatus::kOk);
      cleaned.push_back(m);
    } else if (topic.starts_with("status/")) {
      protocol::SubjectStatusMessage m;
      EXPECT_EQ(protocol::DecodeSubjectStatus(message, &m), protocol::DecodeStatus::kOk);
      statuses.push_back(m);
    } else {
      ++others;
    }
  }
  std::vector<protocol::SkeletonFrameMessage> skeletons;
  std::vector<protocol::CleanedMarkersMessage> cleaned;
  std::vector<protocol::SubjectStatusMessage> statuses;
  int others = 0;
};

class SubjectRunnerTest : public ::testing::Test {
 protected:
  SubjectRunnerTest()
      : fixture_(testing::MakeHumanoidFixture("walk", 2.0, 120.0)),
        map_(*fixture_.markers, fixture_.take) {
    subject_.name = "actor1";
    subject_.model = MakeHumanoidSubject("actor1");
    subject_.rate_hz = 120.0;
    subject_.cleanup.rate_hz = 120.0;
    subject_.cleanup.lookahead = 4;
  }

  protocol::MarkerFrameMessage Frame(int take_frame, uint64_t frame_number,
                                     uint64_t capture_ns) const {
    protocol::MarkerFrameMessage m;
    m.subject = "actor1";
    m.model_hash = protocol::MarkerSetHash(*subject_.model.markers);
    m.frame_number = frame_number;
    m.capture_time_ns = capture_ns;
    m.rate_hz = 120.0f;
    map_.FillMessage(fixture_.take, take_frame, &m);
    return m;
  }

  // Built before an allocation count starts: the messages themselves allocate.
  std::vector<protocol::MarkerFrameMessage> Frames(int first, int end) const {
    std::vector<protocol::MarkerFrameMessage> frames;
    for (int f = first; f < end; ++f) frames.push_back(Frame(f, static_cast<uint64_t>(f), 0));
    return frames;
  }

  // Publishing without keeping anything, for the allocation counts.
  class NullSink : public OutputSink {
   public:
    void Send(std::string_view, std::span<const uint8_t>) override {}
  };

  // The log line for the runner's last re-synchronisation, restarts_since of them.
  static std::string RestartLine(const SubjectRunner& r, uint64_t restarts_since) {
    SubjectStats stats;
    stats.name = r.name();
    stats.counters = r.counters();
    return RestartLogLine(stats, restarts_since);
  }
  static void ExpectBalanced(const SubjectRunner& r) {
    const SubjectCounters& c = r.counters();
    EXPECT_EQ(c.frames_in, c.frames_published + c.dropped_total() + r.pending_received());
  }

  testing::HumanoidFixture fixture_;
  TakeMarkerMap map_;
  SubjectConfig subject_;
  DaemonConfig daemon_;
  RecordingSink sink_;
};

TEST_F(SubjectRunnerTest, EveryFrameComesOutInOrderWithItsNumberAndCaptureTime) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 100; ++f)
    EXPECT_FALSE(runner.Accept(Frame(f, 5000 + f, 1000 * f), f, sink_).has_value());
  EXPECT_EQ(sink_.skeletons.size(), 96u);  // K = 4 held back
  EXPECT_EQ(runner.pending(), 4u);
  ExpectBalanced(runner);
  runner.Flush(sink_);
  ASSERT_EQ(sink_.skeletons.size(), 100u);
  ASSERT_EQ(sink_.cleaned.size(), 100u);
  for (int f = 0; f < 100; ++f) {
    EXPECT_EQ(sink_.skeletons[static_cast<size_t>(f)].frame_number, 5000u + f);
    EXPECT_EQ(sink_.skeletons[static_cast<size_t>(f)].capture_time_ns, 1000u * f);
    EXPECT_EQ(sink_.cleaned[static_cast<size_t>(f)].frame_number, 5000u + f);
  }
  EXPECT_EQ(runner.counters().frames_published, 100u);
  ExpectBalanced(runner);
  // Clean input: every published marker is the captured one, unchanged (as f32).
  const protocol::CleanedMarkersMessage& c = sink_.cleaned[50];
  const protocol::MarkerFrameMessage in = Frame(50, 5050, 0);
  for (size_t m = 0; m < c.positions.size(); ++m) {
    EXPECT_EQ(c.status[m], 0);
    EXPECT_EQ(c.positions[m].cast<float>(), in.positions[m].cast<float>());
  }
  // The solved root follows the truth.
  const Vec3 root_truth = fixture_.motion[50].translation[0];
  EXPECT_LT((sink_.skeletons[50].root_translation - root_truth).norm(), 0.01);
}

TEST_F(SubjectRunnerTest, MissingFrameNumbersBecomeRepairedFrames) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 60; ++f) {
    if (f >= 20 && f < 25) continue;  // five frames lost on the network
    ASSERT_FALSE(runner.Accept(Frame(f, f, 0), 0, sink_).has_value());
  }
  runner.Flush(sink_);
  ASSERT_EQ(sink_.skeletons.size(), 60u);
  for (size_t f = 0; f < 60; ++f) EXPECT_EQ(sink_.skeletons[f].frame_number, f);
  EXPECT_EQ(runner.counters().frames_inserted, 5u);
  EXPECT_EQ(runner.counters().inserted_published, 5u);
  EXPECT_EQ(runner.counters().frames_published, 55u);
  // The inserted frames' markers were all repaired (none is "observed").
  for (uint8_t s : sink_.cleaned[22].status) EXPECT_NE(s, 0);
  ExpectBalanced(runner);
}

// A hole of 0.75 s in a walk's frame numbers, far longer than the lookahead: bridged with
// empty frames, the skeleton held still through it and then swept to the far end over the
// lookahead's frames (1.6 m in 12 frames for 1.5 s). Both ends are known when the hole is
// bridged, so the body moves between them as it walked, no step a frame larger than a
// walk's, and every inserted frame still says it was repaired.
TEST_F(SubjectRunnerTest, AHoleLongerThanTheLookaheadMovesTheBodyAcrossItWithoutAJump) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 240; ++f) {
    if (f >= 60 && f < 150) continue;
    protocol::MarkerFrameMessage m = Frame(f, f, 0);
    // The far end carries a sender's "not seen" 1e30 and a ghost 3 m off under one label:
    // neither may steer the whole body's path through the hole.
    if (f == 150) {
      m.positions[3] = Vec3::Constant(1e30);
      m.positions[7] += Vec3(3.0, 0.0, 0.0);
    }
    ASSERT_FALSE(runner.Accept(m, 0, sink_).has_value());
  }
  runner.Flush(sink_);
  ASSERT_EQ(sink_.skeletons.size(), 240u);
  EXPECT_EQ(runner.counters().frames_inserted, 90u);
  const size_t root = 0;
  double worst_step = 0.0, worst_error = 0.0, walk_step = 0.0;
  for (size_t f = 1; f < 240; ++f) {
    const Vec3 truth_step =
        fixture_.motion[f].translation[root] - fixture_.motion[f - 1].translation[root];
    walk_step = std::max(walk_step, truth_step.norm());
    const Vec3 step = sink_.skeletons[f].root_translation - sink_.skeletons[f - 1].root_translation;
    worst_step = std::max(worst_step, step.norm());
    worst_error = std::max(
        worst_error,
        (sink_.skeletons[f].root_translation - fixture_.motion[f].translation[root]).norm());
  }
  EXPECT_LT(worst_step, 2.0 * walk_step) << "a walk steps at most " << walk_step << " m a frame";
  EXPECT_LT(worst_error, 0.05);
  for (size_t f = 60; f < 150; ++f) {
    EXPECT_NE(sink_.skeletons[f].subject_state, protocol::SubjectState::kTracking) << f;
    for (uint8_t s : sink_.cleaned[f].status) ASSERT_NE(s, 0) << f;  // none "observed"
  }
  ExpectBalanced(runner);
}

TEST_F(SubjectRunnerTest, DuplicatesAndLateFramesAreDroppedAndCounted) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 30; ++f)
    ASSERT_FALSE(runner.Accept(Frame(f, f, 1000 + f), 0, sink_).has_value());
  EXPECT_EQ(runner.Accept(Frame(29, 29, 1029), 0, sink_), DropReason::kDuplicate);
  EXPECT_EQ(runner.Accept(Frame(25, 25, 1025), 0, sink_), DropReason::kOutOfOrder);
  EXPECT_FALSE(runner.Accept(Frame(30, 30, 1030), 0, sink_).has_value());
  runner.Flush(sink_);
  EXPECT_EQ(sink_.skeletons.size(), 31u);
  EXPECT_EQ(runner.counters().dropped[static_cast<size_t>(DropReason::kDuplicate)], 1u);
  EXPECT_EQ(runner.counters().dropped[static_cast<size_t>(DropReason::kOutOfOrder)], 1u);
  EXPECT_EQ(runner.counters().frames_in, 33u);
  ExpectBalanced(runner);
}

TEST_F(SubjectRunnerTest, FramesForAnotherModelOrRateAreNeverApplied) {
  SubjectRunner runner(subject_, daemon_);
  protocol::MarkerFrameMessage wrong_hash = Frame(0, 0, 0);
  wrong_hash.model_hash ^= 1;
  EXPECT_EQ(runner.Accept(wrong_hash, 0, sink_), DropReason::kModelMismatch);
  protocol::MarkerFrameMessage fewer = Frame(0, 0, 0);
  fewer.positions.pop_back();
  fewer.valid.pop_back();
  EXPECT_EQ(runner.Accept(fewer, 0, sink_), DropReason::kModelMismatch);
  // Beyond 0.1 % of the rate and of its NTSC rate (1000/1001 of it) is another rate; the
  // NTSC rate is taken however the sender rounded it (119.88 was dropped, 120000/1001 not).
  protocol::MarkerFrameMessage rate = Frame(0, 0, 0);
  for (const float off : {119.7f, 120.13f, 119.75f, 240.0f}) {
    rate.rate_hz = off;
    EXPECT_EQ(runner.Accept(rate, 0, sink_), DropReason::kRateMismatch) << off;
  }
  SubjectRunner ntsc(subject_, daemon_);
  RecordingSink ntsc_sink;
  for (const float near : {119.88f, 119.88012f, 120.0f}) {
    protocol::MarkerFrameMessage m = Frame(0, 0, 0);
    m.rate_hz = near;
    m.frame_number = ntsc.counters().frames_in;
    EXPECT_FALSE(ntsc.Accept(m, 0, ntsc_sink).has_value()) << near;
  }
  // Configured at the NTSC rate, the nominal one is taken too (120 was dropped by 119.88).
  SubjectConfig at_ntsc = subject_;
  at_ntsc.rate_hz = 119.88;
  SubjectRunner configured_ntsc(at_ntsc, daemon_);
  for (const float near : {120.0f, 119.88f, 120000.0f / 1001.0f}) {
    protocol::MarkerFrameMessage m = Frame(0, 0, 0);
    m.rate_hz = near;
    m.frame_number = configured_ntsc.counters().frames_in;
    EXPECT_FALSE(configured_ntsc.Accept(m, 0, ntsc_sink).has_value()) << near;
  }
  // The warning and /health say which rate came against which was configured (they gave
  // the reason's name alone).
  EXPECT_DOUBLE_EQ(runner.mismatched_rate_hz(), 240.0);
  SubjectStats stats;
  stats.rejecting_input = true;
  stats.rejecting_reason = DropReason::kRateMismatch;
  stats.mismatched_rate_hz = runner.mismatched_rate_hz();
  stats.rate_hz = 120.0;
  EXPECT_EQ(RejectionDetail(stats),
            ": the frames say 240 Hz, the subject is configured for 120 Hz (rate_hz)");
  // Stalled, since nothing was taken, but frames keep coming: /health names the rejection
  // alone ("input stalled" beside it read as a sender gone quiet).
  {
    SubjectStats stalled = stats;
    stalled.name = "actor1";
    stalled.state = protocol::SubjectState::kStalled;
    stalled.since_last_input_s = 0.01;
    DaemonStats daemon_stats;
    daemon_stats.subjects.push_back(stalled);
    std::string health = FormatHealthJson(daemon_stats, true);
    EXPECT_NE(health.find("every frame dropped (rate_mismatch)"), std::string::npos) << health;
    EXPECT_EQ(health.find("input stalled"), std::string::npos) << health;
    // The rejected sender then fell silent: stalled as well.
    daemon_stats.subjects[0].since_last_input_s = 3.0;
    health = FormatHealthJson(daemon_stats, true);
    EXPECT_NE(health.find("subject 'actor1': input stalled"), std::string::npos) << health;
    daemon_stats.subjects[0].since_last_input_s = 0.01;
    daemon_stats.subjects[0].rejecting_input = false;
    health = FormatHealthJson(daemon_stats, true);
    EXPECT_NE(health.find("subject 'actor1': input stalled"), std::string::npos) << health;
  }
  // ...and which marker set came against the model's (a hash written as 0 was told apart
  // from another bridge's set by nothing).
  // The last was the frame one marker short.
  EXPECT_EQ(
      runner.mismatched_model(),
      std::make_pair(protocol::MarkerSetHash(*subject_.model.markers), fewer.positions.size()));
  stats.rejecting_reason = DropReason::kModelMismatch;
  stats.mismatched_model_hash = 0;
  stats.mismatched_marker_count = 59;
  stats.marker_set_hash = 123;
  stats.markers = 59;
  EXPECT_EQ(RejectionDetail(stats),
            ": the frames carry marker-set hash 0 with 59 markers, the subject's model 123 "
            "with 59");
  runner.Flush(sink_);
  EXPECT_TRUE(sink_.skeletons.empty());
  EXPECT_EQ(runner.counters().dropped_total(), 6u);
  ExpectBalanced(runner);
}

TEST_F(SubjectRunnerTest, CaptureRestartFlushesAndStartsOver) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 50; ++f)
    ASSERT_FALSE(runner.Accept(Frame(f, 1000 + f, 1'000'000ull * f), 0, sink_).has_value());
  // The capture restarts: frame numbers from 0 again, its clock going on.
  for (int f = 0; f < 50; ++f)
    ASSERT_FALSE(runner.Accept(Frame(50 + f, f, 1'000'000ull * (100 + f)), 0, sink_).has_value());
  runner.Flush(sink_);
  ASSERT_EQ(sink_.skeletons.size(), 100u);
  EXPECT_EQ(sink_.skeletons[49].frame_number, 1049u);
  EXPECT_EQ(sink_.skeletons[50].frame_number, 0u);
  EXPECT_EQ(sink_.skeletons[99].frame_number, 49u);
  EXPECT_EQ(runner.counters().restarts, 1u);
  EXPECT_EQ(runner.counters().resync_frame, 0u);  // the new stream's first, not its last (49)
  EXPECT_EQ(runner.counters().frames_inserted, 0u);
  ExpectBalanced(runner);
}

// Frames that arrived at the wrong rate are dropped and counted so; bridged by the next
// frame taken, they are not counted again as numbers that never arrived.
TEST_F(SubjectRunnerTest, FramesDroppedMidStreamAreNotAlsoCountedAsSkipped) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 230; ++f) {
    protocol::MarkerFrameMessage m = Frame(f % 120, f, 0);
    if (f >= 100 && f < 190) m.rate_hz = 240.0f;
    runner.Accept(m, 0, sink_);
  }
  runner.Flush(sink_);
  EXPECT_EQ(runner.counters().dropped[static_cast<size_t>(DropReason::kRateMismatch)], 90u);
  EXPECT_EQ(runner.counters().frames_inserted, 90u);
  EXPECT_EQ(runner.counters().frames_skipped, 0u);
  ExpectBalanced(runner);
  // A number that never arrived still is one.
  SubjectRunner other(subject_, daemon_);
  for (int f = 0; f < 50; ++f)
    if (f != 20) other.Accept(Frame(f, f, 0), 0, sink_);
  EXPECT_EQ(other.counters().frames_skipped, 1u);
}

// Version 1: a frame later than restart_backjump (1 s) with its older capture time is
// taken as a restart, but when the interrupted stream then goes on (a newer number and
// clock), the numbers between were published already: a second restart, not a bridge of
// repaired frames re-publishing them (71 duplicates at 60 Hz).
TEST_F(SubjectRunnerTest, AStreamThatGoesOnAfterALatePacketIsNotPublishedTwice) {
  SubjectRunner runner(subject_, daemon_);
  const auto ns = [](int f) { return 1'000'000'000ull + 8'333'333ull * static_cast<uint64_t>(f); };
  for (int f = 0; f < 200; ++f) {
    if (f == 50) continue;  // late: bridged by an inserted frame now
    ASSERT_FALSE(runner.Accept(Frame(f % 120, f, ns(f)), 0, sink_).has_value());
  }
  ASSERT_FALSE(runner.Accept(Frame(50, 50, ns(50)), 0, sink_).has_value());  // 149 back
  EXPECT_EQ(runner.counters().restarts, 1u);
  EXPECT_EQ(RestartLine(runner, 1),
            "subject 'actor1': capture restart or jump in frame numbers, frame 199 -> 50; "
            "pipeline re-synchronised");
  for (int f = 200; f < 230; ++f)
    ASSERT_FALSE(runner.Accept(Frame(f % 120, f, ns(f)), 0, sink_).has_value());
  runner.Flush(sink_);
  EXPECT_EQ(runner.counters().restarts, 2u);
  // Both within one report: the log says there were two (it said one).
  EXPECT_EQ(RestartLine(runner, 2),
            "subject 'actor1': capture restart or jump in frame numbers, frame 50 -> 200; "
            "pipeline re-synchronised (2 re-synchronisations since the last report; the last "
            "shown)");
  EXPECT_EQ(runner.counters().frames_inserted, 1u);  // frame 50, in its own stream
  EXPECT_EQ(runner.counters().frames_skipped, 1u);
  std::map<uint64_t, int> published;
  for (const auto& s : sink_.skeletons) ++published[s.frame_number];
  EXPECT_EQ(published.size(), 230u);
  EXPECT_EQ(published[50], 2);  // inserted, then the late packet itself
  EXPECT_EQ(sink_.skeletons.size(), 231u);
  ExpectBalanced(runner);
  // A capture that restarted with its clock: its stream goes on from where it began.
  SubjectRunner restarted(subject_, daemon_);
  RecordingSink sink;
  for (int f = 0; f < 200; ++f)
    ASSERT_FALSE(restarted.Accept(Frame(f % 120, f, ns(f)), 0, sink).has_value());
  for (int f = 0; f < 40; ++f)
    ASSERT_FALSE(restarted.Accept(Frame(f, f, 1000 + f), 0, sink).has_value());
  EXPECT_EQ(restarted.counters().restarts, 1u);
  EXPECT_EQ(restarted.counters().frames_inserted, 0u);
}

TEST_F(SubjectRunnerTest, ALongJumpAheadResynchronisesInsteadOfInsertingFrames) {
  daemon_.max_gap_frames = 10;
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 20; ++f) ASSERT_FALSE(runner.Accept(Frame(f, f, 0), 0, sink_).has_value());
  for (int f = 20; f < 40; ++f)
    ASSERT_FALSE(runner.Accept(Frame(f, 1000 + f, 0), 0, sink_).has_value());
  runner.Flush(sink_);
  EXPECT_EQ(sink_.skeletons.size(), 40u);
  EXPECT_EQ(runner.counters().frames_inserted, 0u);
  EXPECT_EQ(runner.counters().restarts, 1u);
  ExpectBalanced(runner);
}

// The same 18 lost frames are 150 ms at 120 Hz and 75 ms at 240 Hz: against a 100 ms
// max_gap_ms the first re-synchronises and the second is bridged. Counted in frames, one
// threshold meant twice as long a hole at half the rate.
TEST_F(SubjectRunnerTest, AGapIsBridgedOrResynchronisedByHowLongItLastsAtAnyRate) {
  daemon_.max_gap_s = 0.1;
  for (const double rate : {120.0, 240.0}) {
    subject_.rate_hz = rate;
    subject_.cleanup.rate_hz = rate;
    RecordingSink sink;
    SubjectRunner runner(subject_, daemon_);
    auto send = [&](int f) {
      protocol::MarkerFrameMessage m = Frame(f, static_cast<uint64_t>(f), 0);
      m.rate_hz = static_cast<float>(rate);
      return runner.Accept(m, 0, sink);
    };
    for (int f = 0; f < 20; ++f) ASSERT_FALSE(send(f).has_value());
    for (int f = 38; f < 60; ++f) ASSERT_FALSE(send(f).has_value());  // 18 lost
    runner.Flush(sink);
    EXPECT_EQ(runner.counters().frames_skipped, 18u) << rate << " Hz";
    EXPECT_EQ(runner.counters().frames_inserted, rate == 240.0 ? 18u : 0u) << rate << " Hz";
    EXPECT_EQ(runner.counters().restarts, rate == 240.0 ? 0u : 1u) << rate << " Hz";
    ExpectBalanced(runner);
  }
}

// Protocol v2: the sender's session id, not a guess from frame numbers and clocks, says
// when the capture restarted; frames that never arrived are counted.
protocol::StreamInfo Session(uint64_t id, uint8_t seconds = 0, uint8_t frames = 0) {
  protocol::StreamInfo s;
  s.session_id = id;
  s.rate_numerator = 120;
  s.rate_denominator = 1;
  s.has_timecode = true;
  s.timecode.hours = 1;
  s.timecode.seconds = seconds;
  s.timecode.frames = frames;
  s.timecode.rate = 30;
  return s;
}

TEST_F(SubjectRunnerTest, ANewSessionRestartsTheSubjectEvenWhenItsFrameNumbersGoOn) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 30; ++f) {
    protocol::MarkerFrameMessage m = Frame(f, static_cast<uint64_t>(f), 1000 + f);
    m.stream = Session(7);
    ASSERT_FALSE(runner.Accept(m, 0, sink_).has_value());
  }
  // The capture restarted and its new session numbers frames from where the old one was:
  // the numbers alone would have joined the two takes as one.
  for (int f = 30; f < 60; ++f) {
    protocol::MarkerFrameMessage m = Frame(f, static_cast<uint64_t>(f), 1000 + f);
    m.stream = Session(8);
    ASSERT_FALSE(runner.Accept(m, 0, sink_).has_value());
  }
  runner.Flush(sink_);
  EXPECT_EQ(runner.counters().session_changes, 1u);
  EXPECT_EQ(runner.counters().restarts, 1u);
  EXPECT_EQ(RestartLine(runner, 1),
            "subject 'actor1': capture restart or jump in frame numbers, frame 29 (session 7) "
            "-> 30 (session 8); pipeline re-synchronised");
  EXPECT_EQ(runner.counters().frames_skipped, 0u);
  ASSERT_EQ(sink_.skeletons.size(), 60u);
  EXPECT_EQ(sink_.skeletons[29].stream.session_id, 7u);
  EXPECT_EQ(sink_.skeletons[30].stream.session_id, 8u);
  EXPECT_EQ(runner.counters().last_stream.session_id, 8u);
  ExpectBalanced(runner);
}

TEST_F(SubjectRunnerTest, WithinASessionALateFrameIsOutOfOrderNeverARestart) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 200; ++f) {
    protocol::MarkerFrameMessage m = Frame(f % 200, static_cast<uint64_t>(f), 1000 + f);
    m.stream = Session(7);
    ASSERT_FALSE(runner.Accept(m, 0, sink_).has_value());
  }
  // Far back and stamped later: without a session (v1) this reads as a restart.
  protocol::MarkerFrameMessage late = Frame(10, 10, 5000);
  late.stream = Session(7);
  EXPECT_EQ(runner.Accept(late, 0, sink_), DropReason::kOutOfOrder);
  protocol::MarkerFrameMessage v1 = Frame(10, 10, 5000);
  EXPECT_FALSE(runner.Accept(v1, 0, sink_).has_value());  // session 0: a new capture
  EXPECT_EQ(runner.counters().restarts, 1u);
  ExpectBalanced(runner);
}

TEST_F(SubjectRunnerTest, FramesThatFailedToDecodeAreNotCountedAgainAsSkipped) {
  SubjectRunner runner(subject_, daemon_);
  auto frame = [&](int f) {
    protocol::MarkerFrameMessage m = Frame(f, static_cast<uint64_t>(f), 1000 + f);
    m.stream = Session(7);
    return m;
  };
  for (int f = 0; f < 20; ++f) ASSERT_FALSE(runner.Accept(frame(f), 0, sink_).has_value());
  // 20 and 21 arrive with a NaN in a valid marker: decoded as far as their numbers.
  protocol::MarkerFrameMessage partial;
  for (int f : {20, 21}) {
    std::vector<uint8_t> bytes;
    protocol::EncodeMarkerFrame(frame(f), &bytes);
    const float nan = std::nanf("");
    std::memcpy(&bytes[bytes.size() - 13], &nan, 4);
    bytes.back() = 1;
    ASSERT_EQ(protocol::DecodeMarkerFrame(bytes, &partial), protocol::DecodeStatus::kNonFinite);
    EXPECT_EQ(partial.frame_number, static_cast<uint64_t>(f));
    EXPECT_EQ(runner.Drop(partial, DropReason::kNonFinite, 0), DropReason::kNonFinite);
  }
  // 22's exact rate contradicts its float rate: malformed, read as far as its number.
  protocol::MarkerFrameMessage contradicting = frame(22);
  contradicting.stream.rate_numerator = 120000;
  contradicting.stream.rate_denominator = 1001;
  std::vector<uint8_t> bytes;
  protocol::EncodeMarkerFrame(contradicting, &bytes);
  ASSERT_EQ(protocol::DecodeMarkerFrame(bytes, &partial), protocol::DecodeStatus::kBadField);
  EXPECT_EQ(runner.Drop(partial, DropReason::kMalformed, 0), DropReason::kMalformed);
  // 23 one byte too long, 24 claiming more markers than any frame may carry: neither's
  // stream block is read, but their session id is (they were counted as skipped too).
  protocol::EncodeMarkerFrame(frame(23), &bytes);
  bytes.push_back(0);
  const auto payload = static_cast<uint32_t>(bytes.size() - protocol::kHeaderBytes);
  std::memcpy(&bytes[8], &payload, 4);  // the header's payload length, as a sender would
  ASSERT_EQ(protocol::DecodeMarkerFrame(bytes, &partial), protocol::DecodeStatus::kSizeMismatch);
  EXPECT_EQ(partial.stream.session_id, 7u);
  EXPECT_EQ(runner.Drop(partial, DropReason::kMalformed, 0), DropReason::kMalformed);
  protocol::EncodeMarkerFrame(frame(24), &bytes);
  // The count sits before a reserved u16, the stream block and 13 bytes per marker.
  const size_t count_offset =
      bytes.size() - 13 * frame(24).positions.size() - protocol::kStreamBlockBytes - 4;
  const uint16_t too_many = 0xffff;
  std::memcpy(&bytes[count_offset], &too_many, 2);
  ASSERT_EQ(protocol::DecodeMarkerFrame(bytes, &partial), protocol::DecodeStatus::kTooManyItems);
  EXPECT_EQ(partial.stream.session_id, 7u);
  EXPECT_EQ(runner.Drop(partial, DropReason::kMalformed, 0), DropReason::kMalformed);
  for (int f = 25; f < 40; ++f) ASSERT_FALSE(runner.Accept(frame(f), 0, sink_).has_value());
  runner.Flush(sink_);
  EXPECT_EQ(runner.counters().dropped[static_cast<size_t>(DropReason::kNonFinite)], 2u);
  EXPECT_EQ(runner.counters().dropped[static_cast<size_t>(DropReason::kMalformed)], 3u);
  EXPECT_EQ(runner.counters().frames_inserted, 5u);
  EXPECT_EQ(runner.counters().frames_skipped, 0u);  // each was counted once, as dropped
  ExpectBalanced(runner);
}

// Two v1 bridges sending one subject, the second 100 frames ahead, both stamping the
// capture's clock: each forward jump is in numbers only. Bridged, 99 frames were inserted
// for each of the second bridge's frames (50 times the capture rate published) and
// counted as skipped; /health said ok.
TEST_F(SubjectRunnerTest, TwoBridgesOnOneSubjectInsertNothingAndAreFlaggedUnstable) {
  SubjectRunner runner(subject_, daemon_);
  const auto ns = [](int f) { return 1'000'000'000ull + 8'333'333ull * static_cast<uint64_t>(f); };
  int64_t receive_ns = 0;
  const auto step = int64_t{8'333'333};
  for (int f = 0; f < 30; ++f, receive_ns += step)
    ASSERT_FALSE(runner.Accept(Frame(f, f, ns(f)), receive_ns, sink_).has_value());
  EXPECT_FALSE(runner.unstable_input(receive_ns));
  for (int f = 30; f < 90; ++f, receive_ns += step) {
    runner.Accept(Frame(f, f, ns(f)), receive_ns, sink_);
    runner.Accept(Frame(f, f + 100, ns(f)), receive_ns + 1000, sink_);
  }
  EXPECT_EQ(runner.counters().frames_inserted, 0u);
  EXPECT_EQ(runner.counters().frames_skipped, 0u);
  EXPECT_GT(runner.counters().restarts, 100u);
  EXPECT_TRUE(runner.unstable_input(receive_ns));
  // Two seconds without a restart: stable again.
  for (int f = 90; f < 400; ++f, receive_ns += step)
    ASSERT_FALSE(runner.Accept(Frame(f % 120, f + 100, ns(f)), receive_ns, sink_).has_value());
  EXPECT_FALSE(runner.unstable_input(receive_ns));
  runner.Flush(sink_);
  ExpectBalanced(runner);
  // Both bridges from the first frame on: no consecutive frames to judge the clock by.
  SubjectRunner from_start(subject_, daemon_);
  RecordingSink sink_from_start;
  for (int f = 0; f < 60; ++f) {
    from_start.Accept(Frame(f, f, ns(f)), 0, sink_from_start);
    from_start.Accept(Frame(f, f + 100, ns(f)), 0, sink_from_start);
  }
  EXPECT_EQ(from_start.counters().frames_inserted, 0u);
  EXPECT_EQ(from_start.counters().frames_skipped, 0u);
  // The second bridge joins at the fourth frame, before eight pairs could vouch for the
  // clock: each pair seen had stepped a frame, so the clock is trusted already (99 frames
  // were inserted for the bridge's first frame and the other's then dropped out of order).
  for (int joins_after : {1, 4, 8}) {
    SubjectRunner early(subject_, daemon_);
    RecordingSink sink_early;
    for (int f = 0; f < joins_after; ++f)
      ASSERT_FALSE(early.Accept(Frame(f, f, ns(f)), 0, sink_early).has_value());
    for (int f = joins_after; f < 60; ++f) {
      early.Accept(Frame(f, f, ns(f)), 0, sink_early);
      early.Accept(Frame(f, f + 100, ns(f)), 0, sink_early);
    }
    EXPECT_EQ(early.counters().frames_inserted, 0u) << "joined after " << joins_after;
    EXPECT_EQ(early.counters().frames_skipped, 0u) << "joined after " << joins_after;
    EXPECT_EQ(early.counters().dropped[static_cast<size_t>(DropReason::kOutOfOrder)], 0u)
        << "joined after " << joins_after;
  }
  // The second bridge stamps a moment before the first: a clock gone back shares no jump.
  SubjectRunner lagging(subject_, daemon_);
  for (int f = 0; f < 60; ++f) {
    lagging.Accept(Frame(f, f, ns(f)), 0, sink_from_start);
    lagging.Accept(Frame(f, f + 100, ns(f) - 1000), 0, sink_from_start);
  }
  EXPECT_EQ(lagging.counters().frames_inserted, 0u);
  EXPECT_EQ(lagging.counters().frames_skipped, 0u);
  // The bridge ahead arrives first: the other's frames are out of order, half the input
  // dropped with no restart at all, and that is unstable too.
  SubjectRunner ahead_first(subject_, daemon_);
  int64_t receive = 0;
  for (int f = 0; f < 30; ++f, receive += 8'333'333) {
    ahead_first.Accept(Frame(f, f + 100, ns(f)), receive, sink_from_start);
    ahead_first.Accept(Frame(f, f, ns(f)), receive + 1000, sink_from_start);
  }
  EXPECT_EQ(ahead_first.counters().dropped[static_cast<size_t>(DropReason::kOutOfOrder)], 30u);
  EXPECT_TRUE(ahead_first.unstable_input(receive));
  // A clock in microseconds, not nanoseconds: it does not step a frame period, so it is not
  // judged, and a real loss is bridged.
  SubjectRunner other_units(subject_, daemon_);
  for (int f = 0; f < 60; ++f) {
    if (f >= 20 && f < 25) continue;
    ASSERT_FALSE(other_units.Accept(Frame(f, f, ns(f) / 1000), 0, sink_from_start).has_value());
  }
  EXPECT_EQ(other_units.counters().frames_inserted, 5u);
  EXPECT_EQ(other_units.counters().restarts, 0u);
  // One bridge losing frames, its clock going on with them: still bridged and counted.
  SubjectRunner lossy(subject_, daemon_);
  RecordingSink sink;
  for (int f = 0; f < 60; ++f)
    if (f < 20 || f >= 25) {
      ASSERT_FALSE(lossy.Accept(Frame(f, f, ns(f)), 0, sink).has_value());
    }
  EXPECT_EQ(lossy.counters().frames_inserted, 5u);
  EXPECT_EQ(lossy.counters().frames_skipped, 5u);
  EXPECT_EQ(lossy.counters().restarts, 0u);
}

// A bridge whose every marker is flagged invalid (its valid bit inverted): the subject is
// lost frame after frame, and /health said ok. Lost for half a second, it is a problem;
// a few frames (an actor occluded for a moment) are not.
TEST_F(SubjectRunnerTest, NoMarkerObservedForHalfASecondMakesHealthDegraded) {
  SubjectRunner runner(subject_, daemon_);
  int64_t receive_ns = 0;
  for (int f = 0; f < 30; ++f, receive_ns += 8'333'333)
    ASSERT_FALSE(runner.Accept(Frame(f, f, 0), receive_ns, sink_).has_value());
  EXPECT_LT(runner.unobserved_since_ns(), 0);
  for (int f = 30; f < 150; ++f, receive_ns += 8'333'333) {
    protocol::MarkerFrameMessage m = Frame(f, f, 0);
    std::fill(m.valid.begin(), m.valid.end(), uint8_t{0});
    std::fill(m.positions.begin(), m.positions.end(), Vec3::Constant(kNaN));  // as decoded
    ASSERT_FALSE(runner.Accept(m, receive_ns, sink_).has_value());
  }
  // Published K frames behind: the first unobserved frame out was triggered by frame 30 + K.
  const int64_t lookahead = subject_.cleanup.lookahead;
  EXPECT_EQ(runner.unobserved_since_ns(), (30 + lookahead) * 8'333'333) << lookahead;
  const auto health_of = [](double unobserved_for_s) {
    SubjectStats stats;
    stats.name = "actor1";
    stats.state = protocol::SubjectState::kRepairing;
    stats.unobserved_for_s = unobserved_for_s;
    DaemonStats daemon_stats;
    daemon_stats.subjects.push_back(stats);
    return FormatHealthJson(daemon_stats, true);
  };
  EXPECT_NE(health_of(0.3).find("\"ok\""), std::string::npos) << health_of(0.3);
  EXPECT_NE(health_of(0.6).find("\"degraded\""), std::string::npos) << health_of(0.6);
  EXPECT_NE(health_of(0.6).find("subject 'actor1': no marker observed for 0.6 s"),
            std::string::npos);
  // Markers again: observed once the lookahead has passed them out.
  for (int f = 150; f < 180; ++f, receive_ns += 8'333'333)
    ASSERT_FALSE(runner.Accept(Frame(f, f, 0), receive_ns, sink_).has_value());
  EXPECT_LT(runner.unobserved_since_ns(), 0);
  // The actor leaves the volume, then the take ends: nothing is guessed while the subject
  // waits (it held /health degraded, the seconds growing, after the take had ended).
  for (int f = 180; f < 300; ++f, receive_ns += 8'333'333) {
    protocol::MarkerFrameMessage m = Frame(f % 200, f, 0);  // the fixture holds 240 frames
    std::fill(m.valid.begin(), m.valid.end(), uint8_t{0});
    std::fill(m.positions.begin(), m.positions.end(), Vec3::Constant(kNaN));
    ASSERT_FALSE(runner.Accept(m, receive_ns, sink_).has_value());
  }
  EXPECT_GE(runner.unobserved_since_ns(), 0);
  runner.EndOfStream(sink_);
  EXPECT_LT(runner.unobserved_since_ns(), 0);
  // The next take, minutes later: its first frames are not "unobserved for" those minutes.
  receive_ns += 300'000'000'000;
  for (int f = 0; f < 30; ++f, receive_ns += 8'333'333)
    ASSERT_FALSE(runner.Accept(Frame(f, f, 0), receive_ns, sink_).has_value());
  EXPECT_LT(runner.unobserved_since_ns(), 0);
}

// A bridge writing a new session id into every frame restarts the subject at every frame:
// the cleanup never had its lookahead, and nothing said so but the log.
TEST_F(SubjectRunnerTest, ASessionIdPerFrameIsFlaggedUnstableOnTheWireToo) {
  SubjectRunner runner(subject_, daemon_);
  int64_t receive_ns = 0;
  for (int f = 0; f < 20; ++f, receive_ns += 8'333'333) {
    protocol::MarkerFrameMessage m = Frame(f, f, 0);
    m.stream = Session(static_cast<uint64_t>(1000 + f));
    ASSERT_FALSE(runner.Accept(m, receive_ns, sink_).has_value());
  }
  EXPECT_EQ(runner.counters().session_changes, 19u);
  EXPECT_TRUE(runner.unstable_input(receive_ns));
  runner.PublishStatus(receive_ns, sink_);
  ASSERT_FALSE(sink_.statuses.empty());
  EXPECT_NE(sink_.statuses.back().problems & protocol::kProblemUnstableInput, 0);
  SubjectStats stats;
  stats.name = "actor1";
  stats.unstable_input = true;
  DaemonStats daemon_stats;
  daemon_stats.subjects.push_back(stats);
  const std::string health = FormatHealthJson(daemon_stats, true);
  EXPECT_NE(health.find("\"degraded\""), std::string::npos) << health;
  EXPECT_NE(health.find("subject 'actor1': input unstable"), std::string::npos) << health;
}

// Frame numbers are serial numbers: a stream that loses frames as it wraps past 2^64 - 1
// goes on (compared as plain numbers, every later frame was dropped as out of order).
TEST_F(SubjectRunnerTest, AStreamThatWrapsPastTheLargestFrameNumberGoesOn) {
  SubjectRunner runner(subject_, daemon_);
  const uint64_t last = std::numeric_limits<uint64_t>::max();
  std::vector<uint64_t> numbers;
  for (uint64_t k = 0; k < 40; ++k) numbers.push_back(last - 19 + k);  // wraps to 0 at k = 20
  for (size_t k = 0; k < numbers.size(); ++k) {
    if (k == 18 || k == 19 || k == 20) continue;  // last - 1, last and 0 lost
    protocol::MarkerFrameMessage m = Frame(static_cast<int>(k), numbers[k], 0);
    m.stream = Session(7);
    ASSERT_FALSE(runner.Accept(m, 0, sink_).has_value()) << k;
  }
  protocol::MarkerFrameMessage late = Frame(0, last - 5, 0);  // behind, across the wrap
  late.stream = Session(7);
  EXPECT_EQ(runner.Accept(late, 0, sink_), DropReason::kOutOfOrder);
  runner.Flush(sink_);
  EXPECT_EQ(runner.counters().frames_inserted, 3u);
  EXPECT_EQ(runner.counters().frames_skipped, 3u);
  EXPECT_EQ(runner.counters().restarts, 0u);
  EXPECT_EQ(sink_.skeletons.size(), 40u);
  ExpectBalanced(runner);
}

TEST_F(SubjectRunnerTest, FrameNumbersThatNeverArrivedAreCountedAsSkipped) {
  daemon_.max_gap_frames = 10;
  SubjectRunner runner(subject_, daemon_);
  auto send = [&](int f) {
    protocol::MarkerFrameMessage m = Frame(f, static_cast<uint64_t>(f), 1000 + f);
    m.stream = Session(7);
    return runner.Accept(m, 0, sink_);
  };
  for (int f = 0; f < 20; ++f) ASSERT_FALSE(send(f).has_value());
  for (int f = 25; f < 40; ++f) ASSERT_FALSE(send(f).has_value());    // 5 lost: bridged
  for (int f = 100; f < 120; ++f) ASSERT_FALSE(send(f).has_value());  // 60 lost: too long
  runner.Flush(sink_);
  EXPECT_EQ(runner.counters().frames_skipped, 65u);
  EXPECT_EQ(runner.counters().frames_inserted, 5u);
  EXPECT_EQ(runner.counters().restarts, 1u);
  ExpectBalanced(runner);
}

TEST_F(SubjectRunnerTest, OutputsCarryTheSessionAndTimecodeOfTheirFrame) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 40; ++f) {
    if (f == 20) continue;  // one lost: inserted, with the session but no timecode
    protocol::MarkerFrameMessage m = Frame(f, static_cast<uint64_t>(f), 1000 + f);
    m.stream = Session(99, static_cast<uint8_t>(f / 4 / 30), static_cast<uint8_t>(f / 4 % 30));
    m.stream.timecode.subframe = static_cast<uint8_t>(f % 4);
    ASSERT_FALSE(runner.Accept(m, 0, sink_).has_value());
  }
  runner.Flush(sink_);
  ASSERT_EQ(sink_.skeletons.size(), 40u);
  ASSERT_EQ(sink_.cleaned.size(), 40u);
  for (int f = 0; f < 40; ++f) {
    const auto& skeleton = sink_.skeletons[static_cast<size_t>(f)];
    const auto& cleaned = sink_.cleaned[static_cast<size_t>(f)];
    EXPECT_EQ(skeleton.version, protocol::kVersion2);
    EXPECT_EQ(skeleton.stream.session_id, 99u);
    EXPECT_EQ(cleaned.stream, skeleton.stream);
    if (f == 20) {
      EXPECT_FALSE(skeleton.stream.has_timecode);
      continue;
    }
    ASSERT_TRUE(skeleton.stream.has_timecode);
    EXPECT_EQ(skeleton.stream.timecode.frames, f / 4 % 30);
    EXPECT_EQ(skeleton.stream.timecode.subframe, f % 4);
    EXPECT_EQ(skeleton.stream.rate_numerator, 120u);
  }
}

TEST_F(SubjectRunnerTest, ProtocolVersionOneOutputForOlderConsumers) {
  daemon_.output_protocol_version = 1;
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 10; ++f) {
    protocol::MarkerFrameMessage m = Frame(f, static_cast<uint64_t>(f), 1000 + f);
    m.stream = Session(5);
    ASSERT_FALSE(runner.Accept(m, 0, sink_).has_value());
  }
  runner.Flush(sink_);
  runner.PublishStatus(0, sink_);
  ASSERT_EQ(sink_.skeletons.size(), 10u);
  for (const auto& skeleton : sink_.skeletons) {
    EXPECT_EQ(skeleton.version, protocol::kVersion1);
    EXPECT_EQ(skeleton.stream, protocol::StreamInfo{});  // v1 has no stream block
  }
  EXPECT_EQ(sink_.cleaned.front().version, protocol::kVersion1);
  EXPECT_EQ(sink_.statuses.back().version, protocol::kVersion1);
}

TEST_F(SubjectRunnerTest, WatchdogMarksAStalledSubjectOnceAndPublishesIt) {
  SubjectRunner runner(subject_, daemon_);
  EXPECT_FALSE(runner.CheckStall(10'000'000'000, 500'000'000,
                                 sink_));  // nothing received yet: waiting, not stalled
  EXPECT_EQ(runner.state(), protocol::SubjectState::kWaiting);
  ASSERT_FALSE(runner.Accept(Frame(0, 0, 0), 1'000'000'000, sink_).has_value());
  EXPECT_FALSE(runner.CheckStall(1'400'000'000, 500'000'000, sink_));
  EXPECT_TRUE(runner.CheckStall(1'600'000'000, 500'000'000, sink_));
  EXPECT_FALSE(runner.CheckStall(1'700'000'000, 500'000'000, sink_));
  ASSERT_EQ(sink_.statuses.size(), 1u);
  EXPECT_EQ(sink_.statuses[0].state, protocol::SubjectState::kStalled);
  EXPECT_EQ(sink_.statuses[0].since_last_input_ns, 600'000'000u);
  EXPECT_EQ(runner.counters().stalls, 1u);
  ASSERT_FALSE(runner.Accept(Frame(1, 1, 0), 1'800'000'000, sink_).has_value());
  EXPECT_NE(runner.state(), protocol::SubjectState::kStalled);
  // What the log reports, as it was at the stall and at its end: read a second later,
  // the snapshot's last frame number and silence were of another moment ("no frame for
  // 0.00 s, last frame 140" for a stall after frame 100).
  ASSERT_FALSE(runner.Accept(Frame(2, 2, 0), 1'810'000'000, sink_).has_value());
  EXPECT_DOUBLE_EQ(runner.counters().stall_silence_s, 0.6);
  EXPECT_EQ(runner.counters().stall_last_frame, 0u);
  EXPECT_EQ(runner.counters().resumes, 1u);
  EXPECT_EQ(runner.counters().resume_frame, 1u);
  EXPECT_DOUBLE_EQ(runner.counters().resume_silence_s, 0.8);
  EXPECT_EQ(runner.counters().last_frame_number, 2u);
  // A stall ended by a frame past a gap, the gap bridged: its publishing set the state
  // before the stall's end was counted, and the log never said the input resumed.
  EXPECT_TRUE(runner.CheckStall(2'500'000'000, 500'000'000, sink_));
  ASSERT_FALSE(runner.Accept(Frame(3, 40, 0), 3'000'000'000, sink_).has_value());
  EXPECT_EQ(runner.counters().frames_inserted, 37u);
  EXPECT_EQ(runner.counters().resumes, 2u);
  EXPECT_EQ(runner.counters().resume_frame, 40u);
  EXPECT_DOUBLE_EQ(runner.counters().resume_silence_s, 1.19);
}

// A reload that changes a subject rebuilds its runner. Rebuilt as waiting with no input
// time, a stalled subject read ok in /health while its sender was still dead, and one whose
// sender died just before the reload was never watched for a stall.
TEST_F(SubjectRunnerTest, ARebuiltSubjectKeepsItsStallAndIsWatchedForOne) {
  SubjectRunner stalled(subject_, daemon_);
  ASSERT_FALSE(stalled.Accept(Frame(0, 0, 0), 1'000'000'000, sink_).has_value());
  ASSERT_TRUE(stalled.CheckStall(2'000'000'000, 500'000'000, sink_));
  SubjectRunner rebuilt(subject_, daemon_);
  rebuilt.InheritCounters(stalled);
  EXPECT_EQ(rebuilt.state(), protocol::SubjectState::kStalled);
  EXPECT_EQ(rebuilt.counters().stalls, 1u);
  ASSERT_FALSE(rebuilt.Accept(Frame(1, 1, 0), 3'000'000'000, sink_).has_value());
  EXPECT_EQ(rebuilt.counters().resumes, 1u);  // the log says the input resumed

  SubjectRunner live(subject_, daemon_);
  ASSERT_FALSE(live.Accept(Frame(0, 0, 0), 1'000'000'000, sink_).has_value());
  SubjectRunner rebuilt_live(subject_, daemon_);
  rebuilt_live.InheritCounters(live);
  EXPECT_FALSE(rebuilt_live.CheckStall(1'400'000'000, 500'000'000, sink_));
  EXPECT_TRUE(rebuilt_live.CheckStall(1'600'000'000, 500'000'000, sink_));
  EXPECT_EQ(rebuilt_live.state(), protocol::SubjectState::kStalled);

  // A subject whose take ended stays waiting: silence is no stall.
  SubjectRunner ended(subject_, daemon_);
  ASSERT_FALSE(ended.Accept(Frame(0, 0, 0), 1'000'000'000, sink_).has_value());
  ended.EndOfStream(sink_);
  SubjectRunner rebuilt_ended(subject_, daemon_);
  rebuilt_ended.InheritCounters(ended);
  EXPECT_EQ(rebuilt_ended.state(), protocol::SubjectState::kWaiting);
  EXPECT_FALSE(rebuilt_ended.CheckStall(10'000'000'000, 500'000'000, sink_));
}

// A stalled subject must not keep its last K frames until a next stream arrives that
// may never come: the stall flushes them, and frames after it go on as usual.
TEST_F(SubjectRunnerTest, AStallPublishesTheFramesTheLookaheadHeld) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 30; ++f)
    ASSERT_FALSE(runner.Accept(Frame(f, f, 0), 1'000'000'000 + f, sink_).has_value());
  const size_t before = sink_.skeletons.size();
  ASSERT_LT(before, 30u);  // the lookahead holds the newest frames
  EXPECT_TRUE(runner.CheckStall(2'000'000'000, 500'000'000, sink_));
  ASSERT_EQ(sink_.skeletons.size(), 30u);
  EXPECT_EQ(sink_.skeletons.back().frame_number, 29u);
  EXPECT_EQ(runner.state(), protocol::SubjectState::kStalled);
  for (int f = 30; f < 60; ++f)
    ASSERT_FALSE(runner.Accept(Frame(f, f, 0), 3'000'000'000 + f, sink_).has_value());
  runner.Flush(sink_);
  ASSERT_EQ(sink_.skeletons.size(), 60u);
  for (size_t i = 0; i < 60; ++i) EXPECT_EQ(sink_.skeletons[i].frame_number, i);
  ExpectBalanced(runner);
}

// After an end of stream the subject waits for the next one: silence is not a stall, and
// /health must not turn degraded after a take replayed to its end.
TEST_F(SubjectRunnerTest, AnEndedStreamWaitsInsteadOfStalling) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 30; ++f)
    ASSERT_FALSE(runner.Accept(Frame(f, f, 0), 1'000'000'000, sink_).has_value());
  runner.EndOfStream(sink_);
  EXPECT_EQ(sink_.skeletons.size(), 30u);
  EXPECT_EQ(runner.state(), protocol::SubjectState::kWaiting);
  EXPECT_FALSE(runner.CheckStall(10'000'000'000, 500'000'000, sink_));
  EXPECT_EQ(runner.counters().stalls, 0u);
  ASSERT_FALSE(runner.Accept(Frame(0, 0, 0), 11'000'000'000, sink_).has_value());
  EXPECT_EQ(runner.state(), protocol::SubjectState::kTracking);
}

// A bridge sending another marker set: every frame is dropped, and the subject says so
// (on the wire and to /health) once half a second of frames has gone, not at the first:
// half a second of time, whatever the sender's rate (counted in the subject's frames, a
// 60 Hz sender into a 360 Hz subject was flagged after 3 s). An end of stream does not
// clear it; a frame taken does.
TEST_F(SubjectRunnerTest, ASubjectWhoseFramesAreAllDroppedIsRejectingInput) {
  SubjectRunner runner(subject_, daemon_);
  protocol::MarkerFrameMessage wrong = Frame(0, 0, 0);
  wrong.model_hash ^= 1;
  // A burst of 100 within 0.1 s is no half second.
  for (int f = 0; f < 100; ++f)
    ASSERT_TRUE(runner.Accept(wrong, int64_t{f} * 1'000'000, sink_).has_value());
  EXPECT_FALSE(runner.rejecting().has_value());
  ASSERT_FALSE(runner.Accept(Frame(0, 0, 0), 100'000'000, sink_).has_value());
  constexpr int64_t kSixtyHz = 16'666'667;
  const int64_t start = 1'000'000'000;
  for (int f = 0; f < 30; ++f)
    ASSERT_TRUE(runner.Accept(wrong, start + f * kSixtyHz, sink_).has_value());
  EXPECT_FALSE(runner.rejecting().has_value());
  ASSERT_TRUE(runner.Accept(wrong, start + 30 * kSixtyHz, sink_).has_value());
  ASSERT_TRUE(runner.rejecting().has_value());
  EXPECT_EQ(*runner.rejecting(), DropReason::kModelMismatch);
  runner.PublishStatus(start + 30 * kSixtyHz, sink_);
  ASSERT_EQ(sink_.statuses.size(), 1u);
  EXPECT_EQ(sink_.statuses[0].problems, protocol::kProblemRejectingInput);
  runner.EndOfStream(sink_);
  EXPECT_TRUE(runner.rejecting().has_value());
  ASSERT_FALSE(runner.Accept(Frame(1, 1, 0), start + 31 * kSixtyHz, sink_).has_value());
  EXPECT_FALSE(runner.rejecting().has_value());
}

// A take replayed as fast as it can go, or a backlog, arrives in a burst: a 100 Hz take
// into a 120 Hz subject, 480 frames in 48 ms, every one dropped as rate_mismatch, left
// /health ok, since no half second of arrivals was all drops. The frames' numbers at the
// rate they were sent at say how much capture was lost: 0.39 s is not flagged, 0.5 s is.
TEST_F(SubjectRunnerTest, ABurstOfDroppedFramesIsJudgedByTheCaptureTheyHold) {
  SubjectRunner runner(subject_, daemon_);
  const auto at_100_hz = [&](uint64_t number) {
    protocol::MarkerFrameMessage m = Frame(static_cast<int>(number % 200), 1000 + number, 0);
    m.rate_hz = 100.0f;
    return m;
  };
  for (uint64_t n = 0; n < 40; ++n)
    ASSERT_TRUE(runner.Accept(at_100_hz(n), 1'000'000 + static_cast<int64_t>(n) * 100'000, sink_)
                    .has_value());
  EXPECT_FALSE(runner.rejecting().has_value());
  for (uint64_t n = 40; n < 480; ++n)
    ASSERT_TRUE(runner.Accept(at_100_hz(n), 1'000'000 + static_cast<int64_t>(n) * 100'000, sink_)
                    .has_value());
  ASSERT_TRUE(runner.rejecting().has_value());
  EXPECT_EQ(*runner.rejecting(), DropReason::kRateMismatch);
  runner.PublishStatus(50'000'000, sink_);
  ASSERT_FALSE(sink_.statuses.empty());
  EXPECT_EQ(sink_.statuses.back().problems, protocol::kProblemRejectingInput);
  // Numbers that do not move (a sender that never counts) are judged by arrival alone.
  SubjectRunner unnumbered(subject_, daemon_);
  for (int f = 0; f < 480; ++f)
    ASSERT_TRUE(unnumbered.Accept(at_100_hz(0), int64_t{f} * 100'000, sink_).has_value());
  EXPECT_FALSE(unnumbered.rejecting().has_value());
}

// Two bridges with different marker orders taking turns every 30 frames at 120 Hz: half
// the input dropped as model_mismatch, and never half a second of nothing but drops, so
// never rejecting: /health said ok. Each switch between frames taken and frames dropped is
// an unstable event. A frame dropped now and then (less often than once a second) is
// flagged by nothing but its count.
TEST_F(SubjectRunnerTest, InputSwitchingBetweenTakenAndDroppedFramesIsFlaggedUnstable) {
  constexpr int64_t kPeriod = 8'333'333;
  SubjectRunner runner(subject_, daemon_);
  int64_t receive_ns = 0;
  uint64_t number = 0;
  for (int block = 0; block < 8; ++block)
    for (int f = 0; f < 30; ++f, ++number, receive_ns += kPeriod) {
      protocol::MarkerFrameMessage m = Frame(static_cast<int>(number % 200), number, 0);
      if (block % 2 == 1) m.model_hash ^= 1;
      runner.Accept(m, receive_ns, sink_);
    }
  EXPECT_FALSE(runner.rejecting().has_value());
  EXPECT_TRUE(runner.unstable_input(receive_ns));
  EXPECT_EQ(runner.counters().dropped[static_cast<size_t>(DropReason::kModelMismatch)], 120u);
  EXPECT_EQ(runner.unstable_cause(),
            (UnstableCause{UnstableCause::Kind::kTakenAndDropped, DropReason::kModelMismatch}));
  runner.PublishStatus(receive_ns, sink_);
  ASSERT_FALSE(sink_.statuses.empty());
  EXPECT_EQ(sink_.statuses.back().problems, protocol::kProblemUnstableInput);
  // Clears once 2 s pass with every frame taken.
  for (int f = 0; f < 300; ++f, ++number, receive_ns += kPeriod)
    runner.Accept(Frame(static_cast<int>(number % 200), number, 0), receive_ns, sink_);
  EXPECT_FALSE(runner.unstable_input(receive_ns));

  SubjectRunner now_and_then(subject_, daemon_);
  RecordingSink now_and_then_sink;
  receive_ns = 0;
  for (uint64_t n = 0; n < 1200; ++n, receive_ns += kPeriod) {
    protocol::MarkerFrameMessage m = Frame(static_cast<int>(n % 200), n, 0);
    if (n % 150 == 60) m.model_hash ^= 1;  // every 1.25 s
    now_and_then.Accept(m, receive_ns, now_and_then_sink);
    EXPECT_FALSE(now_and_then.unstable_input(receive_ns)) << n;
  }
  EXPECT_EQ(now_and_then.counters().dropped[static_cast<size_t>(DropReason::kModelMismatch)], 8u);
}

// A third bridge naming its actor "Actor3" for "actor3": a subscribing daemon never sees its
// frames, actor3 read "waiting" like a take that ended, and /health said ok while the other
// actors streamed.
TEST(DaemonHealthTest, AConfiguredSubjectSilentWhileOthersStreamIsAProblem) {
  DaemonStats stats;
  SubjectStats streaming;
  streaming.name = "actor1";
  streaming.rate_hz = 120.0;
  streaming.counters.frames_in = 600;
  streaming.since_last_input_s = 0.01;
  SubjectStats silent;
  silent.name = "actor3";
  silent.rate_hz = 120.0;
  stats.subjects = {streaming, silent};
  std::string health = FormatHealthJson(stats, true);
  EXPECT_NE(health.find("\"degraded\""), std::string::npos) << health;
  EXPECT_NE(health.find("subject 'actor3': no frame received while other subjects stream"),
            std::string::npos)
      << health;
  EXPECT_EQ(health.find("subject 'actor1'"), std::string::npos) << health;
  stats.last_unknown_subject = "Actor3";
  health = FormatHealthJson(stats, true);
  EXPECT_NE(health.find("the last unknown name received: 'Actor3'"), std::string::npos) << health;
  // Not while the others have streamed under two seconds, nor once they stopped: a stage
  // whose actors start one after another, or a day's takes ended.
  stats.subjects[0].counters.frames_in = 100;
  EXPECT_NE(FormatHealthJson(stats, true).find("\"ok\""), std::string::npos);
  stats.subjects[0].counters.frames_in = 600;
  stats.subjects[0].since_last_input_s = 5.0;
  EXPECT_NE(FormatHealthJson(stats, true).find("\"ok\""), std::string::npos);
}

// A sender writing NaN into every 20th frame at 120 Hz: flagged unstable, as it should be,
// but /health and the log asked "two senders for one subject?" and named no NaN.
TEST_F(SubjectRunnerTest, UnstableInputNamesWhatItsEventsMostlyWere) {
  constexpr int64_t kPeriod = 8'333'333;
  SubjectRunner runner(subject_, daemon_);
  int64_t receive_ns = 0;
  for (uint64_t n = 0; n < 360; ++n, receive_ns += kPeriod) {
    const protocol::MarkerFrameMessage m = Frame(static_cast<int>(n % 200), n, 0);
    if (n % 20 == 10)
      runner.Drop(m, DropReason::kNonFinite, receive_ns);
    else
      runner.Accept(m, receive_ns, sink_);
  }
  ASSERT_TRUE(runner.unstable_input(receive_ns));
  EXPECT_EQ(runner.unstable_cause(),
            (UnstableCause{UnstableCause::Kind::kTakenAndDropped, DropReason::kNonFinite}));
  SubjectStats stats;
  stats.name = "actor1";
  stats.unstable_input = true;
  stats.unstable_cause = runner.unstable_cause();
  DaemonStats daemon_stats;
  daemon_stats.subjects.push_back(stats);
  const std::string health = FormatHealthJson(daemon_stats, true);
  EXPECT_NE(health.find("mostly frames dropped as non_finite between frames taken"),
            std::string::npos)
      << health;
  EXPECT_NE(health.find("NaN"), std::string::npos) << health;
  EXPECT_EQ(health.find("two senders"), std::string::npos) << health;

  // A new session id in every frame: re-synchronisations, and the hint is the session id.
  SubjectRunner per_frame(subject_, daemon_);
  receive_ns = 0;
  for (int f = 0; f < 20; ++f, receive_ns += kPeriod) {
    protocol::MarkerFrameMessage m = Frame(f, f, 0);
    m.stream = Session(static_cast<uint64_t>(1000 + f));
    per_frame.Accept(m, receive_ns, sink_);
  }
  ASSERT_TRUE(per_frame.unstable_input(receive_ns));
  stats.unstable_cause = per_frame.unstable_cause();
  EXPECT_EQ(stats.unstable_cause.kind, UnstableCause::Kind::kResynchronisation);
  EXPECT_NE(UnstableInputText(stats).find("a session id that changes every frame"),
            std::string::npos);

  // Every frame sent twice: repeated frames.
  SubjectRunner twice(subject_, daemon_);
  receive_ns = 0;
  for (int f = 0; f < 20; ++f, receive_ns += kPeriod) {
    twice.Accept(Frame(f, f, 0), receive_ns, sink_);
    twice.Accept(Frame(f, f, 0), receive_ns + 1000, sink_);
  }
  ASSERT_TRUE(twice.unstable_input(receive_ns));
  EXPECT_EQ(twice.unstable_cause(),
            (UnstableCause{UnstableCause::Kind::kRepeatedFrame, DropReason::kDuplicate}));
}

// The model's marker names match the bridge's, so every frame is accepted, but its bones
// are 1.5 or 1.1 times too long (a 1.93 m actor's model on a 1.75 m actor): the received
// markers sit far from it, and it is flagged. The actor's own model, fed the same frames,
// is not. At 1.1 the median distance (15 mm) was under the 20 mm that flags; the distance
// two thirds of the samples come within is 30 mm.
TEST_F(SubjectRunnerTest, AModelAtTheWrongScaleIsFlaggedSuspect) {
  const auto run = [&](const SubjectConfig& subject) {
    SubjectRunner runner(subject, daemon_);
    for (int f = 0; f < 240; ++f) EXPECT_FALSE(runner.Accept(Frame(f, f, 0), 0, sink_).has_value());
    runner.PublishStatus(0, sink_);
    return std::make_pair(runner.model_suspect(), runner.model_distance_m());
  };
  const auto [own_suspect, own_distance] = run(subject_);
  EXPECT_FALSE(own_suspect);
  EXPECT_LT(own_distance, 0.005);
  EXPECT_EQ(sink_.statuses.back().problems, 0);

  for (const double scale : {1.5, 1.1}) {
    SubjectConfig scaled = subject_;
    auto skeleton = std::make_shared<const Skeleton>(MakeHumanoidSkeleton(1.75 * scale));
    scaled.model.markers = std::make_shared<const MarkerSet>(
        *skeleton,
        PlaceMarkers(*skeleton, MatchHumanoidRoles(*skeleton), DefaultMarkerLayout(), {}));
    scaled.model.skeleton = skeleton;
    ASSERT_EQ(protocol::MarkerSetHash(*scaled.model.markers),
              protocol::MarkerSetHash(*subject_.model.markers));
    const auto [scaled_suspect, scaled_distance] = run(scaled);
    EXPECT_TRUE(scaled_suspect) << scale << "x: " << scaled_distance;
    EXPECT_GT(scaled_distance, 0.02) << scale << "x";
    EXPECT_EQ(sink_.statuses.back().problems, protocol::kProblemModelSuspect) << scale << "x";
  }
}

// One frame whose every marker reads 10 m or 1 km off (a broken frame), or 1e30: the ingest
// gates take it as missing, and the model's fit must not count it. Counted, the subject
// was "model suspect" for 5 s with a distance of 13 m (or 1e28 mm) decaying.
TEST_F(SubjectRunnerTest, AGlitchFrameDoesNotMakeTheModelSuspect) {
  for (const double glitch : {10.0, 1000.0, 1e30}) {
    SubjectRunner runner(subject_, daemon_);
    double worst = 0.0;
    for (int f = 0; f < 240; ++f) {
      protocol::MarkerFrameMessage m = Frame(f, static_cast<uint64_t>(f), 0);
      if (f == 120)
        for (Vec3& p : m.positions) p += Vec3::Constant(glitch);
      EXPECT_FALSE(runner.Accept(m, 0, sink_).has_value());
      worst = std::max(worst, runner.model_distance_m());
      EXPECT_FALSE(runner.model_suspect()) << glitch << " frame " << f;
    }
    EXPECT_LT(worst, 0.005) << glitch;
  }
}

TEST_F(SubjectRunnerTest, SteadyStateAcceptAllocatesNothing) {
  SubjectRunner runner(subject_, daemon_);
  for (int f = 0; f < 40; ++f) ASSERT_FALSE(runner.Accept(Frame(f, f, 0), 0, sink_).has_value());
  const std::vector<protocol::MarkerFrameMessage> frames = Frames(40, 80);
  NullSink null_sink;
  testing::ScopedAllocationCounter counter;
  for (const auto& frame : frames) ASSERT_FALSE(runner.Accept(frame, 0, null_sink).has_value());
  EXPECT_EQ(counter.count(), 0u);
}

// The live view's copy: none while nobody watches; while someone does, at most one per
// view period (an hour here, so the test does not depend on how fast frames go), and with
// no period the newest frame wins; every marker and joint copied; nothing allocated.
TEST_F(SubjectRunnerTest, TheLiveViewGetsTheNewestFrameOnlyWhileWatchedAndAllocatesNothing) {
  SubjectRunner runner(subject_, daemon_);
  LiveViewBoard board(30.0);
  const auto& model = subject_.model;
  runner.AttachLiveView(board.Register("actor1", *model.skeleton, *model.markers, nullptr));
  const auto slot = board.Slots().at(0);
  LiveViewFrame frame;
  for (int f = 0; f < 40; ++f) ASSERT_FALSE(runner.Accept(Frame(f, f, 0), 0, sink_).has_value());
  EXPECT_FALSE(slot->Take(&frame));  // nobody watching: nothing copied
  board.demand().viewers = 1;
  board.demand().period_ns = int64_t{3600} * 1'000'000'000;
  const std::vector<protocol::MarkerFrameMessage> frames = Frames(40, 80);
  NullSink null_sink;
  {
    testing::ScopedAllocationCounter counter;
    for (const auto& m : frames) ASSERT_FALSE(runner.Accept(m, 0, null_sink).has_value());
    EXPECT_EQ(counter.count(), 0u);
  }
  ASSERT_TRUE(slot->Take(&frame));
  EXPECT_FALSE(slot->Take(&frame));  // taken once
  // One copy in the period: the first frame published once someone watched.
  EXPECT_EQ(frame.frame_number, 40u - 4u);
  EXPECT_EQ(frame.raw.size(), static_cast<size_t>(model.markers->num_markers()));
  EXPECT_EQ(frame.joints.size(), static_cast<size_t>(model.skeleton->num_joints()));
  for (size_t m = 0; m < frame.raw.size(); ++m) {
    if (std::isfinite(frame.raw[m].x())) {
      EXPECT_LT((frame.raw[m] - frame.cleaned[m]).norm(), 0.05);
    }
  }
  EXPECT_LT((frame.joints[0] - frame.cleaned[0]).norm(), 0.5);  // the pelvis by its marker

  // A view with no period: every frame overwrites the slot, and the reader gets the newest.
  LiveViewBoard every_frame(30.0);
  every_frame.demand().viewers = 1;
  every_frame.demand().period_ns = 0;
  runner.AttachLiveView(every_frame.Register("actor1", *model.skeleton, *model.markers, nullptr));
  for (int f = 80; f < 90; ++f)
    ASSERT_FALSE(runner.Accept(Frame(f, f, 0), 0, null_sink).has_value());
  ASSERT_TRUE(every_frame.Slots().at(0)->Take(&frame));
  EXPECT_EQ(frame.frame_number, 90u - 1u - 4u);  // the newest published (lookahead 4)
}

}  // namespace
}  // namespace mocapd
