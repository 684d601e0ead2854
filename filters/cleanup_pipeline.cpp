// Streaming outlier detection, Hermite repair and final solve (see the header).
#include "filters/cleanup_pipeline.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "filters/hermite.hpp"

namespace mocapd {

struct CleanupPipeline::Slot {
  int64_t frame = -1;
  std::vector<Vec3> raw;  // as captured, after swap relabelling
  std::vector<uint8_t> valid;
  std::vector<uint8_t> relabelled;
  std::vector<MaskReason> mask;
  std::vector<Vec3> reference;  // X^ = LBS(Y^)
};

struct CleanupPipeline::MarkerTrack {
  double residual_scale = 0.0;  // running robust residual scale, metres
  int residual_run = 0;         // consecutive residual outliers
  int64_t still_since = -1;          // first frame of the current still run (-1: none)
  Vec3 still_anchor = Vec3::Zero();  // where the marker came to rest ...
  Vec3 still_reference = Vec3::Zero();  // ... and its reference then
  bool frozen = false;                  // excluded from the robust solve while it stays put
  bool fallen = false;  // excluded from the robust solve until it fits again
  bool stray = false;   // far off for a while: excluded until it fits again
  bool has_published = false;
  int64_t last_observed = -1;  // frame of the last published observed sample
  Vec3 offset = Vec3::Zero();  // last published X- - X^ ...
  Vec3 offset_velocity = Vec3::Zero();  // ... and its per-frame change
  Vec3 output = Vec3::Zero();           // last published X- ...
  Vec3 output_velocity = Vec3::Zero();  // ... and its per-frame change
  Vec3 reference_velocity = Vec3::Zero();  // X^'s per-frame change, snaps taken out
  Vec3 held_snap = Vec3::Zero();  // snaps a one-sided fill has not followed yet
  double weight = 1.0;                  // last final-solve weight
  bool catching_up = false;          // the final solve's target is still closing on the sample
  Vec3 data_motion = Vec3::Zero();   // the sample's motion as the catch-up last took it
};

const char* to_string(MaskReason reason) {
  switch (reason) {
    case MaskReason::kNone: return "none";
    case MaskReason::kMissing: return "missing";
    case MaskReason::kDisagreement: return "disagreement";
    case MaskReason::kResidual: return "residual";
    case MaskReason::kSpike: return "spike";
    case MaskReason::kRigidDistance: return "rigid_distance";
    case MaskReason::kSwap: return "swap";
    case MaskReason::kFrozen: return "frozen";
    case MaskReason::kFallenOff: return "fallen_off";
    case MaskReason::kSmallTrack: return "small_track";
    case MaskReason::kTrimmed: return "trimmed";
  }
  return "?";
}

const char* to_string(MarkerStatus status) {
  switch (status) {
    case MarkerStatus::kObserved: return "observed";
    case MarkerStatus::kRepaired: return "repaired";
    case MarkerStatus::kUnrecoverable: return "unrecoverable";
  }
  return "?";
}

CleanupOptions::CleanupOptions() {
  robust_ik.huber_delta_m = 0.004;
  // The reference carries little of its own velocity into the next frame: an unobserved
  // segment then stays near its last pose instead of swinging on (measured on the 12
  // Bandai takes x 2 seeds, K = 12: medium 3.25 -> 3.08 deg, pops 97 -> 91; heavy
  // 6.90 -> 6.64 deg, pops 496 -> 431; light unchanged).
  robust_ik.prediction_velocity_gain = 0.2;
  final_ik.prediction_velocity_gain = 0.5;
  // A stronger pull toward the warm start than plain IK: the final solve sees repaired
  // samples, and smoothness is what a published skeleton needs (measured: mean rotation
  // error 3.4 -> 2.7 deg on the Bandai walk, medium corruption).
  final_ik.temporal_weight = 3e-3;
  // Two LM iterations suffice for the final solve and one for the naive solve (it only
  // has to show which joints the outliers drag), both warm-started from a nearby pose.
  // Measured on the 12 Bandai takes x 2 seeds against 3 and 3: the same errors and pops
  // at light and medium, heavy 71 -> 68 pops and 5.63 -> 5.36 deg; the worst frame's
  // iterations drop from 9 to 6, which is what the per-frame p99 is made of.
  final_ik.max_iterations = 2;
  naive_ik.max_iterations = 1;
  // The anchor starts from last frame's final pose, so one iteration reaches it (measured:
  // the same errors and pops as two).
  anchor_ik = final_ik;
  anchor_ik.max_iterations = 1;
}

void CleanupOptions::Validate() const {
  auto require = [](bool ok, const char* field, const char* expected) {
    if (!ok) throw std::invalid_argument(std::string("CleanupOptions.") + field + ": expected " + expected);
  };
  require(rate_hz > 0.0 && std::isfinite(rate_hz), "rate_hz", "> 0");
  require(lookahead >= 0 && lookahead <= 1000, "lookahead", "0..1000 frames");
  require(window >= 1, "window", ">= 1 frame");
  require(disagreement_position_m > 0.0, "disagreement_position_m", "> 0");
  require(disagreement_rotation_rad > 0.0, "disagreement_rotation_rad", "> 0");
  require(disagreement_residual_m >= 0.0, "disagreement_residual_m", ">= 0");
  require(residual_floor_m > 0.0, "residual_floor_m", "> 0");
  require(residual_scale_factor > 0.0, "residual_scale_factor", "> 0");
  require(spike_m > 0.0, "spike_m", "> 0");
  require(rigid_tolerance_m > 0.0, "rigid_tolerance_m", "> 0");
  require(swap_margin_m >= 0.0, "swap_margin_m", ">= 0");
  require(frozen_radius_m > 0.0 && frozen_reference_motion_m > frozen_radius_m, "frozen_reference_motion_m",
          "> frozen_radius_m > 0");
  require(frozen_frames >= 1, "frozen_frames", ">= 1");
  require(stray_frames >= 1, "stray_frames", ">= 1");
  require(stray_residual_m > 0.0, "stray_residual_m", "> 0");
  require(fallen_frames >= 1, "fallen_frames", ">= 1");
  require(fallen_residual_m > 0.0, "fallen_residual_m", "> 0");
  require(small_gap_frames >= 0, "small_gap_frames", ">= 0");
  require(small_track_frames >= 0, "small_track_frames", ">= 0");
  require(trim_slope_m > 0.0, "trim_slope_m", "> 0");
  require(max_trim_frames >= 0, "max_trim_frames", ">= 0");
  require(max_offset_velocity_m > 0.0, "max_offset_velocity_m", "> 0");
  require(data_catchup_m >= 0.0, "data_catchup_m", ">= 0");
  require(data_motion_acceleration_m > 0.0, "data_motion_acceleration_m", "> 0");
  require(fill_anchor_radius_m >= 0.0, "fill_anchor_radius_m", ">= 0");
  require(fill_snap_release >= 0.0 && fill_snap_release <= 1.0, "fill_snap_release", "0..1");
  require(fill_reference_acceleration_mps2 >= 0.0 && std::isfinite(fill_reference_acceleration_mps2),
          "fill_reference_acceleration_mps2", ">= 0");
  require(fill_weight_ramp > 0.0 && std::isfinite(fill_weight_ramp), "fill_weight_ramp", "> 0");
  require(repaired_weight >= 0.0 && repaired_weight <= 1.0, "repaired_weight", "0..1");
  require(interpolated_weight >= 0.0 && interpolated_weight <= 1.0, "interpolated_weight", "0..1");
  naive_ik.Validate();
  robust_ik.Validate();
  final_ik.Validate();
  anchor_ik.Validate();
}

namespace {
Vec3 ClampNorm(const Vec3& v, double max_norm) {
  const double n = v.norm();
  return n > max_norm ? Vec3(v * (max_norm / n)) : v;
}
}  // namespace

CleanupPipeline::CleanupPipeline(std::shared_ptr<const Skeleton> skeleton, std::shared_ptr<const MarkerSet> markers,
                                 const CleanupOptions& options)
    : skeleton_(std::move(skeleton)),
      markers_(std::move(markers)),
      options_(options),
      naive_(*skeleton_, *markers_),
      robust_(*skeleton_, *markers_),
      final_(*skeleton_, *markers_),
      anchor_(*skeleton_, *markers_),
      held_kinematics_(*skeleton_) {
  options_.Validate();
  const auto m = static_cast<size_t>(markers_->num_markers());
  // The frames being published (t - K), the lookahead up to t, and two frames before for
  // slopes and trajectory continuity.
  ring_.resize(static_cast<size_t>(options_.lookahead) + 3);
  for (Slot& s : ring_) {
    s.raw.assign(m, Vec3::Constant(kNaN));
    s.valid.assign(m, 0);
    s.relabelled.assign(m, 0);
    s.mask.assign(m, MaskReason::kMissing);
    s.reference.assign(m, Vec3::Zero());
  }
  tracks_.assign(m, MarkerTrack{});
  for (MarkerTrack& t : tracks_) t.residual_scale = options_.residual_floor_m / options_.residual_scale_factor;
  markers_of_joint_.assign(static_cast<size_t>(skeleton_->num_joints()), {});
  for (int i = 0; i < markers_->num_markers(); ++i) {
    const MarkerDefinition& d = markers_->marker(i);
    for (int k = 0; k < d.num_attachments; ++k)
      markers_of_joint_[static_cast<size_t>(d.attachments[static_cast<size_t>(k)].joint)].push_back(i);
  }
  // Markers rigidly on the same joint keep their distance.
  for (int i = 0; i < markers_->num_markers(); ++i) {
    for (int j = i + 1; j < markers_->num_markers(); ++j) {
      const MarkerDefinition& a = markers_->marker(i);
      const MarkerDefinition& b = markers_->marker(j);
      if (a.num_attachments != 1 || b.num_attachments != 1 || a.attachments[0].joint != b.attachments[0].joint) continue;
      rigid_pairs_.emplace_back(i, j);
      rigid_distance_.push_back((a.attachments[0].offset - b.attachments[0].offset).norm());
    }
  }
  weights_.assign(m, 0.0);
  anchor_weights_.assign(m, 0.0);
  limb_seen_.assign(static_cast<size_t>(skeleton_->num_joints()), 0);
  held_pose_ = RestPose(*skeleton_);
  held_markers_.assign(m, Vec3::Zero());
  marker_flags_.assign(m, 0);
  swap_candidates_.reserve(m);
  candidate_previous_.assign(m, Vec3::Zero());
  solve_targets_.assign(m, Vec3::Constant(kNaN));
  scratch_.assign(m, Vec3::Zero());  // per-marker residuals of the newest frame
  out_.markers.assign(m, Vec3::Constant(kNaN));
  out_.status.assign(m, MarkerStatus::kUnrecoverable);
  out_.reason.assign(m, MaskReason::kNone);
  out_.weight.assign(m, 0.0);
  out_.pose = RestPose(*skeleton_);
}

CleanupPipeline::~CleanupPipeline() = default;

CleanupPipeline::Slot& CleanupPipeline::slot(int64_t frame) {
  return ring_[static_cast<size_t>(frame % static_cast<int64_t>(ring_.size()))];
}

void CleanupPipeline::Reset() {
  for (Slot& s : ring_) s.frame = -1;
  for (MarkerTrack& t : tracks_) {
    t = MarkerTrack{};
    t.residual_scale = options_.residual_floor_m / options_.residual_scale_factor;
  }
  naive_.Reset();
  naive_fresh_ = false;
  robust_.Reset();
  final_.Reset();
  next_in_ = next_out_ = 0;
}

bool CleanupPipeline::Push(std::span<const Vec3> p_WM) {
  const int64_t t = next_in_++;
  ++counters_.frames_in;
  Slot& s = slot(t);
  s.frame = t;
  const auto m_count = static_cast<size_t>(markers_->num_markers());
  for (size_t m = 0; m < m_count; ++m) {
    const bool valid = m < p_WM.size() && p_WM[m].allFinite();
    s.raw[m] = valid ? p_WM[m] : Vec3::Constant(kNaN);
    s.valid[m] = valid;
    s.relabelled[m] = 0;
    s.mask[m] = valid ? MaskReason::kNone : MaskReason::kMissing;
  }
  RelabelSwaps(t);
  // Y^: robust, without markers that are standing still while the body moves, have come
  // off, or have strayed far for a while. Markers flagged only by a modest residual stay
  // in (the Huber loss bounds their pull): excluding them would let the reference drift
  // away and keep them out.
  for (size_t m = 0; m < m_count; ++m) weights_[m] = s.valid[m] && !tracks_[m].frozen && !tracks_[m].fallen && !tracks_[m].stray ? 1.0 : 0.0;
  CountSolve(SolveIk(*skeleton_, *markers_, options_.robust_ik, s.raw, weights_, &robust_));
  const auto predicted = robust_.predicted_markers();
  std::copy(predicted.begin(), predicted.end(), s.reference.begin());
  // Y: the markers as they are. Disagreement can only mark markers further than
  // disagreement_residual_m from X^, so on frames with none the naive solve is skipped
  // (and re-seeded from Y^ when next needed): about a third of the per-frame work.
  naive_solved_ = false;
  for (size_t m = 0; m < m_count && !naive_solved_; ++m)
    naive_solved_ = s.valid[m] && (s.raw[m] - s.reference[m]).norm() > options_.disagreement_residual_m;
  if (naive_solved_) {
    if (!naive_fresh_) naive_.Reset(robust_.pose());
    for (size_t m = 0; m < m_count; ++m) weights_[m] = s.valid[m] ? 1.0 : 0.0;
    CountSolve(SolveIk(*skeleton_, *markers_, options_.naive_ik, s.raw, weights_, &naive_));
  }
  naive_fresh_ = naive_solved_;
  Detect(t);
  CleanMask(t);
  if (t - options_.lookahead < next_out_) return false;
  Publish(next_out_, t);
  return true;
}

void CleanupPipeline::CountSolve(const IkSummary& summary) {
  counters_.cold_starts += summary.cold_start;
  counters_.solve_failures += summary.status == IkStatus::kNumericalFailure;
  counters_.solve_iterations += summary.iterations;
}

bool CleanupPipeline::Flush() {
  if (next_out_ >= next_in_) return false;
  Publish(next_out_, next_in_ - 1);
  return true;
}

// Relabels swapped pairs before the frame is solved, so the reference is computed from
// the corrected labels.
void CleanupPipeline::RelabelSwaps(int64_t t) {
  Slot& s = slot(t);
  const bool has_previous = t > 0 && slot(t - 1).frame == t - 1;
  const Slot& prev = slot(t - 1 >= 0 ? t - 1 : 0);
  const auto m_count = static_cast<size_t>(markers_->num_markers());
  // Model distance between two markers rigidly on the same joint.
  auto RigidDistance = [&](size_t a, size_t b) {
    return (markers_->marker(static_cast<int>(a)).attachments[0].offset - markers_->marker(static_cast<int>(b)).attachments[0].offset).norm();
  };
  // Swaps first: a relabelled pair is fine for every other detector. Within one rigid
  // segment the layout's distances identify each marker: a pair whose exchanged labels
  // fit the distances to the segment's other markers clearly better is relabelled.
  for (size_t k = 0; k < rigid_pairs_.size(); ++k) {
    const auto i = static_cast<size_t>(rigid_pairs_[k].first);
    const auto j = static_cast<size_t>(rigid_pairs_[k].second);
    if (!s.valid[i] || !s.valid[j] || s.relabelled[i] || s.relabelled[j]) continue;
    double straight = 0.0, crossed = 0.0;
    int witnesses = 0;
    for (int other : markers_of_joint_[static_cast<size_t>(markers_->primary_joint(static_cast<int>(i)))]) {
      const auto o = static_cast<size_t>(other);
      if (o == i || o == j || !s.valid[o] || markers_->marker(other).num_attachments != 1) continue;
      const double di = (s.raw[i] - s.raw[o]).norm(), dj = (s.raw[j] - s.raw[o]).norm();
      const double mi = RigidDistance(i, o), mj = RigidDistance(j, o);
      straight += std::abs(di - mi) + std::abs(dj - mj);
      crossed += std::abs(dj - mi) + std::abs(di - mj);
      ++witnesses;
    }
    if (witnesses == 0 || crossed + options_.swap_margin_m * witnesses >= straight) continue;
    std::swap(s.raw[i], s.raw[j]);
    s.relabelled[i] = s.relabelled[j] = 1;
    ++counters_.swaps_relabelled;
  }
  // Across segments, trajectory
  // continuity decides most of them: each marker's sample is compared with its own
  // constant-velocity prediction, and a pair whose crossed assignment fits clearly better
  // is relabelled. A swap the reference can absorb (two of three markers on a segment)
  // is still a jump in both trajectories.
  const bool has_two_before = t > 1 && slot(t - 2).frame == t - 2;
  if (has_previous && has_two_before) {
    const Slot& prev2 = slot(t - 2);
    // Only markers whose last two samples were fine can be predicted; gathering them and
    // their positions first keeps the pair search to a tight loop over few markers.
    swap_candidates_.clear();
    for (size_t i = 0; i < m_count; ++i) {
      if (!s.valid[i] || prev.mask[i] != MaskReason::kNone || prev2.mask[i] != MaskReason::kNone) continue;
      swap_candidates_.push_back(static_cast<int>(i));
      candidate_previous_[swap_candidates_.size() - 1] = prev.raw[i];
    }
    const size_t n = swap_candidates_.size();
    const double search_sq = options_.swap_search_m * options_.swap_search_m;
    for (size_t a = 0; a < n; ++a) {
      const auto i = static_cast<size_t>(swap_candidates_[a]);
      if (s.relabelled[i]) continue;
      const Vec3 predicted_i = 2.0 * prev.raw[i] - prev2.raw[i];
      for (size_t b = a + 1; b < n; ++b) {
        if ((candidate_previous_[a] - candidate_previous_[b]).squaredNorm() > search_sq) continue;
        const auto j = static_cast<size_t>(swap_candidates_[b]);
        if (s.relabelled[j]) continue;
        const Vec3 predicted_j = 2.0 * prev.raw[j] - prev2.raw[j];
        const double straight = (s.raw[i] - predicted_i).norm() + (s.raw[j] - predicted_j).norm();
        const double crossed = (s.raw[j] - predicted_i).norm() + (s.raw[i] - predicted_j).norm();
        if (crossed + options_.swap_margin_m >= straight) continue;
        // The reference (last frame's, this frame's is not solved yet) must not disagree:
        // a wrong relabel would otherwise persist, since the next frame is predicted from
        // the relabelled one.
        if ((s.raw[j] - prev.reference[i]).norm() + (s.raw[i] - prev.reference[j]).norm() >
            (s.raw[i] - prev.reference[i]).norm() + (s.raw[j] - prev.reference[j]).norm())
          continue;
        std::swap(s.raw[i], s.raw[j]);
        s.relabelled[i] = s.relabelled[j] = 1;
        ++counters_.swaps_relabelled;
        break;
      }
    }
  }
}

void CleanupPipeline::Detect(int64_t t) {
  Slot& s = slot(t);
  const bool has_previous = t > 0 && slot(t - 1).frame == t - 1;
  const Slot& prev = slot(t - 1 >= 0 ? t - 1 : 0);
  const auto m_count = static_cast<size_t>(markers_->num_markers());
  const double alpha = 2.0 / (options_.window + 1.0);

  // Residuals against X^ and each marker's adaptive threshold.
  auto threshold = [&](size_t m) {
    return std::max(options_.residual_floor_m, options_.residual_scale_factor * tracks_[m].residual_scale);
  };
  std::span<Vec3> residual(scratch_.data(), m_count);
  for (size_t m = 0; m < m_count; ++m) residual[m] = s.valid[m] ? Vec3(s.raw[m] - s.reference[m]) : Vec3::Zero();

  // The rest: a pair that each fit the other's reference position.
  for (size_t i = 0; i < m_count; ++i) {
    if (!s.valid[i] || residual[i].norm() <= threshold(i)) continue;
    for (size_t j = i + 1; j < m_count; ++j) {
      if (!s.valid[j] || residual[j].norm() <= threshold(j)) continue;
      const double crossed_i = (s.raw[i] - s.reference[j]).norm();  // i's sample fits j
      const double crossed_j = (s.raw[j] - s.reference[i]).norm();
      if (crossed_i > threshold(j) || crossed_j > threshold(i)) continue;
      if (crossed_i + crossed_j + options_.swap_margin_m >= residual[i].norm() + residual[j].norm()) continue;
      if (options_.relabel_swaps) {
        std::swap(s.raw[i], s.raw[j]);
        s.relabelled[i] = s.relabelled[j] = 1;
        residual[i] = s.raw[i] - s.reference[i];
        residual[j] = s.raw[j] - s.reference[j];
        ++counters_.swaps_relabelled;
      } else {
        s.mask[i] = s.mask[j] = MaskReason::kSwap;
      }
      break;
    }
  }

  // Kinematic disagreement: a joint whose naive and robust solutions differ too much
  // marks every marker skinned to it.
  const KinematicsWorkspace& naive = naive_.kinematics();
  const KinematicsWorkspace& robust = robust_.kinematics();
  for (int j = 0; naive_solved_ && j < skeleton_->num_joints(); ++j) {
    if (skeleton_->joint(j).type == JointType::kFixed) continue;
    const auto uj = static_cast<size_t>(j);
    const double dp = (naive.p_WJ[uj] - robust.p_WJ[uj]).norm();
    const double cos_angle = std::clamp(0.5 * ((naive.R_WJ[uj].transpose() * robust.R_WJ[uj]).trace() - 1.0), -1.0, 1.0);
    if (dp <= options_.disagreement_position_m && std::acos(cos_angle) <= options_.disagreement_rotation_rad) continue;
    for (int m : markers_of_joint_[uj]) {
      const auto um = static_cast<size_t>(m);
      if (s.valid[um] && s.mask[um] == MaskReason::kNone && !s.relabelled[um] && residual[um].norm() > options_.disagreement_residual_m)
        s.mask[um] = MaskReason::kDisagreement;
    }
  }

  // The reference moving away from a still marker only convicts it if the segment's
  // motion is seen: another marker on the same joint fits its reference. (A planted
  // foot's markers stay still while a reference with no foot data drifts.)
  auto has_fitting_neighbour = [&](size_t m) {
    for (int other : markers_of_joint_[static_cast<size_t>(markers_->primary_joint(static_cast<int>(m)))]) {
      const auto o = static_cast<size_t>(other);
      if (o != m && s.valid[o] && !tracks_[o].frozen && residual[o].norm() <= threshold(o)) return true;
    }
    return false;
  };
  for (size_t m = 0; m < m_count; ++m) {
    MarkerTrack& track = tracks_[m];
    if (!s.valid[m]) {
      track.still_since = -1;
      track.frozen = false;
      continue;
    }
    const double r = residual[m].norm();
    const double thr = threshold(m);
    if (r > thr) {
      ++track.residual_run;
      if (s.mask[m] == MaskReason::kNone || s.mask[m] == MaskReason::kDisagreement) s.mask[m] = MaskReason::kResidual;
      // Fallen off: far from where it belongs (not a reference a few cm off) for long.
      if (track.residual_run >= options_.fallen_frames && r > options_.fallen_residual_m) {
        track.fallen = true;
        s.mask[m] = MaskReason::kFallenOff;
      }
      if (track.residual_run >= options_.stray_frames && r > options_.stray_residual_m) track.stray = true;
    } else {
      track.residual_run = 0;
      track.fallen = false;
      track.stray = false;
      // The running scale learns from good samples only (clipped at the threshold).
      track.residual_scale += alpha * (r - track.residual_scale);
    }
    // Frozen: at rest (within a radius, so jitter is not motion) while the reference
    // moves away; the run starts over wherever the marker leaves the radius.
    if (track.still_since < 0 || (s.raw[m] - track.still_anchor).norm() > options_.frozen_radius_m) {
      track.still_since = t;
      track.still_anchor = s.raw[m];
      track.still_reference = s.reference[m];
      track.frozen = false;
    } else if (t - track.still_since + 1 >= options_.frozen_frames &&
               (s.reference[m] - track.still_reference).norm() > options_.frozen_reference_motion_m &&
               has_fitting_neighbour(m)) {
      track.frozen = true;
    }
    if (track.frozen) {
      // Still and far from its reference for long is the more specific diagnosis.
      for (int64_t f = std::max(next_out_, track.still_since); f <= t; ++f)
        if (slot(f).valid[m] && slot(f).mask[m] != MaskReason::kFallenOff) slot(f).mask[m] = MaskReason::kFrozen;
    }
    if (!has_previous || !prev.valid[m]) continue;
    // Spikes: this frame's displacement disagrees with the reference's, from a sample
    // that was itself fine (so the return from a pop is not a spike).
    const Vec3 moved = s.raw[m] - prev.raw[m];
    const Vec3 reference_moved = s.reference[m] - prev.reference[m];
    if (prev.mask[m] == MaskReason::kNone && s.mask[m] == MaskReason::kNone && (moved - reference_moved).norm() > options_.spike_m)
      s.mask[m] = MaskReason::kSpike;
  }

  // Rigid segments: two markers on one joint that changed their distance; blame the one
  // that fits the reference worse.
  for (size_t k = 0; k < rigid_pairs_.size(); ++k) {
    const auto i = static_cast<size_t>(rigid_pairs_[k].first);
    const auto j = static_cast<size_t>(rigid_pairs_[k].second);
    if (!s.valid[i] || !s.valid[j] || s.mask[i] != MaskReason::kNone || s.mask[j] != MaskReason::kNone) continue;
    if (std::abs((s.raw[i] - s.raw[j]).norm() - rigid_distance_[k]) <= options_.rigid_tolerance_m) continue;
    s.mask[residual[i].norm() >= residual[j].norm() ? i : j] = MaskReason::kRigidDistance;
  }
}

void CleanupPipeline::CleanMask(int64_t t) {
  const auto m_count = static_cast<size_t>(markers_->num_markers());
  const int64_t first = std::max<int64_t>(next_out_, 0);
  auto good = [&](int64_t f, size_t m) { return slot(f).mask[m] == MaskReason::kNone; };
  // Most markers are fine over the whole window: neither rule can touch them, and one
  // pass over the window's masks finds them (the per-marker walks below are the costly
  // part).
  std::fill(marker_flags_.begin(), marker_flags_.end(), 0);
  for (int64_t f = std::max<int64_t>(first - 1, 0); f <= t; ++f) {
    const std::vector<MaskReason>& mask = slot(f).mask;
    for (size_t m = 0; m < m_count; ++m) marker_flags_[m] |= mask[m] != MaskReason::kNone;
  }
  for (size_t m = 0; m < m_count; ++m) {
    if (!marker_flags_[m]) continue;
    // Trim returning tracks whose slope disagrees with the reference's, frame by frame.
    for (int64_t g = first; g + 1 <= t; ++g) {
      if (g == 0 || good(g - 1, m) || !good(g, m)) continue;
      if (g - 1 < first - 1) continue;
      for (int n = 0; n < options_.max_trim_frames && g + 1 <= t && good(g, m) && good(g + 1, m); ++n, ++g) {
        const Slot& a = slot(g);
        const Slot& b = slot(g + 1);
        const Vec3 slope = (b.raw[m] - a.raw[m]) - (b.reference[m] - a.reference[m]);
        if (slope.norm() <= options_.trim_slope_m) break;
        slot(g).mask[m] = MaskReason::kTrimmed;
      }
    }
    // Small tracks: a short observed run with a gap on both sides, all still unpublished.
    int64_t run_start = -1;
    for (int64_t f = first; f <= t; ++f) {
      if (good(f, m)) {
        if (run_start < 0) run_start = f;
        continue;
      }
      if (run_start > first && !good(run_start - 1, m) && f - run_start <= options_.small_track_frames)
        for (int64_t g = run_start; g < f; ++g) slot(g).mask[m] = MaskReason::kSmallTrack;
      run_start = -1;
    }
  }
}

// Where the skeleton goes on the samples it can trust alone (captured, fitted, full
// weight): the anchor. A repaired sample may pull the skeleton at most
// fill_anchor_radius_m from it. A fill is a guess, and a guess may jump (its reference
// re-acquiring a segment, an interpolation bending onto a returning track); the anchor
// moves only with real data, so how far a guess can take the skeleton in one frame is
// bounded.
void CleanupPipeline::AnchorRepairs(const Slot& s) {
  const auto m_count = static_cast<size_t>(markers_->num_markers());
  for (size_t m = 0; m < m_count; ++m)
    anchor_weights_[m] = s.mask[m] == MaskReason::kNone && !tracks_[m].catching_up && weights_[m] >= 1.0 ? 1.0 : 0.0;
  anchor_.Reset(final_.pose());
  const IkSummary summary = SolveIk(*skeleton_, *markers_, options_.anchor_ik, solve_targets_, anchor_weights_, &anchor_);
  CountSolve(summary);
  // Too few trusted samples to solve: the anchor is last frame's skeleton.
  std::span<const Vec3> anchor = summary.status == IkStatus::kTooFewMarkers ? final_.predicted_markers() : anchor_.predicted_markers();
  if (summary.status != IkStatus::kTooFewMarkers && options_.anchor_holds_unseen_limbs && HoldUnseenLimbs()) anchor = held_markers_;
  for (size_t m = 0; m < m_count; ++m) {
    if (anchor_weights_[m] > 0.0 || weights_[m] <= 0.0 || tracks_[m].catching_up) continue;
    solve_targets_[m] = anchor[m] + ClampNorm(Vec3(solve_targets_[m] - anchor[m]), options_.fill_anchor_radius_m);
  }
}

// A limb with no trusted sample on it or below it (a lower leg and foot, a forearm and
// hand) keeps in the anchor the world orientation it had last frame: its parent carries
// its root along but does not swing it. A limb held relative to its parent turns with
// it, and a trusted thigh turning over an occluded, planted lower leg then swung the
// guessed foot 2-3 cm a frame faster than the real one (12 Bandai takes x 2 seeds, with
// a 1 cm anchor radius: medium pops K = 0 / 4 / 12 4 / 2 / 1 -> 0 / 0 / 0, heavy
// 11 / 10 / 8 -> 3 / 3 / 5, errors unchanged). Returns false when every limb is seen (the anchor stands as solved).
bool CleanupPipeline::HoldUnseenLimbs() {
  const int joints = skeleton_->num_joints();
  std::fill(limb_seen_.begin(), limb_seen_.end(), 0);
  for (int m = 0; m < markers_->num_markers(); ++m)
    if (anchor_weights_[static_cast<size_t>(m)] > 0.0) limb_seen_[static_cast<size_t>(markers_->primary_joint(m))] = 1;
  for (int j = joints - 1; j > 0; --j)  // parents come first: children fold into them
    if (limb_seen_[static_cast<size_t>(j)]) limb_seen_[static_cast<size_t>(skeleton_->joint(j).parent.value)] = 1;
  const KinematicsWorkspace& now = anchor_.kinematics();
  const KinematicsWorkspace& before = final_.kinematics();
  bool held = false;
  for (int j = 1; j < joints; ++j) {
    const auto uj = static_cast<size_t>(j);
    const int parent = skeleton_->joint(j).parent.value;
    // Only a ball joint can take any orientation; the root of an unseen limb is an
    // unseen joint under a seen one.
    if (parent < 0 || limb_seen_[uj] || !limb_seen_[static_cast<size_t>(parent)] || skeleton_->joint(j).type != JointType::kBall) continue;
    if (!held) held_pose_ = anchor_.pose();
    held_pose_.rotation[uj] = Quat(now.R_WJ[static_cast<size_t>(parent)].transpose() * before.R_WJ[uj]);
    held = true;
  }
  if (!held) return false;
  ForwardKinematics(*skeleton_, held_pose_, &held_kinematics_);
  EvaluateMarkers(*markers_, held_kinematics_, held_markers_);
  return true;
}

void CleanupPipeline::Publish(int64_t tau, int64_t newest) {
  Slot& s = slot(tau);
  const auto m_count = static_cast<size_t>(markers_->num_markers());
  const double max_v = options_.max_offset_velocity_m;
  const double dt = 1.0 / options_.rate_hz;
  const double max_reference_step_change = options_.fill_reference_acceleration_mps2 * dt * dt;
  const bool has_reference_before = tau > 0 && slot(tau - 1).frame == tau - 1;
  // The part of X^'s path over frames from..to that is snapping rather than moving (its
  // per-frame change beyond the acceleration limit), summed; `velocity` comes in as the
  // snap-free reference velocity at from - 1 and leaves as the one at `to`.
  auto reference_snap = [&](size_t m, int64_t from, int64_t to, Vec3* velocity) {
    Vec3 snap = Vec3::Zero();
    if (max_reference_step_change <= 0.0 || !has_reference_before) return snap;
    for (int64_t g = from; g <= to; ++g) {
      const Vec3 step = slot(g).reference[m] - slot(g - 1).reference[m];
      const Vec3 change = step - *velocity;
      const Vec3 excess = change - ClampNorm(change, max_reference_step_change);
      snap += excess;
      *velocity = step - excess;
    }
    return snap;
  };
  out_.frame = tau;
  const double catchup = options_.data_catchup_m;
  for (size_t m = 0; m < m_count; ++m) {
    MarkerTrack& track = tracks_[m];
    const bool previous_data = track.last_observed == tau - 1;  // x at tau - 1 was a captured sample
    const Vec3 previous_output = track.output;
    const Vec3& ref = s.reference[m];
    Vec3 x = Vec3::Constant(kNaN);
    MarkerStatus status = MarkerStatus::kRepaired;
    MaskReason reason = s.mask[m];
    bool interpolated = false;  // filled between two known ends
    // Each branch leaves x and the track's offset / velocities for the next frame.
    if (reason == MaskReason::kNone) {
      // Observed (or relabelled): published exactly as it is.
      x = s.raw[m];
      if (s.relabelled[m]) reason = MaskReason::kSwap;
      status = s.relabelled[m] ? MarkerStatus::kRepaired : MarkerStatus::kObserved;
      const Vec3 offset = x - ref;
      track.offset_velocity = track.has_published ? Vec3(offset - track.offset) : Vec3::Zero();
      track.offset = offset;
      track.output_velocity = track.has_published ? Vec3(x - track.output) : Vec3::Zero();
      track.reference_velocity = has_reference_before ? Vec3(ref - slot(tau - 1).reference[m]) : Vec3::Zero();
      track.held_snap.setZero();
      track.last_observed = tau;
    } else {
      int64_t end = -1;  // the returning track, if the lookahead shows it
      for (int64_t f = tau + 1; f <= newest; ++f) {
        if (slot(f).mask[m] == MaskReason::kNone) {
          end = f;
          break;
        }
      }
      const bool end_slope_known = end >= 0 && end + 1 <= newest && slot(end + 1).mask[m] == MaskReason::kNone;
      if (!track.has_published) {
        if (end < 0) {
          status = MarkerStatus::kUnrecoverable;  // never seen: nothing to repair from
        } else {
          // Nothing before the gap: ride the reference at the returning track's offset.
          track.offset = slot(end).raw[m] - slot(end).reference[m];
          track.offset_velocity = Vec3::Zero();
          x = ref + track.offset;
          track.output_velocity = Vec3::Zero();
        }
      } else if (end >= 0 && track.last_observed == tau - 1 && end - tau <= options_.small_gap_frames) {
        interpolated = true;
        // A short gap right after an observed sample: a plain Hermite on the raw path.
        const HermiteSegment h{track.output, track.output_velocity, slot(end).raw[m],
                               end_slope_known ? Vec3(slot(end + 1).raw[m] - slot(end).raw[m]) : track.output_velocity,
                               static_cast<double>(end - tau + 1)};
        x = h.Value(1.0);
        track.output_velocity = h.Derivative(1.0);
        const Vec3 offset = x - ref;
        track.offset_velocity = offset - track.offset;
        track.offset = offset;
      } else {
        // Offset onto the reference path, from the last published offset and velocity
        // to the returning track's (two-sided), or easing to a constant (one-sided).
        // Both ends are taken against X^ with its snaps taken out, so a reference that
        // jumps (this segment's other markers re-entering its solve) moves no fill.
        HermiteSegment h;
        h.p0 = track.offset;
        h.m0 = ClampNorm(track.offset_velocity, max_v);
        Vec3 velocity = track.reference_velocity;
        const Vec3 snap_now = reference_snap(m, tau, tau, &velocity);
        const Vec3 reference_velocity_now = velocity;
        if (end >= 0) {
          interpolated = true;
          const Slot& e = slot(end);
          const Vec3 snap_at_end = snap_now + reference_snap(m, tau + 1, end, &velocity);
          h.p1 = e.raw[m] - (e.reference[m] - snap_at_end);
          h.m1 = end_slope_known ? ClampNorm((slot(end + 1).raw[m] - slot(end + 1).reference[m]) - (e.raw[m] - e.reference[m]), max_v)
                                 : Vec3::Zero();
          h.length = static_cast<double>(end - tau + 1);
        } else {
          h.p1 = h.p0;
          h.m1 = Vec3::Zero();
          h.length = static_cast<double>(options_.lookahead + 1);
        }
        x = ref - snap_now + h.Value(1.0);
        if (end < 0) {
          // A held snap is taken up a little each frame: a reference that kept up a real
          // fast motion is followed again, with no jump.
          track.held_snap += snap_now;
          const Vec3 released = options_.fill_snap_release * track.held_snap;
          track.held_snap -= released;
          x += released;
        } else {
          track.held_snap.setZero();
        }
        track.offset = x - ref;
        track.offset_velocity = h.Derivative(1.0);
        track.reference_velocity = reference_velocity_now;
        track.output_velocity = x - track.output;
      }
    }
    // The final solve never takes a captured sample at one bound: it fits a target that
    // starts where the skeleton had the marker last frame, moves with the sample's own
    // motion (changing by at most data_motion_acceleration_m per frame, so a swap or pop
    // the detectors missed is not taken for motion) and closes on the sample by at most
    // data_catchup_m per frame. A sample the skeleton already fits is its own target; one
    // that returns away from where the skeleton had it (after a gap, a swap, a repair the
    // lookahead did not see the end of) is reached without a pop, and at full weight.
    Vec3 solve_x = x;
    const bool data = s.mask[m] == MaskReason::kNone;  // x is a captured sample, relabelled or not
    const bool eased = data && catchup > 0.0 && final_.has_solution();
    track.catching_up = false;
    if (eased) {
      Vec3 motion = Vec3::Zero();  // unknown on a sample's first frame back
      if (previous_data) motion = track.data_motion + ClampNorm(Vec3(x - previous_output - track.data_motion), options_.data_motion_acceleration_m);
      track.data_motion = motion;
      const Vec3 from = final_.predicted_markers()[m] + motion;
      if ((x - from).norm() > catchup) {
        solve_x = from + ClampNorm(Vec3(x - from), catchup);
        track.catching_up = true;
      }
    }
    solve_targets_[m] = solve_x;
    if (status != MarkerStatus::kUnrecoverable) {
      track.output = x;
      track.has_published = true;
    }
    out_.markers[m] = x;
    out_.status[m] = status;
    out_.reason[m] = status == MarkerStatus::kObserved ? MaskReason::kNone : reason;
    double weight = data                                       ? 1.0
                    : status == MarkerStatus::kUnrecoverable   ? 0.0
                    : interpolated                             ? options_.interpolated_weight
                                                               : options_.repaired_weight;
    // A sample handed from a guess (a one-sided fill, weak) to data (an interpolation,
    // or a captured sample when the catch-up is off) gains weight gradually, so the final
    // solve does not snap to it in one frame.
    if (options_.fill_weight_ramp > 1.0 && status != MarkerStatus::kUnrecoverable && weight > track.weight && !eased)
      weight = std::min(weight, std::max(track.weight, options_.repaired_weight) * options_.fill_weight_ramp);
    track.weight = weight;
    weights_[m] = weight;
    out_.weight[m] = weight;
    ++counters_.samples_out;
    if (status == MarkerStatus::kRepaired) ++counters_.repaired_by[static_cast<size_t>(reason)];
    if (status == MarkerStatus::kUnrecoverable) ++counters_.unrecoverable;
  }
  if (options_.fill_anchor_radius_m > 0.0 && final_.has_solution()) AnchorRepairs(s);
  out_.final_solve = SolveIk(*skeleton_, *markers_, options_.final_ik, solve_targets_, weights_, &final_);
  CountSolve(out_.final_solve);
  out_.pose = final_.pose();
  ++counters_.frames_out;
  next_out_ = tau + 1;
}

}  // namespace mocapd
