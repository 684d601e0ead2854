// The replay of a take (N actors, loops, corruption) and of a recording: what to send,
// in what order and when; sockets, timing and measures are the schedule's.
#include "sim/replay.hpp"

#include <chrono>
#include <cmath>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <random>
#include <stdexcept>
#include <utility>

#include "filters/resample.hpp"
#include "formats/take_frames.hpp"
#include "protocol/messages.hpp"
#include "sim/corruption.hpp"
#include "sim/graph_stream.hpp"
#include "sim/recording.hpp"
#include "sim/replay_schedule.hpp"
#include "sim/synthesis.hpp"

namespace mocapd {
namespace {

uint64_t WallNs() {
  return static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                   std::chrono::system_clock::now().time_since_epoch())
                                   .count());
}

// Actors stand this far apart along x, so that copies of one take never overlap.
constexpr double kActorSpacingM = 2.5;

std::string SubjectName(const ReplayOptions& o, int k) {
  return o.subject_prefix + std::to_string(k + 1);
}

// The exact rate as a fraction: whole rates over 1, the NTSC ones (119.88 = 120000/1001)
// over 1001, anything else to a thousandth of a hertz.
std::pair<uint32_t, uint32_t> RateFraction(double hz) {
  if (std::abs(hz - std::round(hz)) < 1e-6 * hz) return {static_cast<uint32_t>(std::lround(hz)), 1};
  const double ntsc = hz * 1.001;
  if (std::abs(ntsc - std::round(ntsc)) < 1e-6 * hz)
    return {static_cast<uint32_t>(std::lround(ntsc) * 1000), 1001};
  return {static_cast<uint32_t>(std::lround(hz * 1000)), 1000};
}

// Non-drop timecode of capture frame f of a take starting at 01:00:00:00 (the usual
// start of a recorded take); the subframe counts capture frames within a timecode frame.
protocol::Timecode TimecodeOf(uint64_t f, double rate_hz, int fps) {
  const auto tc_frame =
      static_cast<uint64_t>(std::floor(static_cast<double>(f) * fps / rate_hz + 1e-9));
  const auto first =
      static_cast<uint64_t>(std::ceil(static_cast<double>(tc_frame) * rate_hz / fps - 1e-9));
  const uint64_t seconds = tc_frame / static_cast<uint64_t>(fps);
  protocol::Timecode tc;
  tc.rate = static_cast<uint16_t>(fps);
  tc.frames = static_cast<uint8_t>(tc_frame % static_cast<uint64_t>(fps));
  tc.seconds = static_cast<uint8_t>(seconds % 60);
  tc.minutes = static_cast<uint8_t>(seconds / 60 % 60);
  tc.hours = static_cast<uint8_t>((1 + seconds / 3600) % 24);
  tc.subframe = static_cast<uint8_t>(std::min<uint64_t>(255, f - first));
  return tc;
}

// The wire options a take replay and a graph stream share.
void CheckStreamOptions(const ReplayOptions& o) {
  if (o.protocol_version != protocol::kVersion1 && o.protocol_version != protocol::kVersion2)
    throw std::invalid_argument("replay: protocol version must be 1 or 2");
  // The frames field is one byte: above 256 fps the frame numbers would wrap unseen.
  if (o.timecode_fps < 0 || o.timecode_fps > 256)
    throw std::invalid_argument("replay: timecode rate must be 0 (none) .. 256 fps");
  if (o.timecode_fps > 0 && o.protocol_version < protocol::kVersion2)
    throw std::invalid_argument("replay: timecode needs protocol version 2");
}

// Frames go out subject after subject for each capture tick; when ends_pass says a pass is
// over (after its last tick), an end of stream per subject. fill puts a subject's markers
// for a tick into the message (positions and validity); the rest is filled here.
struct TickProducerSetup {
  std::vector<replay::SubjectLog>* logs = nullptr;
  uint64_t total = 0;
  int64_t period_ns = 0;
  bool max_rate = false;
  std::function<bool(uint64_t next_tick)> ends_pass;
  std::function<void(size_t subject, uint64_t tick, protocol::MarkerFrameMessage*)> fill;
  std::function<protocol::StreamInfo(uint64_t tick)> stream_of;
  protocol::MarkerFrameMessage message;  ///< Hash, rate and version set.
};

replay::FrameProducer TickProducer(TickProducerSetup setup) {
  struct State {
    TickProducerSetup setup;
    uint64_t seq = 0;
    size_t subject = 0;
    bool ending = false;
  };
  auto state = std::make_shared<State>();
  state->setup = std::move(setup);
  return [state](replay::Outgoing* next, std::vector<uint8_t>* bytes) {
    State& st = *state;
    TickProducerSetup& su = st.setup;
    if (st.seq >= su.total && !st.ending) return false;
    next->subject = st.subject;
    next->due_ns =
        su.max_rate ? -1 : static_cast<int64_t>(st.ending ? st.seq - 1 : st.seq) * su.period_ns;
    replay::SubjectLog& log = (*su.logs)[st.subject];
    if (st.ending) {
      next->end_of_stream = true;
      next->frame_number = st.seq - 1;
      protocol::EncodeEndOfStream({log.name, st.seq - 1}, bytes);
    } else {
      protocol::MarkerFrameMessage& message = su.message;
      su.fill(st.subject, st.seq, &message);
      for (size_t m = 0; m < message.positions.size(); ++m)
        if (message.valid[m]) message.positions[m] += log.offset;
      message.subject = log.name;
      message.frame_number = st.seq;
      message.stream = su.stream_of(st.seq);
      message.capture_time_ns = WallNs();
      next->end_of_stream = false;
      next->frame_number = st.seq;
      protocol::EncodeMarkerFrame(message, bytes);
    }
    if (++st.subject == su.logs->size()) {
      st.subject = 0;
      if (st.ending) {
        st.ending = false;
      } else {
        ++st.seq;
        st.ending = su.ends_pass(st.seq);
      }
    }
    return true;
  };
}

// A session id per replay run: random, so that two runs never look like one capture.
uint64_t NewSessionBase() {
  std::random_device device;
  const uint64_t id = (static_cast<uint64_t>(device()) << 32) ^ device();
  return id == 0 ? 1 : id;
}

}  // namespace

ReplayReport RunReplay(const ReplaySource& source, const ReplayOptions& o) {
  if (o.subjects < 1 || o.loops < 1)
    throw std::invalid_argument("replay: subjects and loops must be at least 1");
  const int n = source.take.num_frames;
  if (n < 1) throw std::invalid_argument("replay: the take has no frames");
  const size_t total = static_cast<size_t>(n) * static_cast<size_t>(o.loops);
  const double rate = o.rate_hz > 0 ? o.rate_hz : source.rate_hz;
  const bool max_rate = o.rate_hz < 0;
  const TakeMarkerMap map(*source.markers, source.take);
  const uint64_t marker_hash = protocol::MarkerSetHash(*source.markers);

  std::vector<replay::SubjectLog> logs(static_cast<size_t>(o.subjects));
  std::vector<C3dTake> corrupted(static_cast<size_t>(o.subjects));
  for (int k = 0; k < o.subjects; ++k) {
    replay::SubjectLog& log = logs[static_cast<size_t>(k)];
    log.name = SubjectName(o, k);
    log.topic = "markers/" + log.name + "/";
    log.offset = Vec3(kActorSpacingM * k, 0.0, 0.0);
    log.sent.reserve(total + static_cast<size_t>(o.loops));
    log.received_ns.reserve(total);
    for (size_t seq = 0; seq < total; ++seq)
      log.received_ns.emplace(replay::SubjectLog::FrameKey{0, seq}, 0);
    if (!o.corrupt.empty()) {
      CorruptionOptions c;
      c.severity = ParseCorruptionSeverity(o.corrupt);
      c.seed = o.seed + static_cast<uint64_t>(k);
      corrupted[static_cast<size_t>(k)] = CorruptTake(source.take, source.markers.get(), c).take;
    }
  }
  // After each pass over the take, an end of stream per subject (the next pass starts afresh).
  CheckStreamOptions(o);
  // Each pass over the take is a capture of its own when it ends with an end of stream.
  const uint64_t session_base = NewSessionBase();
  const std::pair<uint32_t, uint32_t> rate_fraction = RateFraction(source.rate_hz);
  const auto stream_of = [&](uint64_t frame_number) {
    protocol::StreamInfo s;
    if (o.protocol_version < protocol::kVersion2) return s;
    const uint64_t pass = o.end_of_stream ? frame_number / static_cast<uint64_t>(n) : 0;
    s.session_id = session_base + pass;
    s.rate_numerator = rate_fraction.first;
    s.rate_denominator = rate_fraction.second;
    if (o.timecode_fps > 0) {
      s.has_timecode = true;
      const uint64_t f = o.end_of_stream ? frame_number % static_cast<uint64_t>(n) : frame_number;
      s.timecode = TimecodeOf(f, source.rate_hz, o.timecode_fps);
    }
    return s;
  };
  TickProducerSetup ticks;
  ticks.logs = &logs;
  ticks.total = total;
  ticks.period_ns = static_cast<int64_t>(1e9 / rate);
  ticks.max_rate = max_rate;
  ticks.ends_pass = [&](uint64_t next) {
    return o.end_of_stream && next % static_cast<uint64_t>(n) == 0;
  };
  ticks.fill = [&](size_t subject, uint64_t seq, protocol::MarkerFrameMessage* message) {
    const C3dTake& take = o.corrupt.empty() ? source.take : corrupted[subject];
    map.FillMessage(take, static_cast<int>(seq % static_cast<uint64_t>(n)), message);
  };
  ticks.stream_of = stream_of;
  ticks.message.model_hash = marker_hash;
  ticks.message.rate_hz = static_cast<float>(source.rate_hz);
  ticks.message.version = static_cast<uint16_t>(o.protocol_version);
  const replay::FrameProducer produce = TickProducer(std::move(ticks));
  replay::ScheduleSetup setup;
  setup.marker_hash = marker_hash;
  setup.check_hash = true;
  setup.check_rate = true;
  setup.skeleton = source.skeleton.get();
  setup.frame_period_s = 1.0 / rate;
  setup.capture_rate_hz = source.rate_hz;
  if (o.protocol_version >= protocol::kVersion2)
    setup.sent_stream = [&](size_t, uint64_t frame_number) { return stream_of(frame_number); };
  // Where an actor stands moves the joint that carries the travel (Hips below a fixed
  // joint_Root in some BVH rigs), in its parent's frame.
  int travel_joint = 0;
  Mat3 travel_parent = Mat3::Identity();
  if (!source.truth.empty()) {
    for (int j = source.skeleton->num_joints() - 1; j >= 0; --j)
      if (source.skeleton->joint(j).type == JointType::kFree) travel_joint = j;
    KinematicsWorkspace ws(*source.skeleton);
    ForwardKinematics(*source.skeleton, source.truth.front(), &ws);
    const int parent = source.skeleton->joint(travel_joint).parent.value;
    if (parent >= 0) travel_parent = ws.R_WJ[static_cast<size_t>(parent)];
  }
  setup.truth = [&](size_t k, uint64_t frame_number, Pose* scratch) -> const Pose* {
    if (source.truth.empty()) return nullptr;
    *scratch = source.truth[frame_number % static_cast<uint64_t>(n)];
    scratch->translation[static_cast<size_t>(travel_joint)] +=
        travel_parent.transpose() * logs[k].offset;
    return scratch;
  };
  ReplayReport report = replay::RunSchedule(logs, produce, setup, o);
  report.source = source.description;
  report.rate_hz = rate;
  report.capture_rate_hz = source.rate_hz;
  return report;
}

namespace {

// Graph actors stand this far apart: each walks around its own spot (within a few metres).
constexpr double kGraphActorSpacingM = 8.0;

// One actor's endless stream (GraphActorStream), and the recent chunks' truth for the
// receiver thread.
class GraphActor {
 public:
  explicit GraphActor(GraphActorStream stream) : stream_(std::move(stream)) {}

  // The chunk holding frame_number, synthesizing the next one when the stream reaches it.
  const C3dTake& ChunkFor(uint64_t frame_number, uint64_t total, int* frame_in_chunk) {
    if (frame_number >= chunk_first_ + static_cast<uint64_t>(chunk_.num_frames) ||
        chunk_.num_frames == 0)
      NextChunk(frame_number, total);
    *frame_in_chunk = static_cast<int>(frame_number - chunk_first_);
    return chunk_;
  }
  const TakeMarkerMap& map() const { return *map_; }

  // The truth of a frame sent in one of the last few chunks (nullptr if older).
  const Pose* Truth(uint64_t frame_number, Pose* scratch) {
    std::lock_guard<std::mutex> lock(truth_mutex_);
    for (const auto& [first, poses] : truth_)
      if (frame_number >= first && frame_number < first + poses.size()) {
        *scratch = poses[static_cast<size_t>(frame_number - first)];
        return scratch;
      }
    return nullptr;
  }

 private:
  void NextChunk(uint64_t first, uint64_t total) {
    GraphStreamChunk next = stream_.Next(first, total);
    chunk_ = std::move(next.corrupted.take);
    map_ = std::make_unique<TakeMarkerMap>(*stream_.markers(), chunk_);
    chunk_first_ = first;
    std::lock_guard<std::mutex> lock(truth_mutex_);
    truth_.emplace_back(first, std::move(next.truth));
    // The receiver scores frames a lookahead and a network hop behind: a few chunks do.
    while (truth_.size() > 4) truth_.pop_front();
  }

  GraphActorStream stream_;
  C3dTake chunk_;
  uint64_t chunk_first_ = 0;
  std::unique_ptr<TakeMarkerMap> map_;
  std::mutex truth_mutex_;
  std::deque<std::pair<uint64_t, std::vector<Pose>>> truth_;
};

}  // namespace

ReplayReport RunGraphReplay(const GraphReplaySource& source, double seconds, double rate_hz,
                            const ReplayOptions& o) {
  if (o.subjects < 1) throw std::invalid_argument("replay: subjects must be at least 1");
  if (!(seconds > 0) || !(rate_hz > 0))
    throw std::invalid_argument("replay: seconds and rate must be > 0");
  CheckStreamOptions(o);
  const auto total = std::max<uint64_t>(1, static_cast<uint64_t>(std::llround(seconds * rate_hz)));
  const double send_rate = o.rate_hz > 0 ? o.rate_hz : rate_hz;
  const bool max_rate = o.rate_hz < 0;
  const uint64_t marker_hash = protocol::MarkerSetHash(*source.markers);

  std::vector<replay::SubjectLog> logs(static_cast<size_t>(o.subjects));
  std::vector<std::unique_ptr<GraphActor>> actors;
  for (int k = 0; k < o.subjects; ++k) {
    replay::SubjectLog& log = logs[static_cast<size_t>(k)];
    log.name = SubjectName(o, k);
    log.topic = "markers/" + log.name + "/";
    log.offset = Vec3(kGraphActorSpacingM * k, 0.0, 0.0);
    log.sent.reserve(static_cast<size_t>(total) + 1);
    log.received_ns.reserve(static_cast<size_t>(total));
    for (uint64_t seq = 0; seq < total; ++seq)
      log.received_ns.emplace(replay::SubjectLog::FrameKey{0, seq}, 0);
    actors.push_back(
        std::make_unique<GraphActor>(ReplayGraphActor(source, o.seed, k, rate_hz, o.corrupt)));
  }
  const uint64_t session = NewSessionBase();
  const std::pair<uint32_t, uint32_t> rate_fraction = RateFraction(rate_hz);
  const auto stream_of = [&](uint64_t frame_number) {
    protocol::StreamInfo s;
    if (o.protocol_version < protocol::kVersion2) return s;
    s.session_id = session;
    s.rate_numerator = rate_fraction.first;
    s.rate_denominator = rate_fraction.second;
    if (o.timecode_fps > 0) {
      s.has_timecode = true;
      s.timecode = TimecodeOf(frame_number, rate_hz, o.timecode_fps);
    }
    return s;
  };
  TickProducerSetup ticks;
  ticks.logs = &logs;
  ticks.total = total;
  ticks.period_ns = static_cast<int64_t>(1e9 / send_rate);
  ticks.max_rate = max_rate;
  ticks.ends_pass = [&](uint64_t next) { return o.end_of_stream && next == total; };
  ticks.fill = [&](size_t subject, uint64_t seq, protocol::MarkerFrameMessage* message) {
    int f = 0;
    GraphActor& actor = *actors[subject];
    const C3dTake& chunk = actor.ChunkFor(seq, total, &f);
    actor.map().FillMessage(chunk, f, message);
  };
  ticks.stream_of = stream_of;
  ticks.message.model_hash = marker_hash;
  ticks.message.rate_hz = static_cast<float>(rate_hz);
  ticks.message.version = static_cast<uint16_t>(o.protocol_version);
  const replay::FrameProducer produce = TickProducer(std::move(ticks));
  replay::ScheduleSetup setup;
  setup.marker_hash = marker_hash;
  setup.check_hash = true;
  setup.check_rate = true;
  setup.skeleton = source.library->skeleton.get();
  setup.frame_period_s = 1.0 / send_rate;
  setup.capture_rate_hz = rate_hz;
  if (o.protocol_version >= protocol::kVersion2)
    setup.sent_stream = [&](size_t, uint64_t frame_number) { return stream_of(frame_number); };
  setup.truth = [&](size_t k, uint64_t frame_number, Pose* scratch) -> const Pose* {
    const Pose* p = actors[k]->Truth(frame_number, scratch);
    // The actor's spot is in the world; the body root's translation is in its parent's frame.
    if (p)
      scratch->translation[static_cast<size_t>(source.library->body_root)] +=
          source.library->parent_rotation.transpose() * logs[k].offset;
    return p;
  };
  ReplayReport report = replay::RunSchedule(logs, produce, setup, o);
  report.source = source.description;
  report.rate_hz = send_rate;
  report.capture_rate_hz = rate_hz;
  return report;
}

ReplayReport RunRecordingReplay(const Recording& recording, const std::string& description,
                                const ReplayOptions& o) {
  // The subjects and frames in the recording: every marker frame and end of stream.
  std::vector<replay::SubjectLog> logs;
  std::vector<std::pair<size_t, uint64_t>> index(recording.messages.size(), {SIZE_MAX, 0});
  std::vector<uint64_t> session(recording.messages.size(), 0);
  std::vector<bool> is_end(recording.messages.size(), false);
  protocol::MarkerFrameMessage frame;
  protocol::EndOfStreamMessage end;
  double rate_hz = 0.0;
  for (size_t i = 0; i < recording.messages.size(); ++i) {
    const auto& bytes = recording.messages[i].message;
    std::string subject;
    uint64_t number = 0;
    if (protocol::DecodeMarkerFrame(bytes, &frame) == protocol::DecodeStatus::kOk) {
      subject = frame.subject;
      number = frame.frame_number;
      rate_hz = frame.rate_hz;
      session[i] = frame.version >= protocol::kVersion2 ? frame.stream.session_id : 0;
    } else if (protocol::DecodeEndOfStream(bytes, &end) == protocol::DecodeStatus::kOk) {
      subject = end.subject;
      number = end.last_frame_number;
      is_end[i] = true;
    } else {
      continue;  // recorded as it came; a glitch the daemon will count, not ours to send
    }
    size_t k = 0;
    while (k < logs.size() && logs[k].name != subject) ++k;
    if (k == logs.size()) {
      logs.emplace_back();
      logs.back().name = subject;
      logs.back().topic = "markers/" + subject + "/";
    }
    if (!is_end[i])
      logs[k].received_ns.emplace(replay::SubjectLog::FrameKey{session[i], number}, 0);
    index[i] = {k, number};
  }
  if (logs.empty()) throw std::runtime_error("replay: the recording holds no marker frames");
  for (replay::SubjectLog& log : logs) log.sent.reserve(recording.messages.size());
  const bool max_rate = o.rate_hz < 0;
  size_t i = 0;
  size_t closing = 0;  // after the recording: end the streams it left open
  const replay::FrameProducer produce = [&](replay::Outgoing* next, std::vector<uint8_t>* bytes) {
    while (i < recording.messages.size() && index[i].first == SIZE_MAX) ++i;
    if (i >= recording.messages.size()) {
      for (; o.end_of_stream && closing < logs.size(); ++closing) {
        const replay::SubjectLog& log = logs[closing];
        if (log.sent.empty() || log.sent.back().end_of_stream) continue;
        next->subject = closing;
        next->session = log.sent.back().session;
        next->frame_number = log.sent.back().frame_number;
        next->end_of_stream = true;
        next->due_ns = -1;
        protocol::EncodeEndOfStream({log.name, next->frame_number}, bytes);
        ++closing;
        return true;
      }
      return false;
    }
    const RecordedMessage& m = recording.messages[i];
    next->subject = index[i].first;
    next->session = session[i];
    next->frame_number = index[i].second;
    next->end_of_stream = is_end[i];
    next->due_ns = max_rate ? -1 : m.offset_ns - recording.messages.front().offset_ns;
    bytes->assign(m.message.begin(), m.message.end());
    ++i;
    return true;
  };
  replay::ScheduleSetup setup;
  setup.key_by_session = true;
  setup.frame_period_s = rate_hz > 0 ? 1.0 / rate_hz : 1.0 / 120.0;
  if (rate_hz > 0) setup.capture_rate_hz = rate_hz;
  ReplayReport report = replay::RunSchedule(logs, produce, setup, o);
  report.source = description;
  report.rate_hz = rate_hz;
  report.capture_rate_hz = rate_hz;
  return report;
}

}  // namespace mocapd
