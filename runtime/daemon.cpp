// The daemon's data plane (ZeroMQ ingest, per-subject pipelines, publish) and control
// plane (Asio signals, timers, reload, HTTP).
#include "runtime/daemon.hpp"

#include <spdlog/spdlog.h>

#include <malloc.h>  // malloc_trim: give a burst's freed memory back
#include <boost/asio/io_context.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>

#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <csignal>
#include <cstdio>
#include <map>
#include <optional>
#include <set>
#include <tuple>
#include <zmq.hpp>

#include "runtime/http_server.hpp"

namespace mocapd {
namespace {

// A float rate as the double its shortest decimal spells: 119.88f widened is
// 119.87999725341797, which is what /subjects printed for the rate a sender wrote.
double AsWritten(float value) {
  char text[32];
  const auto written = std::to_chars(text, text + sizeof text, value);
  double out = value;
  std::from_chars(text, written.ptr, out);
  return out;
}

int64_t SteadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

int64_t Seconds(double s) { return static_cast<int64_t>(s * 1e9); }

// ZeroMQ binds an interface or an address, not a host name, and an IPv6 address only with
// the socket's IPv6 option: "tcp://localhost:N" and "tcp://[::1]:N", which the config
// takes as loopback, failed with "No such device".
void BindTo(zmq::socket_t& socket, const std::string& endpoint) {
  const std::string localhost = "tcp://localhost:";
  if (endpoint.find('[') != std::string::npos) socket.set(zmq::sockopt::ipv6, 1);
  socket.bind(endpoint.rfind(localhost, 0) == 0
                  ? "tcp://127.0.0.1:" + endpoint.substr(localhost.size())
                  : endpoint);
}
void ConnectTo(zmq::socket_t& socket, const std::string& endpoint) {
  if (endpoint.find('[') != std::string::npos) socket.set(zmq::sockopt::ipv6, 1);
  socket.connect(endpoint);
}

}  // namespace

uint64_t DaemonStats::published_total() const {
  uint64_t n = retired_published;
  for (const SubjectStats& s : subjects) n += s.counters.frames_published;
  return n;
}

uint64_t DaemonStats::dropped_total() const {
  uint64_t n = retired_dropped;
  for (uint64_t d : unattributed_dropped) n += d;
  for (const SubjectStats& s : subjects) n += s.counters.dropped_total();
  return n;
}

uint64_t DaemonStats::pending_total() const {
  uint64_t n = 0;
  for (const SubjectStats& s : subjects) n += s.pending;
  return n;
}

namespace {

// Between the workers and the forwarding thread (in process): large, so a burst waits in
// the pipe rather than being dropped where no counter sees it.
constexpr int kInternalHighWaterMark = 1'000'000;

// zmq::poll, except that a signal arriving on this thread is not an error (cppzmq throws
// on EINTR, and an exception leaving a thread ends the process). False: nothing ready.
bool PollRetryingOnSignals(zmq::pollitem_t* items, size_t count,
                           std::chrono::milliseconds timeout) {
  try {
    return zmq::poll(items, count, timeout) > 0;
  } catch (const zmq::error_t& e) {
    if (e.num() == EINTR) return false;
    throw;
  }
}

}  // namespace

// A subject's runner, with its live-view slot when the view is on.
static std::unique_ptr<SubjectRunner> MakeRunner(const SubjectConfig& subject,
                                                 const DaemonConfig& config, LiveViewBoard* board,
                                                 LiveCalibrationBoard& calibrations) {
  auto runner = std::make_unique<SubjectRunner>(subject, config);
  if (subject.live.enabled) runner->AttachLiveCalibration(calibrations.Attach(subject, config));
  if (board)
    runner->AttachLiveView(board->Register(subject.name, *subject.model.skeleton,
                                           *subject.model.markers, subject.character.get()));
  return runner;
}

// ---------------------------------------------------------------------------------------
// Data plane: workers, each a thread owning its input and output sockets and its runners.

struct Daemon::DataPlane final : OutputSink {
  DataPlane(DaemonConfig cfg, zmq::context_t& shared_context, int worker_index,
            std::shared_ptr<LiveViewBoard> board, LiveCalibrationBoard& calibrations)
      : context(shared_context),
        config(std::move(cfg)),
        index(worker_index),
        view_board(std::move(board)) {
    for (const SubjectConfig& s : config.subjects)
      runners.push_back(MakeRunner(s, config, view_board.get(), calibrations));
    frame.positions.reserve(protocol::kMaxMarkers);
    frame.valid.reserve(protocol::kMaxMarkers);
    frame.subject.reserve(protocol::kMaxSubjectName);
  }

  // Binds and connects; throws std::runtime_error naming the endpoint.
  void Open() {
    try {
      input = zmq::socket_t(context, config.input_pattern == InputPattern::kSub
                                         ? zmq::socket_type::sub
                                         : zmq::socket_type::pull);
      input.set(zmq::sockopt::rcvhwm, config.receive_high_water_mark);
      input.set(zmq::sockopt::linger, 0);
      if (config.curve) {
        const bool client = config.input_pattern == InputPattern::kSub;
        if (client)
          curve::MakeClient(input, config.curve_keys, config.curve_input_server_key);
        else
          curve::MakeServer(input, config.curve_keys, CurveSocketName(CurveSocket::kInput));
        // Watched from before the first handshake (Open runs before the worker starts).
        if (authenticator) authenticator->Monitor(input.handle(), CurveSocket::kInput, client);
      }
      if (config.input_pattern == InputPattern::kSub) {
        if (config.subscribe_all) {
          input.set(zmq::sockopt::subscribe, "");
        } else {
          for (const auto& r : runners) {
            subscribed_topics.insert(Topic("markers", r->name()));
            input.set(zmq::sockopt::subscribe, Topic("markers", r->name()));
          }
        }
        ConnectTo(input, config.input_endpoint);
      } else {
        BindTo(input, config.input_endpoint);
      }
    } catch (const zmq::error_t& e) {
      throw std::runtime_error("input endpoint '" + config.input_endpoint + "': " + e.what());
    }
    try {
      output = zmq::socket_t(context, zmq::socket_type::pub);
      output.set(zmq::sockopt::sndhwm,
                 forwarded ? kInternalHighWaterMark : config.send_high_water_mark);
      // Give subscribers a moment to receive the last frames at shutdown, never forever.
      output.set(zmq::sockopt::linger, 2000);
      if (config.curve && !forwarded) {
        curve::MakeServer(output, config.curve_keys, CurveSocketName(CurveSocket::kOutput));
        if (authenticator) authenticator->Monitor(output.handle(), CurveSocket::kOutput, false);
      }
      BindTo(output, config.output_endpoint);
    } catch (const zmq::error_t& e) {
      throw std::runtime_error("output endpoint '" + config.output_endpoint + "': " + e.what());
    }
  }

  void Send(std::string_view topic, std::span<const uint8_t> message) override {
    // PUB never blocks: a slow subscriber loses messages at its high-water mark instead.
    const auto a = output.send(zmq::const_buffer(topic.data(), topic.size()),
                               zmq::send_flags::sndmore | zmq::send_flags::dontwait);
    const auto b = a ? output.send(zmq::const_buffer(message.data(), message.size()),
                                   zmq::send_flags::dontwait)
                     : std::nullopt;
    if (!b) ++stats.output_send_failures;
  }

  SubjectRunner* FindRunner(std::string_view name) {
    for (auto& r : runners)
      if (r->name() == name) return r.get();
    return nullptr;
  }

  void Drop(DropReason reason) {
    ++stats.unattributed_dropped[static_cast<size_t>(reason)];
    if (reason != DropReason::kUnknownSubject) unattributed_reason = reason;
  }
  void DropUnknown(const std::string& subject) {
    stats.last_unknown_subject.assign(subject);  // reserved for the longest name: no allocation
    Drop(DropReason::kUnknownSubject);
  }

  // One message from the input socket: handled, then whether it is one more of a run of
  // messages dropped before any subject could be named (judged as a subject's drops are).
  void Handle(size_t part_count, const zmq::message_t& message, int64_t receive_ns) {
    unattributed_reason.reset();
    HandleMessage(part_count, message, receive_ns);
    if (!unattributed_reason) {
      unattributed_run = 0;
      stats.rejecting_unattributed = false;
      return;
    }
    if (unattributed_run++ == 0) unattributed_run_first_ns = receive_ns;
    stats.rejecting_unattributed_reason = *unattributed_reason;
    stats.rejecting_unattributed =
        unattributed_run >= SubjectRunner::kRejectingMinFrames &&
        receive_ns - unattributed_run_first_ns >= SubjectRunner::kRejectingAfterNs;
  }
  std::optional<DropReason> unattributed_reason;  // set by Drop while a message is handled
  uint64_t unattributed_run = 0;
  int64_t unattributed_run_first_ns = 0;

  void HandleMessage(size_t part_count, const zmq::message_t& message, int64_t receive_ns) {
    ++stats.messages_in;
    // One part (the message), or two (a topic, then the message).
    if (part_count > 2) return Drop(DropReason::kMalformed);
    if (message.size() > config.max_message_bytes) return Drop(DropReason::kOversized);
    const std::span<const uint8_t> bytes(static_cast<const uint8_t*>(message.data()),
                                         message.size());
    protocol::MessageType type;
    if (protocol::PeekType(bytes, &type) != protocol::DecodeStatus::kOk)
      return Drop(DropReason::kMalformed);
    if (type == protocol::MessageType::kEndOfStream) {
      if (protocol::DecodeEndOfStream(bytes, &end_of_stream) != protocol::DecodeStatus::kOk)
        return Drop(DropReason::kMalformed);
      SubjectRunner* runner = FindRunner(end_of_stream.subject);
      if (runner == nullptr) return DropUnknown(end_of_stream.subject);
      ++stats.control_messages;
      return runner->EndOfStream(*this);
    }
    if (type != protocol::MessageType::kMarkerFrame) return Drop(DropReason::kNotMarkerFrame);
    const protocol::DecodeStatus status = protocol::DecodeMarkerFrame(bytes, &frame);
    if (status != protocol::DecodeStatus::kOk) {
      const DropReason reason = status == protocol::DecodeStatus::kNonFinite
                                    ? DropReason::kNonFinite
                                    : DropReason::kMalformed;
      // Failed after the subject's name: charged to that subject, so a sender whose frames
      // all fail (a rate fraction contradicting its float) is named in /health.
      SubjectRunner* runner = frame.subject.empty() ? nullptr : FindRunner(frame.subject);
      if (runner != nullptr) {
        (void)runner->Drop(frame, reason, receive_ns);
        return;
      }
      return Drop(reason);
    }
    SubjectRunner* runner = FindRunner(frame.subject);
    if (runner == nullptr) return DropUnknown(frame.subject);
    runner->Accept(frame, receive_ns, *this);
  }

  // Receives the messages waiting on the input socket, at most a batch of them, so a
  // backlog (a burst, a replay at full speed) never keeps the loop from its housekeeping:
  // the watchdog, the statistics the control plane serves, reloads. Returns how many.
  static constexpr size_t kBatchMessages = 512;
  static constexpr int64_t kBatchNs = 4'000'000;
  size_t DrainInput() {
    size_t n = 0;
    const int64_t until = SteadyNs() + kBatchNs;
    while (n < kBatchMessages && input.recv(body, zmq::recv_flags::dontwait)) {
      size_t parts = 1;
      while (body.more()) {
        // The rest of a multipart message arrives with its first part; keep the last.
        (void)input.recv(extra, zmq::recv_flags::none);
        std::swap(body, extra);
        ++parts;
      }
      const int64_t now = SteadyNs();
      Handle(parts, body, now);
      ++n;
      if (now > until) break;
    }
    const bool full = n >= kBatchMessages || (n > 0 && SteadyNs() > until);
    stats.catching_up = full;
    stats.full_batches += full;
    return n;
  }

  void ApplyPendingReload() {
    std::unique_ptr<PendingReload> reload;
    {
      std::lock_guard lock(mailbox_mutex);
      reload = std::move(pending_reload);
      has_pending_reload.store(false);
    }
    if (!reload) return;
    std::vector<std::unique_ptr<SubjectRunner>> next;
    for (auto& fresh : reload->runners) {
      auto old = std::find_if(runners.begin(), runners.end(),
                              [&](const auto& r) { return r && r->name() == fresh->name(); });
      if (old != runners.end() && (*old)->fingerprint() == fresh->fingerprint()) {
        next.push_back(std::move(*old));  // unchanged: keeps its lookahead and timing
        continue;
      }
      if (old != runners.end()) {
        (*old)->Flush(*this);
        fresh->InheritCounters(**old);
        old->reset();
      }
      next.push_back(std::move(fresh));
    }
    for (auto& removed : runners) {
      if (!removed) continue;
      removed->Flush(*this);
      stats.retired_published += removed->counters().frames_published;
      stats.retired_dropped += removed->counters().dropped_total();
    }
    runners = std::move(next);
    // Only the topics that changed: unsubscribing a kept subject's topic and subscribing
    // it again lets the publisher filter out whatever it sends in between, and the kept
    // subject then bridges a frame it was sent as a repaired one.
    if (config.input_pattern == InputPattern::kSub && !config.subscribe_all) {
      std::set<std::string> wanted;
      for (const auto& r : runners) wanted.insert(Topic("markers", r->name()));
      for (const std::string& topic : subscribed_topics)
        if (!wanted.contains(topic)) input.set(zmq::sockopt::unsubscribe, topic);
      for (const std::string& topic : wanted)
        if (!subscribed_topics.contains(topic)) input.set(zmq::sockopt::subscribe, topic);
      subscribed_topics = std::move(wanted);
    }
    // Endpoints and socket options stay as bound; the rest of the config applies now.
    reload->config.input_endpoint = config.input_endpoint;
    reload->config.input_pattern = config.input_pattern;
    reload->config.output_endpoint = config.output_endpoint;
    reload->config.subscribe_all = config.subscribe_all;
    config = std::move(reload->config);
    // A reload posted while an older one waited replaced it: the count is the newest's.
    stats.reloads = reload->sequence;
    for (const auto& r : runners) r->PublishDescription(*this);
  }

  void Snapshot(bool wait) {
    std::unique_lock lock(stats_mutex, std::defer_lock);
    if (wait) {
      lock.lock();
    } else if (!lock.try_lock()) {
      return;  // the control plane is reading; next time
    }
    const int64_t now = SteadyNs();
    DaemonStats& out = shared_stats;
    auto subjects = std::move(out.subjects);
    out = stats;
    out.subjects = std::move(subjects);
    out.uptime_s = static_cast<double>(now - start_ns) * 1e-9;
    out.data_plane_heartbeat_ns = now;
    out.subjects.resize(runners.size());
    for (size_t i = 0; i < runners.size(); ++i) {
      const SubjectRunner& r = *runners[i];
      SubjectStats& s = out.subjects[i];
      s.name = r.name();
      s.state = r.state();
      s.counters = r.counters();
      s.cleanup = r.cleanup_counters();
      s.pending = r.pending_received();
      s.since_last_input_s =
          r.last_input_ns() < 0 ? -1.0 : static_cast<double>(now - r.last_input_ns()) * 1e-9;
      const protocol::SubjectDescriptionMessage& d = r.description();
      s.markers = static_cast<int>(d.marker_names.size());
      s.joints = static_cast<int>(d.joint_names.size());
      s.rate_hz = AsWritten(d.rate_hz);
      s.lookahead = d.lookahead_frames;
      s.marker_set_hash = d.marker_set_hash;
      s.skeleton_hash = d.skeleton_hash;
      const auto rejecting = r.rejecting();
      s.rejecting_input = rejecting.has_value();
      if (rejecting) s.rejecting_reason = *rejecting;
      s.mismatched_rate_hz = AsWritten(static_cast<float>(r.mismatched_rate_hz()));
      std::tie(s.mismatched_model_hash, s.mismatched_marker_count) = r.mismatched_model();
      s.character = r.character_info();
      s.model_suspect = r.model_suspect();
      s.unobserved_for_s = r.unobserved_since_ns() < 0
                               ? 0.0
                               : static_cast<double>(now - r.unobserved_since_ns()) * 1e-9;
      s.unstable_input = r.unstable_input(now);
      s.unstable_cause = r.unstable_cause();
      s.model_distance_mm = r.model_distance_m() * 1e3;
      s.worker = index;
      s.config_rank = r.rank();
    }
  }

  void Loop() {
    start_ns = SteadyNs();
    int64_t next_tick = start_ns;
    int64_t next_snapshot = start_ns;
    zmq::pollitem_t items[] = {{input.handle(), 0, ZMQ_POLLIN, 0}};
    stats.last_unknown_subject.reserve(protocol::kMaxSubjectName + 1);
    stats.running = true;
    while (!stop.load(std::memory_order_acquire)) {
      if (has_pending_reload.load(std::memory_order_acquire)) ApplyPendingReload();
      // A short poll so the watchdog, the stats tick and a stop request are seen promptly.
      PollRetryingOnSignals(items, 1, std::chrono::milliseconds(2));
      // A backlog is read batch by batch without waiting on the poll.
      if ((items[0].revents & ZMQ_POLLIN) != 0 || stats.catching_up) DrainInput();
      const int64_t now = SteadyNs();
      for (auto& r : runners) r->CheckStall(now, Seconds(config.watchdog_timeout_s), *this);
      if (now >= next_tick) {
        for (auto& r : runners) {
          r->PublishStatus(now, *this);
          r->PublishDescription(*this);
        }
        next_tick = now + Seconds(config.stats_interval_s);
      }
      if (now >= next_snapshot) {
        Snapshot(false);
        next_snapshot = now + 20'000'000;  // 20 ms
      }
    }
    // Graceful shutdown: read what has already arrived (a live feed never falls silent,
    // so reading stops at once the queue is empty, or after kShutdownReadNs at most),
    // publish everything the lookahead holds, then let PUB linger to send it.
    stats.stopping = true;
    Snapshot(true);
    const int64_t read_until = SteadyNs() + kShutdownReadNs;
    for (int quiet = 0; quiet < 2 && SteadyNs() < read_until;) {
      PollRetryingOnSignals(items, 1, std::chrono::milliseconds(5));
      quiet = (items[0].revents & ZMQ_POLLIN) != 0 && DrainInput() > 0 ? 0 : quiet + 1;
      Snapshot(false);
    }
    for (auto& r : runners) {
      r->Flush(*this);
      r->StopPublishing();
      r->PublishStatus(SteadyNs(), *this);
    }
    stats.running = false;
    Snapshot(true);
    input.close();
    output.close();
    finished.store(true, std::memory_order_release);
  }

  static constexpr int64_t kShutdownReadNs = 300'000'000;

  struct PendingReload {
    DaemonConfig config;
    std::vector<std::unique_ptr<SubjectRunner>> runners;
    uint64_t sequence = 0;  // the control plane's count of reloads, this one included
  };

  zmq::context_t& context;
  zmq::socket_t input;
  zmq::socket_t output;
  std::set<std::string> subscribed_topics;  // the input's (a SUB's, per subject)
  DaemonConfig config;
  int index = 0;           // which worker
  bool forwarded = false;  // publishes to the forwarding thread, not to consumers
  CurveAuthenticator* authenticator = nullptr;  // counts this worker's failed handshakes
  std::shared_ptr<LiveViewBoard> view_board;    // null: no live view
  std::vector<std::unique_ptr<SubjectRunner>> runners;
  protocol::MarkerFrameMessage frame;
  protocol::EndOfStreamMessage end_of_stream;
  zmq::message_t body, extra;
  DaemonStats stats;  // owned by the data plane thread
  int64_t start_ns = 0;
  std::thread thread;
  std::atomic<bool> stop{false};
  std::atomic<bool> finished{false};  // Loop has returned: the thread can be joined at once
  std::mutex mailbox_mutex;
  std::unique_ptr<PendingReload> pending_reload;
  std::atomic<bool> has_pending_reload{false};
  mutable std::mutex stats_mutex;
  DaemonStats shared_stats;
};

// ---------------------------------------------------------------------------------------
// Control plane: Asio on the thread that called Run.

struct Daemon::ControlPlane {
  boost::asio::io_context io;
  std::optional<boost::asio::signal_set> signals;
  std::optional<boost::asio::steady_timer> tick;
  std::unique_ptr<HttpServer> http;
  std::unique_ptr<LiveViewHub> live;  // the browser view's WebSockets (with the HTTP endpoint)
  // Each endpoint's last answer, rendered at most once per kRenderPeriodNs however often
  // it is asked for: a scraper hammering /metrics costs a copy, not a render and a turn
  // at the data plane's statistics lock.
  static constexpr int64_t kRenderPeriodNs = 20'000'000;
  struct Rendered {
    int64_t at_ns = -1;
    HttpResponse response;
  };
  std::map<std::string, Rendered> rendered;
  DaemonConfig config;  // the control plane's copy (what was last applied)
  DaemonStats last_logged;
  std::array<int64_t, kDropReasonCount> last_drop_log_ns{};
  std::array<uint64_t, kDropReasonCount> logged_drops{};
  // When each reason's count last grew (seen at a tick), and its count then: a line that
  // waited out the log interval says how long ago its drops stopped.
  std::array<int64_t, kDropReasonCount> last_drop_seen_ns{};
  std::array<uint64_t, kDropReasonCount> drops_at_last_tick{};
  // Per subject, the drops the last warning covered: the next one names who dropped what.
  std::map<std::string, std::array<uint64_t, kDropReasonCount>> logged_subject_drops;
  // Frame numbers that never arrived, per subject, as of the last line that said so.
  std::map<std::string, uint64_t> logged_skipped;
  int64_t last_skipped_log_ns = 0;
  int64_t last_log_ns = 0;
  bool data_plane_alive = true;
  bool stopping = false;
  std::optional<boost::asio::steady_timer> shutdown;  // polls the data plane's flush...
  std::function<void(const boost::system::error_code&)> on_shutdown_poll;  // ...with this
};

// ---------------------------------------------------------------------------------------
// With several workers, each publishes on its own inproc PUB and this thread forwards
// everything to the one output endpoint (and consumers' subscriptions back), so no socket
// is shared between threads and each subject's messages keep their order (one worker, one
// pipe). Stopped after the workers have flushed: it forwards what they left, then exits.

struct Daemon::OutputProxy {
  OutputProxy(zmq::context_t& context, const DaemonConfig& config, const std::string& prefix,
              int workers, CurveAuthenticator* authenticator)
      : from_workers(context, zmq::socket_type::xsub),
        to_consumers(context, zmq::socket_type::xpub),
        control_in(context, zmq::socket_type::pair),
        control_out(context, zmq::socket_type::pair) {
    // Inside the daemon nothing may be lost: the high-water mark is the consumers' (XPUB).
    from_workers.set(zmq::sockopt::rcvhwm, kInternalHighWaterMark);
    to_consumers.set(zmq::sockopt::sndhwm, config.send_high_water_mark);
    to_consumers.set(zmq::sockopt::linger, 2000);
    if (config.curve) {
      curve::MakeServer(to_consumers, config.curve_keys, CurveSocketName(CurveSocket::kOutput));
      if (authenticator) authenticator->Monitor(to_consumers.handle(), CurveSocket::kOutput, false);
    }
    try {
      BindTo(to_consumers, config.output_endpoint);
    } catch (const zmq::error_t& e) {
      throw std::runtime_error("output endpoint '" + config.output_endpoint + "': " + e.what());
    }
    try {
      for (int i = 0; i < workers; ++i) from_workers.connect(prefix + std::to_string(i));
      control_in.bind(prefix + "control");
      control_out.connect(prefix + "control");
    } catch (const zmq::error_t& e) {
      throw std::runtime_error("output forwarding '" + prefix + "': " + e.what());
    }
    thread = std::thread([this] { Loop(); });
  }

  void Loop() {
    zmq::pollitem_t items[] = {{from_workers.handle(), 0, ZMQ_POLLIN, 0},
                               {to_consumers.handle(), 0, ZMQ_POLLIN, 0},
                               {control_in.handle(), 0, ZMQ_POLLIN, 0}};
    zmq::message_t part;
    // Up to a batch of messages per wake-up: one per poll would let a burst fill the pipe.
    auto forward = [&](zmq::socket_t& from, zmq::socket_t& to) {
      for (int messages = 0; messages < 1024 && from.recv(part, zmq::recv_flags::dontwait);) {
        const bool more = part.more();
        (void)to.send(part, more ? zmq::send_flags::sndmore : zmq::send_flags::none);
        messages += more ? 0 : 1;
      }
    };
    for (;;) {
      if (!PollRetryingOnSignals(items, 3, std::chrono::milliseconds(-1))) continue;
      if ((items[1].revents & ZMQ_POLLIN) != 0) forward(to_consumers, from_workers);
      if ((items[0].revents & ZMQ_POLLIN) != 0) forward(from_workers, to_consumers);
      if ((items[2].revents & ZMQ_POLLIN) != 0) {
        // The workers have closed: what they sent is already in the pipe; pass it all on.
        zmq::pollitem_t rest = {from_workers.handle(), 0, ZMQ_POLLIN, 0};
        while (PollRetryingOnSignals(&rest, 1, std::chrono::milliseconds(20)))
          forward(from_workers, to_consumers);
        return;
      }
    }
  }

  void Stop() {
    if (!thread.joinable()) return;
    (void)control_out.send(zmq::str_buffer("stop"), zmq::send_flags::none);
    thread.join();
    // Unbinds the output endpoint now, as one worker's PUB would at the end of its loop.
    from_workers.close();
    to_consumers.close();
    control_in.close();
    control_out.close();
  }

  ~OutputProxy() { Stop(); }

  zmq::socket_t from_workers, to_consumers, control_in, control_out;
  std::thread thread;
};

// The workers a daemon starts with when input.workers is 0: one per core, at most one per
// subject.
static int AutoWorkers(size_t subjects) {
  const int cores = std::max(1u, std::thread::hardware_concurrency());
  return std::clamp(static_cast<int>(subjects), 1, cores);
}

Daemon::Daemon(DaemonConfig config, std::string config_path, zmq::context_t* context)
    : config_path_(std::move(config_path)),
      owned_context_(context == nullptr ? std::make_unique<zmq::context_t>(1) : nullptr),
      context_(context != nullptr ? context : owned_context_.get()),
      control_(std::make_unique<ControlPlane>()) {
  // One worker per core (at most one per subject); PULL deals messages out to whoever
  // reads, and subscribing to everything would give every worker every message, so those
  // inputs keep one.
  int workers = config.workers > 0 ? config.workers : AutoWorkers(config.subjects.size());
  if (workers > 1 && (config.input_pattern != InputPattern::kSub || config.subscribe_all)) {
    if (config.workers > 1)
      spdlog::warn("input.workers = {}: a PULL input or subscribe = \"all\" has one worker",
                   config.workers);
    workers = 1;
  }
  // Unique in the process for good: libzmq frees an inproc name only some time after its
  // socket closed, so a daemon built where an old one was must not reuse its names.
  static std::atomic<uint64_t> daemons_made{0};
  worker_output_prefix_ = "inproc://mocapd-" + std::to_string(++daemons_made) + "-worker-";
  if (config.curve)
    authenticator_ = std::make_unique<CurveAuthenticator>(*context_, config.curve_authorized_keys,
                                                          config.log_interval_s);
  if (config.http_enabled && config.live_view)
    view_board_ = std::make_shared<LiveViewBoard>(config.live_view_rate_hz);
  planes_.resize(static_cast<size_t>(workers));
  AssignWorkers(config);
  for (int i = 0; i < workers; ++i) {
    planes_[static_cast<size_t>(i)] = std::make_unique<DataPlane>(
        WorkerConfig(config, i), *context_, i, view_board_, *calibrations_);
    planes_[static_cast<size_t>(i)]->forwarded = workers > 1;
    planes_[static_cast<size_t>(i)]->authenticator = authenticator_.get();
  }
  control_->config = std::move(config);
}

void Daemon::AssignWorkers(const DaemonConfig& config) {
  // A subject once seen keeps its worker for good, even while a reload has removed it: one
  // that comes back while its old worker still runs it must not start on another as well.
  std::vector<int> load(planes_.size(), 0);
  for (const SubjectConfig& s : config.subjects)
    if (const auto kept = worker_of_.find(s.name); kept != worker_of_.end())
      ++load[static_cast<size_t>(kept->second)];
  for (const SubjectConfig& s : config.subjects) {
    if (worker_of_.count(s.name) > 0) continue;
    const auto least = std::min_element(load.begin(), load.end()) - load.begin();
    worker_of_[s.name] = static_cast<int>(least);
    ++load[static_cast<size_t>(least)];
  }
}

DaemonConfig Daemon::WorkerConfig(const DaemonConfig& config, int worker) const {
  DaemonConfig c = config;
  c.subjects.clear();
  for (size_t k = 0; k < config.subjects.size(); ++k) {
    if (worker_of_.at(config.subjects[k].name) != worker) continue;
    c.subjects.push_back(config.subjects[k]);
    c.subjects.back().rank = static_cast<int>(k);
  }
  if (planes_.size() > 1) c.output_endpoint = worker_output_prefix_ + std::to_string(worker);
  return c;
}

void Daemon::StopProxy() {
  if (proxy_) proxy_->Stop();
}

void Daemon::RunCalibrations() {
  // Below the data plane: a refinement is a bundle adjustment of hundreds of milliseconds,
  // and a frame must never wait for it.
  (void)setpriority(PRIO_PROCESS, static_cast<id_t>(gettid()), 10);
  std::unique_lock lock(calibration_mutex_);
  while (!calibration_stop_) {
    calibration_cv_.wait_for(lock, std::chrono::seconds(1));
    if (calibration_stop_) break;
    lock.unlock();
    for (const auto& calibration : calibrations_->All()) {
      calibration->Collect();
      try {
        calibration->Refine();
      } catch (const std::exception& e) {
        spdlog::error("subject '{}': live calibration: {}", calibration->subject(), e.what());
      }
    }
    lock.lock();
  }
}

void Daemon::StopCalibrations() {
  {
    std::lock_guard lock(calibration_mutex_);
    calibration_stop_ = true;
  }
  calibration_cv_.notify_all();
  if (calibration_thread_.joinable()) calibration_thread_.join();
}

Daemon::~Daemon() {
  Stop();
  StopCalibrations();
  for (auto& plane : planes_) {
    if (plane && plane->thread.joinable()) {
      plane->stop.store(true);
      plane->thread.join();
    }
  }
  proxy_.reset();
  if (authenticator_) authenticator_->Stop();
}

void Daemon::Stop() {
  boost::asio::post(control_->io, [this] {
    ControlPlane& cp = *control_;
    if (cp.stopping) return;
    cp.stopping = true;
    spdlog::info("shutting down: reading what has arrived, flushing the lookahead");
    for (auto& plane : planes_) plane->stop.store(true, std::memory_order_release);
    // The control plane keeps serving (/health says "stopping") and a second signal is
    // still heard while the data plane flushes; it is joined once it has finished.
    cp.shutdown.emplace(cp.io);
    cp.on_shutdown_poll = [this](const boost::system::error_code&) {
      ControlPlane& c = *control_;
      for (auto& plane : planes_) {
        if (!plane->finished.load(std::memory_order_acquire)) {
          c.shutdown->expires_after(std::chrono::milliseconds(5));
          c.shutdown->async_wait(c.on_shutdown_poll);
          return;
        }
      }
      for (auto& plane : planes_)
        if (plane->thread.joinable()) plane->thread.join();
      StopProxy();
      if (authenticator_) authenticator_->Stop();
      if (c.http) c.http->Stop();
      if (c.live) c.live->Stop();
      if (c.tick) c.tick->cancel();
      if (c.signals) c.signals->cancel();
      c.io.stop();
    };
    cp.on_shutdown_poll({});
  });
}

bool Daemon::Reload() {
  if (config_path_.empty()) {
    spdlog::warn("reload requested, but this daemon was not started from a config file");
    return false;
  }
  try {
    Reload(LoadDaemonConfig(config_path_));
    return true;
  } catch (const std::exception& e) {
    spdlog::error("reload failed, keeping the running config: {}", e.what());
    ++reload_failures_;
    return false;
  }
}

void Daemon::Reload(DaemonConfig config) {
  // Runs on the control plane, which owns its copy of the config.
  boost::asio::post(control_->io,
                    [this, c = std::make_shared<DaemonConfig>(std::move(config))]() mutable {
                      ApplyReload(std::move(*c));
                    });
}

void Daemon::ApplyReload(DaemonConfig config) {
  if (control_->stopping) {
    spdlog::warn("reload of {} ignored: the daemon is stopping (flushing what it holds)",
                 config.source);
    return;
  }
  const DaemonConfig& old = control_->config;
  // What only a restart changes, against what runs: each such field keeps its running
  // value in the control plane's copy, so a later reload is compared with the sockets as
  // they are (compared with the last file, a second reload that kept a changed endpoint
  // said nothing, and one that put the running one back warned).
  std::string restart_only;
  auto keep_running = [&](const char* name, auto DaemonConfig::*field) {
    if (config.*field == old.*field) return;
    restart_only += (restart_only.empty() ? "" : ", ") + std::string(name);
    config.*field = old.*field;
  };
  keep_running("input.endpoint", &DaemonConfig::input_endpoint);
  keep_running("input.pattern", &DaemonConfig::input_pattern);
  keep_running("input.subscribe", &DaemonConfig::subscribe_all);
  keep_running("input.workers", &DaemonConfig::workers);
  keep_running("input.pin_workers", &DaemonConfig::pin_workers);
  // Set on the sockets when they open; a reload that changed them said "applying" only.
  keep_running("input.receive_high_water_mark", &DaemonConfig::receive_high_water_mark);
  keep_running("output.endpoint", &DaemonConfig::output_endpoint);
  keep_running("output.send_high_water_mark", &DaemonConfig::send_high_water_mark);
  keep_running("control.http_port", &DaemonConfig::http_port);
  keep_running("control.http_address", &DaemonConfig::http_address);
  keep_running("control.http", &DaemonConfig::http_enabled);
  keep_running("control.http_token_file", &DaemonConfig::http_token);
  keep_running("control.http_max_connections", &DaemonConfig::http_max_connections);
  keep_running("control.live_view", &DaemonConfig::live_view);
  keep_running("control.live_view_rate_hz", &DaemonConfig::live_view_rate_hz);
  keep_running("control.live_view_max_viewers", &DaemonConfig::live_view_max_viewers);
  // A file turning CURVE off lists no keys: with CURVE kept on, those would have been the
  // allow-list, refusing every client.
  if (config.curve != old.curve) config.curve_authorized_keys = old.curve_authorized_keys;
  keep_running("security.curve", &DaemonConfig::curve);
  keep_running("security.input_server_key_file", &DaemonConfig::curve_input_server_key);
  if (config.curve_keys.secret_key != old.curve_keys.secret_key) {
    restart_only += (restart_only.empty() ? "" : ", ") + std::string("security.key_file");
    config.curve_keys = old.curve_keys;
  }
  if (!restart_only.empty())
    spdlog::warn(
        "reload: {} changed, which takes effect only after a restart; the sockets, the "
        "workers and the HTTP endpoint stay as they are",
        restart_only);
  // A new split applies at once; said, since the subjects it adds or removes were
  // otherwise logged without their cause.
  if (config.shard_index != old.shard_index || config.shard_count != old.shard_count)
    spdlog::info("reload: input.shard {}/{} -> {}/{}: solving {} of {} configured subjects",
                 old.shard_index, old.shard_count, config.shard_index, config.shard_count,
                 config.subjects.size(),
                 config.subjects.size() + config.other_shards_subjects.size());
  AssignWorkers(config);
  // The workers were counted at start-up from the subjects then: subjects added by a
  // reload share them while cores stand idle, which was said nowhere.
  const int could = AutoWorkers(config.subjects.size());
  const bool can_spread =
      config.input_pattern == InputPattern::kSub && !config.subscribe_all && config.workers == 0;
  if (can_spread && static_cast<int>(planes_.size()) < could)
    spdlog::info("reload: {} subjects on {} worker{} (counted at start-up; a restart would use {})",
                 config.subjects.size(), planes_.size(), planes_.size() == 1 ? "" : "s", could);
  // Every worker's part is built before any is posted: a reload applies everywhere or
  // nowhere.
  std::vector<std::unique_ptr<DataPlane::PendingReload>> parts;
  // What the reload does to each subject, for the log: an operator editing one subject
  // sees which lookaheads restart.
  std::string kept, rebuilt, added;
  auto list = [](std::string* names, const std::string& name) {
    *names += (names->empty() ? "" : ", ") + name;
  };
  for (size_t i = 0; i < planes_.size(); ++i) {
    auto pending = std::make_unique<DataPlane::PendingReload>();
    pending->config = WorkerConfig(config, static_cast<int>(i));
    pending->sequence = reloads_posted_ + 1;
    for (const SubjectConfig& s : pending->config.subjects) {
      // A subject the reload leaves as it was keeps its running pipeline (the worker
      // drops this new runner), and with it its live-view slot.
      const SubjectConfig* before = old.FindSubject(s.name);
      const bool unchanged = before != nullptr && SubjectFingerprint(*before, old) ==
                                                      SubjectFingerprint(s, pending->config);
      list(unchanged ? &kept : before != nullptr ? &rebuilt : &added, s.name);
      pending->runners.push_back(
          MakeRunner(s, pending->config, unchanged ? nullptr : view_board_.get(), *calibrations_));
    }
    parts.push_back(std::move(pending));
  }
  if (authenticator_ && config.curve) {
    authenticator_->SetAuthorizedKeys(config.curve_authorized_keys);
    spdlog::info("reload: {} authorized CURVE client keys", config.curve_authorized_keys.size());
  }
  ++reloads_posted_;
  for (size_t i = 0; i < planes_.size(); ++i) {
    DataPlane& plane = *planes_[i];
    std::lock_guard lock(plane.mailbox_mutex);
    plane.pending_reload = std::move(parts[i]);
    plane.has_pending_reload.store(true, std::memory_order_release);
  }
  std::string removed;
  for (const SubjectConfig& s : old.subjects)
    if (config.FindSubject(s.name) == nullptr) list(&removed, s.name);
  spdlog::info("reload: applying {} ({} subjects)", config.source, config.subjects.size());
  if (!kept.empty())
    spdlog::info("reload: kept as they run (lookahead and timing carry on): {}", kept);
  if (!rebuilt.empty())
    spdlog::info("reload: rebuilt (lookahead flushed, solves start afresh): {}", rebuilt);
  if (!added.empty()) spdlog::info("reload: added: {}", added);
  if (!removed.empty()) spdlog::info("reload: removed (lookahead flushed): {}", removed);
  control_->config = std::move(config);
}

DaemonStats Daemon::Stats() const {
  DaemonStats stats;
  for (size_t i = 0; i < planes_.size(); ++i) {
    std::lock_guard lock(planes_[i]->stats_mutex);
    const DaemonStats& w = planes_[i]->shared_stats;
    if (i == 0) {
      stats = w;
      continue;
    }
    // The daemon runs while every worker does, and is alive while the slowest reports.
    stats.running = stats.running && w.running;
    stats.stopping = stats.stopping || w.stopping;
    stats.catching_up = stats.catching_up || w.catching_up;
    stats.full_batches += w.full_batches;
    stats.uptime_s = std::max(stats.uptime_s, w.uptime_s);
    stats.messages_in += w.messages_in;
    stats.control_messages += w.control_messages;
    for (size_t r = 0; r < stats.unattributed_dropped.size(); ++r)
      stats.unattributed_dropped[r] += w.unattributed_dropped[r];
    if (!w.last_unknown_subject.empty()) stats.last_unknown_subject = w.last_unknown_subject;
    stats.retired_published += w.retired_published;
    stats.retired_dropped += w.retired_dropped;
    stats.output_send_failures += w.output_send_failures;
    stats.reloads = std::min(stats.reloads, w.reloads);  // applied once every worker has it
    stats.data_plane_heartbeat_ns =
        std::min(stats.data_plane_heartbeat_ns, w.data_plane_heartbeat_ns);
    stats.subjects.insert(stats.subjects.end(), w.subjects.begin(), w.subjects.end());
  }
  // In the config's order, whichever worker solves each (from the snapshots alone: this
  // runs on any thread, and the control plane's config is its own).
  if (planes_.size() > 1)
    std::stable_sort(
        stats.subjects.begin(), stats.subjects.end(),
        [](const SubjectStats& a, const SubjectStats& b) { return a.config_rank < b.config_rank; });
  for (SubjectStats& s : stats.subjects) s.calibration = calibrations_->StatusOf(s.name);
  stats.reload_failures = reload_failures_.load();
  stats.curve = authenticator_ != nullptr;
  if (authenticator_) stats.curve_counts = authenticator_->Counts();
  return stats;
}

bool Daemon::WaitUntilRunning(std::chrono::milliseconds timeout) {
  std::unique_lock lock(run_mutex_);
  run_cv_.wait_for(lock, timeout, [&] { return run_state_ != RunState::kStarting; });
  return run_state_ == RunState::kRunning;
}

namespace {

void LogStartup(const DaemonConfig& c, int http_port) {
  spdlog::info("mocapd starting: input {} {} ({}), output PUB {}",
               c.input_pattern == InputPattern::kSub ? "SUB connect" : "PULL bind",
               c.input_endpoint,
               c.input_pattern == InputPattern::kSub && !c.subscribe_all ? "subjects' topics"
                                                                         : "all messages",
               c.output_endpoint);
  if (c.curve) {
    spdlog::info("security: CURVE on, this daemon's key {}, {} authorized client keys{}",
                 curve::ShortKey(c.curve_keys.public_key), c.curve_authorized_keys.size(),
                 c.input_pattern == InputPattern::kSub
                     ? ", capture publisher's key " + curve::ShortKey(c.curve_input_server_key)
                     : std::string());
    if (c.curve_authorized_keys.empty())
      spdlog::warn("security.authorized_keys ({}) holds no *.key: every client will be refused",
                   c.curve_authorized_keys_dir);
  } else {
    spdlog::info("security: CURVE off (open to local processes; endpoints are loopback only)");
  }
  if (c.shard_count > 1) {
    std::string others;
    for (const std::string& name : c.other_shards_subjects) others += " " + name;
    spdlog::info("shard {}/{}: solving {} of {} configured subjects; the other shards'{}",
                 c.shard_index, c.shard_count, c.subjects.size(),
                 c.subjects.size() + c.other_shards_subjects.size(), others);
    if (c.subjects.empty())
      spdlog::warn("shard {}/{} has no subjects: this daemon solves nothing", c.shard_index,
                   c.shard_count);
  }
  for (const SubjectConfig& s : c.subjects) {
    const double budget_ms = 1e3 / s.rate_hz;
    spdlog::info(
        "  subject '{}': {} markers, {} joints, {:g} Hz, lookahead K={} ({:.1f} ms delay), frame "
        "budget {:.2f} ms, {}",
        s.name, s.model.markers->num_markers(), s.model.skeleton->num_joints(), s.rate_hz,
        s.cleanup.lookahead, s.cleanup.lookahead * budget_ms, budget_ms,
        s.live.enabled ? "calibrated live (" + s.live.marker_set + "; the subject goes to " +
                             s.live.out_path + ")"
                       : "model " + s.model_path);
    // The character it drives, and how it matched: the operator saw none of it.
    if (s.character)
      spdlog::info("    drives character {} ({} joints, {} bones matched, scale {:.3f}{})",
                   s.character_path, s.character->num_joints(), s.character_map.bones.size(),
                   s.character_map.target_leg_length_m / s.character_map.source_leg_length_m,
                   CharacterTravels(*s.character)
                       ? ""
                       : "; in place: its root only turns, the actor's travel left out");
  }
  if (http_port > 0) {
    spdlog::info(
        "control: http://{}:{}/health /subjects /metrics; watchdog {:.2f} s; stats every {:.2f} s",
        // An IPv6 address goes in brackets in a URL (http://::1:8480/ opens nothing).
        c.http_address.find(':') == std::string::npos ? c.http_address : "[" + c.http_address + "]",
        http_port, c.watchdog_timeout_s, c.stats_interval_s);
  } else {
    spdlog::info("control: HTTP disabled; watchdog {:.2f} s", c.watchdog_timeout_s);
  }
}

}  // namespace

void Daemon::Run(bool handle_signals) {
  ControlPlane& cp = *control_;
  try {
    for (auto& plane : planes_) plane->Open();
    if (planes_.size() > 1)
      proxy_ =
          std::make_unique<OutputProxy>(*context_, cp.config, worker_output_prefix_,
                                        static_cast<int>(planes_.size()), authenticator_.get());
    if (authenticator_) authenticator_->Start();
    if (cp.config.http_enabled) {
      auto render = [this](const std::string& target) {
        DaemonStats stats = Stats();
        if (control_->http) {
          stats.http_unauthorized = control_->http->counters().unauthorized;
          stats.http_over_connections = control_->http->counters().over_connections;
          stats.http_foreign_host = control_->http->counters().foreign_host;
        }
        if (control_->live) {
          stats.live_view = true;
          stats.live_viewers = control_->live->viewers();
          stats.live_counters = control_->live->counters();
        }
        const bool alive = (stats.running || stats.stopping) &&
                           SteadyNs() - stats.data_plane_heartbeat_ns < 1'000'000'000;
        if (target == "/metrics")
          return HttpResponse{200, "text/plain; version=0.0.4; charset=utf-8",
                              FormatPrometheusMetrics(stats)};
        if (target == "/subjects")
          return HttpResponse{200, "application/json", FormatSubjectsJson(stats)};
        return HttpResponse{alive ? 200 : 503, "application/json", FormatHealthJson(stats, alive)};
      };
      HttpServerOptions options;
      options.bearer_token = cp.config.http_token;
      options.max_connections = cp.config.http_max_connections;
      if (view_board_) {
        cp.live = std::make_unique<LiveViewHub>(cp.io, view_board_, cp.config.live_view_max_viewers,
                                                cp.config.live_view_close_stalled_s);
        options.upgrade = [this](const std::string& path, boost::asio::ip::tcp::socket& socket,
                                 HttpRequest request) -> std::optional<HttpResponse> {
          if (path != "/live")
            return HttpResponse{
                404, "text/plain; charset=utf-8",
                "no WebSocket at " + path.substr(0, 64) + "; the live view's is /live\n"};
          if (!control_->live || control_->stopping)
            return HttpResponse{503, "text/plain; charset=utf-8", "the daemon is stopping\n"};
          return control_->live->Accept(socket, std::move(request));
        };
      }
      cp.http = std::make_unique<HttpServer>(
          cp.io, cp.config.http_address, cp.config.http_port,
          [this, render](const std::string& target) {
            if (target != "/metrics" && target != "/subjects" && target != "/health") {
              if (control_->live && target == "/live")
                return HttpResponse{426, "text/plain; charset=utf-8",
                                    "/live is the live view's WebSocket: open / in a browser, "
                                    "or connect with a WebSocket client\n"};
              if (control_->live)
                if (auto file = LiveViewFile(target))
                  return HttpResponse{file->status, file->content_type, std::move(file->body)};
              return HttpResponse{404, "text/plain; charset=utf-8",
                                  control_->live
                                      ? "not found; try /, /health, /subjects or /metrics\n"
                                      : "not found; try /health, /subjects or /metrics\n"};
            }
            ControlPlane::Rendered& r = control_->rendered[target];
            const int64_t now = SteadyNs();
            if (r.at_ns < 0 || now - r.at_ns >= ControlPlane::kRenderPeriodNs) {
              r.response = render(target);
              r.at_ns = now;
            }
            return r.response;
          },
          options);
      http_port_.store(cp.http->port());
    }
  } catch (...) {
    {
      std::lock_guard lock(run_mutex_);
      run_state_ = RunState::kFailed;
    }
    run_cv_.notify_all();
    throw;
  }
  LogStartup(cp.config, http_port_.load());
  if (planes_.size() > 1) {
    std::string split;
    for (const auto& plane : planes_) {
      split += fmt::format(" [{}:", plane->index);
      for (const SubjectConfig& s : plane->config.subjects) split += " " + s.name;
      split += "]";
    }
    spdlog::info("data plane: {} workers{}{}", planes_.size(),
                 cp.config.pin_workers ? ", pinned" : "", split);
  }
  calibration_thread_ = std::thread([this] { RunCalibrations(); });
  const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  for (auto& plane : planes_) {
    plane->Snapshot(true);
    DataPlane* p = plane.get();
    p->thread = std::thread([p] { p->Loop(); });
    if (cp.config.pin_workers) {
      cpu_set_t set;
      CPU_ZERO(&set);
      CPU_SET(static_cast<unsigned>(p->index) % cores, &set);
      if (pthread_setaffinity_np(p->thread.native_handle(), sizeof set, &set) != 0)
        spdlog::warn("worker {}: could not pin it to core {}", p->index,
                     static_cast<unsigned>(p->index) % cores);
    }
  }

  // Handlers re-arm themselves through these, which live until Run returns.
  std::function<void(const boost::system::error_code&, int)> on_signal;
  if (handle_signals) {
    cp.signals.emplace(cp.io, SIGINT, SIGTERM, SIGHUP);
    on_signal = [this, &on_signal](const boost::system::error_code& ec, int sig) {
      if (ec) return;
      if (sig == SIGHUP) {
        // Once stopping, the workers only flush: a reload would build runners that never
        // run, and the log would say it was applied.
        if (control_->stopping)
          spdlog::warn("SIGHUP ignored: the daemon is stopping (flushing what it holds)");
        else {
          spdlog::info("SIGHUP: reloading {}", config_path_);
          Reload();
        }
        control_->signals->async_wait(on_signal);
        return;
      }
      if (control_->stopping) {
        // A second SIGINT/SIGTERM: the operator (or a service manager) wants out now.
        spdlog::warn("{} received again while flushing: exiting at once, the flush unfinished",
                     sig == SIGINT ? "SIGINT" : "SIGTERM");
        spdlog::shutdown();
        std::_Exit(130);
      }
      spdlog::info("{} received", sig == SIGINT ? "SIGINT" : "SIGTERM");
      Stop();
      control_->signals->async_wait(on_signal);
    };
    cp.signals->async_wait(on_signal);
  }

  // Stats tick: the watchdog on the data plane itself, and rate-limited drop warnings.
  cp.tick.emplace(cp.io);
  std::function<void(const boost::system::error_code&)> on_tick =
      [this, &on_tick](const boost::system::error_code& ec) {
        if (ec) return;
        ControlPlane& c = *control_;
        const DaemonStats now = Stats();
        const int64_t t = SteadyNs();
        const bool alive =
            (now.running || now.stopping) && t - now.data_plane_heartbeat_ns < 1'000'000'000;
        if (alive != c.data_plane_alive) {
          if (!alive)
            spdlog::error("watchdog: the data plane has not reported for over 1 s");
          else
            spdlog::info("watchdog: the data plane is reporting again");
          c.data_plane_alive = alive;
        }
        for (const SubjectStats& s : now.subjects) {
          const SubjectStats* before = nullptr;
          for (const SubjectStats& b : c.last_logged.subjects)
            if (b.name == s.name) before = &b;
          // Each event as it was when it happened (a second may hold a stall, its end and a
          // resync: the snapshot's last frame number is none of theirs).
          if (before != nullptr && s.counters.stalls > before->counters.stalls)
            spdlog::warn(
                "watchdog: subject '{}' input stalled (no frame taken for {:.2f} s, last frame {})",
                s.name, s.counters.stall_silence_s, s.counters.stall_last_frame);
          if (before != nullptr && s.counters.resumes > before->counters.resumes)
            spdlog::info(
                "subject '{}' input resumed at frame {} after {:.2f} s without a frame taken",
                s.name, s.counters.resume_frame, s.counters.resume_silence_s);
          if (before != nullptr && s.counters.restarts > before->counters.restarts)
            spdlog::warn("{}", RestartLogLine(s, s.counters.restarts - before->counters.restarts));
          if (s.rejecting_input && (before == nullptr || !before->rejecting_input))
            spdlog::warn("subject '{}': every frame dropped as {} for over 0.5 s{}", s.name,
                         to_string(s.rejecting_reason), RejectionDetail(s));
          // The end of a rejection is said too: /health stops naming it, and an operator
          // reading the log must not think every frame is still dropped.
          if (!s.rejecting_input && before != nullptr && before->rejecting_input)
            spdlog::info("subject '{}': no longer dropping every frame ({} accepted so far)",
                         s.name, s.counters.frames_accepted);
          if (s.unstable_input && (before == nullptr || !before->unstable_input))
            spdlog::warn("subject '{}': {}", s.name, UnstableInputText(s));
          if (!s.unstable_input && before != nullptr && before->unstable_input)
            spdlog::info(
                "subject '{}': input stable again (no re-synchronisation, repeated "
                "frame or switch between taken and dropped frames for 2 s)",
                s.name);
          if (s.model_suspect && (before == nullptr || !before->model_suspect))
            spdlog::warn(
                "subject '{}': model suspect: the received markers sit {:.0f} mm (median) from "
                "the model's; is this the actor's calibrated model, at the right scale?",
                s.name, s.model_distance_mm);
          if (!s.model_suspect && before != nullptr && before->model_suspect)
            spdlog::info("subject '{}': the model fits again ({:.0f} mm median)", s.name,
                         s.model_distance_mm);
        }
        // A backlog was read: its messages went through the allocator, which keeps the freed
        // pages; hand them back so a burst does not leave the daemon tens of MB larger (on
        // the control thread, so the data plane never waits for it).
        if (c.last_logged.catching_up && !now.catching_up) {
          malloc_trim(0);
          spdlog::info("backlog read ({} full input batches so far); freed memory returned",
                       now.full_batches);
        }
        // Drops: at most one line per reason per log interval, with the count since the last.
        for (int reason = 0; reason < kDropReasonCount; ++reason) {
          auto total = [&](const DaemonStats& st) {
            uint64_t n = st.unattributed_dropped[static_cast<size_t>(reason)];
            for (const SubjectStats& s : st.subjects)
              n += s.counters.dropped[static_cast<size_t>(reason)];
            return n;
          };
          const uint64_t n = total(now);
          if (n > c.drops_at_last_tick[static_cast<size_t>(reason)])
            c.last_drop_seen_ns[static_cast<size_t>(reason)] = t;
          c.drops_at_last_tick[static_cast<size_t>(reason)] = n;
          if (t - c.last_drop_log_ns[static_cast<size_t>(reason)] <
              Seconds(c.config.log_interval_s))
            continue;
          auto& logged = c.logged_drops;
          if (n > logged[static_cast<size_t>(reason)]) {
            std::string who;
            for (const SubjectStats& s : now.subjects) {
              uint64_t& seen = c.logged_subject_drops[s.name][static_cast<size_t>(reason)];
              const uint64_t count = s.counters.dropped[static_cast<size_t>(reason)];
              if (count > seen) who += fmt::format(", subject '{}' {}", s.name, count - seen);
              seen = count;
            }
            if (reason == static_cast<int>(DropReason::kUnknownSubject))
              who += fmt::format(", the last for '{}'",
                                 protocol::PrintableName(now.last_unknown_subject));
            // Held back by the log interval, the line can come after the drops stopped.
            const double quiet_s =
                static_cast<double>(t - c.last_drop_seen_ns[static_cast<size_t>(reason)]) * 1e-9;
            if (quiet_s >= 0.5) who += fmt::format("; none for the last {:.1f} s", quiet_s);
            spdlog::warn("dropped {} input message(s): {} (total {}){}",
                         n - logged[static_cast<size_t>(reason)],
                         to_string(static_cast<DropReason>(reason)), n, who);
            logged[static_cast<size_t>(reason)] = n;
            c.last_drop_log_ns[static_cast<size_t>(reason)] = t;
          }
        }
        // Frames lost before the daemon: at most one line per log interval. Losing every
        // other frame said nothing in the log but, later, "model suspect".
        if (t - c.last_skipped_log_ns >= Seconds(c.config.log_interval_s)) {
          std::string who;
          for (const SubjectStats& s : now.subjects) {
            uint64_t& seen = c.logged_skipped[s.name];
            if (s.counters.frames_skipped > seen)
              who += fmt::format("{}subject '{}' {} (total {})", who.empty() ? "" : ", ", s.name,
                                 s.counters.frames_skipped - seen, s.counters.frames_skipped);
            seen = s.counters.frames_skipped;
          }
          if (!who.empty()) {
            spdlog::warn("frame numbers that never arrived (lost before the daemon): {}", who);
            c.last_skipped_log_ns = t;
          }
        }
        if (t - c.last_log_ns >= Seconds(c.config.log_interval_s)) {
          spdlog::info("stats: {} messages in, {} frames published, {} dropped, {} pending",
                       now.messages_in, now.published_total(), now.dropped_total(),
                       now.pending_total());
          c.last_log_ns = t;
        }
        if (c.live && c.live->viewers() > 0) c.live->OnStats(now);
        c.last_logged = now;
        c.tick->expires_after(std::chrono::milliseconds(
            static_cast<int64_t>(std::min(c.config.stats_interval_s, 0.25) * 1e3)));
        c.tick->async_wait(on_tick);
      };
  cp.last_log_ns = SteadyNs();
  cp.tick->expires_after(std::chrono::milliseconds(100));
  cp.tick->async_wait(on_tick);

  {
    std::lock_guard lock(run_mutex_);
    run_state_ = RunState::kRunning;
  }
  run_cv_.notify_all();
  cp.io.run();
  for (auto& plane : planes_) {
    if (plane->thread.joinable()) {
      plane->stop.store(true);
      plane->thread.join();
    }
  }
  StopCalibrations();
  StopProxy();
  // A calibration still collecting is lost with the process: said, with what it lacked
  // (a stop said nothing of it, and no subject file was written). One whose stream ended
  // just before the stop first gets the refinement that end is owed.
  for (const auto& calibration : calibrations_->All()) {
    try {
      (void)calibration->RefineIfStreamEnded();
    } catch (const std::exception& e) {
      spdlog::error("subject '{}': live calibration: {}", calibration->subject(), e.what());
    }
    const LiveCalibrationStatus status = calibration->Status();
    if (status.state != LiveCalibrationState::kWaiting &&
        status.state != LiveCalibrationState::kCollecting)
      continue;
    // Known once refined: before, every joint reads not ready.
    const std::string not_ready = status.refinements > 0 ? JointsNotReady(status.joints) : "";
    spdlog::warn(
        "subject '{}': live calibration not finished at stop ({}, {:.0f} s of motion, {} "
        "refinements{}{}): nothing written",
        calibration->subject(), to_string(status.state), status.collected_s, status.refinements,
        not_ready.empty() ? "" : "; joints not ready: ", not_ready);
  }
  const DaemonStats final_stats = Stats();
  spdlog::info("mocapd stopped: {} messages in, {} frames published, {} dropped, {} pending ({})",
               final_stats.messages_in, final_stats.published_total(), final_stats.dropped_total(),
               final_stats.pending_total(),
               final_stats.Balanced() ? "every frame accounted for" : "ACCOUNTING MISMATCH");
  std::lock_guard lock(run_mutex_);
  run_state_ = RunState::kStopped;
}

}  // namespace mocapd
