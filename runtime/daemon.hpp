// The mocapd daemon (`mocapd run`): data-plane workers, each a thread owning its ZeroMQ
// sockets and its subjects' pipelines (with several, a forwarding thread joins their
// outputs on the one endpoint), and a Boost.Asio control plane (signals, stats and
// watchdog timers, config reload, the HTTP /health, /subjects and /metrics endpoint).
// They meet only in mailboxes (reloads, stop) and statistics snapshots that each worker
// refreshes with try_lock, so nothing the control plane does can stall a frame.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "runtime/curve_authenticator.hpp"
#include "runtime/daemon_config.hpp"
#include "runtime/live_calibration.hpp"
#include "runtime/live_view.hpp"
#include "runtime/subject_runner.hpp"

namespace zmq {
class context_t;
}

namespace mocapd {

struct SubjectStats {
  std::string name;
  protocol::SubjectState state = protocol::SubjectState::kWaiting;
  SubjectCounters counters;
  CleanupCounters cleanup;
  uint64_t pending = 0;              ///< Received frames held in the lookahead.
  double since_last_input_s = -1.0;  ///< -1 before the first frame.
  int markers = 0;
  int joints = 0;
  double rate_hz = 0.0;
  int lookahead = 0;
  uint64_t marker_set_hash = 0;
  uint64_t skeleton_hash = 0;
  bool rejecting_input = false;                          ///< Every recent frame dropped...
  DropReason rejecting_reason = DropReason::kMalformed;  ///< ...the last one for this.
  double mismatched_rate_hz = 0.0;         ///< The last rate_mismatch frame's rate (0: none).
  uint64_t mismatched_model_hash = 0;      ///< The last model_mismatch frame's hash...
  size_t mismatched_marker_count = 0;      ///< ...and marker count.
  std::optional<CharacterInfo> character;  ///< The character it drives, if any.
  bool model_suspect = false;              ///< Received samples persistently far from the model.
  /// How long every frame published has had no marker observed (0: the last one had one).
  double unobserved_for_s = 0.0;
  /// 5 re-synchronisations, repeated frames or switches between taken and dropped frames
  /// within 2 s (two senders, a session id per frame).
  bool unstable_input = false;
  UnstableCause unstable_cause;    ///< What the recent events mostly were.
  double model_distance_mm = 0.0;  ///< Median sample-to-model distance, over about a second.
  int worker = 0;                  ///< The data-plane thread that solves it.
  int config_rank = 0;             ///< Its place in the config's subject list.
  /// A live-calibrated subject's progress (filled from the calibration, not the worker).
  std::optional<LiveCalibrationStatus> calibration;
};

struct DaemonStats {
  bool running = false;
  bool stopping = false;  ///< A stop was asked for: the lookahead is being flushed.
  /// The input drains in batches; true while the last ones were full (a backlog).
  bool catching_up = false;
  uint64_t full_batches = 0;  ///< Input batches that hit their limit (a backlog was read).
  double uptime_s = 0.0;
  uint64_t messages_in = 0;       ///< Every message received on the input socket.
  uint64_t control_messages = 0;  ///< Accepted end-of-stream messages (not frames).
  /// Drops not attributable to a configured subject (malformed, unknown subject, ...).
  std::array<uint64_t, kDropReasonCount> unattributed_dropped{};
  /// Every input message for half a second (10 at least) was dropped before a subject
  /// could be named (oversized, malformed, not a marker frame), the last for this reason:
  /// a sender whose every frame was too large left /health ok. Cleared by the next message
  /// that reaches a subject. Unknown subjects are named by last_unknown_subject instead.
  bool rejecting_unattributed = false;
  DropReason rejecting_unattributed_reason = DropReason::kMalformed;
  /// The name the last unknown_subject drop carried: a sender's typo ("Actor1" for
  /// "actor1") was counted but named nowhere.
  std::string last_unknown_subject;
  /// Frames published by subjects a reload removed (so the totals still add up).
  uint64_t retired_published = 0;
  uint64_t retired_dropped = 0;
  uint64_t output_send_failures = 0;
  uint64_t reloads = 0;  ///< Reloads every worker has applied.
  uint64_t reload_failures = 0;
  uint64_t http_unauthorized = 0;      ///< HTTP requests without the bearer token.
  uint64_t http_over_connections = 0;  ///< HTTP connections closed: too many open.
  uint64_t http_foreign_host = 0;      ///< HTTP requests for another Host (403).
  bool live_view = false;              ///< The browser view is served.
  int live_viewers = 0;                ///< Pages open on it now.
  LiveViewCounters live_counters;
  bool curve = false;                   ///< CURVE on the input and output sockets.
  CurveCounts curve_counts;             ///< Its handshakes: admitted, refused, failed.
  int64_t data_plane_heartbeat_ns = 0;  ///< Steady clock of the data plane's last loop.
  std::vector<SubjectStats> subjects;

  /// Frames published (received ones, not inserted), over all subjects and retired ones.
  uint64_t published_total() const;
  uint64_t dropped_total() const;
  uint64_t pending_total() const;
  /// messages_in == published + dropped + pending (+ control messages): every frame accounted for.
  bool Balanced() const {
    return messages_in == published_total() + dropped_total() + pending_total() + control_messages;
  }
};

class Daemon {
 public:
  /// config_path is re-read on reload (SIGHUP); may be empty when config is built in code.
  /// context: a ZeroMQ context to share (inproc endpoints need it); nullptr for its own.
  Daemon(DaemonConfig config, std::string config_path, zmq::context_t* context = nullptr);
  ~Daemon();
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  /// Binds and connects the sockets and starts the data plane; then runs the control
  /// plane on the calling thread until Stop() or SIGINT/SIGTERM (with handle_signals).
  /// Returns after the data plane flushed and published everything pending.
  /// Throws std::runtime_error if a socket or the HTTP port cannot be bound.
  void Run(bool handle_signals);
  /// Thread-safe; Run returns once the shutdown is done.
  void Stop();
  /// Thread-safe: re-reads the config file and applies it; false (logged) if invalid.
  bool Reload();
  /// Thread-safe: applies a new config (on the control plane, so only while Run runs).
  /// Subjects whose model and options are unchanged keep their pipeline (no frame lost or
  /// re-timed); changed ones are flushed and rebuilt; removed ones are flushed. Once Stop()
  /// has been called, a reload is ignored with a warning (the workers only flush).
  void Reload(DaemonConfig config);
  /// Blocks until Run has bound everything (or failed); false on timeout or failure.
  bool WaitUntilRunning(std::chrono::milliseconds timeout);
  /// The latest statistics snapshot (at most a few milliseconds old; exact after Run returns).
  DaemonStats Stats() const;
  /// The HTTP port actually bound (after WaitUntilRunning), 0 if disabled.
  int http_port() const { return http_port_.load(); }

  struct DataPlane;
  struct ControlPlane;

 private:
  void ApplyReload(DaemonConfig config);

  /// Which worker solves each subject: kept across reloads (a subject never moves), new
  /// subjects go to the least loaded. Control plane only.
  void AssignWorkers(const DaemonConfig& config);
  DaemonConfig WorkerConfig(const DaemonConfig& config, int worker) const;
  void StopProxy();

  std::string config_path_;
  std::atomic<uint64_t> reload_failures_{0};
  std::unique_ptr<zmq::context_t> owned_context_;
  zmq::context_t* context_ = nullptr;
  /// The ZAP handler when security.curve is on: bound before any socket and destroyed
  /// after them all (declared before them), so no client is ever admitted unchecked.
  std::unique_ptr<CurveAuthenticator> authenticator_;
  std::vector<std::unique_ptr<DataPlane>> planes_;
  std::map<std::string, int> worker_of_;
  uint64_t reloads_posted_ = 0;       ///< Control plane only.
  std::string worker_output_prefix_;  ///< inproc endpoints the workers publish on (> 1 worker)
  struct OutputProxy;
  std::unique_ptr<OutputProxy> proxy_;
  std::unique_ptr<ControlPlane> control_;
  /// Every subject's live-view slot (when the view is on), shared with the workers.
  std::shared_ptr<LiveViewBoard> view_board_;
  /// Every live calibration, and the thread that refines them (off the data plane).
  std::shared_ptr<LiveCalibrationBoard> calibrations_ = std::make_shared<LiveCalibrationBoard>();
  std::thread calibration_thread_;
  std::mutex calibration_mutex_;
  std::condition_variable calibration_cv_;
  bool calibration_stop_ = false;
  void RunCalibrations();
  void StopCalibrations();
  std::atomic<int> http_port_{0};
  std::mutex run_mutex_;
  std::condition_variable run_cv_;
  enum class RunState { kStarting, kRunning, kFailed, kStopped } run_state_ = RunState::kStarting;
};

/// Prometheus text exposition (version 0.0.4) of a snapshot.
std::string FormatPrometheusMetrics(const DaemonStats& stats);
/// JSON for /subjects and /health.
std::string FormatSubjectsJson(const DaemonStats& stats);
std::string FormatHealthJson(const DaemonStats& stats, bool data_plane_alive);
/// Why a subject rejecting every frame does, beyond the drop reason's name (a rate
/// mismatch: the frames' rate against the configured one; a model mismatch: the frames'
/// hash and marker count against the model's); empty if nothing to add.
std::string RejectionDetail(const SubjectStats& s);
/// What /health and the log say of a subject whose input is unstable: the rule, what the
/// events mostly were, and the likeliest sender fault for that.
std::string UnstableInputText(const SubjectStats& s);
/// The log line for a subject's re-synchronisation: where its frame numbers (and v2
/// sessions) jumped from and to, and how many restarts there were since the last report
/// (a v1 packet late by over restart_backjump makes two: back, then forward again).
std::string RestartLogLine(const SubjectStats& s, uint64_t restarts_since_last_report);

}  // namespace mocapd
