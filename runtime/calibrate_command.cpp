// `mocapd calibrate` implementation.
#include "runtime/calibrate_command.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include "filters/resample.hpp"
#include "formats/bvh.hpp"
#include "formats/c3d.hpp"
#include "formats/file_paths.hpp"
#include "formats/marker_set.hpp"
#include "formats/subject_file.hpp"
#include "formats/subject_from_markers.hpp"
#include "protocol/messages.hpp"

namespace mocapd {

namespace {

std::string Fixed(double v, int decimals) {
  char b[48];
  std::snprintf(b, sizeof(b), "%.*f", decimals, v);
  return b;
}

// A take with no frames names itself: "the takes hold no markers" hid which file of
// several was empty, and that it had its labels.
C3dTake ReadTakeWithFrames(const std::string& path, const std::string& actor) {
  C3dTake take = ReadC3d(path);
  SelectActor(&take, actor, path);
  if (take.num_frames == 0)
    throw std::runtime_error(path + ": the take has no frames (" +
                             std::to_string(take.num_points()) +
                             " points labelled): nothing to calibrate from");
  return take;
}

// The calibration from markers alone: summary on the terminal, JSON report, subject file.
int CalibrateFromMarkersOnly(const CalibrateCommandOptions& options, std::ostream& out) {
  std::vector<C3dTake> takes;
  for (const std::string& path : options.markers_c3d)
    takes.push_back(ReadTakeWithFrames(path, options.actor));
  MarkersOnlyOptions mo;
  mo.marker_set = options.marker_set;
  mo.solve.interleaved_solves = options.interleaved_solves;
  const std::string name = options.subject_name.empty()
                               ? std::filesystem::path(options.out_subject).stem().string()
                               : options.subject_name;
  // Its errors are about the takes (no motion, no marker set found): say which.
  MarkersOnlyCalibration cal = [&] {
    try {
      return CalibrateFromMarkers(takes, mo, name);
    } catch (const std::runtime_error& e) {
      std::string files;
      for (const std::string& path : options.markers_c3d)
        files += (files.empty() ? "" : ", ") + path;
      std::string what = e.what();
      if (what.starts_with("calibrate: ")) what.erase(0, 11);
      throw std::runtime_error("calibrate: " + files + ": " + what);
    }
  }();
  const SubjectCalibrationResult& r = cal.solve;
  const Skeleton& sk = *cal.model.skeleton;

  out << "calibrate: " << takes.size() << " take(s), " << cal.frames_total << " frames; marker set "
      << cal.marker_set << " (" << cal.markers.size() << " markers";
  if (!cal.studio_markers.empty())
    out << ", " << cal.studio_markers.size() << " of the studio's own";
  out << "); " << cal.skipped.size() << " channels skipped; " << r.frames_used.size()
      << " varied poses solved in " << r.iterations << " iterations";
  if (r.solves > 1)
    out << "; the mean of " << r.solves << " solves (the whole take and " << r.solves - 1
        << " interleaved subsets of its frames)";
  out << "\n";
  if (cal.samples_out_of_volume > 0 || cal.glitch_frames > 0)
    out << "  left out as no body's: " << cal.samples_out_of_volume
        << " samples beyond the capture volume (" << mo.capture_volume_m << " m along an axis), "
        << cal.glitch_frames << " frames whose markers all jumped away and back\n";
  // The calibration takes the first point of a label; a second one is an exporter's merge
  // or a labelling mistake the user should hear of.
  for (size_t k = 0; k < takes.size(); ++k) {
    std::map<std::string, int> points_of_label;
    for (const std::string& label : takes[k].labels) ++points_of_label[BareLabel(label)];
    for (const auto& [label, points] : points_of_label)
      if (points > 1)
        out << "  warning: " << options.markers_c3d[k] << ": " << points << " points are labelled "
            << label << "; the first is used\n";
  }
  if (!cal.set_missing.empty()) {
    out << "  the set's markers missing from the take:";
    for (const std::string& m : cal.set_missing) out << " " << protocol::PrintableName(m);
    out << "\n";
  }
  for (const ChannelNote& n : cal.skipped)
    out << "  skipped " << protocol::PrintableName(n.label) << ": " << n.reason << "\n";
  if (cal.hip_regression)
    out << "  hip centre prior: Harrington 2007 regression on the pelvis markers\n";
  if (cal.clusters)
    out << "  " << cal.clustered_because
        << ": every marker placed by the body's shape (template fitted to take "
        << cal.clusters->reference_take + 1 << " frame " << cal.clusters->reference_take_frame
        << ", up nearest " << cal.clusters->up_axis << " (" << Fixed(cal.clusters->tilt_deg, 0)
        << " deg off it), height " << Fixed(cal.clusters->height_m, 2) << " m, markers "
        << Fixed(cal.clusters->landmark_rms_m * 1e3, 0) << " mm RMS from its landmarks) and "
        << "rigidity (" << cal.clusters->moved_by_rigidity << " moved by it, "
        << cal.clusters->placed_again_by_rigidity << " placed again after not fitting)"
        << (cal.clusters->turned_round ? "; turned round to face the way the take walks" : "")
        << "; segments below\n";
  char line[256];
  std::snprintf(line, sizeof(line), "%-12s %-17s %26s %10s %11s %9s %8s\n", "joint", "method",
                "motion-only sigma (mm)", "solves mm", "uncert. mm", "bone mm", "L/R %");
  out << line;
  nlohmann::json joints = nlohmann::json::array();
  for (int j = 0; j < sk.num_joints(); ++j) {
    const JointCalibrationReport& jr = r.joints[static_cast<size_t>(j)];
    const std::string mirror = MirrorRole(jr.name);
    double asymmetry = kNaN;
    if (!mirror.empty()) {
      const double a = jr.bone_length_m;
      const double b = r.joints[static_cast<size_t>(sk.FindJoint(mirror)->value)].bone_length_m;
      asymmetry = 200.0 * std::abs(a - b) / std::max(1e-9, a + b);
    }
    auto sigma = [](double v) { return v > 1.0 ? std::string(">1000") : Fixed(v * 1e3, 1); };
    const std::string sigmas = j == 0
                                   ? "-"
                                   : sigma(jr.data_sigma_m[0]) + " / " + sigma(jr.data_sigma_m[1]) +
                                         " / " + sigma(jr.data_sigma_m[2]);
    std::snprintf(line, sizeof(line), "%-12s %-17s %26s %10s %11s %9s %8s\n", jr.name.c_str(),
                  jr.method.c_str(), sigmas.c_str(),
                  j == 0 || r.solves < 2 ? "-" : Fixed(jr.solves_sigma_m * 1e3, 1).c_str(),
                  j == 0 ? "-" : Fixed(jr.uncertainty_m * 1e3, 1).c_str(),
                  j == 0 ? "-" : Fixed(jr.bone_length_m * 1e3, 1).c_str(),
                  std::isfinite(asymmetry) ? Fixed(asymmetry, 1).c_str() : "-");
    out << line;
    nlohmann::json jj = {{"joint", jr.name}, {"method", jr.method}};
    if (j > 0) {
      jj["motion_only_sigma_mm"] = {jr.data_sigma_m[0] * 1e3, jr.data_sigma_m[1] * 1e3,
                                    jr.data_sigma_m[2] * 1e3};
      jj["directions_covered"] = jr.directions_covered;
      jj["rotation_range_deg"] = {jr.rotation_spread_deg[0], jr.rotation_spread_deg[1],
                                  jr.rotation_spread_deg[2]};
      jj["uncertainty_mm"] = jr.uncertainty_m * 1e3;
      if (r.solves > 1) jj["solves_sigma_mm"] = jr.solves_sigma_m * 1e3;
      jj["bone_length_mm"] = jr.bone_length_m * 1e3;
      jj["centre_in_parent_mm"] = {sk.joint(j).offset.x() * 1e3, sk.joint(j).offset.y() * 1e3,
                                   sk.joint(j).offset.z() * 1e3};
      if (std::isfinite(asymmetry)) jj["left_right_asymmetry_percent"] = asymmetry;
    }
    joints.push_back(jj);
  }
  if (std::any_of(r.joints.begin(), r.joints.end(),
                  [](const JointCalibrationReport& jr) { return jr.method == "chain"; }))
    out << "chain: beside a segment fewer than two markers ride (an unmarked spine or neck "
           "link, a one-marker clavicle): the motion places such joints only together, not "
           "each on its own, so their bones' lengths may be far off while the chain fits\n";
  nlohmann::json markers = nlohmann::json::array();
  std::vector<double> rms;
  for (size_t m = 0; m < cal.markers.size(); ++m) {
    rms.push_back(r.marker_rms_m[m]);
    markers.push_back(
        {{"marker", cal.markers[m]},
         {"segment", sk.joint(cal.model.markers->primary_joint(static_cast<int>(m))).name},
         {"residual_rms_mm", r.marker_rms_m[m] * 1e3},
         {"samples", r.marker_frames[m]}});
  }
  std::vector<double> sorted = rms;
  std::sort(sorted.begin(), sorted.end());
  out << "marker residual RMS: median " << Fixed(sorted[sorted.size() / 2] * 1e3, 1)
      << " mm, worst " << Fixed(sorted.back() * 1e3, 1) << " mm; per sample: median "
      << Fixed(r.median_residual_m * 1e3, 1) << " mm, RMS " << Fixed(r.rms_m * 1e3, 1) << " mm\n";
  for (const ChannelNote& n : cal.rejected)
    out << "  REJECTED " << protocol::PrintableName(n.label) << ": " << n.reason << "\n";
  if (cal.clusters) {
    // Nobody named these markers' segments: say where each went, so a wrong one shows.
    for (int j = 0; j < sk.num_joints(); ++j) {
      std::string members;
      for (size_t m = 0; m < cal.markers.size(); ++m)
        if (cal.model.markers->primary_joint(static_cast<int>(m)) == j)
          members += " " + protocol::PrintableName(cal.markers[m]);
      if (!members.empty()) out << "  " << sk.joint(j).name << ":" << members << "\n";
    }
  }

  cal.model.calibration = CalibrationRecordOf(cal);
  WriteSubjectModel(options.out_subject, cal.model);
  out << "wrote " << options.out_subject << ": " << sk.num_joints() << " joints, "
      << cal.markers.size() << " markers\n";
  if (!options.report_json.empty()) {
    nlohmann::json report = {{"takes", options.markers_c3d},
                             {"frames", cal.frames_total},
                             {"samples_out_of_volume", cal.samples_out_of_volume},
                             {"glitch_frames", cal.glitch_frames},
                             {"marker_set", cal.marker_set},
                             {"set_markers_missing", cal.set_missing},
                             {"studio_markers", cal.studio_markers},
                             {"hip_prior_from_pelvis_regression", cal.hip_regression},
                             {"poses_solved", r.frames_used.size()},
                             {"iterations", r.iterations},
                             {"solves", r.solves},
                             {"median_residual_mm", r.median_residual_m * 1e3},
                             {"rms_residual_mm", r.rms_m * 1e3},
                             {"joints", joints},
                             {"markers", markers}};
    nlohmann::json skipped = nlohmann::json::array(), rejected = nlohmann::json::array();
    for (const ChannelNote& n : cal.skipped)
      skipped.push_back({{"label", n.label}, {"reason", n.reason}});
    for (const ChannelNote& n : cal.rejected)
      rejected.push_back({{"label", n.label}, {"reason", n.reason}});
    if (cal.clusters)
      report["placed_by_clustering"] = {
          {"reference_take", cal.clusters->reference_take + 1},
          {"reference_frame", cal.clusters->reference_take_frame},
          {"because", cal.clustered_because},
          {"up_axis", cal.clusters->up_axis},
          {"tilt_deg", cal.clusters->tilt_deg},
          {"height_m", cal.clusters->height_m},
          {"landmark_rms_mm", cal.clusters->landmark_rms_m * 1e3},
          {"moved_by_rigidity", cal.clusters->moved_by_rigidity},
          {"placed_again_by_rigidity", cal.clusters->placed_again_by_rigidity},
          {"turned_round", cal.clusters->turned_round}};
    report["skipped"] = skipped;
    report["rejected"] = rejected;
    std::ofstream file(options.report_json);
    if (!file) throw std::runtime_error(options.report_json + ": cannot open for writing");
    // Labels as the take spelt them: bytes that are no UTF-8 are written as U+FFFD rather
    // than failing the report after the subject was written.
    file << report.dump(1, ' ', false, nlohmann::json::error_handler_t::replace) << "\n";
    out << "wrote " << options.report_json << "\n";
  }
  return static_cast<int>(cal.markers.size());
}

}  // namespace

int RunCalibrateCommand(const CalibrateCommandOptions& options, std::ostream& out) {
  if (options.markers_c3d.empty()) throw std::runtime_error("calibrate: no --markers take given");
  // The same take twice weighed its frames double, and the result moved (a forearm 316.8 ->
  // 314.4 mm) with no word.
  for (size_t a = 0; a < options.markers_c3d.size(); ++a)
    for (size_t b = a + 1; b < options.markers_c3d.size(); ++b) {
      std::error_code ec;
      if (std::filesystem::equivalent(options.markers_c3d[a], options.markers_c3d[b], ec))
        throw std::runtime_error("calibrate: --markers " + options.markers_c3d[b] +
                                 " is the take given before as " + options.markers_c3d[a] +
                                 ": give each take once");
    }
  std::vector<NamedPath> inputs = {{"--skeleton", options.skeleton_bvh}};
  for (const std::string& take : options.markers_c3d) inputs.push_back({"--markers", take});
  // A set name (auto, cmu-41) is no file; a set file is an input like any other.
  if (std::filesystem::is_regular_file(options.marker_set))
    inputs.push_back({"--marker-set", options.marker_set});
  const NamedPath outputs[] = {{"--out", options.out_subject}, {"--report", options.report_json}};
  CheckOutputPaths(inputs, outputs);
  if (options.skeleton_bvh.empty()) return CalibrateFromMarkersOnly(options, out);
  if (options.markers_c3d.size() != 1)
    throw std::runtime_error(
        "calibrate: with --skeleton, give the one --markers take of the same motion");
  BvhReadOptions bvh_options;
  bvh_options.units = options.bvh_units;
  const BvhTake bvh = ReadBvh(options.skeleton_bvh, bvh_options);
  const C3dTake c3d = ReadTakeWithFrames(options.markers_c3d.front(), options.actor);
  std::vector<Pose> motion = bvh.frames;
  // The same rate as two files print it: a C3D stores 119.88 Hz as a float of its
  // decimal digits, a BVH reads as 120000/1001 Hz; 1e-6 apart, no reason to resample.
  // A genlocked take labelled at the whole rate in one file and at the NTSC rate (1000/1001
  // of it) in the other holds the same frames: resampled, it drifted half a frame over four
  // seconds and markers were attached to the wrong joint.
  const bool same_frames_other_label =
      std::abs(static_cast<int>(bvh.frames.size()) - c3d.num_frames) <= 1 &&
      std::abs(bvh.rate_hz() - c3d.rate_hz) <= 1.5e-3 * c3d.rate_hz;
  if (same_frames_other_label && std::abs(bvh.rate_hz() - c3d.rate_hz) > 2e-5 * c3d.rate_hz) {
    out << options.skeleton_bvh << " says " << bvh.rate_hz() << " Hz and the capture "
        << c3d.rate_hz << " Hz, with " << bvh.frames.size() << " and " << c3d.num_frames
        << " frames: paired frame for frame (one rate is the other's NTSC label)\n";
  } else if (std::abs(bvh.rate_hz() - c3d.rate_hz) > 2e-5 * c3d.rate_hz) {
    out << "resampling " << options.skeleton_bvh << " from " << bvh.rate_hz()
        << " Hz to the capture's " << c3d.rate_hz << " Hz\n";
    motion = ResampleMotion(bvh.skeleton, bvh.frames, bvh.rate_hz(), c3d.rate_hz);
  }
  const int frames = std::min(static_cast<int>(motion.size()), c3d.num_frames);
  const int longer = std::max(static_cast<int>(motion.size()), c3d.num_frames);
  // Resampling can round the last frame either way; anything more means different takes.
  if (frames == 0 || longer - frames > 1)
    throw std::runtime_error("calibrate: the skeleton motion has " + std::to_string(motion.size()) +
                             " frames at the capture's rate but " + options.markers_c3d.front() +
                             " has " + std::to_string(c3d.num_frames) +
                             ": they are not the same take");

  // Every marker would be rejected for it, and the summary would blame the skeleton.
  if (frames < options.calibration.min_frames)
    throw std::runtime_error("calibrate: the take has " + std::to_string(frames) +
                             " frames; a marker's placement needs at least " +
                             std::to_string(options.calibration.min_frames) +
                             " (poses it is seen in). No subject written");
  std::vector<KinematicsWorkspace> fk(static_cast<size_t>(frames),
                                      KinematicsWorkspace(bvh.skeleton));
  for (int f = 0; f < frames; ++f)
    ForwardKinematics(bvh.skeleton, motion[static_cast<size_t>(f)], &fk[static_cast<size_t>(f)]);
  std::vector<std::string> names;
  std::vector<int> points;
  for (int p = 0; p < c3d.num_points(); ++p) {
    if (!c3d.is_marker(p)) continue;
    names.push_back(c3d.labels[static_cast<size_t>(p)]);
    points.push_back(p);
  }
  std::vector<Vec3> observed(static_cast<size_t>(frames) * names.size());
  for (int f = 0; f < frames; ++f)
    for (size_t m = 0; m < names.size(); ++m)
      observed[static_cast<size_t>(f) * names.size() + m] = c3d.at(f, points[m]);

  const auto results = CalibrateMarkers(bvh.skeleton, fk, names, observed, options.calibration);
  std::vector<MarkerDefinition> accepted;
  std::vector<double> rms;
  char line[256];
  std::snprintf(line, sizeof(line), "%-16s %-28s %8s %8s  %s\n", "marker", "attached to", "rms mm",
                "frames", "status");
  out << line;
  for (const MarkerCalibration& r : results) {
    std::string where = "-";
    if (r.definition.attachments[0].joint >= 0) {
      where = bvh.skeleton.joint(r.definition.attachments[0].joint).name;
      if (r.definition.num_attachments == 2)
        where += " + " + bvh.skeleton.joint(r.definition.attachments[1].joint).name;
    }
    std::snprintf(line, sizeof(line), "%-16s %-28s %8.3f %8d  %s\n", r.name.c_str(), where.c_str(),
                  r.rms_m * 1e3, r.frames_used,
                  r.accepted ? "ok" : ("REJECTED: " + r.reason).c_str());
    out << line;
    if (r.accepted) {
      accepted.push_back(r.definition);
      rms.push_back(r.rms_m);
    }
  }
  // A skeleton that most markers do not fit is the wrong skeleton (or the wrong units):
  // writing a subject from the few that happen to fit would solve with metres of error.
  if (accepted.size() < 3 || 2 * accepted.size() < results.size())
    throw std::runtime_error(
        "calibrate: only " + std::to_string(accepted.size()) + " of " +
        std::to_string(results.size()) + " markers fit the skeleton " + options.skeleton_bvh +
        " (read in " + bvh.units +
        "; see the REJECTED lines above): is it the same take, in the units guessed "
        "(--bvh-units)? No subject written");
  SubjectModel model;
  model.name = options.subject_name.empty()
                   ? std::filesystem::path(options.out_subject).stem().string()
                   : options.subject_name;
  model.skeleton = std::make_shared<const Skeleton>(bvh.skeleton);
  model.markers = std::make_shared<const MarkerSet>(bvh.skeleton, std::move(accepted));
  model.fit_rms_m = rms;
  model.bvh_units = bvh.units;
  WriteSubjectModel(options.out_subject, model);
  out << "wrote " << options.out_subject << ": " << model.markers->num_markers()
      << " markers accepted, " << results.size() - static_cast<size_t>(model.markers->num_markers())
      << " rejected, " << frames << " frames used\n";
  return model.markers->num_markers();
}

}  // namespace mocapd
