// The replay simulator: sender, receiver and the latency / accuracy report.
#include "sim/replay.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <random>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <unordered_map>
#include <zmq.hpp>

#include "filters/pose_error.hpp"
#include "protocol/messages.hpp"
#include "formats/bvh.hpp"
#include "sim/corruption.hpp"
#include "sim/humanoid.hpp"
#include "sim/humanoid_subject.hpp"
#include "formats/marker_layout.hpp"
#include "sim/recording.hpp"
#include "formats/subject_file.hpp"
#include "sim/synthesis.hpp"
#include "formats/take_frames.hpp"

namespace mocapd {
namespace {

using Clock = std::chrono::steady_clock;

int64_t SteadyNs() { return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch()).count(); }

uint64_t WallNs() {
  return static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch()).count());
}

// Actors stand this far apart along x, so that copies of one take never overlap.
constexpr double kActorSpacingM = 2.5;

LatencySummary Summarise(std::vector<double> ms) {
  LatencySummary s;
  s.count = ms.size();
  if (ms.empty()) return s;
  double sum = 0.0;
  for (double v : ms) sum += v;
  s.mean_ms = sum / static_cast<double>(ms.size());
  s.p50_ms = Quantile(ms, 0.5);
  s.p90_ms = Quantile(ms, 0.9);
  s.p99_ms = Quantile(ms, 0.99);
  s.p999_ms = Quantile(ms, 0.999);
  s.max_ms = *std::max_element(ms.begin(), ms.end());
  return s;
}

nlohmann::json SummaryJson(const LatencySummary& s) {
  return {{"count", s.count}, {"p50_ms", s.p50_ms}, {"p90_ms", s.p90_ms}, {"p99_ms", s.p99_ms},
          {"p99.9_ms", s.p999_ms}, {"max_ms", s.max_ms}, {"mean_ms", s.mean_ms}};
}

std::string SubjectName(const ReplayOptions& o, int k) { return o.subject_prefix + std::to_string(k + 1); }

// One frame (or end of stream) to send, produced in order by a FrameProducer.
struct Outgoing {
  size_t subject = 0;
  uint64_t frame_number = 0;
  bool end_of_stream = false;
  int64_t due_ns = 0;  ///< Since the start; < 0: as soon as possible.
};

// Per subject: every frame sent (in send order) and when its skeleton came back.
struct SubjectLog {
  std::string name;
  std::string topic;
  Vec3 offset = Vec3::Zero();  ///< Where this actor stands (takes: for the truth).
  struct Sent {
    uint64_t frame_number;
    int64_t sent_ns;
    bool end_of_stream;
  };
  std::vector<Sent> sent;
  std::unordered_map<uint64_t, int64_t> received_ns;  ///< Frame number -> arrival; pre-sized.
};

// Encodes the next message into bytes; false when there is nothing more to send.
using FrameProducer = std::function<bool(Outgoing*, std::vector<uint8_t>*)>;

// The truth for a received skeleton frame, or nullptr when unknown.
using TruthLookup = std::function<const Pose*(size_t subject, uint64_t frame_number, Pose* scratch)>;

ReplayReport RunSchedule(std::vector<SubjectLog>& logs, uint64_t marker_hash, bool check_hash, const FrameProducer& produce,
                         const TruthLookup& truth, const Skeleton* skeleton, double frame_period_s, const ReplayOptions& o) {
  zmq::context_t context;
  zmq::socket_t out(context, o.push ? zmq::socket_type::push : zmq::socket_type::xpub);
  out.set(zmq::sockopt::sndhwm, 0);  // never drop a frame on our side
  out.set(zmq::sockopt::linger, 2000);
  try {
    if (o.push) out.connect(o.to);
    else out.bind(o.to);
  } catch (const zmq::error_t& e) {
    throw std::runtime_error("replay: cannot " + std::string(o.push ? "connect to " : "bind ") + o.to + ": " + e.what());
  }
  std::optional<zmq::socket_t> in;
  if (!o.from.empty()) {
    in.emplace(context, zmq::socket_type::sub);
    in->set(zmq::sockopt::rcvhwm, 0);
    in->set(zmq::sockopt::subscribe, "skeleton/");
    in->set(zmq::sockopt::subscribe, "subject/");
    in->connect(o.from);
  }

  // Handshake: the daemon subscribed to our frames, and we hold its subject descriptions.
  ReplayReport report;
  report.subjects = static_cast<int>(logs.size());
  const int64_t deadline = SteadyNs() + static_cast<int64_t>(o.connect_timeout_s * 1e9);
  std::vector<bool> subscribed(logs.size(), o.push), described(logs.size(), !in.has_value());
  auto all = [](const std::vector<bool>& v) { return std::all_of(v.begin(), v.end(), [](bool b) { return b; }); };
  while (!(all(subscribed) && all(described))) {
    if (SteadyNs() > deadline) {
      for (size_t k = 0; k < logs.size(); ++k) {
        if (!subscribed[k])
          throw std::runtime_error("replay: nothing subscribed to " + logs[k].topic + " on " + o.to + " within " +
                                   std::to_string(o.connect_timeout_s) + " s (is the daemon running with subject '" + logs[k].name + "'?)");
        if (!described[k])
          throw std::runtime_error("replay: no description of subject '" + logs[k].name + "' from " + o.from + " within " +
                                   std::to_string(o.connect_timeout_s) + " s (is the daemon publishing there, with that subject?)");
      }
    }
    std::vector<zmq::pollitem_t> items = {{out.handle(), 0, ZMQ_POLLIN, 0}};
    if (in) items.push_back({in->handle(), 0, ZMQ_POLLIN, 0});
    zmq::poll(items.data(), items.size(), std::chrono::milliseconds(20));
    zmq::message_t m;
    while (!o.push && out.recv(m, zmq::recv_flags::dontwait)) {
      const std::string sub = m.to_string();
      if (sub.empty() || sub[0] != 1) continue;
      for (size_t k = 0; k < logs.size(); ++k)
        if (logs[k].topic.starts_with(sub.substr(1))) subscribed[k] = true;
    }
    while (in && in->recv(m, zmq::recv_flags::dontwait)) {
      zmq::message_t body;
      if (!m.more() || !in->recv(body)) continue;
      protocol::SubjectDescriptionMessage d;
      if (!m.to_string().starts_with("subject/") ||
          protocol::DecodeSubjectDescription({static_cast<const uint8_t*>(body.data()), body.size()}, &d) != protocol::DecodeStatus::kOk)
        continue;
      for (size_t k = 0; k < logs.size(); ++k) {
        if (logs[k].name != d.subject) continue;
        if (check_hash && d.marker_set_hash != marker_hash)
          throw std::runtime_error("replay: the daemon's subject '" + d.subject + "' has another marker set than this take's (model hash mismatch)");
        described[k] = true;
        report.lookahead = d.lookahead_frames;
      }
    }
  }

  // Receiver: stamps each skeleton frame on arrival and scores it against the truth.
  std::atomic<bool> receiving{true};
  std::atomic<uint64_t> received{0}, duplicated{0};
  std::optional<PoseErrorAccumulator> accuracy;
  if (skeleton != nullptr) accuracy.emplace(*skeleton);
  std::thread receiver;
  if (in) {
    receiver = std::thread([&] {
      zmq::pollitem_t item = {in->handle(), 0, ZMQ_POLLIN, 0};
      protocol::SkeletonFrameMessage message;
      std::optional<KinematicsWorkspace> solved_fk, truth_fk;
      Pose solved, scratch;
      if (skeleton != nullptr) {
        solved_fk.emplace(*skeleton);
        truth_fk.emplace(*skeleton);
        solved = RestPose(*skeleton);
      }
      zmq::message_t topic, body;
      while (receiving.load()) {
        zmq::poll(&item, 1, std::chrono::milliseconds(5));
        while (in->recv(topic, zmq::recv_flags::dontwait)) {
          if (!topic.more() || !in->recv(body)) continue;
          const int64_t now = SteadyNs();
          if (!topic.to_string().starts_with("skeleton/")) continue;
          if (protocol::DecodeSkeletonFrame({static_cast<const uint8_t*>(body.data()), body.size()}, &message) != protocol::DecodeStatus::kOk)
            continue;
          size_t k = 0;
          while (k < logs.size() && logs[k].name != message.subject) ++k;
          if (k == logs.size()) continue;
          const auto slot = logs[k].received_ns.find(message.frame_number);
          if (slot == logs[k].received_ns.end()) continue;  // not one we sent (inserted by the daemon)
          if (slot->second != 0) {
            ++duplicated;
            continue;
          }
          slot->second = now;
          ++received;
          const Pose* expected = truth ? truth(k, message.frame_number, &scratch) : nullptr;
          if (expected == nullptr || static_cast<int>(message.rotations.size()) != skeleton->num_joints()) continue;
          for (size_t j = 0; j < message.rotations.size(); ++j) solved.rotation[j] = message.rotations[j].normalized();
          solved.translation[0] = message.root_translation;
          ForwardKinematics(*skeleton, solved, &*solved_fk);
          ForwardKinematics(*skeleton, *expected, &*truth_fk);
          accuracy->Add(*truth_fk, *solved_fk);
        }
      }
    });
  }

  // Sender, paced by the steady clock.
  std::vector<uint8_t> bytes;
  Outgoing next;
  const int64_t start = SteadyNs();
  int64_t next_status = start + 1'000'000'000;
  uint64_t sent = 0;
  while (!(o.stop != nullptr && o.stop->load()) && produce(&next, &bytes)) {
    if (next.due_ns >= 0) std::this_thread::sleep_until(Clock::time_point(std::chrono::nanoseconds(start + next.due_ns)));
    SubjectLog& log = logs[next.subject];
    const int64_t now = SteadyNs();
    log.sent.push_back({next.frame_number, now, next.end_of_stream});
    out.send(zmq::buffer(log.topic), zmq::send_flags::sndmore);
    out.send(zmq::buffer(bytes), zmq::send_flags::none);
    if (!next.end_of_stream) ++sent;
    if (o.on_status && now >= next_status) {
      char line[160];
      std::snprintf(line, sizeof(line), "t=%6.1fs  sent %8llu frames  received %8llu skeletons", static_cast<double>(now - start) * 1e-9,
                    static_cast<unsigned long long>(sent), static_cast<unsigned long long>(received.load()));
      o.on_status(line);
      next_status += 1'000'000'000;
    }
  }
  const int64_t send_end = SteadyNs();
  report.frames_sent = sent;
  report.send_seconds = static_cast<double>(send_end - start) * 1e-9;
  if (!in) return report;
  report.listened = true;
  const int64_t drain_deadline = SteadyNs() + static_cast<int64_t>(o.drain_timeout_s * 1e9);
  while (received.load() < sent && SteadyNs() < drain_deadline) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  receiving = false;
  receiver.join();

  report.frames_received = received.load();
  report.frames_duplicated = duplicated.load();
  report.frames_lost = sent - std::min<uint64_t>(sent, report.frames_received);
  std::vector<double> e2e;
  e2e.reserve(sent);
  report.processing_ms.reserve(sent);
  const auto K = static_cast<uint64_t>(report.lookahead);
  for (const SubjectLog& log : logs) {
    for (size_t i = 0; i < log.sent.size(); ++i) {
      const SubjectLog::Sent& s = log.sent[i];
      if (s.end_of_stream) continue;
      const int64_t got = log.received_ns.at(s.frame_number);
      if (got == 0) continue;
      e2e.push_back(static_cast<double>(got - s.sent_ns) * 1e-6);
      // What let this frame out: the first later frame numbered at least K on (the
      // daemon fills numbers that never came), or the end of its stream.
      int64_t trigger_ns = 0;
      for (size_t j = i; j < log.sent.size(); ++j) {
        if (log.sent[j].end_of_stream || log.sent[j].frame_number < s.frame_number || log.sent[j].frame_number >= s.frame_number + K) {
          if (log.sent[j].end_of_stream || log.sent[j].frame_number >= s.frame_number + K) trigger_ns = log.sent[j].sent_ns;
          break;
        }
      }
      if (trigger_ns == 0) continue;
      const double ms = static_cast<double>(got - trigger_ns) * 1e-6;
      report.processing_ms.push_back(ms);
      if (ms * 1e-3 > frame_period_s) ++report.frames_late;
    }
  }
  report.end_to_end = Summarise(e2e);
  report.processing = Summarise(report.processing_ms);
  report.throughput_fps = report.send_seconds > 0 ? static_cast<double>(report.frames_received) / report.send_seconds : 0.0;
  if (accuracy && accuracy->frames() > 0) {
    report.has_truth = true;
    report.mean_position_error_cm = accuracy->mean_position_error_m() * 100.0;
    report.max_position_error_cm = accuracy->max_position_error_m() * 100.0;
    report.mean_rotation_error_deg = accuracy->mean_rotation_error_rad() * 180.0 / M_PI;
  }
  return report;
}

}  // namespace

ReplaySource HumanoidReplaySource(const std::string& motion, double seconds, double rate_hz, double noise_mm, uint64_t seed) {
  ReplaySource s;
  const SubjectModel model = MakeHumanoidSubject("actor1");
  s.skeleton = model.skeleton;
  s.markers = model.markers;
  s.rate_hz = rate_hz;
  s.truth = MakeHumanoidMotion(*s.skeleton, ParseHumanoidMotion(motion), seconds, rate_hz);
  std::mt19937_64 rng(seed);
  s.take = SynthesizeMarkers(*s.skeleton, *s.markers, s.truth, rate_hz, noise_mm * 1e-3, &rng);
  char d[160];
  std::snprintf(d, sizeof(d), "built-in humanoid, %s, %.1f s at %.0f Hz, %.1f mm noise", motion.c_str(), seconds, rate_hz, noise_mm);
  s.description = d;
  return s;
}

ReplaySource BvhReplaySource(const std::string& path, double rate_hz, const std::string& units) {
  BvhReadOptions read;
  read.units = units;
  const BvhTake bvh = ReadBvh(path, read);
  ReplaySource s;
  s.rate_hz = rate_hz > 0 ? rate_hz : bvh.rate_hz();
  s.skeleton = std::make_shared<const Skeleton>(bvh.skeleton);
  s.markers = std::make_shared<const MarkerSet>(
      bvh.skeleton, PlaceMarkers(bvh.skeleton, MatchHumanoidRoles(bvh.skeleton), DefaultMarkerLayout(), bvh.end_sites));
  s.truth = ResampleMotion(bvh.skeleton, bvh.frames, bvh.rate_hz(), s.rate_hz);
  std::mt19937_64 rng(1);
  s.take = SynthesizeMarkers(*s.skeleton, *s.markers, s.truth, s.rate_hz, 0.0, &rng);
  s.description = path + " (markers synthesized, " + std::to_string(static_cast<int>(s.rate_hz)) + " Hz)";
  return s;
}

ReplaySource C3dReplaySource(const std::string& path, const std::string& subject_path) {
  ReplaySource s;
  const SubjectModel model = subject_path.empty() ? MakeHumanoidSubject("actor1") : ReadSubjectModel(subject_path);
  s.skeleton = model.skeleton;
  s.markers = model.markers;
  s.take = ReadC3d(path);
  s.rate_hz = s.take.rate_hz;
  s.description = path;
  return s;
}

ReplayReport RunReplay(const ReplaySource& source, const ReplayOptions& o) {
  if (o.subjects < 1 || o.loops < 1) throw std::invalid_argument("replay: subjects and loops must be at least 1");
  const int n = source.take.num_frames;
  if (n < 1) throw std::invalid_argument("replay: the take has no frames");
  const size_t total = static_cast<size_t>(n) * static_cast<size_t>(o.loops);
  const double rate = o.rate_hz > 0 ? o.rate_hz : source.rate_hz;
  const bool max_rate = o.rate_hz < 0;
  const TakeMarkerMap map(*source.markers, source.take);
  const uint64_t marker_hash = protocol::MarkerSetHash(*source.markers);

  std::vector<SubjectLog> logs(static_cast<size_t>(o.subjects));
  std::vector<C3dTake> corrupted(static_cast<size_t>(o.subjects));
  for (int k = 0; k < o.subjects; ++k) {
    SubjectLog& log = logs[static_cast<size_t>(k)];
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
  const FrameProducer produce = [&](Outgoing* next, std::vector<uint8_t>* bytes) {
    if (seq >= total && !ending) return false;
    next->subject = subject;
    // An end of stream goes out right after its pass's last frame.
    next->due_ns = max_rate ? -1 : static_cast<int64_t>(ending ? seq - 1 : seq) * period_ns;
    SubjectLog& log = logs[subject];
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
  const TruthLookup truth = [&](size_t k, uint64_t frame_number, Pose* scratch) -> const Pose* {
    if (source.truth.empty()) return nullptr;
    *scratch = source.truth[frame_number % static_cast<uint64_t>(n)];
    scratch->translation[0] += logs[k].offset;
    return scratch;
  };
  ReplayReport report = RunSchedule(logs, marker_hash, true, produce, truth, source.skeleton.get(), 1.0 / rate, o);
  report.source = source.description;
  report.rate_hz = rate;
  return report;
}

ReplayReport RunRecordingReplay(const Recording& recording, const std::string& description, const ReplayOptions& o) {
  // The subjects and frames in the recording: every marker frame and end of stream.
  std::vector<SubjectLog> logs;
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
  for (SubjectLog& log : logs) log.sent.reserve(recording.messages.size());
  const bool max_rate = o.rate_hz < 0;
  size_t i = 0;
  size_t closing = 0;  // after the recording: end the streams it left open
  const FrameProducer produce = [&](Outgoing* next, std::vector<uint8_t>* bytes) {
    while (i < recording.messages.size() && index[i].first == SIZE_MAX) ++i;
    if (i >= recording.messages.size()) {
      for (; o.end_of_stream && closing < logs.size(); ++closing) {
        const SubjectLog& log = logs[closing];
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
  ReplayReport report = RunSchedule(logs, 0, false, produce, nullptr, nullptr, rate_hz > 0 ? 1.0 / rate_hz : 1.0 / 120.0, o);
  report.source = description;
  report.rate_hz = rate_hz;
  return report;
}

nlohmann::json ReplayReport::ToJson() const {
  nlohmann::json j = {{"source", source},
                      {"rate_hz", rate_hz},
                      {"subjects", subjects},
                      {"lookahead_frames", lookahead},
                      {"frames_sent", frames_sent},
                      {"frames_received", frames_received},
                      {"frames_lost", frames_lost},
                      {"frames_duplicated", frames_duplicated},
                      {"frames_late", frames_late},
                      {"send_seconds", send_seconds},
                      {"throughput_fps", throughput_fps},
                      {"end_to_end_latency", SummaryJson(end_to_end)},
                      {"processing_latency", SummaryJson(processing)}};
  if (has_truth)
    j["accuracy"] = {{"mean_joint_position_error_cm", mean_position_error_cm},
                     {"max_joint_position_error_cm", max_position_error_cm},
                     {"mean_joint_rotation_error_deg", mean_rotation_error_deg}};
  return j;
}

std::string ReplayReport::FormatTable() const {
  std::ostringstream s;
  char line[200];
  auto row = [&](const char* name, const std::string& value) {
    std::snprintf(line, sizeof(line), "  %-34s %s\n", name, value.c_str());
    s << line;
  };
  auto num = [](double v, int decimals) {
    char b[40];
    std::snprintf(b, sizeof(b), "%.*f", decimals, v);
    return std::string(b);
  };
  s << "replay: " << source << "\n";
  row("subjects x rate", std::to_string(subjects) + " x " + num(rate_hz, 0) + " Hz, lookahead K = " + std::to_string(lookahead));
  if (!listened) {
    row("frames sent", std::to_string(frames_sent) + " (the daemon's output was not measured: --from \"\")");
    return s.str();
  }
  row("frames sent / received", std::to_string(frames_sent) + " / " + std::to_string(frames_received));
  row("frames lost / duplicated / late", std::to_string(frames_lost) + " / " + std::to_string(frames_duplicated) + " / " + std::to_string(frames_late));
  row("throughput (skeletons/s)", num(throughput_fps, 1));
  std::snprintf(line, sizeof(line), "  %-34s %8s %8s %8s %8s %8s\n", "latency (ms)", "p50", "p90", "p99", "p99.9", "max");
  s << line;
  for (const auto& [name, l] : {std::pair<const char*, const LatencySummary&>{"  end to end (sent -> skeleton)", end_to_end},
                                {"  processing (beyond lookahead)", processing}}) {
    std::snprintf(line, sizeof(line), "  %-34s %8.3f %8.3f %8.3f %8.3f %8.3f\n", name, l.p50_ms, l.p90_ms, l.p99_ms, l.p999_ms, l.max_ms);
    s << line;
  }
  if (has_truth) {
    row("joint position error mean (cm)", num(mean_position_error_cm, 3));
    row("joint position error max (cm)", num(max_position_error_cm, 3));
    row("joint rotation error mean (deg)", num(mean_rotation_error_deg, 3));
  }
  return s.str();
}

std::string LatencyHistogramSvg(const std::vector<double>& latencies_ms, const std::string& title) {
  // Log-spaced bins from 10 us to 100 ms; anything outside lands in the end bins.
  constexpr int kBins = 48;
  constexpr double kLo = 0.01, kHi = 100.0;
  std::vector<int> counts(kBins, 0);
  for (double v : latencies_ms) {
    const double x = std::log10(std::clamp(v, kLo, kHi) / kLo) / std::log10(kHi / kLo);
    ++counts[static_cast<size_t>(std::min(kBins - 1, static_cast<int>(x * kBins)))];
  }
  const int peak = std::max(1, *std::max_element(counts.begin(), counts.end()));
  const double w = 720, h = 360, left = 60, right = 20, top = 40, bottom = 50;
  const double plot_w = w - left - right, plot_h = h - top - bottom;
  std::ostringstream s;
  s << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << w << "\" height=\"" << h << "\" font-family=\"sans-serif\" font-size=\"12\">\n";
  s << "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  std::string escaped;
  for (char c : title) escaped += c == '<' ? "&lt;" : c == '&' ? "&amp;" : std::string(1, c);
  s << "<text x=\"" << w / 2 << "\" y=\"22\" text-anchor=\"middle\" font-size=\"14\">" << escaped << "</text>\n";
  for (int b = 0; b < kBins; ++b) {
    const double bh = plot_h * counts[static_cast<size_t>(b)] / peak;
    s << "<rect x=\"" << left + plot_w * b / kBins << "\" y=\"" << top + plot_h - bh << "\" width=\"" << plot_w / kBins - 1 << "\" height=\"" << bh
      << "\" fill=\"#4878a8\"><title>" << counts[static_cast<size_t>(b)] << "</title></rect>\n";
  }
  s << "<line x1=\"" << left << "\" y1=\"" << top + plot_h << "\" x2=\"" << left + plot_w << "\" y2=\"" << top + plot_h << "\" stroke=\"black\"/>\n";
  s << "<line x1=\"" << left << "\" y1=\"" << top << "\" x2=\"" << left << "\" y2=\"" << top + plot_h << "\" stroke=\"black\"/>\n";
  const char* ticks[] = {"0.01", "0.1", "1", "10", "100"};
  for (int d = 0; d <= 4; ++d) {
    const double x = left + plot_w * d / 4.0;
    s << "<text x=\"" << x << "\" y=\"" << top + plot_h + 16 << "\" text-anchor=\"middle\">" << ticks[d] << "</text>\n";
  }
  s << "<text x=\"" << left + plot_w / 2 << "\" y=\"" << h - 12 << "\" text-anchor=\"middle\">processing latency (ms, log scale)</text>\n";
  s << "<text x=\"14\" y=\"" << top + plot_h / 2 << "\" transform=\"rotate(-90 14 " << top + plot_h / 2
    << ")\" text-anchor=\"middle\">frames</text>\n";
  s << "<text x=\"" << left + 4 << "\" y=\"" << top + 12 << "\">peak " << peak << "</text>\n";
  if (!latencies_ms.empty()) {
    for (const auto& [q, name] : {std::pair{0.5, "p50"}, std::pair{0.99, "p99"}}) {
      const double v = Quantile(latencies_ms, q);
      const double x = left + plot_w * std::log10(std::clamp(v, kLo, kHi) / kLo) / std::log10(kHi / kLo);
      s << "<line x1=\"" << x << "\" y1=\"" << top << "\" x2=\"" << x << "\" y2=\"" << top + plot_h << "\" stroke=\"#c04040\" stroke-dasharray=\"4 3\"/>\n";
      s << "<text x=\"" << x + 3 << "\" y=\"" << top + 26 + (q > 0.9 ? 14 : 0) << "\" fill=\"#c04040\">" << name << " " << v << " ms</text>\n";
    }
  }
  s << "</svg>\n";
  return s.str();
}

}  // namespace mocapd
