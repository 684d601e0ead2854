// Formatting the replay's report.
#include "sim/replay_report.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

#include "filters/pose_error.hpp"
#include "formats/svg_plot.hpp"
#include "protocol/messages.hpp"

namespace mocapd {
namespace {

nlohmann::json TailJson(const std::vector<ReplayReport::TailJoint>& tail) {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& t : tail)
    out.push_back({{"joint", t.joint},
                   {"frames", t.frames},
                   {"episodes", t.episodes},
                   {"worst_cm", t.worst_cm},
                   {"worst_subject", t.worst_subject},
                   {"worst_frame_number", t.worst_frame_number}});
  return out;
}

nlohmann::json SummaryJson(const LatencySummary& s) {
  return {{"count", s.count},    {"p50_ms", s.p50_ms},    {"p90_ms", s.p90_ms},
          {"p99_ms", s.p99_ms},  {"p99.9_ms", s.p999_ms}, {"max_ms", s.max_ms},
          {"mean_ms", s.mean_ms}};
}

}  // namespace

LatencySummary SummariseLatencies(std::vector<double> ms) {
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

nlohmann::json ReplayReport::ToJson() const {
  nlohmann::json j = {{"source", source},
                      {"rate_hz", rate_hz},
                      {"capture_rate_hz", capture_rate_hz},
                      {"subjects", subjects},
                      {"lookahead_frames", lookahead},
                      {"frames_sent", frames_sent},
                      {"frames_received", frames_received},
                      {"frames_lost", frames_lost},
                      {"frames_duplicated", frames_duplicated},
                      {"frames_late", frames_late},
                      {"stream_checked", stream_checked},
                      {"stream_mismatched", stream_mismatched},
                      {"send_seconds", send_seconds},
                      {"receive_seconds", receive_seconds},
                      {"throughput_fps", throughput_fps},
                      {"end_to_end_latency", SummaryJson(end_to_end)},
                      {"processing_latency", SummaryJson(processing)}};
  if (!lookahead_by_subject.empty()) {
    nlohmann::json by_subject = nlohmann::json::object();
    for (const auto& [name, ks] : lookahead_by_subject) by_subject[name] = ks;
    j["lookahead_frames_by_subject"] = by_subject;
  }
  if (!processing_per_interval.empty()) {
    j["interval_s"] = interval_s;
    nlohmann::json intervals = nlohmann::json::array();
    for (const Interval& i : processing_per_interval) {
      nlohmann::json entry = SummaryJson(i.processing);
      entry["from_s"] = i.from_s;
      intervals.push_back(std::move(entry));
    }
    j["processing_latency_per_interval"] = std::move(intervals);
  }
  if (has_truth)
    j["accuracy"] = {{"mean_joint_position_error_cm", mean_position_error_cm},
                     {"max_joint_position_error_cm", max_position_error_cm},
                     {"p999_frame_position_error_cm", p999_frame_error_cm},
                     {"worst_frame",
                      {{"subject", worst_frame_subject},
                       {"frame_number", worst_frame_number},
                       {"joint", worst_frame_joint}}},
                     {"p999_tail", TailJson(p999_tail)},
                     {"mean_joint_rotation_error_deg", mean_rotation_error_deg}};
  if (frames_unscored > 0)
    j["accuracy_unscored"] = {{"frames", frames_unscored}, {"reason", unscored_reason}};
  return j;
}

std::string ReplayReport::LookaheadText() const {
  if (lookahead_by_subject.empty()) return std::to_string(lookahead);
  std::string text;
  for (const auto& [name, ks] : lookahead_by_subject) {
    text += (text.empty() ? "" : ", ") + protocol::PrintableName(name);
    for (size_t i = 0; i < ks.size(); ++i) text += (i == 0 ? " " : " -> ") + std::to_string(ks[i]);
  }
  return text;
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
  // A rate as a person writes it: 120, 119.88 (an NTSC rate read as 120 is another rate).
  auto rate = [](double hz) {
    char b[40];
    std::snprintf(b, sizeof(b), "%.6g", hz);
    return std::string(b);
  };
  s << "replay: " << source << "\n";
  // Paced at another rate than captured, the frames still say the capture's: a 120 Hz
  // take sent at --rate 240 is played twice as fast, not resampled.
  const bool repaced = capture_rate_hz > 0 && rate_hz > 0 &&
                       std::abs(rate_hz - capture_rate_hz) > 1e-6 * capture_rate_hz;
  row("subjects x rate",
      std::to_string(subjects) + " x " + rate(repaced ? capture_rate_hz : rate_hz) + " Hz" +
          (repaced ? " (sent at " + rate(rate_hz) + " frames/s, " +
                         num(rate_hz / capture_rate_hz, 2) + "x the take's rate, not resampled)"
                   : "") +
          (listened ? ", lookahead K = " + LookaheadText() : std::string()));
  if (!listened) {
    row("frames sent",
        std::to_string(frames_sent) + " (the daemon's output was not measured: --from \"\")");
    return s.str();
  }
  row("frames sent / received",
      std::to_string(frames_sent) + " / " + std::to_string(frames_received));
  row("frames lost / duplicated / late", std::to_string(frames_lost) + " / " +
                                             std::to_string(frames_duplicated) + " / " +
                                             std::to_string(frames_late));
  if (stream_checked > 0)
    row("session/timecode echoed", std::to_string(stream_checked - stream_mismatched) + " of " +
                                       std::to_string(stream_checked) +
                                       (stream_mismatched > 0 ? "  (MISMATCHED)" : ""));
  row("throughput (skeletons/s)", num(throughput_fps, 1));
  std::snprintf(line, sizeof(line), "  %-34s %8s %8s %8s %8s %8s\n", "latency (ms)", "p50", "p90",
                "p99", "p99.9", "max");
  s << line;
  for (const auto& [name, l] : {std::pair<const char*, const LatencySummary&>{
                                    "  end to end (sent -> skeleton)", end_to_end},
                                {"  processing (beyond lookahead)", processing}}) {
    std::snprintf(line, sizeof(line), "  %-34s %8.3f %8.3f %8.3f %8.3f %8.3f\n", name, l.p50_ms,
                  l.p90_ms, l.p99_ms, l.p999_ms, l.max_ms);
    s << line;
  }
  if (!processing_per_interval.empty()) {
    const auto worst =
        std::max_element(processing_per_interval.begin(), processing_per_interval.end(),
                         [](const Interval& a, const Interval& b) {
                           return a.processing.p99_ms < b.processing.p99_ms;
                         });
    row("worst interval's processing p99",
        num(worst->processing.p99_ms, 3) + " ms  (" + num(worst->from_s, 0) + " s + " +
            num(interval_s, 0) + " s, of " + std::to_string(processing_per_interval.size()) + ")");
  }
  if (has_truth) {
    row("joint position error mean (cm)", num(mean_position_error_cm, 3));
    row("frame position error p99.9 (cm)", num(p999_frame_error_cm, 3));
    row("worst frame (cm)",
        num(max_position_error_cm, 3) + "  (" + protocol::PrintableName(worst_frame_subject) +
            " frame " + std::to_string(worst_frame_number) + ", " + worst_frame_joint + ")");
    if (!p999_tail.empty()) {
      std::string tail;
      constexpr size_t kShown = 6;
      for (size_t i = 0; i < p999_tail.size() && i < kShown; ++i) {
        const auto& t = p999_tail[i];
        tail += (i > 0 ? ", " : "") + t.joint + " " + std::to_string(t.frames) + " (" +
                std::to_string(t.episodes) + (t.episodes == 1 ? " episode" : " episodes") +
                ", worst " + num(t.worst_cm, 1) + " at " +
                protocol::PrintableName(t.worst_subject) + " frame " +
                std::to_string(t.worst_frame_number) + ")";
      }
      if (p999_tail.size() > kShown)
        tail += ", " + std::to_string(p999_tail.size() - kShown) +
                (p999_tail.size() - kShown == 1 ? " more joint" : " more joints");
      row("frames over p99.9 by joint", tail);
    }
    row("joint rotation error mean (deg)", num(mean_rotation_error_deg, 3));
  }
  if (frames_unscored > 0)
    row("accuracy not scored", std::to_string(frames_unscored) + " frames: " + unscored_reason);
  return s.str();
}

std::string LatencyHistogramSvg(const std::vector<double>& latencies_ms, const std::string& title) {
  return svg::LogHistogram(title, "processing latency (ms, log scale)", latencies_ms, 0.01, 100.0,
                           {0.5, 0.99, 0.999}, "ms");
}

std::vector<ReplayReport::TailJoint> SummarizeTail(
    std::span<const PoseErrorAccumulator::FrameError> tail,
    std::span<const std::pair<size_t, uint64_t>> scored, std::span<const std::string> subject_names,
    const Skeleton& skeleton, uint64_t episode_gap_frames) {
  std::map<int, ReplayReport::TailJoint> by_joint;
  // (joint, subject) -> the latest frame number seen: frame numbers are unique per
  // subject, and a frame received out of order must not split an episode.
  std::map<std::pair<int, size_t>, uint64_t> last_frame;
  for (const auto& f : tail) {
    const auto& [subject, frame_number] = scored[static_cast<size_t>(f.frame)];
    auto [group, new_joint] = by_joint.try_emplace(f.joint);
    ReplayReport::TailJoint& t = group->second;
    if (new_joint) t.joint = skeleton.joint(f.joint).name;
    ++t.frames;
    if (f.error_m * 100.0 > t.worst_cm) {
      t.worst_cm = f.error_m * 100.0;
      t.worst_subject = subject < subject_names.size() ? subject_names[subject] : "?";
      t.worst_frame_number = frame_number;
    }
    // Frames of different subjects interleave: the frame numbers of one subject say
    // whether this continues an episode.
    auto [it, first] = last_frame.try_emplace({f.joint, subject}, frame_number);
    if (first || frame_number > it->second + episode_gap_frames) ++t.episodes;
    it->second = std::max(it->second, frame_number);
  }
  std::vector<ReplayReport::TailJoint> out;
  for (auto& [joint, t] : by_joint) out.push_back(std::move(t));
  std::stable_sort(out.begin(), out.end(),
                   [](const auto& a, const auto& b) { return a.frames > b.frames; });
  return out;
}

}  // namespace mocapd
