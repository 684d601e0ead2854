// The replay's report: frames sent, received, lost, duplicated and late; end-to-end and
// processing latency percentiles; accuracy against the truth when it is known; as a
// table for a person, JSON for a program, and an SVG latency histogram.
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "filters/pose_error.hpp"

namespace mocapd {

struct LatencySummary {
  size_t count = 0;
  double p50_ms = 0, p90_ms = 0, p99_ms = 0, p999_ms = 0, max_ms = 0, mean_ms = 0;
};

struct ReplayReport {
  std::string source;
  double rate_hz = 0.0;          ///< Frames sent per second (the pacing).
  double capture_rate_hz = 0.0;  ///< The rate the frames say they were captured at.
  int subjects = 0;
  bool listened = false;  ///< The daemon's output was measured (--from given).
  int lookahead = 0;      ///< K, from the daemon's subject description (the first subject's).
  /// Each subject's K as the descriptions gave it, in order, when not every subject had
  /// `lookahead` throughout (subjects configured apart, or a reload changed one).
  std::vector<std::pair<std::string, std::vector<int>>> lookahead_by_subject;
  uint64_t frames_sent = 0;  ///< Over all subjects.
  uint64_t frames_received = 0;
  uint64_t frames_lost = 0;  ///< Sent, never received.
  uint64_t frames_duplicated = 0;
  uint64_t frames_late = 0;  ///< Processing latency over one frame period.
  /// Skeletons whose session id and timecode (protocol v2) were compared with the sent
  /// frame's, and of those, how many differed.
  uint64_t stream_checked = 0;
  uint64_t stream_mismatched = 0;
  double send_seconds = 0.0;     ///< Wall time spent sending.
  double receive_seconds = 0.0;  ///< From the first frame sent to the last skeleton received.
  double throughput_fps = 0.0;   ///< Skeleton frames received per receive_seconds.
  LatencySummary end_to_end;
  LatencySummary processing;
  std::vector<double> processing_ms;  ///< Every frame's, for the histogram.
  /// Processing latency per interval of sending time (ReplayOptions::latency_interval_s),
  /// so a long soak shows whether it drifts: [from_s, from_s + interval_s).
  struct Interval {
    double from_s = 0.0;
    LatencySummary processing;
  };
  double interval_s = 0.0;
  std::vector<Interval> processing_per_interval;
  bool has_truth = false;
  double mean_position_error_cm = 0.0;
  double mean_rotation_error_deg = 0.0;
  double max_position_error_cm = 0.0;  ///< The worst frame's (a frame's error: its worst joint's).
  double p999_frame_error_cm = 0.0;    ///< 99.9th percentile over frames.
  std::string worst_frame_subject;     ///< Where the worst frame was.
  uint64_t worst_frame_number = 0;
  std::string worst_frame_joint;
  /// The frames at or above the p99.9 by the joint that made each worst: how many frames,
  /// in how many episodes (a subject's tail frames of that joint at most a second apart
  /// are one), and the worst with where it was; most frames first. What to fix to bring
  /// the tail down, and where to look.
  struct TailJoint {
    std::string joint;
    uint64_t frames = 0;
    uint64_t episodes = 0;
    double worst_cm = 0.0;
    std::string worst_subject;
    uint64_t worst_frame_number = 0;
  };
  std::vector<TailJoint> p999_tail;
  /// Frames with a ground truth the replay could not score, and the first reason why.
  uint64_t frames_unscored = 0;
  std::string unscored_reason;
  nlohmann::json ToJson() const;
  std::string FormatTable() const;
  /// "12", or per subject when they differ ("actor1 12, actor2 36"; "actor1 12 -> 20").
  std::string LookaheadText() const;
};

/// Groups tail frames (PoseErrorAccumulator::frames_at_least) by their worst joint
/// (ReplayReport::p999_tail). scored[f]: frame f's subject (an index into subject_names)
/// and frame number; frames of one subject and joint at most episode_gap_frames apart
/// make one episode.
std::vector<ReplayReport::TailJoint> SummarizeTail(
    std::span<const PoseErrorAccumulator::FrameError> tail,
    std::span<const std::pair<size_t, uint64_t>> scored, std::span<const std::string> subject_names,
    const Skeleton& skeleton, uint64_t episode_gap_frames);

/// Percentiles, mean and max of latencies in milliseconds (all zero when empty).
LatencySummary SummariseLatencies(std::vector<double> ms);

/// An SVG histogram of processing latencies (log-spaced bins), for a person to look at.
std::string LatencyHistogramSvg(const std::vector<double>& latencies_ms, const std::string& title);

}  // namespace mocapd
