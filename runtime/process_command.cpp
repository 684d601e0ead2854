// `mocapd process` implementation.
#include "runtime/process_command.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <string_view>

#include "filters/pose_error.hpp"
#include "formats/bvh.hpp"
#include "formats/c3d.hpp"
#include "formats/file_paths.hpp"
#include "formats/marker_layout.hpp"
#include "formats/retarget_map.hpp"
#include "formats/subject_file.hpp"
#include "formats/svg_plot.hpp"
#include "formats/take_frames.hpp"
#include "protocol/messages.hpp"

namespace mocapd {
namespace {

// What the plots show, collected frame by frame.
struct PlotData {
  std::vector<std::vector<uint8_t>> marker_category;  // per marker, per frame
  std::vector<double> residual_mm, iterations;        // per frame
  std::vector<double> truth_mean_cm, truth_worst_cm;  // per frame (with a truth)
};

// Marker timeline categories: observed, repaired by each detector (the wire's reason
// codes 1..10), unrecoverable.
const std::vector<svg::Category>& MarkerCategories() {
  static const std::vector<svg::Category> categories = {
      {"observed", "#d9dde3"},    {"gap filled", "#4d8fdc"}, {"disagreement", "#9b59b6"},
      {"residual", "#e67e22"},    {"spike", "#e84393"},      {"rigid distance", "#16a085"},
      {"swap", "#f1c40f"},        {"frozen", "#6ab04c"},     {"fallen off", "#a0785a"},
      {"small track", "#48c9b0"}, {"trimmed", "#7f8cff"},    {"unrecoverable", "#c0392b"},
      {"repaired", "#34495e"}};
  return categories;
}

void WritePlot(const std::filesystem::path& path, const std::string& svg, std::ostream& out) {
  std::ofstream file(path);
  if (!file) throw std::runtime_error(path.string() + ": cannot open for writing");
  file << svg;
  out << "wrote " << path.string() << "\n";
}

void WritePlots(const ProcessCommandOptions& options, const PlotData& data,
                const MarkerSet& markers, double rate_hz, std::ostream& out) {
  const std::filesystem::path dir(options.plot_dir);
  std::filesystem::create_directories(dir);
  const std::string take = std::filesystem::path(options.input_c3d).filename().string();
  std::vector<svg::TimelineRow> rows;
  for (int m = 0; m < markers.num_markers(); ++m)
    rows.push_back({markers.marker(m).name, data.marker_category[static_cast<size_t>(m)]});
  WritePlot(dir / "markers.svg",
            svg::Timeline(take + ": each marker's samples as published", 1.0 / rate_hz, rows,
                          MarkerCategories()),
            out);
  WritePlot(dir / "solve.svg",
            svg::LineCharts(take + ": the final solve, frame by frame", 1.0 / rate_hz,
                            {{"RMS residual (mm)", {{"residual", "#2a7fc1", data.residual_mm}}},
                             {"LM iterations", {{"iterations", "#e67e22", data.iterations}}}}),
            out);
  if (!data.truth_mean_cm.empty())
    WritePlot(dir / "joint_error.svg",
              svg::LineCharts(take + ": joint position error against the truth", 1.0 / rate_hz,
                              {{"error (cm)",
                                {{"mean over joints", "#2a7fc1", data.truth_mean_cm},
                                 {"worst joint", "#c0392b", data.truth_worst_cm}}}}),
              out);
}

// Fails before the take is solved, not after (the solved BVH written, the user waiting a
// take's length): a plot folder that is a file. The output files are CheckOutputPaths'.
void CheckPlotFolder(const ProcessCommandOptions& options) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!options.plot_dir.empty() && fs::exists(options.plot_dir, ec) &&
      !fs::is_directory(options.plot_dir, ec))
    throw std::runtime_error("--plot " + options.plot_dir + ": is a file, not a folder");
}

// What the take captures at all: a label whose every sample is invalid (an exporter that
// kept a lost marker's channel) is never published, and frames with none of the subject's
// markers (a dropped camera sync) come out as repairs counted like any short gap's; the
// summary says so rather than leaving either to be found in the counts.
void MeasureCoverage(const C3dTake& take, const TakeMarkerMap& map, const MarkerSet& markers,
                     ProcessSummary* summary) {
  const int M = markers.num_markers();
  std::vector<Vec3> observed(static_cast<size_t>(M));
  std::vector<double> weights(observed.size());
  std::vector<uint8_t> captured(observed.size(), 0);
  int run = 0;
  bool captured_before = false;
  for (int f = 0; f < take.num_frames; ++f) {
    map.Observe(take, f, observed, weights);
    bool any = false;
    for (size_t m = 0; m < weights.size(); ++m)
      if (weights[m] > 0.0) captured[m] = 1, any = true;
    if (any && captured_before)
      summary->longest_blank_run_between_captures =
          std::max(summary->longest_blank_run_between_captures, run);
    captured_before |= any;
    run = any ? 0 : run + 1;
    summary->blank_frames += !any;
    summary->longest_blank_run = std::max(summary->longest_blank_run, run);
  }
  for (int m = 0; m < M; ++m)
    if (map.point_of_marker(m) >= 0 && !captured[static_cast<size_t>(m)])
      summary->never_captured.push_back(markers.marker(m).name);
}

// The largest lookahead the cleanup takes (its options table's bound).
int LookaheadLimit() {
  for (const CleanupOptionField& f : CleanupOptionFields())
    if (std::string_view(f.name) == "lookahead") return static_cast<int>(f.max);
  return 0;
}

}  // namespace

std::string CharacterOutputPath(const ProcessCommandOptions& options) {
  if (options.retarget_bvh.empty()) return "";
  if (!options.output_character_bvh.empty()) return options.output_character_bvh;
  // Beside the solved BVH, never into the character asset's folder.
  std::filesystem::path path(options.output_bvh);
  return (path.parent_path() / (path.stem().string() + ".character.bvh")).string();
}

ProcessSummary RunProcessCommand(const ProcessCommandOptions& options, std::ostream& out) {
  const NamedPath inputs[] = {{"--subject", options.subject},
                              {"--in", options.input_c3d},
                              {"--retarget", options.retarget_bvh},
                              {"--truth-bvh", options.truth_bvh}};
  const NamedPath outputs[] = {
      {"--out-bvh", options.output_bvh},
      {"--out-c3d", options.output_c3d},
      {options.output_character_bvh.empty() ? "--out-character-bvh (derived from --out-bvh)"
                                            : "--out-character-bvh",
       CharacterOutputPath(options)},
      {"--report", options.report_json}};
  CheckOutputPaths(inputs, outputs);
  const SubjectModel subject = ReadSubjectModel(options.subject);
  C3dTake take = ReadC3d(options.input_c3d);
  SelectActor(&take, options.actor, options.input_c3d);
  if (take.num_frames == 0)
    throw std::runtime_error(options.input_c3d + ": the take has no frames: nothing to process");
  for (const std::string& note : take.notes)
    out << "note: " << options.input_c3d << ": " << note << "\n";
  // Said now, not found when the cleaned take's write fails after the whole solve.
  if (take.analog.channels() > 255 && !options.output_c3d.empty()) {
    out << "note: " << options.input_c3d << ": its " << take.analog.channels()
        << " analog channels are more than the cleaned C3D carries (255): " << options.output_c3d
        << " is written without them\n";
    take.analog = {};
  }
  // Said of the take, before any output: the cleanup's own check named an internal field
  // (a C3D synthesized from a BVH whose Frame Time was 1e30).
  if (!(take.rate_hz >= kMinCaptureRateHz && take.rate_hz <= kMaxCaptureRateHz)) {
    char rate[64];
    std::snprintf(rate, sizeof(rate), "%.6g", take.rate_hz);
    throw std::runtime_error(options.input_c3d + ": a capture rate of " + rate +
                             " Hz; the cleanup runs at 1 to 10000 Hz (POINT:RATE)");
  }
  const MarkerSet& markers = *subject.markers;
  // The map's own message says what is missing, not which take or subject it is about.
  const TakeMarkerMap map = [&] {
    try {
      return TakeMarkerMap(markers, take);
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument(options.input_c3d + ": " + e.what() + " (subject " +
                                  options.subject + ")");
    }
  }();
  auto warn = [&out](const std::vector<std::string>& names, const char* what) {
    if (names.empty()) return;
    out << "warning: " << names.size() << " of the subject's markers " << what << ":";
    for (const auto& n : names) out << " " << n;
    out << "\n";
  };
  warn(map.unmatched(), "are not in the take and stay missing");
  warn(map.ambiguous(),
       "match several of the take's labels, so none is used and they stay missing");
  warn(map.duplicated(), "label more than one point of the take; the first point is used for");
  // Half the subject's markers is what the solves need to start on their own
  // (cold_start_min_fraction). Fewer is most likely the wrong subject or marker set: 4 of
  // 59 labels matched, 93 % of the samples came out unrecoverable, and the fit of the 4
  // looked excellent.
  if (2 * map.matched() < markers.num_markers() && !options.allow_partial)
    throw std::runtime_error(
        options.input_c3d + ": only " + std::to_string(map.matched()) + " of the subject's " +
        std::to_string(markers.num_markers()) + " markers (" + options.subject +
        ") are labelled in the take: is it this subject's take, with its marker set? "
        "(--allow-partial solves it anyway)");
  CheckPlotFolder(options);
  // The character is read and matched before the take is solved, so a bad one costs no
  // solve and leaves no half-written output.
  std::optional<BvhTake> character;
  std::shared_ptr<const Skeleton> target;
  std::optional<RetargetMap> joints;
  if (!options.retarget_bvh.empty()) {
    character = ReadBvh(options.retarget_bvh);
    target = std::make_shared<const Skeleton>(CharacterSkeleton(*character));
    try {
      joints =
          MakeRetargetMap(*subject.skeleton, {}, *target, character->end_sites, options.joint_map);
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(options.retarget_bvh + ": " + e.what());
    }
  }

  CleanupOptions cleanup;
  cleanup.rate_hz = take.rate_hz;
  cleanup.lookahead = options.lookahead;
  CleanupPipeline pipeline(subject.skeleton, subject.markers, cleanup);

  ProcessSummary summary;
  summary.frames = take.num_frames;
  summary.markers = markers.num_markers();
  summary.matched_markers = map.matched();
  MeasureCoverage(take, map, markers, &summary);
  warn(summary.never_captured,
       "are in the take but captured in no frame: never published (unrecoverable), "
       "and the solve goes without them");
  if (summary.blank_frames > 0) {
    out << "warning: " << summary.blank_frames << " frames capture none of the subject's markers "
        << "(the longest run " << summary.longest_blank_run << " frames, "
        << summary.longest_blank_run / take.rate_hz
        << " s): their skeleton and markers are guesses (between the frames either side, or "
           "from one side where the run is longer than the lookahead)";
    // Seen from its first frame, a run's return is `run` frames ahead.
    const int bridge = summary.longest_blank_run_between_captures;
    if (bridge > options.lookahead && bridge <= LookaheadLimit())
      out << "; --lookahead " << bridge << " or more bridges the longest between captured frames";
    out << "\n";
  }
  std::vector<Pose> poses(static_cast<size_t>(take.num_frames), RestPose(*subject.skeleton));
  std::vector<Vec3> observed(static_cast<size_t>(markers.num_markers()));
  std::vector<double> weights(observed.size());
  std::vector<int> point_of_marker;
  for (const MarkerDefinition& m : markers.markers())
    point_of_marker.push_back(take.FindLabel(m.name));
  std::vector<double> times_us;
  times_us.reserve(static_cast<size_t>(take.num_frames));
  C3dTake cleaned = take;  // untouched samples keep their exact file values

  // The truth, frame for frame, and which of its joints each solved joint is.
  std::optional<BvhTake> truth;
  std::vector<std::pair<int, int>> truth_joints;  // (solved, truth)
  std::string truth_matched_by;
  if (!options.truth_bvh.empty()) {
    BvhReadOptions truth_read;
    truth_read.units = options.truth_units;
    truth = ReadBvh(options.truth_bvh, truth_read);
    // Paired frame by frame: a truth of another length is another take (or rate).
    if (truth->num_frames() != take.num_frames)
      throw std::runtime_error(options.truth_bvh + ": " + std::to_string(truth->num_frames()) +
                               " frames, the take has " + std::to_string(take.num_frames) +
                               ": not the truth of this take");
    // The same length at another rate (a 30 Hz truth of a 120 Hz take's first quarter)
    // pairs frames of different moments. Within 0.5 %, as a C3D's header and POINT:RATE
    // may differ before a note: a frame time printed to 3 digits (0.00833) is 120 Hz.
    if (std::abs(truth->rate_hz() - take.rate_hz) > 0.005 * take.rate_hz) {
      char rates[96];
      std::snprintf(rates, sizeof(rates), " is at %.6g Hz, the take at %.6g Hz", truth->rate_hz(),
                    take.rate_hz);
      throw std::runtime_error(options.truth_bvh + rates + ": not the truth of this take");
    }
    // A subject calibrated from markers names its joints by role (thigh_l...): it is
    // scored on the limb joints, whose centres (hip, knee, ankle, shoulder, elbow, wrist)
    // every convention shares, matched by humanoid role whatever the truth calls them;
    // the trunk's joints are placed differently by each convention, even where a truth
    // shares their names. Any other subject is matched by joint name.
    if (subject.skeleton->FindJoint("thigh_l") && subject.skeleton->FindJoint("thigh_r")) {
      try {
        const HumanoidRoles roles = MatchHumanoidRoles(truth->skeleton);
        for (const char* role :
             {"thigh_l", "thigh_r", "shin_l", "shin_r", "foot_l", "foot_r", "upper_arm_l",
              "upper_arm_r", "forearm_l", "forearm_r", "hand_l", "hand_r"}) {
          const auto solved = subject.skeleton->FindJoint(role);
          const auto found = roles.joint_of_role.find(role);
          if (solved && found != roles.joint_of_role.end())
            truth_joints.emplace_back(static_cast<int>(*solved), found->second);
        }
        truth_matched_by = "by humanoid role, limb joints";
      } catch (const std::invalid_argument&) {
        // Not a humanoid: matched by name below.
      }
    }
    if (truth_joints.empty()) {
      for (int j = 0; j < subject.skeleton->num_joints(); ++j)
        if (const auto t = truth->skeleton.FindJoint(subject.skeleton->joint(j).name))
          truth_joints.emplace_back(j, static_cast<int>(*t));
      truth_matched_by = "by name";
    }
    if (truth_joints.empty())
      throw std::runtime_error(options.truth_bvh +
                               ": no joint named like the subject's, nor a humanoid whose limb "
                               "joints match the subject's roles: not its truth");
  }
  PlotData plot;
  const bool plotting = !options.plot_dir.empty();
  if (plotting) {
    plot.marker_category.assign(observed.size(),
                                std::vector<uint8_t>(static_cast<size_t>(take.num_frames), 0));
    plot.residual_mm.assign(static_cast<size_t>(take.num_frames), std::nan(""));
    plot.iterations.assign(static_cast<size_t>(take.num_frames), std::nan(""));
  }
  if (truth && plotting) {
    plot.truth_mean_cm.assign(static_cast<size_t>(take.num_frames), std::nan(""));
    plot.truth_worst_cm.assign(static_cast<size_t>(take.num_frames), std::nan(""));
  }
  std::optional<KinematicsWorkspace> truth_kinematics;
  if (truth) truth_kinematics.emplace(truth->skeleton);
  double truth_sum = 0.0;
  int64_t truth_count = 0;
  KinematicsWorkspace solved(*subject.skeleton);
  std::vector<double> residuals, sum_sq(observed.size(), 0.0);
  std::vector<int> residual_count(observed.size(), 0);
  std::optional<int> first_solved;
  // The world axis the subject's hips point up along, voted by every solved frame: judged
  // on the first frame alone, a take that opened leaning 45-60 degrees had its whole upright
  // walk written 85 degrees over.
  std::optional<RetargetMap> own_map;
  try {
    own_map = MakeRetargetMap(*subject.skeleton, {}, *subject.skeleton, {});
  } catch (const std::invalid_argument&) {
    // No humanoid: its world is the capture's.
  }
  std::array<int64_t, 6> up_votes{};  // +x, -x, +y, -y, +z, -z
  auto collect = [&]() {
    const CleanFrame& frame = pipeline.output();
    const auto f = static_cast<int>(frame.frame);
    poses[static_cast<size_t>(f)] = frame.pose;
    ForwardKinematics(*subject.skeleton, frame.pose, &solved);
    const auto frame_index = static_cast<size_t>(f);
    if (plotting) {
      plot.residual_mm[frame_index] = frame.final_solve.rms_residual_m * 1e3;
      plot.iterations[frame_index] = frame.final_solve.iterations;
      for (size_t m = 0; m < observed.size(); ++m)
        plot.marker_category[m][frame_index] =
            frame.status[m] == MarkerStatus::kObserved        ? 0
            : frame.status[m] == MarkerStatus::kUnrecoverable ? 11
            : frame.reason[m] == MaskReason::kNone            ? 12
                                                   : static_cast<uint8_t>(frame.reason[m]);
    }
    const bool solved_here = frame.final_solve.status == IkStatus::kConverged ||
                             frame.final_solve.status == IkStatus::kMaxIterations;
    if (!solved_here) {
      ++summary.unsolved_frames;
      if (!first_solved) ++summary.frames_before_first_solve;
    } else if (!first_solved) {
      first_solved = f;
    }
    if (solved_here && own_map) {
      const Vec3 up =
          solved.R_WJ[static_cast<size_t>(own_map->source_root)] * own_map->source_hips_up;
      Eigen::Index axis = 0;
      up.cwiseAbs().maxCoeff(&axis);
      ++up_votes[static_cast<size_t>(2 * axis + (up[axis] > 0 ? 0 : 1))];
    }
    // An unsolved frame's pose is a held one, not a fit: no residual to report.
    for (size_t m = 0; m < observed.size() && solved_here; ++m) {
      if (frame.status[m] != MarkerStatus::kObserved) continue;
      const double r =
          (frame.markers[m] - EvaluateMarker(markers.marker(static_cast<int>(m)), solved)).norm();
      residuals.push_back(r);
      sum_sq[m] += r * r;
      ++residual_count[m];
    }
    for (size_t m = 0; m < observed.size(); ++m) {
      if (frame.status[m] != MarkerStatus::kRepaired) continue;
      summary.repaired_captured += frame.source[m] == SampleSource::kCaptured;
      summary.repaired_interpolated += frame.source[m] == SampleSource::kInterpolated;
      summary.repaired_extrapolated += frame.source[m] == SampleSource::kExtrapolated;
    }
    for (size_t m = 0; m < point_of_marker.size(); ++m) {
      const int p = point_of_marker[m];
      if (p < 0) continue;
      const size_t sample = static_cast<size_t>(f) * static_cast<size_t>(cleaned.num_points()) +
                            static_cast<size_t>(p);
      if (frame.status[m] == MarkerStatus::kRepaired) {
        cleaned.at(f, p) = frame.markers[m];
        cleaned.residuals[sample] = 0.0f;
      } else if (frame.status[m] == MarkerStatus::kUnrecoverable) {
        // A captured sample judged bad with nothing to repair it from is missing, as the
        // report counts it (it was written back as captured, bit for bit).
        cleaned.positions[sample] = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
        cleaned.residuals[sample] = -1.0f;
      }
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

  if (!first_solved)
    throw std::runtime_error(options.input_c3d + ": no frame of " +
                             std::to_string(take.num_frames) + " shows enough of the " +
                             std::to_string(map.matched()) +
                             " labelled markers to solve the subject: nothing to write");
  // Offline, frames before the subject is first seen hold its first solved pose: the rest
  // pose at the origin, which the live path publishes (marked too_few_markers), would be a
  // jump across the stage in the written file.
  for (int f = 0; f < summary.frames_before_first_solve; ++f)
    poses[static_cast<size_t>(f)] = poses[static_cast<size_t>(*first_solved)];
  std::vector<double> frame_worst_cm;  // per frame: its worst joint's error
  if (truth) frame_worst_cm.reserve(static_cast<size_t>(take.num_frames));
  for (int f = 0; truth && f < take.num_frames; ++f) {
    const auto frame_index = static_cast<size_t>(f);
    ForwardKinematics(*subject.skeleton, poses[frame_index], &solved);
    ForwardKinematics(truth->skeleton, truth->frames[frame_index], &*truth_kinematics);
    double sum = 0.0, worst = 0.0;
    int worst_joint = -1;
    for (const auto& [j, t] : truth_joints) {
      const double e =
          (solved.p_WJ[static_cast<size_t>(j)] - truth_kinematics->p_WJ[static_cast<size_t>(t)])
              .norm() *
          100.0;
      sum += e;
      if (worst_joint < 0 || e > worst) {
        worst = e;
        worst_joint = j;
      }
    }
    frame_worst_cm.push_back(worst);
    if (summary.truth_worst_index < 0 || worst > summary.truth_worst_cm) {
      summary.truth_worst_cm = worst;
      summary.truth_worst_index = f;
      summary.truth_worst_frame = static_cast<int64_t>(take.first_frame) + f;
      summary.truth_worst_joint = subject.skeleton->joint(worst_joint).name;
    }
    if (plotting) {
      plot.truth_mean_cm[frame_index] = sum / static_cast<double>(truth_joints.size());
      plot.truth_worst_cm[frame_index] = worst;
    }
    truth_sum += sum;
    truth_count += static_cast<int64_t>(truth_joints.size());
  }

  summary.counters = pipeline.counters();
  if (truth_count > 0) {
    summary.has_truth = true;
    summary.truth_mean_cm = truth_sum / static_cast<double>(truth_count);
    summary.truth_p999_cm = Quantile(std::move(frame_worst_cm), 0.999);
  }
  std::vector<double> marker_rms;
  for (size_t m = 0; m < observed.size(); ++m)
    if (residual_count[m] > 0) marker_rms.push_back(std::sqrt(sum_sq[m] / residual_count[m]));
  if (!residuals.empty()) summary.residual_median_mm = Quantile(residuals, 0.5) * 1e3;
  if (!marker_rms.empty()) {
    summary.marker_rms_median_mm = Quantile(marker_rms, 0.5) * 1e3;
    summary.marker_rms_worst_mm = *std::max_element(marker_rms.begin(), marker_rms.end()) * 1e3;
  }
  if (!times_us.empty()) {
    summary.timed = true;
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

  // The solve is written in the world its subject's rest pose stands in (+Y for a subject
  // calibrated from markers, as BVH readers expect), not the capture's: a Vicon capture
  // stands on +Z, and its solve lay on its back in a tool reading the BVH. The cleaned C3D
  // keeps the capture's world.
  Mat3 upright = Mat3::Identity();
  Vec3 rest_up = Vec3::UnitY();
  if (own_map) {
    const auto most = static_cast<Eigen::Index>(std::max_element(up_votes.begin(), up_votes.end()) -
                                                up_votes.begin());
    const Vec3 capture_up = (most % 2 == 0 ? 1.0 : -1.0) * Vec3::Unit(most / 2);
    upright = Quat::FromTwoVectors(capture_up, own_map->target_up).toRotationMatrix();
    rest_up = own_map->target_up;
  }
  if (!upright.isIdentity()) {
    for (Pose& pose : poses) TurnPoseWorld(*subject.skeleton, upright, &pose);
    out << "the capture stands on " << AxisName(upright.transpose() * rest_up)
        << ": the solve is written turned to stand as its subject's rest pose does\n";
  }
  summary.solve_turned = !upright.isIdentity();
  BvhTake bvh =
      MakeBvhTake(*subject.skeleton, std::move(poses), 1.0 / take.rate_hz, subject.bvh_units);
  WriteBvh(options.output_bvh, bvh);
  out << "wrote " << options.output_bvh << " (" << take.num_frames << " frames at " << take.rate_hz
      << " Hz, " << subject.bvh_units << ")\n";
  if (!options.output_c3d.empty()) {
    WriteC3d(options.output_c3d, cleaned);
    out << "wrote " << options.output_c3d << "\n";
  }
  if (character) {
    // The written frames in order, one at a time as the live path feeds the retargeter
    // (the frames before the subject is seen hold its first solved pose here).
    out << joints->report;
    RetargetOptions retarget_options;
    retarget_options.rate_hz = take.rate_hz;
    Retargeter retargeter(subject.skeleton, target, *joints, retarget_options);
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
    character->skeleton = *target;  // the joints that carry the motion, as solved
    character->frames = std::move(motion);
    character->frame_time_s = 1.0 / take.rate_hz;
    const std::string path = CharacterOutputPath(options);
    WriteBvh(path, *character);
    out << "wrote " << path << " (the character, " << character->frames.size() << " frames, "
        << character->units << "; retarget p50 " << summary.retarget_p50_us << " us, p99 "
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
  const int64_t repaired =
      summary.repaired_captured + summary.repaired_interpolated + summary.repaired_extrapolated;
  if (repaired > 0) {
    std::snprintf(line, sizeof(line),
                  "  of the repairs: %lld captured samples relabelled, %lld filled between "
                  "captured ends, %lld guessed from one side\n",
                  static_cast<long long>(summary.repaired_captured),
                  static_cast<long long>(summary.repaired_interpolated),
                  static_cast<long long>(summary.repaired_extrapolated));
    out << line;
  }
  std::snprintf(line, sizeof(line), "  unrecoverable            %8lld samples  %6.2f %%\n",
                static_cast<long long>(c.unrecoverable),
                100.0 * static_cast<double>(c.unrecoverable) / samples);
  out << line;
  if (!summary.timed) {
    out << "per frame: not timed (the take is no longer than the first K + 1 cold-start "
           "frames)\n";
  } else {
    std::snprintf(line, sizeof(line),
                  "per frame (after the first K + 1 cold-start frames): mean %.1f us, p50 %.1f "
                  "us, p99 %.1f us, max %.1f us\n",
                  summary.mean_us, summary.p50_us, summary.p99_us, summary.max_us);
    out << line;
  }
  if (summary.unsolved_frames > 0)
    out << "warning: " << summary.unsolved_frames
        << " frames could not be solved (too few markers, or the solve failed); "
        << summary.frames_before_first_solve
        << " of them, before the subject is first seen, hold its first solved pose, the "
           "others the last solved one\n";
  std::snprintf(line, sizeof(line),
                "solved skeleton against the observed samples: median %.1f mm per sample; per "
                "marker RMS median %.1f mm, worst %.1f mm\n",
                summary.residual_median_mm, summary.marker_rms_median_mm,
                summary.marker_rms_worst_mm);
  out << line;
  if (summary.has_truth) {
    // The worst frame by the take's own numbering (what a C3D viewer shows) and its time.
    std::snprintf(line, sizeof(line),
                  "against the truth (%zu joints matched %s): mean %.2f cm; per frame (its "
                  "worst joint) p99.9 %.2f cm, worst %.2f cm (frame %lld, %.3f s, ",
                  truth_joints.size(), truth_matched_by.c_str(), summary.truth_mean_cm,
                  summary.truth_p999_cm, summary.truth_worst_cm,
                  static_cast<long long>(summary.truth_worst_frame),
                  summary.truth_worst_index / take.rate_hz);
    out << line << protocol::PrintableName(summary.truth_worst_joint) << ")\n";
  }
  if (plotting) WritePlots(options, plot, markers, take.rate_hz, out);
  if (!options.report_json.empty()) {
    std::ofstream report(options.report_json);
    if (!report) throw std::runtime_error(options.report_json + ": cannot open for writing");
    // Paths and names as given: bytes that are no UTF-8 are written as U+FFFD rather than
    // failing the report after every other output was written.
    report << ProcessSummaryJson(summary, options)
                  .dump(2, ' ', false, nlohmann::json::error_handler_t::replace)
           << "\n";
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
          {"repaired_samples_by_source",
           {{"captured", summary.repaired_captured},
            {"interpolated", summary.repaired_interpolated},
            {"extrapolated", summary.repaired_extrapolated}}},
          {"markers_never_captured", summary.never_captured},
          {"frames_capturing_no_marker", summary.blank_frames},
          {"longest_run_capturing_no_marker", summary.longest_blank_run},
          {"swaps_relabelled", c.swaps_relabelled},
          {"lone_samples_overruled", c.lone_samples_overruled},
          {"unrecoverable_samples", c.unrecoverable},
          {"unsolved_frames", summary.unsolved_frames},
          {"solve_turned_to_rest_up", summary.solve_turned},
          {"frames_before_first_solve", summary.frames_before_first_solve},
          {"per_frame_us", summary.timed ? nlohmann::json{{"mean", summary.mean_us},
                                                          {"p50", summary.p50_us},
                                                          {"p99", summary.p99_us},
                                                          {"max", summary.max_us}}
                                         : nlohmann::json(nullptr)},
          {"residual_mm",
           {{"median_per_sample", summary.residual_median_mm},
            {"marker_rms_median", summary.marker_rms_median_mm},
            {"marker_rms_worst", summary.marker_rms_worst_mm}}},
          {"retarget_per_frame_us",
           {{"p50", summary.retarget_p50_us}, {"p99", summary.retarget_p99_us}}},
          {"truth_joint_error_cm",
           summary.has_truth ? nlohmann::json{{"mean", summary.truth_mean_cm},
                                              {"frame_p999", summary.truth_p999_cm},
                                              {"worst", summary.truth_worst_cm},
                                              {"worst_frame", summary.truth_worst_frame},
                                              {"worst_frame_index", summary.truth_worst_index},
                                              {"worst_joint", summary.truth_worst_joint}}
                             : nlohmann::json(nullptr)}};
}

}  // namespace mocapd
