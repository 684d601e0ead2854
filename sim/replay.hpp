// The replay simulator (`mocap-sim replay`): publishes a take's marker frames over
// ZeroMQ exactly as a capture system would (paced by a steady clock at the take's rate,
// or faster), for one or several actors, optionally corrupted on the fly; subscribes to
// the daemon's skeletons and measures, per frame, end-to-end latency (sent -> skeleton
// received), processing latency (the frame that completed the publication was sent ->
// skeleton received: what the daemon adds beyond its lookahead), frames lost, and --
// when the ground truth is known (BVH or built-in humanoid) -- the skeletons' accuracy.
// Take sources are in sim/replay_sources.hpp, the report in sim/replay_report.hpp, the
// sending and measuring in sim/replay_schedule.hpp.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <string>

#include "sim/replay_report.hpp"
#include "sim/replay_sources.hpp"

namespace mocapd {

struct ReplayOptions {
  std::string to = "tcp://127.0.0.1:5555";    ///< Where marker frames go.
  bool push = false;                          ///< PUSH-connect instead of PUB-bind.
  std::string from = "tcp://127.0.0.1:5556";  ///< The daemon's output; "" = do not listen.
  double rate_hz = 0.0;  ///< 0: the take's rate ("realtime"); < 0: as fast as possible.
  int subjects = 1;
  std::string subject_prefix = "actor";  ///< Subjects are actor1 .. actorN.
  int loops = 1;
  /// light | medium | heavy: each subject's copy corrupted with seed + its index ("": clean).
  std::string corrupt;
  uint64_t seed = 1;
  double connect_timeout_s = 10.0;
  double drain_timeout_s = 5.0;
  bool end_of_stream = true;  ///< Send end-of-stream at the end so the daemon flushes.
  /// Wire version of the marker frames: 2 gives them a capture session (a new one per pass
  /// over the take when ends of stream are sent), the exact rate and, with timecode_fps,
  /// an SMPTE timecode; the replay then checks that the daemon echoes them.
  int protocol_version = 2;
  int timecode_fps = 0;  ///< Non-drop timecode at this many frames per second (0: none).
  /// Also summarise processing latency per this many seconds of sending (0: not).
  double latency_interval_s = 0.0;
  /// CURVE (both or neither): the replay's own key pair (a .key_secret certificate; its
  /// PUB serves with it) and the daemon's public certificate (its SUB on the daemon's
  /// output and a PUSH into a PULL input connect as clients of that key).
  std::string curve_key_file;
  std::string curve_server_key_file;
  /// Called about every second with a one-line live status (nullptr: silent).
  std::function<void(const std::string&)> on_status;
  /// Set from elsewhere (a signal handler) to stop sending early.
  const std::atomic<bool>* stop = nullptr;
};

/// Replays source through the daemon and measures. Throws std::runtime_error naming the
/// endpoint if nothing subscribes to the frames or the daemon never describes a subject
/// within connect_timeout_s, if a CURVE --push is refused or gets no handshake within it,
/// or if a --push cannot queue a frame for that long.
ReplayReport RunReplay(const ReplaySource& source, const ReplayOptions& options);

/// Replays endless motion from a motion graph: each actor walks the graph on its own
/// (seeded by options.seed and its index), resampled to rate_hz, for `seconds`, with
/// markers synthesized and (options.corrupt) corrupted a couple of seconds at a time, and
/// the walk as the truth. One capture session; an end of stream at the end. Loops do not
/// apply. Throws like RunReplay.
ReplayReport RunGraphReplay(const GraphReplaySource& source, double seconds, double rate_hz,
                            const ReplayOptions& options);

struct Recording;
/// Replays a recorded stream (sim/recording.hpp) with its original timing (rate_hz < 0:
/// as fast as possible), measuring like RunReplay (no ground truth). Messages that were
/// not marker frames or ends of stream when recorded are skipped.
ReplayReport RunRecordingReplay(const Recording& recording, const std::string& description,
                                const ReplayOptions& options);

}  // namespace mocapd
