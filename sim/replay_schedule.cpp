// Sending, receiving and measuring for the replay (see the header).
#include "sim/replay_schedule.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <optional>
#include <stdexcept>
#include <thread>
#include <zmq.hpp>

#include "filters/pose_error.hpp"
#include "protocol/curve.hpp"
#include "protocol/messages.hpp"

namespace mocapd::replay {
namespace {

using Clock = std::chrono::steady_clock;

// The output socket (PUB-bind, or PUSH-connect) and, when the daemon's output is
// measured, the SUB socket on it; a CURVE PUSH's handshakes are watched.
struct Sockets {
  zmq::context_t context;
  zmq::socket_t out;
  std::optional<zmq::socket_t> in;
  std::optional<zmq::socket_t> push_handshakes;
};

constexpr char kPushHandshakeMonitor[] = "inproc://replay-push-handshakes";

// Seconds to nanoseconds, capped at 1e9 s so a huge timeout means "for ever", not overflow.
int64_t TimeoutNs(double seconds) { return static_cast<int64_t>(std::min(seconds, 1e9) * 1e9); }

// The connect timeout as the error messages give it ("10 s", "0.5 s").
std::string ConnectTimeoutText(const ReplayOptions& o) {
  char text[32];
  std::snprintf(text, sizeof(text), "%g s", o.connect_timeout_s);
  return text;
}

void OpenSockets(const ReplayOptions& o, Sockets* s) {
  const std::optional<curve::ClientKeys> keys =
      curve::ReadClientKeys(o.curve_key_file, o.curve_server_key_file, "replay");
  s->out = zmq::socket_t(s->context, o.push ? zmq::socket_type::push : zmq::socket_type::xpub);
  s->out.set(zmq::sockopt::sndhwm, 0);  // never drop a frame on our side
  s->out.set(zmq::sockopt::linger, 2000);
  // A PUB feed serves its key to every subscriber (a simulator has no allow-list).
  if (keys && o.push) curve::MakeClient(s->out, keys->own, keys->server_public_key);
  if (keys && !o.push) curve::MakeServer(s->out, keys->own, "");
  if (o.push) {
    // A PUSH the daemon refused can be left with no pipe, and a send would then wait for
    // ever: past the connect timeout a send is an error (SendAll).
    const double ms = o.connect_timeout_s * 1e3;
    s->out.set(zmq::sockopt::sndtimeo,
               ms >= std::numeric_limits<int>::max() ? -1 : static_cast<int>(std::lround(ms)));
  }
  if (keys && o.push) {
    if (zmq_socket_monitor(s->out.handle(), kPushHandshakeMonitor,
                           ZMQ_EVENT_HANDSHAKE_SUCCEEDED | ZMQ_EVENT_HANDSHAKE_FAILED_AUTH |
                               ZMQ_EVENT_HANDSHAKE_FAILED_PROTOCOL |
                               ZMQ_EVENT_HANDSHAKE_FAILED_NO_DETAIL) != 0)
      throw std::runtime_error(std::string("replay: cannot watch the CURVE handshake: ") +
                               zmq_strerror(zmq_errno()));
    s->push_handshakes.emplace(s->context, zmq::socket_type::pair);
    s->push_handshakes->connect(kPushHandshakeMonitor);
  }
  try {
    if (o.push)
      s->out.connect(o.to);
    else
      s->out.bind(o.to);
  } catch (const zmq::error_t& e) {
    throw std::runtime_error("replay: cannot " + std::string(o.push ? "connect to " : "bind ") +
                             o.to + ": " + e.what());
  }
  if (o.from.empty()) return;
  s->in.emplace(s->context, zmq::socket_type::sub);
  s->in->set(zmq::sockopt::rcvhwm, 0);
  s->in->set(zmq::sockopt::subscribe, "skeleton/");
  s->in->set(zmq::sockopt::subscribe, "subject/");
  if (keys) curve::MakeClient(*s->in, keys->own, keys->server_public_key);
  s->in->connect(o.from);
}

// A CURVE PUSH into the daemon's PULL: a refused key is otherwise silence (frames queued
// for a peer that never takes them), so wait for the handshake and say why it failed.
void WaitForPushHandshake(Sockets& s, const ReplayOptions& o) {
  const int64_t deadline = SteadyNs() + TimeoutNs(o.connect_timeout_s);
  zmq::pollitem_t item = {s.push_handshakes->handle(), 0, ZMQ_POLLIN, 0};
  std::string dropped;  // the last connection lost mid-handshake (libzmq retries those)
  while (SteadyNs() < deadline) {
    zmq::poll(&item, 1, std::chrono::milliseconds(20));
    while (const std::optional<curve::MonitorEvent> e =
               curve::ReadMonitorEvent(*s.push_handshakes)) {
      if (e->event == ZMQ_EVENT_HANDSHAKE_SUCCEEDED) return;
      if (e->event == ZMQ_EVENT_HANDSHAKE_FAILED_NO_DETAIL) {
        dropped =
            std::string("; the last attempt ended: ") + std::strerror(static_cast<int>(e->value));
        continue;
      }
      char code[16];
      std::snprintf(code, sizeof(code), "%#x", e->value);
      if (e->event == ZMQ_EVENT_HANDSHAKE_FAILED_AUTH)
        throw std::runtime_error("replay: the daemon at " + o.to +
                                 " refused this replay's CURVE key (ZAP status " +
                                 std::to_string(e->value) + "): is the public half of " +
                                 o.curve_key_file + " in the daemon's authorized_keys?");
      throw std::runtime_error("replay: the CURVE handshake with " + o.to + " failed (code " +
                               code + "): is the daemon's input CURVE, and " +
                               o.curve_server_key_file + " the daemon's public key?");
    }
  }
  const std::string seconds = ConnectTimeoutText(o);
  throw std::runtime_error("replay: no CURVE handshake with " + o.to + " within " + seconds +
                           " (is the daemon running, with a PULL input there, the public half of " +
                           o.curve_key_file + " in its authorized_keys, and " +
                           o.curve_server_key_file + " its public key?" + dropped + ")");
}

// Waits until the daemon subscribed to every subject's topic (PUB) and described every
// subject (when listening), noting each subject's lookahead from its description.
void WaitForDaemon(Sockets& s, std::vector<SubjectLog>& logs, const ScheduleSetup& setup,
                   const ReplayOptions& o) {
  const int64_t deadline = SteadyNs() + TimeoutNs(o.connect_timeout_s);
  std::vector<bool> subscribed(logs.size(), o.push), described(logs.size(), !s.in.has_value());
  auto all = [](const std::vector<bool>& v) {
    return std::all_of(v.begin(), v.end(), [](bool b) { return b; });
  };
  while (!(all(subscribed) && all(described))) {
    if (SteadyNs() > deadline) {
      const std::string seconds = ConnectTimeoutText(o);
      // Under CURVE a refused handshake looks like silence: name the keys to check.
      const std::string curve_send =
          o.curve_key_file.empty()
              ? ""
              : "; with CURVE: is the daemon's input_server_key_file this replay's public key?";
      const std::string curve_listen =
          o.curve_key_file.empty()
              ? ""
              : "; with CURVE: is this replay's public key in the daemon's authorized_keys, "
                "and --curve-server-key the daemon's?";
      for (size_t k = 0; k < logs.size(); ++k) {
        if (!subscribed[k])
          throw std::runtime_error("replay: nothing subscribed to " + logs[k].topic + " on " +
                                   o.to + " within " + seconds +
                                   " (is the daemon running with subject '" +
                                   protocol::PrintableName(logs[k].name) + "'?" + curve_send + ")");
        if (!described[k])
          throw std::runtime_error(
              "replay: no description of subject '" + protocol::PrintableName(logs[k].name) +
              "' from " + o.from + " within " + seconds +
              " (is the daemon publishing there, with that subject?" + curve_listen + ")");
      }
    }
    std::vector<zmq::pollitem_t> items = {{s.out.handle(), 0, ZMQ_POLLIN, 0}};
    if (s.in) items.push_back({s.in->handle(), 0, ZMQ_POLLIN, 0});
    zmq::poll(items.data(), items.size(), std::chrono::milliseconds(20));
    zmq::message_t m;
    // An XPUB hears each subscription as a message: 1, then the topic prefix.
    while (!o.push && s.out.recv(m, zmq::recv_flags::dontwait)) {
      const std::string sub = m.to_string();
      if (sub.empty() || sub[0] != 1) continue;
      for (size_t k = 0; k < logs.size(); ++k)
        if (logs[k].topic.starts_with(sub.substr(1))) subscribed[k] = true;
    }
    while (s.in && s.in->recv(m, zmq::recv_flags::dontwait)) {
      zmq::message_t body;
      if (!m.more() || !s.in->recv(body)) continue;
      protocol::SubjectDescriptionMessage d;
      if (!m.to_string().starts_with("subject/") ||
          protocol::DecodeSubjectDescription(
              {static_cast<const uint8_t*>(body.data()), body.size()}, &d) !=
              protocol::DecodeStatus::kOk)
        continue;
      for (size_t k = 0; k < logs.size(); ++k) {
        if (logs[k].name != d.subject) continue;
        if (setup.check_hash && d.marker_set_hash != setup.marker_hash)
          throw std::runtime_error(
              "replay: the daemon's subject '" + d.subject +
              "' expects other markers, or another order, than this replay sends (model hash "
              "mismatch): a C3D's markers are sent in the order of --subject SUBJECT.toml "
              "(default: "
              "the built-in humanoid's), or with --marker-set NAME in that set's order, which a "
              "subject calibrated live with that marker_set expects");
        // Frames at another rate are all dropped as rate_mismatch: said here, as the
        // hash is (the replay ended "frames lost 360", exit 2, and nothing said why), by
        // the daemon's own rule.
        const double subject_hz = d.rate_hz, frames_hz = setup.capture_rate_hz;
        if (setup.check_rate && subject_hz > 0.0 &&
            !protocol::CaptureRateAccepted(frames_hz, subject_hz)) {
          char line[320];
          std::snprintf(line, sizeof(line),
                        "replay: the daemon's subject '%s' is configured for %g Hz, and this "
                        "replay's frames are captured at %g Hz: the daemon would drop every one "
                        "as rate_mismatch (resample the take with mocap-sim synth --rate, or "
                        "set the subject's rate_hz)",
                        protocol::PrintableName(logs[k].name).c_str(), subject_hz, frames_hz);
          throw std::runtime_error(line);
        }
        described[k] = true;
        logs[k].lookahead_since = {{0, d.lookahead_frames}};
      }
    }
  }
}

// A thread that stamps each skeleton frame on arrival and scores it against the truth.
class SkeletonReceiver {
 public:
  SkeletonReceiver(zmq::socket_t& in, std::vector<SubjectLog>& logs, const ScheduleSetup& setup)
      : in_(in), logs_(logs), setup_(setup) {
    if (setup_.skeleton != nullptr) {
      accuracy_.emplace(*setup_.skeleton);
      for (int j = setup_.skeleton->num_joints() - 1; j >= 0; --j)
        if (setup_.skeleton->joint(j).type == JointType::kFree) translating_joint_ = j;
    }
    thread_ = std::thread([this] { Run(); });
  }
  ~SkeletonReceiver() { Stop(); }
  SkeletonReceiver(const SkeletonReceiver&) = delete;
  SkeletonReceiver& operator=(const SkeletonReceiver&) = delete;

  void Stop() {
    running_ = false;
    if (thread_.joinable()) thread_.join();
  }
  uint64_t received() const { return received_.load(); }
  uint64_t duplicated() const { return duplicated_.load(); }
  uint64_t stream_checked() const { return stream_checked_.load(); }
  uint64_t stream_mismatched() const { return stream_mismatched_.load(); }
  /// Valid after Stop().
  const std::optional<PoseErrorAccumulator>& accuracy() const { return accuracy_; }
  /// Valid after Stop(): frames with a truth that could not be scored, and why (the first reason).
  uint64_t unscored() const { return unscored_; }
  const std::string& unscored_reason() const { return unscored_reason_; }
  /// Valid after Stop(): which subject and frame number each scored frame was.
  const std::vector<std::pair<size_t, uint64_t>>& scored() const { return scored_; }

 private:
  void Run() {
    zmq::pollitem_t item = {in_.handle(), 0, ZMQ_POLLIN, 0};
    protocol::SkeletonFrameMessage message;
    std::optional<KinematicsWorkspace> solved_fk, truth_fk;
    Pose solved, scratch;
    const Skeleton* skeleton = setup_.skeleton;
    if (skeleton != nullptr) {
      solved_fk.emplace(*skeleton);
      truth_fk.emplace(*skeleton);
      solved = RestPose(*skeleton);
    }
    zmq::message_t topic, body;
    while (running_.load()) {
      zmq::poll(&item, 1, std::chrono::milliseconds(5));
      while (in_.recv(topic, zmq::recv_flags::dontwait)) {
        if (!topic.more() || !in_.recv(body)) continue;
        const int64_t now = SteadyNs();
        if (topic.to_string().starts_with("subject/")) {
          NoteLookahead(body, now);
          continue;
        }
        if (!topic.to_string().starts_with("skeleton/")) continue;
        if (protocol::DecodeSkeletonFrame({static_cast<const uint8_t*>(body.data()), body.size()},
                                          &message) != protocol::DecodeStatus::kOk)
          continue;
        size_t k = 0;
        while (k < logs_.size() && logs_[k].name != message.subject) ++k;
        if (k == logs_.size()) continue;
        const auto slot = logs_[k].received_ns.find(
            {setup_.key_by_session ? message.stream.session_id : 0, message.frame_number});
        if (slot == logs_[k].received_ns.end())
          continue;  // not one we sent (inserted by the daemon)
        if (slot->second != 0) {
          ++duplicated_;
          continue;
        }
        slot->second = now;
        ++received_;
        if (setup_.sent_stream && message.version >= protocol::kVersion2) {
          ++stream_checked_;
          if (!(message.stream == setup_.sent_stream(k, message.frame_number)))
            ++stream_mismatched_;
        }
        const Pose* expected =
            setup_.truth ? setup_.truth(k, message.frame_number, &scratch) : nullptr;
        if (expected == nullptr) continue;
        if (static_cast<int>(message.rotations.size()) != skeleton->num_joints()) {
          Unscored("the daemon's skeleton has " + std::to_string(message.rotations.size()) +
                   " joints, the take's " + std::to_string(skeleton->num_joints()) +
                   ": the daemon's subject is not this take's");
          continue;
        }
        if (message.global_positions.size() == message.rotations.size()) {
          // The global block: exact for any skeleton.
          for (size_t j = 0; j < message.global_positions.size(); ++j) {
            solved_fk->p_WJ[j] = message.global_positions[j];
            solved_fk->R_WJ[j] = message.global_rotations[j].normalized().toRotationMatrix();
          }
        } else if (translating_joint_ > 0) {
          // Only joint 0's translation is on the wire (protocol/README.md, "Skeleton pose").
          Unscored("the skeleton translates at joint '" + skeleton->joint(translating_joint_).name +
                   "', not joint 0, and the daemon sends no global transforms (set [output] "
                   "global_transforms = true to score it)");
          continue;
        } else {
          for (size_t j = 0; j < message.rotations.size(); ++j)
            solved.rotation[j] = message.rotations[j].normalized();
          solved.translation[0] = message.root_translation;
          ForwardKinematics(*skeleton, solved, &*solved_fk);
        }
        ForwardKinematics(*skeleton, *expected, &*truth_fk);
        accuracy_->Add(*truth_fk, *solved_fk);
        scored_.push_back({k, message.frame_number});
      }
    }
  }

  // A description whose K differs from the one in effect: a reload changed the subject's
  // lookahead, and its skeletons from now on are held that much (only this thread writes
  // lookahead_since while the replay runs).
  void NoteLookahead(const zmq::message_t& body, int64_t now) {
    protocol::SubjectDescriptionMessage d;
    if (protocol::DecodeSubjectDescription({static_cast<const uint8_t*>(body.data()), body.size()},
                                           &d) != protocol::DecodeStatus::kOk)
      return;
    for (SubjectLog& log : logs_)
      if (log.name == d.subject &&
          (log.lookahead_since.empty() || log.lookahead_since.back().second != d.lookahead_frames))
        log.lookahead_since.push_back({now, d.lookahead_frames});
  }

  zmq::socket_t& in_;
  std::vector<SubjectLog>& logs_;
  const ScheduleSetup& setup_;
  std::optional<PoseErrorAccumulator> accuracy_;
  int translating_joint_ = 0;  ///< The first free joint of the truth's skeleton.
  uint64_t unscored_ = 0;
  std::string unscored_reason_;

  void Unscored(const std::string& reason) {
    ++unscored_;
    if (unscored_reason_.empty()) unscored_reason_ = reason;
  }
  std::vector<std::pair<size_t, uint64_t>> scored_;
  std::atomic<bool> running_{true};
  std::atomic<uint64_t> received_{0}, duplicated_{0}, stream_checked_{0}, stream_mismatched_{0};
  std::thread thread_;
};

// Sends everything the producer makes, each message at its due time; returns the number
// of marker frames sent. Prints a status line about every second.
uint64_t SendAll(zmq::socket_t& out, std::vector<SubjectLog>& logs, const FrameProducer& produce,
                 const SkeletonReceiver* receiver, const ReplayOptions& o, int64_t start) {
  std::vector<uint8_t> bytes;
  Outgoing next;
  int64_t next_status = start + 1'000'000'000;
  uint64_t sent = 0;
  while (!(o.stop != nullptr && o.stop->load()) && produce(&next, &bytes)) {
    if (next.due_ns >= 0)
      std::this_thread::sleep_until(
          Clock::time_point(std::chrono::nanoseconds(start + next.due_ns)));
    SubjectLog& log = logs[next.subject];
    const int64_t now = SteadyNs();
    log.sent.push_back({next.session, next.frame_number, now, next.end_of_stream});
    if (!out.send(zmq::buffer(log.topic), zmq::send_flags::sndmore)) {
      const std::string seconds = ConnectTimeoutText(o);
      throw std::runtime_error("replay: could not queue a frame for " + o.to + " for " + seconds +
                               " after " + std::to_string(sent) +
                               " (the connection was dropped, as after a refused handshake: "
                               "with CURVE, are this replay's keys the daemon's?)");
    }
    out.send(zmq::buffer(bytes), zmq::send_flags::none);
    if (!next.end_of_stream) ++sent;
    if (o.on_status && now >= next_status) {
      char line[160];
      std::snprintf(
          line, sizeof(line), "t=%6.1fs  sent %8llu frames  received %8llu skeletons",
          static_cast<double>(now - start) * 1e-9, static_cast<unsigned long long>(sent),
          static_cast<unsigned long long>(receiver != nullptr ? receiver->received() : 0));
      o.on_status(line);
      next_status += 1'000'000'000;
    }
  }
  return sent;
}

// The report's K: the first subject's, and each subject's in turn when they differ.
void SummariseLookaheads(const std::vector<SubjectLog>& logs, ReplayReport* report) {
  if (logs.empty() || logs.front().lookahead_since.empty()) return;
  report->lookahead = logs.front().lookahead_since.front().second;
  bool one_k = true;
  for (const SubjectLog& log : logs)
    for (const auto& [since, k] : log.lookahead_since) one_k = one_k && k == report->lookahead;
  if (one_k) return;
  for (const SubjectLog& log : logs) {
    std::vector<int> ks;
    for (const auto& [since, k] : log.lookahead_since) ks.push_back(k);
    report->lookahead_by_subject.emplace_back(log.name, std::move(ks));
  }
}

// End-to-end latency (sent -> skeleton) and processing latency (the message that let the
// frame out -> skeleton) from the logs, into the report.
void MeasureLatencies(const std::vector<SubjectLog>& logs, double frame_period_s, int64_t start_ns,
                      double interval_s, ReplayReport* report) {
  std::vector<std::vector<double>> per_interval;
  std::vector<double> e2e;
  e2e.reserve(report->frames_sent);
  report->processing_ms.reserve(report->frames_sent);
  for (const SubjectLog& log : logs) {
    for (size_t i = 0; i < log.sent.size(); ++i) {
      const SubjectLog::Sent& s = log.sent[i];
      if (s.end_of_stream) continue;
      const int64_t got = log.received_ns.at({s.session, s.frame_number});
      if (got == 0) continue;
      e2e.push_back(static_cast<double>(got - s.sent_ns) * 1e-6);
      // This subject's K when the skeleton came (subjects may differ; a reload changes it).
      const auto K = static_cast<uint64_t>(log.LookaheadAt(got));
      // What let this frame out: the first later frame numbered at least K on (the
      // daemon fills numbers that never came), or the end of its stream.
      int64_t trigger_ns = 0;
      for (size_t j = i; j < log.sent.size(); ++j) {
        const SubjectLog::Sent& later = log.sent[j];
        // A new capture session lets the old one's held frames out, as an end does.
        const bool ends = later.end_of_stream || later.session != s.session;
        if (ends || later.frame_number < s.frame_number ||
            later.frame_number >= s.frame_number + K) {
          if (ends || later.frame_number >= s.frame_number + K) trigger_ns = later.sent_ns;
          break;
        }
      }
      if (trigger_ns == 0) continue;
      const double ms = static_cast<double>(got - trigger_ns) * 1e-6;
      report->processing_ms.push_back(ms);
      if (interval_s > 0) {
        const auto slot = static_cast<size_t>(
            std::max<double>(0.0, static_cast<double>(trigger_ns - start_ns) * 1e-9 / interval_s));
        if (slot >= per_interval.size()) per_interval.resize(slot + 1);
        per_interval[slot].push_back(ms);
      }
      if (ms * 1e-3 > frame_period_s) ++report->frames_late;
    }
  }
  report->end_to_end = SummariseLatencies(e2e);
  report->processing = SummariseLatencies(report->processing_ms);
  report->interval_s = interval_s;
  for (size_t k = 0; k < per_interval.size(); ++k)
    report->processing_per_interval.push_back(
        {static_cast<double>(k) * interval_s, SummariseLatencies(std::move(per_interval[k]))});
}

}  // namespace

int64_t SteadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch())
      .count();
}

int SubjectLog::LookaheadAt(int64_t arrival_ns) const {
  int k = 0;
  for (const auto& [since, frames] : lookahead_since)
    if (since <= arrival_ns) k = frames;
  return k;
}

ReplayReport RunSchedule(std::vector<SubjectLog>& logs, const FrameProducer& produce,
                         const ScheduleSetup& setup, const ReplayOptions& o) {
  if (!(o.connect_timeout_s >= 0.0) || !(o.drain_timeout_s >= 0.0))
    throw std::runtime_error("replay: the connect and drain timeouts must be 0 s or more");
  Sockets sockets;
  OpenSockets(o, &sockets);
  if (sockets.push_handshakes) WaitForPushHandshake(sockets, o);
  ReplayReport report;
  report.subjects = static_cast<int>(logs.size());
  WaitForDaemon(sockets, logs, setup, o);

  std::optional<SkeletonReceiver> receiver;
  if (sockets.in) receiver.emplace(*sockets.in, logs, setup);
  const int64_t start = SteadyNs();
  const uint64_t sent =
      SendAll(sockets.out, logs, produce, receiver ? &*receiver : nullptr, o, start);
  report.frames_sent = sent;
  // Until the last frame went out (the end of stream), as the log has it: a clock read
  // after SendAll returns could come after the skeletons that frame let out.
  int64_t last_sent_ns = start;
  for (const SubjectLog& log : logs)
    if (!log.sent.empty()) last_sent_ns = std::max(last_sent_ns, log.sent.back().sent_ns);
  report.send_seconds = static_cast<double>(last_sent_ns - start) * 1e-9;
  if (!receiver) return report;
  report.listened = true;
  const int64_t drain_deadline = SteadyNs() + TimeoutNs(o.drain_timeout_s);
  while (receiver->received() < sent && SteadyNs() < drain_deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  receiver->Stop();

  report.frames_received = receiver->received();
  report.frames_duplicated = receiver->duplicated();
  report.stream_checked = receiver->stream_checked();
  report.stream_mismatched = receiver->stream_mismatched();
  report.frames_lost = sent - std::min<uint64_t>(sent, report.frames_received);
  SummariseLookaheads(logs, &report);
  MeasureLatencies(logs, setup.frame_period_s, start, o.latency_interval_s, &report);
  // Until the last skeleton came back, not until the last frame went out: at --rate max
  // the sender finishes long before the daemon does.
  int64_t last_received_ns = start;
  for (const SubjectLog& log : logs)
    for (const auto& [frame, ns] : log.received_ns)
      last_received_ns = std::max(last_received_ns, ns);
  report.receive_seconds = static_cast<double>(last_received_ns - start) * 1e-9;
  report.throughput_fps = report.receive_seconds > 0
                              ? static_cast<double>(report.frames_received) / report.receive_seconds
                              : 0.0;
  report.frames_unscored = receiver->unscored();
  report.unscored_reason = receiver->unscored_reason();
  const auto& accuracy = receiver->accuracy();
  if (accuracy && accuracy->frames() > 0) {
    report.has_truth = true;
    report.mean_position_error_cm = accuracy->mean_position_error_m() * 100.0;
    report.max_position_error_cm = accuracy->max_position_error_m() * 100.0;
    report.mean_rotation_error_deg = accuracy->mean_rotation_error_rad() * 180.0 / M_PI;
    const double p999_m = accuracy->frame_position_error_quantile_m(0.999);
    report.p999_frame_error_cm = p999_m * 100.0;
    int joint = -1;
    const int worst = accuracy->worst_frame(&joint);
    if (worst >= 0 && setup.skeleton != nullptr) {
      const auto& [subject, frame_number] = receiver->scored()[static_cast<size_t>(worst)];
      report.worst_frame_subject = logs[subject].name;
      report.worst_frame_number = frame_number;
      report.worst_frame_joint = setup.skeleton->joint(joint).name;
      // In metres as measured: through centimetres and back, the p99.9 frame itself could
      // fall below its own threshold. A take without error has no tail to speak of.
      if (p999_m > 0.0) {
        std::vector<std::string> names;
        for (const auto& log : logs) names.push_back(log.name);
        report.p999_tail = SummarizeTail(
            accuracy->frames_at_least(p999_m), receiver->scored(), names, *setup.skeleton,
            static_cast<uint64_t>(std::ceil(std::max(setup.capture_rate_hz, 1.0))));
      }
    }
  }
  return report;
}

}  // namespace mocapd::replay
