// The replay simulator (`mocap-sim replay`): publishes a take's marker frames over
// ZeroMQ exactly as a capture system would (paced by a steady clock at the take's rate,
// or faster), for one or several actors, optionally corrupted on the fly; subscribes to
// the daemon's skeletons and measures, per frame, end-to-end latency (sent -> skeleton
// received), processing latency (the frame that completed the publication was sent ->
// skeleton received: what the daemon adds beyond its lookahead), frames lost, and --
// when the ground truth is known (BVH or built-in humanoid) -- the skeletons' accuracy.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>
#include <string>
#include <vector>

#include "filters/marker_model.hpp"
#include "formats/c3d.hpp"

namespace mocapd {

/// What to replay: markers in the subject's order, plus the truth when it is known.
struct ReplaySource {
  std::string description;
  std::shared_ptr<const Skeleton> skeleton;
  std::shared_ptr<const MarkerSet> markers;
  C3dTake take;
  std::vector<Pose> truth;  ///< Empty for a recorded C3D.
  double rate_hz = 120.0;
};

/// The built-in humanoid (config/demo_subject.toml) doing motion for seconds.
ReplaySource HumanoidReplaySource(const std::string& motion, double seconds, double rate_hz, double noise_mm, uint64_t seed);
/// A BVH: markers synthesized on the fly from its motion (default layout), resampled to
/// rate_hz (0: the file's rate); the truth is the motion.
ReplaySource BvhReplaySource(const std::string& path, double rate_hz, const std::string& units);
/// A recorded C3D: markers matched by label to the subject's (subject_path, or the
/// built-in humanoid when empty).
ReplaySource C3dReplaySource(const std::string& path, const std::string& subject_path);

struct ReplayOptions {
  std::string to = "tcp://127.0.0.1:5555";    ///< Where marker frames go.
  bool push = false;                           ///< PUSH-connect instead of PUB-bind.
  std::string from = "tcp://127.0.0.1:5556";  ///< The daemon's output; "" = do not listen.
  double rate_hz = 0.0;                        ///< 0: the take's rate ("realtime"); < 0: as fast as possible.
  int subjects = 1;
  std::string subject_prefix = "actor";  ///< Subjects are actor1 .. actorN.
  int loops = 1;
  /// light | medium | heavy: each subject's copy corrupted with seed + its index ("": clean).
  std::string corrupt;
  uint64_t seed = 1;
  double connect_timeout_s = 10.0;
  double drain_timeout_s = 5.0;
  bool end_of_stream = true;  ///< Send end-of-stream at the end so the daemon flushes.
  /// Called about every second with a one-line live status (nullptr: silent).
  std::function<void(const std::string&)> on_status;
  /// Set from elsewhere (a signal handler) to stop sending early.
  const std::atomic<bool>* stop = nullptr;
};

struct LatencySummary {
  size_t count = 0;
  double p50_ms = 0, p90_ms = 0, p99_ms = 0, p999_ms = 0, max_ms = 0, mean_ms = 0;
};

struct ReplayReport {
  std::string source;
  double rate_hz = 0.0;
  int subjects = 0;
  bool listened = false;      ///< The daemon's output was measured (--from given).
  int lookahead = 0;          ///< K, from the daemon's subject description.
  uint64_t frames_sent = 0;   ///< Over all subjects.
  uint64_t frames_received = 0;
  uint64_t frames_lost = 0;   ///< Sent, never received.
  uint64_t frames_duplicated = 0;
  uint64_t frames_late = 0;   ///< Processing latency over one frame period.
  double send_seconds = 0.0;  ///< Wall time spent sending.
  double throughput_fps = 0.0;  ///< Skeleton frames received per second while sending.
  LatencySummary end_to_end;
  LatencySummary processing;
  std::vector<double> processing_ms;  ///< Every frame's, for the histogram.
  bool has_truth = false;
  double mean_position_error_cm = 0.0;
  double mean_rotation_error_deg = 0.0;
  double max_position_error_cm = 0.0;
  nlohmann::json ToJson() const;
  std::string FormatTable() const;
};

/// Replays source through the daemon and measures. Throws std::runtime_error naming the
/// endpoint if nothing subscribes to the frames or the daemon never describes a subject
/// within connect_timeout_s.
ReplayReport RunReplay(const ReplaySource& source, const ReplayOptions& options);

struct Recording;
/// Replays a recorded stream (sim/recording.hpp) with its original timing (rate_hz < 0:
/// as fast as possible), measuring like RunReplay (no ground truth). Messages that were
/// not marker frames or ends of stream when recorded are skipped.
ReplayReport RunRecordingReplay(const Recording& recording, const std::string& description, const ReplayOptions& options);

/// An SVG histogram of processing latencies (log-spaced bins), for a person to look at.
std::string LatencyHistogramSvg(const std::vector<double>& latencies_ms, const std::string& title);

}  // namespace mocapd
