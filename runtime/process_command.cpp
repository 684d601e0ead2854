// `mocapd process` implementation.
#include "runtime/process_command.hpp"

#include <chrono>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>

#include "filters/pose_error.hpp"
#include "formats/bvh.hpp"
#include "formats/c3d.hpp"
#include "formats/retarget_map.hpp"
#include "formats/subject_file.hpp"
#include "formats/take_frames.hpp"

namespace mocapd {

ProcessSummary RunProcessCommand(const ProcessCommandOptions& options, std::ostream& out) {
  const SubjectModel subject = ReadSubjectModel(options.subject);
  C3dTake take = ReadC3d(options.input_c3d);
  const MarkerSet& markers = *subject.markers;
  const TakeMarkerMap map(markers, take);
  if (!map.unmatched().empty()) {
    out << "warning: " << map.unmatched().size()
        << " of the subject's markers are not in the take and stay missing:";
    for (const auto& n : map.unmatched()) out << " " << n;
    out << "\n";
  }
  CleanupOptions cleanup;
  cleanup.rate_hz = take.rate_hz;
  cleanup.lookahead = options.lookahead;
  CleanupPipeline pipeline(subject.skeleton, subject.markers, cleanup);

  ProcessSummary summary;
  summary.frames = take.num_frames;
  summary.markers = markers.num_markers();
  summary.matched_markers = map.matched();
  std::vector<Pose> poses(static_cast<size_t>(take.num_frames), RestPose(*subject.skeleton));
  std::vector<Vec3> observed(static_cast<size_t>(markers.num_markers()));
  std::vector<double> weights(observed.size());
  std::vector<int> point_of_marker;
  for (const MarkerDefinition& m : markers.markers())
    point_of_marker.push_back(take.FindLabel(m.name));
  std::vector<double> times_us;
  times_us.reserve(static_cast<size_t>(take.num_frames));
  C3dTake cleaned = take;  // untouched samples keep their exact file values

  KinematicsWorkspace solved(*subject.skeleton);
  std::vector<double> residuals, sum_sq(observed.size(), 0.0);
  std::vector<int> residual_count(observed.size(), 0);
  auto collect = [&]() {
    const CleanFrame& frame = pipeline.output();
    const auto f = static_cast<int>(frame.frame);
    poses[static_cast<size_t>(f)] = frame.pose;
    ForwardKinematics(*subject.skeleton, frame.pose, &solved);
    for (size_t m = 0; m < observed.size(); ++m) {
      if (frame.status[m] != MarkerStatus::kObserved) continue;
      const double r =
          (frame.markers[m] - EvaluateMarker(markers.marker(static_cast<int>(m)), solved)).norm();
      residuals.push_back(r);
      sum_sq[m] += r * r;
      ++residual_count[m];
    }
    for (size_t m = 0; m < point_of_marker.size(); ++m) {
      const int p = point_of_marker[m];
      if (p < 0 || frame.status[m] != MarkerStatus::kRepaired) continue;
      cleaned.at(f, p) = frame.markers[m];
      cleaned.residuals[static_cast<size_t>(f) * static_cast<size_t>(cleaned.num_points()) +
                        static_cast<size_t>(p)] = 0.0f;
    }
  };
  auto draw_progress = [&](int done) {
    if (!options.progress) return;
    const int width = 40;
    const int filled = take.num_frames > 0 ? done * width / take.num_frames : width;
    out << "\r[" << std::string(static_cast<size_t>(filled), '#')
        << std::string(static_cast<size_t>(width - filled), ' ') << "] " << done << "/"
        << take.num_frames << " frames" << std::flush;
  };
  for (int f = 0; f < take.num_frames; ++f) {
    map.Observe(take, f, observed, weights);
    const auto t0 = std::chrono::steady_clock::now();
    const bool ready = pipeline.Push(observed);
    // The first K + 1 frames hold the solvers' cold starts; the rest is the steady state.
    if (f > options.lookahead)
      times_us.push_back(
          std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count());
    if (ready) collect();
    if (f % 64 == 0) draw_progress(f);
  }
  while (pipeline.Flush()) collect();
  draw_progress(take.num_frames);
  if (options.progress) out << "\n";

  summary.counters = pipeline.counters();
  std::vector<double> marker_rms;
  for (size_t m = 0; m < observed.size(); ++m)
    if (residual_count[m] > 0) marker_rms.push_back(std::sqrt(sum_sq[m] / residual_count[m]));
  if (!residuals.empty()) summary.residual_median_mm = Quantile(residuals, 0.5) * 1e3;
  if (!marker_rms.empty()) {
    summary.marker_rms_median_mm = Quantile(marker_rms, 0.5) * 1e3;
    summary.marker_rms_worst_mm = *std::max_element(marker_rms.begin(), marker_rms.end()) * 1e3;
  }
  if (!times_us.empty()) {
    double sum = 0.0, worst = 0.0;
    for (double t : times_us) {
      sum += t;
      worst = std::max(worst, t);
    }
    summary.mean_us = sum / static_cast<double>(times_us.size());
    summary.p50_us = Quantile(times_us, 0.5);
    summary.p99_us = Quantile(times_us, 0.99);
    summary.max_us = worst;
  }

  BvhTake bvh =
      MakeBvhTake(*subject.skeleton, std::move(poses), 1.0 / take.rate_hz, subject.bvh_units);
  WriteBvh(options.output_bvh, bvh);
  out << "wrote " << options.output_bvh << " (" << take.num_frames << " frames at " << take.rate_hz
      << " Hz, " << subject.bvh_units << ")\n";
  if (!options.output_c3d.empty()) {
    WriteC3d(options.output_c3d, cleaned);
    out << "wrote " << options.output_c3d << "\n";
  }
  if (!options.retarget_bvh.empty()) {
    // The solved frames in order, exactly as the live path feeds them to the retargeter.
    BvhTake character = ReadBvh(options.retarget_bvh);
    auto target = std::make_shared<const Skeleton>(character.skeleton);
    const RetargetMap joints =
        MakeRetargetMap(*subject.skeleton, {}, *target, character.end_sites, options.joint_map);
    out << joints.report;
    RetargetOptions retarget_options;
    retarget_options.rate_hz = take.rate_hz;
    Retargeter retargeter(subject.skeleton, target, joints, retarget_options);
    std::vector<Pose> motion;
    motion.reserve(bvh.frames.size());
    std::vector<double> retarget_us;
    retarget_us.reserve(bvh.frames.size());
    for (const Pose& pose : bvh.frames) {
      const auto t0 = std::chrono::steady_clock::now();
      motion.push_back(retargeter.Retarget(pose));
      retarget_us.push_back(
          std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count());
    }
    summary.retarget_p50_us = Quantile(retarget_us, 0.5);
    summary.retarget_p99_us = Quantile(retarget_us, 0.99);
    character.frames = std::move(motion);
    character.frame_time_s = 1.0 / take.rate_hz;
    const std::string path = options.output_character_bvh.empty()
                                 ? options.retarget_bvh + ".retargeted.bvh"
                                 : options.output_character_bvh;
    WriteBvh(path, character);
    out << "wrote " << path << " (the character, " << character.frames.size() << " frames, "
        << character.units << "; retarget p50 " << summary.retarget_p50_us << " us, p99 "
        << summary.retarget_p99_us << " us per frame)\n";
  }

  const CleanupCounters& c = summary.counters;
  const double samples = std::max<double>(1.0, static_cast<double>(c.samples_out));
  char line[160];
  std::snprintf(line, sizeof(line),
                "%d frames, %d markers (%d in the take), lookahead %d frames (%.1f ms)\n",
                summary.frames, summary.markers, summary.matched_markers, options.lookahead,
                1000.0 * options.lookahead / take.rate_hz);
  out << line;
  for (int r = 1; r < kMaskReasonCount; ++r) {
    const int64_t n = c.repaired_by[static_cast<size_t>(r)];
    if (n == 0) continue;
    std::snprintf(line, sizeof(line), "  repaired (%-14s) %8lld samples  %6.2f %%\n",
                  to_string(static_cast<MaskReason>(r)), static_cast<long long>(n),
                  100.0 * static_cast<double>(n) / samples);
    out << line;
  }
  std::snprintf(line, sizeof(line), "  unrecoverable            %8lld samples  %6.2f %%\n",
                static_cast<long long>(c.unrecoverable),
                100.0 * static_cast<double>(c.unrecoverable) / samples);
  out << line;
  std::snprintf(line, sizeof(line),
                "per frame (after the first K + 1 cold-start frames): mean %.1f us, p50 %.1f us, "
                "p99 %.1f us, max %.1f us\n",
                summary.mean_us, summary.p50_us, summary.p99_us, summary.max_us);
  out << line;
  std::snprintf(line, sizeof(line),
                "solved skeleton against the observed samples: median %.1f mm per sample; per "
                "marker RMS median %.1f mm, worst %.1f mm\n",
                summary.residual_median_mm, summary.marker_rms_median_mm,
                summary.marker_rms_worst_mm);
  out << line;
  if (!options.report_json.empty()) {
    std::ofstream report(options.report_json);
    if (!report) throw std::runtime_error(options.report_json + ": cannot open for writing");
    report << ProcessSummaryJson(summary, options).dump(2) << "\n";
    out << "wrote " << options.report_json << "\n";
  }
  return summary;
}

nlohmann::json ProcessSummaryJson(const ProcessSummary& summary,
                                  const ProcessCommandOptions& options) {
  const CleanupCounters& c = summary.counters;
  nlohmann::json repaired = nlohmann::json::object();
  for (int r = 1; r < kMaskReasonCount; ++r)
    repaired[to_string(static_cast<MaskReason>(r))] = c.repaired_by[static_cast<size_t>(r)];
  return {{"input", options.input_c3d},
          {"subject", options.subject},
          {"lookahead_frames", options.lookahead},
          {"frames_in", c.frames_in},
          {"frames_out", c.frames_out},
          {"markers", summary.markers},
          {"markers_in_take", summary.matched_markers},
          {"samples", c.samples_out},
          {"repaired_samples_by_reason", repaired},
          {"swaps_relabelled", c.swaps_relabelled},
          {"unrecoverable_samples", c.unrecoverable},
          {"per_frame_us",
           {{"mean", summary.mean_us},
            {"p50", summary.p50_us},
            {"p99", summary.p99_us},
            {"max", summary.max_us}}},
          {"residual_mm",
           {{"median_per_sample", summary.residual_median_mm},
            {"marker_rms_median", summary.marker_rms_median_mm},
            {"marker_rms_worst", summary.marker_rms_worst_mm}}},
          {"retarget_per_frame_us",
           {{"p50", summary.retarget_p50_us}, {"p99", summary.retarget_p99_us}}}};
}

}  // namespace mocapd
