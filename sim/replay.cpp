// The replay of a take (N actors, loops, corruption) and of a recording: what to send,
// in what order and when; sockets, timing and measures are the schedule's.
#include "sim/replay.hpp"

#include <chrono>
#include <cmath>
#include <random>
#include <stdexcept>
#include <utility>

#include "formats/take_frames.hpp"
#include "protocol/messages.hpp"
#include "sim/corruption.hpp"
#include "sim/recording.hpp"
#include "sim/replay_schedule.hpp"

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
    for (size_t seq = 0; seq < total; ++seq) log.received_ns.emplace(seq, 0);
    if (!o.corrupt.empty()) {
      CorruptionOptions c;
      c.severity = ParseCorruptionSeverity(o.corrupt);
      c.seed = o.seed + static_cast<uint64_t>(k);
      corrupted[static_cast<size_t>(k)] = CorruptTake(source.take, source.markers.get(), c).take;
    }
  }
  // Frames go out subject after subject for each capture tick; after each pass over the
  // take, an end of stream per subject (the next pass starts afresh).
  protocol::MarkerFrameMessage message;
  message.model_hash = marker_hash;
  message.rate_hz = static_cast<float>(source.rate_hz);
  message.version = static_cast<uint16_t>(o.protocol_version);
  if (o.protocol_version != protocol::kVersion1 && o.protocol_version != protocol::kVersion2)
    throw std::invalid_argument("replay: protocol version must be 1 or 2");
  if (o.timecode_fps < 0 || o.timecode_fps > 1000)
    throw std::invalid_argument("replay: timecode rate must be 0 (none) .. 1000 fps");
  if (o.timecode_fps > 0 && o.protocol_version < protocol::kVersion2)
    throw std::invalid_argument("replay: timecode needs protocol version 2");
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
  size_t seq = 0, subject = 0;
  bool ending = false;
  const int64_t period_ns = static_cast<int64_t>(1e9 / rate);
  const replay::FrameProducer produce = [&](replay::Outgoing* next, std::vector<uint8_t>* bytes) {
    if (seq >= total && !ending) return false;
    next->subject = subject;
    // An end of stream goes out right after its pass's last frame.
    next->due_ns = max_rate ? -1 : static_cast<int64_t>(ending ? seq - 1 : seq) * period_ns;
    replay::SubjectLog& log = logs[subject];
    if (ending) {
      next->end_of_stream = true;
      next->frame_number = seq - 1;
      protocol::EncodeEndOfStream({log.name, seq - 1}, bytes);
    } else {
      const int f = static_cast<int>(seq % static_cast<size_t>(n));
      const C3dTake& take = o.corrupt.empty() ? source.take : corrupted[subject];
      map.FillMessage(take, f, &message);
      for (size_t m = 0; m < message.positions.size(); ++m)
        if (message.valid[m]) message.positions[m] += log.offset;
      message.subject = log.name;
      message.frame_number = seq;
      message.stream = stream_of(seq);
      message.capture_time_ns = WallNs();
      next->end_of_stream = false;
      next->frame_number = seq;
      protocol::EncodeMarkerFrame(message, bytes);
    }
    if (++subject == logs.size()) {
      subject = 0;
      if (ending) {
        ending = false;
      } else {
        ++seq;
        ending = o.end_of_stream && seq % static_cast<size_t>(n) == 0;
      }
    }
    return true;
  };
  replay::ScheduleSetup setup;
  setup.marker_hash = marker_hash;
  setup.check_hash = true;
  setup.skeleton = source.skeleton.get();
  setup.frame_period_s = 1.0 / rate;
  if (o.protocol_version >= protocol::kVersion2)
    setup.sent_stream = [&](size_t, uint64_t frame_number) { return stream_of(frame_number); };
  setup.truth = [&](size_t k, uint64_t frame_number, Pose* scratch) -> const Pose* {
    if (source.truth.empty()) return nullptr;
    *scratch = source.truth[frame_number % static_cast<uint64_t>(n)];
    scratch->translation[0] += logs[k].offset;
    return scratch;
  };
  ReplayReport report = replay::RunSchedule(logs, produce, setup, o);
  report.source = source.description;
  report.rate_hz = rate;
  return report;
}

ReplayReport RunRecordingReplay(const Recording& recording, const std::string& description,
                                const ReplayOptions& o) {
  // The subjects and frames in the recording: every marker frame and end of stream.
  std::vector<replay::SubjectLog> logs;
  std::vector<std::pair<size_t, uint64_t>> index(recording.messages.size(), {SIZE_MAX, 0});
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
    if (!is_end[i]) logs[k].received_ns.emplace(number, 0);
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
    next->frame_number = index[i].second;
    next->end_of_stream = is_end[i];
    next->due_ns = max_rate ? -1 : m.offset_ns - recording.messages.front().offset_ns;
    bytes->assign(m.message.begin(), m.message.end());
    ++i;
    return true;
  };
  replay::ScheduleSetup setup;
  setup.frame_period_s = rate_hz > 0 ? 1.0 / rate_hz : 1.0 / 120.0;
  ReplayReport report = replay::RunSchedule(logs, produce, setup, o);
  report.source = description;
  report.rate_hz = rate_hz;
  return report;
}

}  // namespace mocapd
