// Markers-only calibration: channels, marker set, template, priors, bundle adjustment.
#include "formats/subject_from_markers.hpp"

#include "formats/marker_clusters.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <set>
#include <stdexcept>

namespace mocapd {
namespace {

double Median(std::vector<double> v) {
  if (v.empty()) return kNaN;
  const auto mid = v.begin() + static_cast<long>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

// Every take's samples of the kept labels, frame-major, the takes one after another with
// an all-missing frame between them (so no solve mistakes the cut for motion).
struct Observations {
  std::vector<std::string> labels;
  std::vector<Vec3> positions;
  int frames = 0;
  const Vec3& at(int f, int m) const {
    return positions[static_cast<size_t>(f) * labels.size() + static_cast<size_t>(m)];
  }
};

Observations Gather(std::span<const C3dTake> takes, const std::vector<std::string>& labels) {
  Observations o;
  o.labels = labels;
  for (size_t k = 0; k < takes.size(); ++k) {
    const C3dTake& take = takes[k];
    std::vector<int> point(labels.size(), -1);
    for (int p = 0; p < take.num_points(); ++p) {
      const std::string bare = BareLabel(take.labels[static_cast<size_t>(p)]);
      for (size_t m = 0; m < labels.size(); ++m)
        if (labels[m] == bare && point[m] < 0) point[m] = p;
    }
    if (k > 0) {
      o.positions.insert(o.positions.end(), labels.size(), Vec3::Constant(kNaN));
      ++o.frames;
    }
    for (int f = 0; f < take.num_frames; ++f) {
      for (size_t m = 0; m < labels.size(); ++m) {
        Vec3 p = Vec3::Constant(kNaN);
        if (point[m] >= 0 && take.valid(f, point[m])) p = take.at(f, point[m]);
        o.positions.push_back(p);
      }
      ++o.frames;
    }
  }
  return o;
}

double DistanceSpread(const Observations& o, int a, int b, int stride) {
  return mocapd::DistanceSpread(o.positions, static_cast<int>(o.labels.size()), o.frames, a, b,
                                stride);
}

HumanoidRoles TemplateRolesOf(const Skeleton& skeleton) {
  HumanoidRoles roles;
  for (int j = 0; j < skeleton.num_joints(); ++j) roles.joint_of_role[skeleton.joint(j).name] = j;
  roles.spine_chain = {roles.joint_of_role.at("spine"), roles.joint_of_role.at("chest")};
  return roles;
}

// End sites for the template's end segments, so markers on them are placed along the
// template's own bones.
std::vector<BvhEndSite> TemplateEndSites(const Skeleton& skeleton, double height) {
  std::vector<BvhEndSite> sites;
  for (const char* role : {"head", "hand_l", "hand_r", "toe_l", "toe_r"})
    sites.push_back({skeleton.FindJoint(role)->value, TemplateBone(role, height)});
  return sites;
}

// Every built-in set's markers placed on the template: where markers go on a body, for
// placing a set nobody described. Landmarks within 1 cm of one already kept are dropped.
std::vector<MarkerDefinition> AnatomicalLandmarks(const Skeleton& templ,
                                                  const HumanoidRoles& roles) {
  std::vector<MarkerDefinition> out;
  for (const MarkerSetDefinition& set : BuiltInMarkerSets())
    for (const MarkerDefinition& d :
         PlaceMarkerSet(templ, roles, set, TemplateEndSites(templ, 1.75))) {
      bool repeated = false;
      for (const MarkerDefinition& kept : out)
        repeated =
            repeated || (kept.attachments[0].joint == d.attachments[0].joint &&
                         (kept.attachments[0].offset - d.attachments[0].offset).norm() < 0.01);
      if (!repeated) out.push_back(d);
    }
  return out;
}

// A clustered marker's first offset is the nearest landmark's: a guess, held loosely.
constexpr double kClusteredOffsetSigmaM = 0.08;
// Clustering alone places a full-body set: fewer markers (a lower-body or sparse set)
// fitted the template upside down or put pelvis markers on an arm when tried.
constexpr size_t kClusteringMinMarkers = 20;
// A placement where more than this share of the markers do not fit their segment has
// not found the body (a capture tilted 37 degrees put head markers on a shin when tried).
constexpr double kClusteringMaxMisfitShare = 0.2;

// The part of the body a template role belongs to, for the coverage check.
std::string BodyRegion(const std::string& role) {
  const std::string side = role.ends_with("_l") ? "left " : role.ends_with("_r") ? "right " : "";
  if (role == "head" || role == "neck") return "head";
  if (role.starts_with("upper_arm") || role.starts_with("forearm") || role.starts_with("hand"))
    return side + "arm";
  if (role.starts_with("thigh") || role.starts_with("shin") || role.starts_with("foot") ||
      role.starts_with("toe"))
    return side + "leg";
  return "trunk";  // pelvis, spine, chest, clavicles
}

// One calibration over a chosen list of markers (labels with their template joint and
// offset); fills what the caller reports.
struct Candidate {
  std::string label;
  int joint = -1;
  Vec3 offset = Vec3::Zero();
  double prior_sigma = 0.0;  // <= 0: default
  bool unknown = false;      // a studio marker: offset from the data
  bool guessed = false;      // placed by clustering, not on a known set's landmark
};

// The segments a full body needs markers on that none of the candidates rides: whole
// regions (the head, the trunk, a limb), and each limb's long bones.
std::string Uncovered(const Skeleton& templ, const std::vector<Candidate>& candidates) {
  std::string uncovered;
  auto add = [&](const std::string& what) { uncovered += (uncovered.empty() ? "" : ", ") + what; };
  for (const char* region : {"head", "trunk", "left arm", "right arm", "left leg", "right leg"}) {
    bool covered = false;
    for (const Candidate& c : candidates)
      covered = covered || BodyRegion(templ.joint(c.joint).name) == region;
    if (!covered) add(region);
  }
  for (const char* role : {"thigh_l", "thigh_r", "shin_l", "shin_r", "upper_arm_l", "upper_arm_r",
                           "forearm_l", "forearm_r"}) {
    bool covered = false;
    for (const Candidate& c : candidates) covered = covered || templ.joint(c.joint).name == role;
    if (!covered && uncovered.find(BodyRegion(role)) == std::string::npos) add(role);
  }
  return uncovered;
}

}  // namespace

std::string MirrorRole(const std::string& role) {
  if (role.ends_with("_l")) return role.substr(0, role.size() - 2) + "_r";
  if (role.ends_with("_r")) return role.substr(0, role.size() - 2) + "_l";
  return "";
}

namespace {

// The takes with the samples no body gives taken as missing (MarkersOnlyOptions'
// capture_volume_m and glitch_speed_mps), counted in `out`.
std::vector<C3dTake> WithoutImpossibleSamples(std::span<const C3dTake> takes,
                                              const MarkersOnlyOptions& options,
                                              MarkersOnlyCalibration* out) {
  std::vector<C3dTake> gated(takes.begin(), takes.end());
  for (C3dTake& take : gated) {
    const int points = take.num_points();
    const auto drop = [&](int f, int p) {
      take.at(f, p) = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
      take.residuals[static_cast<size_t>(f) * static_cast<size_t>(points) +
                     static_cast<size_t>(p)] = -1.0f;
    };
    for (int f = 0; f < take.num_frames; ++f)
      for (int p = 0; p < points; ++p)
        if (take.valid(f, p) && take.is_marker(p)) {
          if (!take.at(f, p).allFinite()) {
            drop(f, p);  // missing, as the live gate takes it: not a position to count
          } else if (take.at(f, p).cwiseAbs().maxCoeff() > options.capture_volume_m) {
            drop(f, p);
            ++out->samples_out_of_volume;
          }
        }
    if (take.rate_hz <= 0.0) continue;
    const double jump_m = options.glitch_speed_mps / take.rate_hz;
    // The median distance of the markers seen in both frames, or 0 with fewer than three
    // (as the live gate: one or two mislabelled markers are no frame's jump).
    std::vector<double> distances;
    const auto median_move = [&](int a, int b) {
      distances.clear();
      for (int p = 0; p < points; ++p)
        if (take.is_marker(p) && take.valid(a, p) && take.valid(b, p))
          distances.push_back((take.at(a, p) - take.at(b, p)).norm());
      return distances.size() < 3 ? 0.0 : Median(distances);
    };
    std::vector<int> glitches;
    for (int f = 1; f + 1 < take.num_frames; ++f)
      if (median_move(f, f - 1) > jump_m && median_move(f, f + 1) > jump_m &&
          median_move(f - 1, f + 1) <= 2.0 * jump_m)
        glitches.push_back(f);
    for (const int f : glitches)
      for (int p = 0; p < points; ++p)
        if (take.valid(f, p)) drop(f, p);
    out->glitch_frames += static_cast<int>(glitches.size());
  }
  return gated;
}

}  // namespace

MarkersOnlyCalibration CalibrateFromMarkers(std::span<const C3dTake> raw_takes,
                                            const MarkersOnlyOptions& options,
                                            const std::string& subject_name) {
  if (raw_takes.empty()) throw std::runtime_error("calibrate: no marker take given");
  MarkersOnlyCalibration out;
  const std::vector<C3dTake> gated = WithoutImpossibleSamples(raw_takes, options, &out);
  const std::span<const C3dTake> takes = gated;
  // The labels of every take, with how often each is seen and whether any file calls it
  // a model output.
  std::vector<std::string> labels;
  std::map<std::string, std::pair<long, bool>> seen;  // valid samples, model output
  long total_frames = 0;
  for (const C3dTake& take : takes) {
    total_frames += take.num_frames;
    for (int p = 0; p < take.num_points(); ++p) {
      const std::string bare = BareLabel(take.labels[static_cast<size_t>(p)]);
      if (!seen.count(bare)) labels.push_back(bare);
      auto& [valid, model_output] = seen[bare];
      model_output = model_output || !take.is_marker(p);
      for (int f = 0; f < take.num_frames; ++f)
        valid += take.valid(f, p) && take.at(f, p).allFinite();
    }
  }
  out.frames_total = static_cast<int>(total_frames);
  if (labels.empty() || total_frames == 0)
    throw std::runtime_error("calibrate: the takes hold no markers");
  std::vector<std::string> markers;
  for (const std::string& label : labels) {
    const auto& [valid, model_output] = seen[label];
    const ChannelKind kind = ClassifyChannel(
        label, model_output, static_cast<double>(valid) / total_frames, options.min_valid_fraction);
    if (kind == ChannelKind::kMarker)
      markers.push_back(label);
    else
      out.skipped.push_back({label, to_string(kind)});
  }
  if (markers.size() < 3)
    throw std::runtime_error(
        "calibrate: only " + std::to_string(markers.size()) + " markers are seen in at least " +
        std::to_string(static_cast<int>(options.min_valid_fraction * 100)) + " % of the frames (" +
        std::to_string(out.skipped.size()) + " channels skipped): nothing to calibrate from");

  // The marker set.
  MarkerSetDefinition chosen;
  MarkerSetMatch match;
  if (options.marker_set == "auto") {
    match = RecognizeMarkerSet(BuiltInMarkerSets(), markers);
    if (match.set != nullptr) chosen = *match.set;
  } else if (options.marker_set != "none") {
    chosen = FindMarkerSet(options.marker_set);
    match = MatchMarkerSet(chosen, markers);
    match.set = &chosen;
    // A named set the labels do not explain is the wrong set: it was used anyway, CMU's
    // 41 markers read as Plug-in Gait's (every pelvis and tibia marker missing) gave a
    // 67 cm thigh and 34-39 cm clavicles with exit 0.
    const MarkerSetMatch recognised = RecognizeMarkerSet(BuiltInMarkerSets(), markers);
    // Even a set the take holds whole: the lower-body set of a full-body take placed the
    // upper body's 23 markers as the studio's own, and the calibration failed on them.
    if (recognised.set != nullptr && recognised.set->name != chosen.name &&
        ExplainsLabelsBetter(recognised, match))
      throw std::runtime_error(
          "calibrate: the take's labels fit marker set '" + recognised.set->name + "' (" +
          std::to_string(recognised.required_found) + " of its " +
          std::to_string(recognised.required) + " markers) better than '" + chosen.name + "' (" +
          std::to_string(match.required_found) + " of " + std::to_string(match.required) +
          "): --marker-set " + recognised.set->name + " or auto");
    if (match.required_found < kMarkerSetMinRequiredShare * match.required)
      throw std::runtime_error(
          "calibrate: the take holds " + std::to_string(match.required_found) + " of the " +
          std::to_string(match.required) + " markers marker set '" + chosen.name +
          "' requires (at least " +
          std::to_string(static_cast<int>(std::lround(kMarkerSetMinRequiredShare * 100))) +
          " % are needed): is it the take's set? --marker-set auto recognises the set the "
          "labels fit; none places every marker by the body's shape");
  }
  const bool clustered = match.set == nullptr;
  if (clustered && options.marker_set != "auto" && options.marker_set != "none")
    throw std::logic_error("a named marker set always matches");
  out.marker_set = clustered ? std::string(kClusteredSetName) : chosen.name;
  {
    std::vector<uint8_t> found(chosen.markers.size(), 0);
    for (const std::string& label : markers)
      if (const auto m = chosen.Find(label)) found[static_cast<size_t>(*m)] = 1;
    for (size_t m = 0; m < chosen.markers.size(); ++m)
      if (!found[m] && !chosen.markers[m].optional)
        out.set_missing.push_back(chosen.markers[m].name);
  }

  // A take with no motion cannot show where any joint turns.
  {
    const Observations moving = Gather(takes, markers);
    const int stride = std::max(1, moving.frames / 600);
    std::vector<double> travel;
    for (size_t m = 0; m < markers.size(); ++m) {
      Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
      for (int f = 0; f < moving.frames; f += stride) {
        const Vec3& p = moving.at(f, static_cast<int>(m));
        if (!p.allFinite()) continue;
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
      }
      if (hi.x() >= lo.x()) travel.push_back((hi - lo).norm());
    }
    // Standing in place, most markers stay put while one limb moves: motion anywhere
    // counts (the 90th percentile of how far markers travel).
    std::sort(travel.begin(), travel.end());
    const double moved = travel.empty() ? 0.0 : travel[travel.size() * 9 / 10];
    if (moved < 0.03)
      throw std::runtime_error(
          std::string(takes.size() == 1 ? "calibrate: the take shows"
                                        : "calibrate: the takes show") +
          " no motion (the markers travel " +
          std::to_string(static_cast<int>(std::round(moved * 1e3))) +
          " mm at most, 90th percentile): calibration needs the joints to move, e.g. a "
          "range-of-motion take");
  }

  const Skeleton templ = MakeTemplateHumanoid(1.75);
  const HumanoidRoles roles = TemplateRolesOf(templ);
  const std::vector<MarkerDefinition> placed =
      PlaceMarkerSet(templ, roles, chosen, TemplateEndSites(templ, 1.75));
  const Observations all = Gather(takes, markers);
  auto marker_index = [&](const std::string& label) {
    return static_cast<int>(std::find(markers.begin(), markers.end(), label) - markers.begin());
  };
  const int stride = std::max(1, all.frames / 600);

  // Set markers ride their segment; a studio's own marker rides the segment it keeps its
  // distances to. With no set, every marker is placed by clustering.
  std::vector<Candidate> candidates;
  std::vector<int> studio;
  if (clustered) {
    // Why clustering: forced, or the labels' nearest set is too far from them.
    std::string why = "--marker-set none";
    if (options.marker_set == "auto") {
      why = "the labels match no known marker set";
      double best_share = -1.0;
      for (const MarkerSetDefinition& set : BuiltInMarkerSets()) {
        const MarkerSetMatch m = MatchMarkerSet(set, markers);
        const double share =
            m.required > 0 ? static_cast<double>(m.required_found) / m.required : 0;
        if (m.required_found > 0 && share > best_share) {
          best_share = share;
          why = "the labels match no known marker set (nearest: " + set.name + ", " +
                std::to_string(m.required_found) + " of its " + std::to_string(m.required) +
                " markers; 60 % needed)";
        }
      }
    }
    out.clustered_because = why;
    // The body's shape places markers only when they show a whole body.
    if (markers.size() < kClusteringMinMarkers)
      throw std::runtime_error(
          "calibrate: " + why +
          ", and clustering alone needs a full-body set (markers on the "
          "head, trunk, both arms and both legs; " +
          std::to_string(kClusteringMinMarkers) + " at least): " + std::to_string(markers.size()) +
          " markers are too few to place by clustering. Name the set with --marker-set NAME or "
          "FILE.toml. Nothing written");
    const ClusterPlacement placement =
        PlaceByClustering(templ, roles, AnatomicalLandmarks(templ, roles), all.positions,
                          static_cast<int>(markers.size()), all.frames);
    out.clusters = ClusterSummary{.up_axis = placement.up_axis,
                                  .tilt_deg = placement.tilt_deg,
                                  .height_m = placement.height_m,

                                  .landmark_rms_m = placement.landmark_rms_m,
                                  .moved_by_rigidity = placement.moved_by_rigidity,
                                  .turned_round = placement.turned_round};
    // The joined frames back to a take and a frame of it (one separator between takes).
    for (int f = placement.reference_frame;
         out.clusters->reference_take < static_cast<int>(takes.size());
         ++out.clusters->reference_take) {
      const int n = takes[static_cast<size_t>(out.clusters->reference_take)].num_frames;
      if (f < n) {
        out.clusters->reference_take_frame = f;
        break;
      }
      f -= n + 1;
    }
    for (size_t i = 0; i < markers.size(); ++i)
      candidates.push_back({markers[i], placement.joint[i], placement.offset[i],
                            kClusteredOffsetSigmaM, false, placement.anatomical[i] == 0});
    // A fit that leaves a limb, the head or the trunk without a marker has not found the
    // body (a lower-body set fitted upside down, a sparse set): refused, not written.
    const std::string uncovered = Uncovered(templ, candidates);
    if (!uncovered.empty())
      throw std::runtime_error(
          "calibrate: " + why + ", and clustering placed no marker on the " + uncovered +
          ": it needs a full-body set (a lower-body or sparse set cannot be placed by the "
          "body's shape). Name the set with --marker-set NAME or FILE.toml. Nothing written");
  }
  for (size_t i = 0; i < markers.size() && !clustered; ++i) {
    if (const auto m = chosen.Find(markers[i])) {
      const MarkerDefinition& d = placed[static_cast<size_t>(*m)];
      candidates.push_back(
          {markers[i], d.attachments[0].joint, d.attachments[0].offset, 0.0, false, false});
    } else {
      studio.push_back(static_cast<int>(i));
    }
  }
  // The segment whose placed markers (of known offset) keep their distances to marker u
  // best: the mean spread of its nearest two; -1 when no segment has two.
  auto rigid_segment = [&](int u, const std::vector<Candidate>& on_segments, double* best,
                           int near = -1) {
    *best = kNaN;
    int best_joint = -1;
    for (int j = 0; j < templ.num_joints(); ++j) {
      // near >= 0: only that segment or a neighbour of it (a knee marker keeps its
      // distances to the foot's too, from the hinge's axis).
      if (near >= 0 && j != near && templ.joint(j).parent.value != near &&
          templ.joint(near).parent.value != j)
        continue;
      std::vector<double> spreads;
      for (const Candidate& c : on_segments) {
        if (c.joint != j || c.unknown) continue;
        const double s = DistanceSpread(all, u, marker_index(c.label), stride);
        if (std::isfinite(s)) spreads.push_back(s);
      }
      if (spreads.size() < 2) continue;
      std::sort(spreads.begin(), spreads.end());
      const double score = 0.5 * (spreads[0] + spreads[1]);
      if (!(score >= *best)) {
        *best = score;
        best_joint = j;
      }
    }
    return best_joint;
  };
  for (int u : studio) {
    double best = kNaN;
    const int best_joint = rigid_segment(u, candidates, &best);
    const std::string& label = markers[static_cast<size_t>(u)];
    if (best_joint < 0 || !(best <= options.rigid_std_m)) {
      char why[160];
      std::snprintf(why, sizeof(why),
                    "not in the %s set and rides no segment rigidly (best: %.1f mm spread)",
                    chosen.name.c_str(), std::isfinite(best) ? best * 1e3 : 0.0);
      out.rejected.push_back({label, why});
      continue;
    }
    candidates.push_back({label, best_joint, Vec3::Zero(), 0.0, true, false});
    out.studio_markers.push_back(label);
  }

  // The hip centres: Harrington et al. 2007 from the pelvis markers' width and depth,
  // where the set has two front and at least one back pelvis marker.
  std::vector<Vec3> joint_prior;
  for (int j = 0; j < templ.num_joints(); ++j) joint_prior.push_back(templ.joint(j).offset);
  std::vector<double> joint_sigma(static_cast<size_t>(templ.num_joints()), 0.0);
  {
    int front_l = -1, front_r = -1;
    std::vector<int> back;
    for (size_t c = 0; c < candidates.size(); ++c) {
      if (clustered || candidates[c].unknown || candidates[c].joint != 0) continue;
      const auto m = chosen.Find(candidates[c].label);
      const Vec3& o = chosen.markers[static_cast<size_t>(*m)].offset_m;
      if (o.z() > 0.03 && o.x() > 0.05) front_l = static_cast<int>(c);
      if (o.z() > 0.03 && o.x() < -0.05) front_r = static_cast<int>(c);
      if (o.z() < -0.03) back.push_back(static_cast<int>(c));
    }
    auto index = [&](int c) { return marker_index(candidates[static_cast<size_t>(c)].label); };
    if (front_l >= 0 && front_r >= 0 && !back.empty()) {
      std::vector<double> widths, depths;
      for (int f = 0; f < all.frames; f += stride) {
        const Vec3& l = all.at(f, index(front_l));
        const Vec3& r = all.at(f, index(front_r));
        Vec3 mid_back = Vec3::Zero();
        int nb = 0;
        for (int b : back)
          if (all.at(f, index(b)).allFinite()) {
            mid_back += all.at(f, index(b));
            ++nb;
          }
        if (!l.allFinite() || !r.allFinite() || nb == 0) continue;
        const Vec3 across = (l - r).normalized();
        const Vec3 d = 0.5 * (l + r) - mid_back / nb;
        widths.push_back((l - r).norm());
        depths.push_back((d - d.dot(across) * across).norm());
      }
      if (widths.size() >= 10) {
        const double pw = Median(widths), pd = Median(depths);
        // Mid-ASIS relative to the mid-hip point, [left, up, forward].
        const Vec3 mid_front(0.0, 0.30 * pw + 0.0109, 0.24 * pd + 0.0099);
        candidates[static_cast<size_t>(front_l)].offset = mid_front + Vec3(0.5 * pw, 0, 0);
        candidates[static_cast<size_t>(front_r)].offset = mid_front - Vec3(0.5 * pw, 0, 0);
        candidates[static_cast<size_t>(front_l)].prior_sigma =
            candidates[static_cast<size_t>(front_r)].prior_sigma = 0.012;
        const double half = 0.33 * pw + 0.0073;
        const int tl = templ.FindJoint("thigh_l")->value, tr = templ.FindJoint("thigh_r")->value;
        joint_prior[static_cast<size_t>(tl)] = Vec3(half, 0, 0);
        joint_prior[static_cast<size_t>(tr)] = Vec3(-half, 0, 0);
        joint_sigma[static_cast<size_t>(tl)] = joint_sigma[static_cast<size_t>(tr)] = 0.012;
        out.hip_regression = true;
      }
    }
  }

  // Calibrate; reject markers that do not fit and calibrate again without them. Markers
  // that the body's shape placed (no set) and that do not fit get one more chance: the
  // segment they ride rigidly, as a studio's own marker would.
  const int passes = clustered ? 3 : 2;
  std::set<std::string> misfit_labels;  // clustering's markers that did not fit, once each
  for (int pass = 0; pass < passes; ++pass) {
    if (candidates.size() < 3)
      throw std::runtime_error("calibrate: fewer than 3 markers could be placed; nothing written");
    CalibrationTemplate t;
    t.skeleton = templ;
    t.joint_prior = joint_prior;
    t.joint_prior_sigma_m = joint_sigma;
    for (int j = 0; j < templ.num_joints(); ++j) {
      const std::string mirror = MirrorRole(templ.joint(j).name);
      t.mirror.push_back(mirror.empty() ? -1 : templ.FindJoint(mirror)->value);
    }
    t.gauge_left = templ.FindJoint("thigh_l")->value;
    t.gauge_right = templ.FindJoint("thigh_r")->value;
    std::vector<std::string> used;
    for (const Candidate& c : candidates) {
      MarkerDefinition d;
      d.name = c.label;
      d.attachments[0] = {c.joint, 1.0, c.offset};
      t.markers.push_back(d);
      t.marker_prior_sigma_m.push_back(c.prior_sigma);
      t.offset_unknown.push_back(c.unknown);
      t.offset_guessed.push_back(c.guessed);
      used.push_back(c.label);
    }
    const Observations obs = Gather(takes, used);
    try {
      out.solve = CalibrateSubject(t, obs.positions, obs.frames, options.solve);
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(std::string("calibrate: ") + e.what());
    }
    std::vector<Candidate> kept;
    bool changed = false;
    for (size_t m = 0; m < candidates.size(); ++m) {
      const double rms = out.solve.marker_rms_m[m];
      const int frames = out.solve.marker_frames[m];
      if (frames >= 10 && rms <= options.max_marker_rms_m) {
        kept.push_back(candidates[m]);
        continue;
      }
      changed = true;
      if (clustered && pass == 0 && frames >= 10) {
        double spread = kNaN;
        const int u = marker_index(candidates[m].label);
        std::vector<Candidate> others = candidates;
        others.erase(others.begin() + static_cast<long>(m));
        const int joint = rigid_segment(u, others, &spread, candidates[m].joint);
        misfit_labels.insert(candidates[m].label);
        if (joint >= 0 && spread <= options.rigid_std_m) {
          kept.push_back({candidates[m].label, joint, Vec3::Zero(), 0.0, true, false});
          ++out.clusters->placed_again_by_rigidity;
          continue;
        }
      }
      if (clustered && frames >= 10) misfit_labels.insert(candidates[m].label);
      char why[160];
      if (frames < 10)
        std::snprintf(why, sizeof(why), "seen in %d of the calibration's poses (10 needed)",
                      frames);
      else
        std::snprintf(why, sizeof(why), "fits its segment to %.1f mm RMS only (limit %.0f mm)",
                      rms * 1e3, options.max_marker_rms_m * 1e3);
      out.rejected.push_back({candidates[m].label, why});
    }
    if (!changed) break;
    if (2 * kept.size() < markers.size() || kept.size() < 3)
      throw std::runtime_error(
          "calibrate: only " + std::to_string(kept.size()) + " of " +
          std::to_string(markers.size()) +
          (clustered ? " markers fit a skeleton as clustering placed them; name the set with "
                       "--marker-set NAME or FILE.toml. Nothing written"
                     : " markers fit a skeleton; is the marker set right (--marker-set)? Nothing "
                       "written"));
    candidates = std::move(kept);
    if (pass == passes - 1)
      throw std::runtime_error(
          "calibrate: markers still fail to fit after rejecting the worst (a take this corrupt, "
          "or a wrong set: --marker-set NAME or FILE.toml). Nothing written");
  }
  if (clustered) {
    const size_t misfits = misfit_labels.size();
    if (static_cast<double>(misfits) >=
        kClusteringMaxMisfitShare * static_cast<double>(markers.size()))
      throw std::runtime_error(
          "calibrate: " + out.clustered_because + ", and clustering found no body they fit: " +
          std::to_string(misfits) + " of " + std::to_string(markers.size()) +
          " markers did not fit the segment the body's shape gave them (or the data is too "
          "corrupt to tell). Name the set with --marker-set NAME or FILE.toml. Nothing written");
    // Re-placed and rejected markers may have left a limb bare.
    const std::string uncovered = Uncovered(templ, candidates);
    if (!uncovered.empty())
      throw std::runtime_error("calibrate: " + out.clustered_because +
                               ", and after placing the markers that did not fit, no marker is "
                               "left on the " +
                               uncovered +
                               ". Name the set with --marker-set NAME or FILE.toml. Nothing "
                               "written");
  }
  if (2 * candidates.size() < markers.size())
    throw std::runtime_error("calibrate: only " + std::to_string(candidates.size()) + " of " +
                             std::to_string(markers.size()) +
                             " markers could be placed; nothing written");
  out.model.name = subject_name;
  out.model.bvh_units = "cm";
  out.model.skeleton = std::make_shared<const Skeleton>(out.solve.skeleton);
  out.model.markers = std::make_shared<const MarkerSet>(*out.model.skeleton, out.solve.markers);
  out.model.fit_rms_m = out.solve.marker_rms_m;
  for (const Candidate& c : candidates) out.markers.push_back(c.label);
  return out;
}

SubjectCalibrationRecord CalibrationRecordOf(const MarkersOnlyCalibration& calibration) {
  SubjectCalibrationRecord record;
  record.marker_set = calibration.marker_set;
  record.poses = static_cast<int>(calibration.solve.frames_used.size());
  record.median_residual_mm = calibration.solve.median_residual_m * 1e3;
  for (const JointCalibrationReport& jr : calibration.solve.joints) {
    record.joint_method.push_back(jr.method);
    record.joint_uncertainty_mm.push_back(jr.method == "root" ? kNaN : jr.uncertainty_m * 1e3);
  }
  return record;
}

SubjectModel TemplateSubject(const MarkerSetDefinition& set, std::span<const std::string> labels,
                             double height_m, const std::string& subject_name) {
  const Skeleton templ = MakeTemplateHumanoid(height_m);
  const std::vector<MarkerDefinition> placed =
      PlaceMarkerSet(templ, TemplateRolesOf(templ), set, TemplateEndSites(templ, height_m));
  std::vector<MarkerDefinition> ordered;
  std::string unknown;
  for (const std::string& label : labels) {
    const auto m = set.Find(label);
    if (!m) {
      unknown += (unknown.empty() ? "" : ", ") + label;
      continue;
    }
    MarkerDefinition d = placed[static_cast<size_t>(*m)];
    d.name = label;
    ordered.push_back(std::move(d));
  }
  if (!unknown.empty())
    throw std::runtime_error("markers not in the " + set.name + " set: " + unknown);
  SubjectModel model;
  model.name = subject_name;
  model.skeleton = std::make_shared<const Skeleton>(templ);
  model.markers = std::make_shared<const MarkerSet>(*model.skeleton, std::move(ordered));
  model.fit_rms_m.assign(labels.size(), kNaN);
  return model;
}

std::optional<double> EstimateHeight(const Skeleton& template_skeleton,
                                     const MarkerSet& template_markers, double template_height_m,
                                     std::span<const Vec3> frame) {
  const MarkerSet& markers = template_markers;
  if (frame.size() != static_cast<size_t>(markers.num_markers())) return std::nullopt;
  KinematicsWorkspace rest(template_skeleton);
  ForwardKinematics(template_skeleton, RestPose(template_skeleton), &rest);
  std::vector<Vec3> placed(frame.size());
  EvaluateMarkers(markers, rest, placed);
  std::vector<double> ratios;
  for (int a = 0; a < markers.num_markers(); ++a)
    for (int b = a + 1; b < markers.num_markers(); ++b) {
      const auto ua = static_cast<size_t>(a), ub = static_cast<size_t>(b);
      if (markers.primary_joint(a) != markers.primary_joint(b)) continue;
      if (!frame[ua].allFinite() || !frame[ub].allFinite()) continue;
      // Markers a few centimetres apart say more about noise than about size.
      const double expected = (placed[ua] - placed[ub]).norm();
      if (expected < 0.05) continue;
      ratios.push_back((frame[ua] - frame[ub]).norm() / expected);
    }
  if (ratios.size() < 3) return std::nullopt;
  const double height = Median(ratios) * template_height_m;
  if (!(height >= 0.5 && height <= 2.6)) return std::nullopt;
  return height;
}

SubjectModel InTemplateOrder(const MarkersOnlyCalibration& calibration,
                             const SubjectModel& template_subject) {
  const Skeleton& calibrated = *calibration.model.skeleton;
  const Skeleton& templ = *template_subject.skeleton;
  if (calibrated.num_joints() != templ.num_joints())
    throw std::logic_error("calibrated skeleton differs from its template");
  std::vector<MarkerDefinition> ordered;
  std::vector<double> rms;
  for (const MarkerDefinition& t : template_subject.markers->markers()) {
    const auto found = calibration.model.markers->FindMarker(t.name);
    if (found) {
      ordered.push_back(calibration.model.markers->marker(found->value));
      rms.push_back(calibration.model.fit_rms_m[static_cast<size_t>(found->value)]);
    } else {
      ordered.push_back(t);
      rms.push_back(kNaN);
    }
  }
  SubjectModel model = calibration.model;
  model.name = template_subject.name;
  model.markers = std::make_shared<const MarkerSet>(calibrated, std::move(ordered));
  model.fit_rms_m = std::move(rms);
  model.calibration = CalibrationRecordOf(calibration);
  return model;
}

}  // namespace mocapd
