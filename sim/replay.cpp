// The replay of a take (N actors, loops, corruption) and of a recording: what to send,
// in what order and when; sockets, timing and measures are the schedule's.
#include "sim/replay.hpp"

#include <chrono>
#include <stdexcept>

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
