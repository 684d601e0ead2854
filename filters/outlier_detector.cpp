// Swap relabelling, the two reference solves, the detectors and the mask clean-up.
#include "filters/outlier_detector.hpp"

#include <algorithm>
#include <cmath>

namespace mocapd {
namespace {

void ExchangeSamples(WindowFrame& s, size_t i, size_t j) {
  std::swap(s.raw[i], s.raw[j]);
  std::swap(s.valid[i], s.valid[j]);
  std::swap(s.mask[i], s.mask[j]);
  s.relabelled[i] = s.relabelled[j] = 1;
}

// Where marker m's sample is expected in the frame after prev: on from its last two
// samples, else at its last sample, else (back from a gap) at prev's reference.
Vec3 ExpectedSample(const WindowFrame& prev, const WindowFrame& prev2, bool has_two_before,
                    size_t m) {
  if (prev.valid[m] && has_two_before && prev2.valid[m]) return 2.0 * prev.raw[m] - prev2.raw[m];
  if (prev.valid[m]) return prev.raw[m];
  return prev.reference[m];
}

// A solve that left a pose for this frame (not a hold on too few markers, not a failure).
bool Solved(const IkSummary& summary) {
  return summary.status == IkStatus::kConverged || summary.status == IkStatus::kMaxIterations;
}

}  // namespace

OutlierDetector::OutlierDetector(const Skeleton& skeleton, const MarkerSet& markers,
                                 const CleanupOptions& options)
    : skeleton_(skeleton),
      markers_(markers),
      options_(options),
      rules_(FrameRules(options)),
      naive_(skeleton, markers),
      robust_(skeleton, markers),
      without_lone_(skeleton, markers),
      robust_ik_on_any_(options.robust_ik) {
  robust_ik_on_any_.cold_start_min_fraction = 0.0;
  const auto m = static_cast<size_t>(markers_.num_markers());
  tracks_.assign(m, FreshTrack());
  swap_partner_.assign(m, -1);
  continuity_partner_.assign(m, -1);
  previous_continuity_partner_.assign(m, -1);
  markers_of_joint_.assign(static_cast<size_t>(skeleton_.num_joints()), {});
  for (int i = 0; i < markers_.num_markers(); ++i) {
    const MarkerDefinition& d = markers_.marker(i);
    for (int k = 0; k < d.num_attachments; ++k)
      markers_of_joint_[static_cast<size_t>(d.attachments[static_cast<size_t>(k)].joint)].push_back(
          i);
  }
  // Markers rigidly on the same joint keep their distance.
  for (int i = 0; i < markers_.num_markers(); ++i) {
    for (int j = i + 1; j < markers_.num_markers(); ++j) {
      const MarkerDefinition& a = markers_.marker(i);
      const MarkerDefinition& b = markers_.marker(j);
      if (a.num_attachments != 1 || b.num_attachments != 1 ||
          a.attachments[0].joint != b.attachments[0].joint)
        continue;
      rigid_pairs_.emplace_back(i, j);
      rigid_distance_.push_back((a.attachments[0].offset - b.attachments[0].offset).norm());
    }
  }
  pairs_of_marker_.assign(m, {});
  for (size_t k = 0; k < rigid_pairs_.size(); ++k) {
    pairs_of_marker_[static_cast<size_t>(rigid_pairs_[k].first)].push_back(static_cast<int>(k));
    pairs_of_marker_[static_cast<size_t>(rigid_pairs_[k].second)].push_back(static_cast<int>(k));
  }
  distance_at_rest_.assign(rigid_pairs_.size(), {kNaN, kNaN});
  layout_fitted_frame_.assign(rigid_pairs_.size(), -1);
  weights_.assign(m, 0.0);
  trusted_on_joint_.assign(static_cast<size_t>(skeleton_.num_joints()), 0);
  readmit_on_joint_.assign(static_cast<size_t>(skeleton_.num_joints()), 0);
  residual_.assign(m, Vec3::Zero());
  marker_flags_.assign(m, 0);
  swap_candidates_.reserve(m);
  weights_without_lone_.assign(m, 0.0);
  lone_samples_.reserve(m);
  candidate_previous_.assign(m, Vec3::Zero());
}

double OutlierDetector::JointOriginDistance(const WindowFrame& s, size_t m,
                                            const KinematicsWorkspace& joints) const {
  const int joint = markers_.marker(static_cast<int>(m)).attachments[0].joint;
  return (s.raw[m] - joints.p_WJ[static_cast<size_t>(joint)]).norm();
}

bool OutlierDetector::OffItsJoint(double distance, size_t m, double tolerance) const {
  // Written to accept, so that a NaN distance (nothing to judge by) never convicts.
  return std::abs(distance - markers_.marker(static_cast<int>(m)).attachments[0].offset.norm()) >
         tolerance;
}

bool OutlierDetector::StillForFrozenS(const WindowFrame& s, size_t m, int64_t t) const {
  const Track& track = tracks_[m];
  return track.still_since >= 0 && t - track.still_since + 1 >= rules_.frozen_frames &&
         t - track.last_seen - 1 <= rules_.frozen_backdate_frames &&
         (s.raw[m] - track.still_anchor).norm() <= options_.frozen_radius_m &&
         !std::isnan(track.joint_distance_at_rest);
}

OutlierDetector::Track OutlierDetector::FreshTrack() const {
  Track t;
  t.residual_scale = options_.residual_floor_m / options_.residual_scale_factor;
  return t;
}

void OutlierDetector::Reset() {
  std::fill(tracks_.begin(), tracks_.end(), FreshTrack());
  std::fill(swap_partner_.begin(), swap_partner_.end(), -1);
  std::fill(continuity_partner_.begin(), continuity_partner_.end(), -1);
  continuity_frame_ = -1;
  std::fill(distance_at_rest_.begin(), distance_at_rest_.end(), std::array<double, 2>{kNaN, kNaN});
  std::fill(layout_fitted_frame_.begin(), layout_fitted_frame_.end(), -1);
  naive_.Reset();
  naive_fresh_ = false;
  robust_.Reset();
  unsolved_since_ = -1;
}

void OutlierDetector::Process(CleanupWindow& window, int64_t t, int64_t first_unpublished,
                              CleanupCounters* counters) {
  ApplyPersistentSwaps(window, t, counters);
  RelabelSwaps(window, t, counters);
  SolveReferences(window.at(t), counters);
  // With no reference yet, every sample would be judged against the template's rest pose
  // wherever it stands: the samples are data, kept as they came.
  if (window.at(t).reference_solved) Detect(window, t, first_unpublished, counters);
  CleanMask(window, t, first_unpublished);
}

void OutlierDetector::SolveReferences(WindowFrame& s, CleanupCounters* counters) {
  const auto m_count = static_cast<size_t>(markers_.num_markers());
  // Y^: robust, without markers that are standing still while the body moves, have come
  // off, have strayed far for a while, or were off their joint's distance last frame.
  // Markers flagged only by a modest residual stay in (the Huber loss bounds their pull):
  // excluding them would let the reference drift away and keep them out.
  // (With relabelling off, a sample a swap test masked stays out too: it is another
  // marker's trajectory.)
  for (size_t m = 0; m < m_count; ++m)
    weights_[m] =
        s.valid[m] && !excluded(static_cast<int>(m)) && s.mask[m] != MaskReason::kSwap ? 1.0 : 0.0;
  ReadmitConsistentSegments(s);
  // A cold start waits for half the marker set (robust_ik.cold_start_min_fraction), but
  // only reference_cold_start_wait_s: a take may never show that many.
  const bool waited =
      unsolved_since_ >= 0 && s.frame - unsolved_since_ >= rules_.reference_cold_start_wait_frames;
  const IkOptions& robust_ik = waited ? robust_ik_on_any_ : options_.robust_ik;
  // Kept to solve this frame again from the same start (OverruleLoneSamples).
  without_lone_.CopyHistoryFrom(robust_);
  const IkSummary solve = SolveIk(skeleton_, markers_, robust_ik, s.raw, weights_, &robust_);
  counters->CountSolve(solve);
  if (Solved(solve) && !solve.cold_start) OverruleLoneSamples(s, robust_ik, counters);
  if (robust_.has_solution()) {
    unsolved_since_ = -1;
  } else if (unsolved_since_ < 0 &&
             std::count(weights_.begin(), weights_.end(), 1.0) >= options_.robust_ik.min_markers) {
    unsolved_since_ = s.frame;
  }
  const auto predicted = robust_.predicted_markers();
  std::copy(predicted.begin(), predicted.end(), s.reference.begin());
  s.reference_solved = robust_.has_solution();
  // Y: the markers as they are. Disagreement can only mark markers further than
  // disagreement_residual_m from X^, so on frames with none the naive solve is skipped
  // (and re-seeded from Y^ when next needed): about a third of the per-frame work.
  naive_solved_ = false;
  for (size_t m = 0; m < m_count && !naive_solved_; ++m)
    naive_solved_ =
        s.valid[m] && (s.raw[m] - s.reference[m]).norm() > options_.disagreement_residual_m;
  if (naive_solved_) {
    if (!naive_fresh_) naive_.Reset(robust_.pose());
    for (size_t m = 0; m < m_count; ++m) weights_[m] = s.valid[m] ? 1.0 : 0.0;
    counters->CountSolve(SolveIk(skeleton_, markers_, options_.naive_ik, s.raw, weights_, &naive_));
  }
  naive_fresh_ = naive_solved_;
}

// A segment's only sample can pull its parent off the parent's own markers: the robust
// solve bends the joint and turns the parent to reach it, and where the sample is wrong
// the parent's clean markers are the ones rejected (the soak's actor3: a fallen-off foot
// marker lying on the floor under a toe's label, the toe's other marker occluded; the
// solve kept the toe on it as the foot lifted away, rejected both clean foot markers one
// after the other, and the toe was published 21 cm off). No test on that pose can see it:
// the pose was made to fit the sample. So where a lone sample fits while a marker of its
// parent does not, Y^ is solved again without it, from the same start. Where that solve
// fits the parent on every one of two or more markers and puts the sample where no turn
// of its segment reaches (off its joint's origin by off_joint_m), or, for a sample still
// for frozen_s, where its distance to the origin has changed by what a frozen marker's
// reference must move, the sample is overruled: off its joint for this frame, so out of
// the next frame's Y^, and that solve is this frame's Y^. (With the parent seen on one
// marker it turns freely about it, and the solve without the sample shows nothing; the
// still radius instead of frozen_reference_motion_m would convict a resting hand's clean
// marker when its forearm's markers move a wrist by soft tissue alone.)
void OutlierDetector::OverruleLoneSamples(const WindowFrame& s, const IkOptions& robust_ik,
                                          CleanupCounters* counters) {
  auto fits = [&](size_t m, std::span<const Vec3> model) {
    return (s.raw[m] - model[m]).norm() <= ResidualThreshold(m);
  };
  // Of joint j's parent's markers with weight: how many, and how many fit the model.
  struct ParentFit {
    int trusted = 0, fitting = 0;
  };
  auto parent_fit = [&](int j, std::span<const double> weights, std::span<const Vec3> model) {
    ParentFit fit;
    for (int o : markers_of_joint_[static_cast<size_t>(skeleton_.joint(j).parent.value)]) {
      const auto uo = static_cast<size_t>(o);
      if (weights[uo] <= 0.0) continue;
      ++fit.trusted;
      fit.fitting += fits(uo, model) ? 1 : 0;
    }
    return fit;
  };
  const auto predicted = robust_.predicted_markers();
  lone_samples_.clear();
  for (int j = 0; j < skeleton_.num_joints(); ++j) {
    const int parent = skeleton_.joint(j).parent.value;
    if (parent < 0) continue;
    int trusted = 0, lone = -1;
    for (int m : markers_of_joint_[static_cast<size_t>(j)])
      if (weights_[static_cast<size_t>(m)] > 0.0) {
        ++trusted;
        lone = m;
      }
    if (trusted != 1 || markers_.marker(lone).num_attachments != 1 ||
        !fits(static_cast<size_t>(lone), predicted))
      continue;
    const ParentFit fit = parent_fit(j, weights_, predicted);
    if (fit.fitting < fit.trusted && fit.trusted >= 2) lone_samples_.push_back(lone);
  }
  if (lone_samples_.empty()) return;
  std::copy(weights_.begin(), weights_.end(), weights_without_lone_.begin());
  for (int m : lone_samples_) weights_without_lone_[static_cast<size_t>(m)] = 0.0;
  // without_lone_ holds the history the robust solve started from (SolveReferences).
  const IkSummary refit =
      SolveIk(skeleton_, markers_, robust_ik, s.raw, weights_without_lone_, &without_lone_);
  counters->CountSolve(refit);
  if (!Solved(refit) || refit.cold_start) return;
  const auto refit_markers = without_lone_.predicted_markers();
  const KinematicsWorkspace& refit_joints = without_lone_.kinematics();
  int overruled = 0;
  for (const int lone : lone_samples_) {
    const auto m = static_cast<size_t>(lone);
    const ParentFit fit =
        parent_fit(markers_.primary_joint(lone), weights_without_lone_, refit_markers);
    const double distance = JointOriginDistance(s, m, refit_joints);
    const Track& track = tracks_[m];
    const bool off_joint =
        options_.off_joint_m > 0.0 && OffItsJoint(distance, m, options_.off_joint_m);
    const bool left_while_still =
        StillForFrozenS(s, m, s.frame) &&
        std::abs(distance - track.joint_distance_at_rest) > options_.frozen_reference_motion_m;
    if (fit.fitting < fit.trusted || fit.fitting < 2 || !(off_joint || left_while_still)) continue;
    tracks_[m].overruled_frame = s.frame;
    ++counters->lone_samples_overruled;
    ++overruled;
  }
  // Where another lone sample stands, the solve without it is no Y^ for this frame: the
  // overruled ones leave from the next.
  if (overruled == static_cast<int>(lone_samples_.size())) std::swap(robust_, without_lone_);
}

// Excluding a stray or fallen-off sample protects its segment's good markers from it. When
// every marker of a segment is excluded, there is nothing left to protect, and the
// exclusion only keeps the segment's data out while the reference guesses it (a foot
// whose shin is occluded: the guessed shin takes the foot away from its clean markers,
// they turn stray, and stay out because the reference never comes back to them). Two or
// more such markers that keep the segment's rigid distances to each other are the
// segment, not strays: they are taken back into the reference. A lone one, or ones that
// disagree (a swapped sample among them), stay out.
void OutlierDetector::ReadmitConsistentSegments(const WindowFrame& s) {
  std::fill(trusted_on_joint_.begin(), trusted_on_joint_.end(), 0);
  std::fill(readmit_on_joint_.begin(), readmit_on_joint_.end(), 0);
  for (int m = 0; m < markers_.num_markers(); ++m)
    if (weights_[static_cast<size_t>(m)] > 0.0)
      ++trusted_on_joint_[static_cast<size_t>(markers_.primary_joint(m))];
  // A joint's excluded samples are readmitted when at least one pair of them is present
  // and every such pair keeps its rigid distance.
  for (size_t k = 0; k < rigid_pairs_.size(); ++k) {
    const auto i = static_cast<size_t>(rigid_pairs_[k].first),
               j = static_cast<size_t>(rigid_pairs_[k].second);
    const auto joint = static_cast<size_t>(markers_.primary_joint(rigid_pairs_[k].first));
    if (trusted_on_joint_[joint] > 0 || !s.valid[i] || !s.valid[j] || tracks_[i].frozen ||
        tracks_[j].frozen)
      continue;
    const bool rigid =
        std::abs((s.raw[i] - s.raw[j]).norm() - rigid_distance_[k]) <= options_.rigid_tolerance_m;
    if (readmit_on_joint_[joint] >= 0) readmit_on_joint_[joint] = rigid ? 1 : -1;
  }
  for (size_t m = 0; m < weights_.size(); ++m) {
    const auto joint = static_cast<size_t>(markers_.primary_joint(static_cast<int>(m)));
    if (readmit_on_joint_[joint] > 0 && s.valid[m] && !tracks_[m].frozen &&
        s.mask[m] != MaskReason::kSwap && markers_.marker(static_cast<int>(m)).num_attachments == 1)
      weights_[m] = 1.0;
  }
  // One trusted marker cannot tell a segment's rotation about it: the reference turns
  // where the prior takes it, and an excluded marker of the segment stays far from it
  // however clean it is (a toe whose other marker froze for half a second stayed out for
  // the rest of the take, its repairs 5-10 cm off). An excluded marker that keeps its
  // rigid distance to the one trusted marker of its segment is on the segment: taken back.
  for (size_t k = 0; k < rigid_pairs_.size(); ++k) {
    const auto i = static_cast<size_t>(rigid_pairs_[k].first),
               j = static_cast<size_t>(rigid_pairs_[k].second);
    const auto joint = static_cast<size_t>(markers_.primary_joint(rigid_pairs_[k].first));
    if (trusted_on_joint_[joint] != 1 || !s.valid[i] || !s.valid[j]) continue;
    const auto trusted = [&](size_t m) {
      return !excluded(static_cast<int>(m)) && s.mask[m] != MaskReason::kSwap;
    };
    const bool i_trusted = trusted(i), j_trusted = trusted(j);
    if (i_trusted == j_trusted) continue;
    const size_t left_out = i_trusted ? j : i;
    if (tracks_[left_out].frozen ||
        markers_.marker(static_cast<int>(left_out)).num_attachments != 1)
      continue;
    if (std::abs((s.raw[i] - s.raw[j]).norm() - rigid_distance_[k]) <= options_.rigid_tolerance_m)
      weights_[left_out] = 1.0;
  }
}

// Exchanges the samples of markers i and j in frame s. A capture that swapped two labels
// keeps them swapped until it re-identifies them; relabelled for one frame only, the
// swapped sample came back into the next frame's reference (a forearm marker carrying a
// clavicle's trajectory dragged the forearm to the chest). So a relabelling by the
// reference test (each sample fits the other's reference) of two markers on different
// segments is remembered, and relabelling a remembered pair again forgets it. On one
// segment the layout's distances identify each marker in every frame, and a remembered
// pair would escape them (a false hand relabel lasted 1000 frames: 60 Hz rotation error
// +37 %). The layout-distance and continuity tests judge nearby markers from one frame's
// motion; remembered, their mistakes outlived them (worse on every severity), so they
// decide frame by frame.
void OutlierDetector::Relabel(WindowFrame& s, size_t i, size_t j, CleanupCounters* counters,
                              bool remember) {
  if (!options_.relabel_swaps) {  // both are filled instead
    s.mask[i] = s.mask[j] = MaskReason::kSwap;
    return;
  }
  int& partner_i = swap_partner_[i];
  int& partner_j = swap_partner_[j];
  if (remember && partner_i == static_cast<int>(j)) {
    // The pair carried into this frame was wrong: exchanged back, the samples are as
    // captured again, not a relabelling.
    ExchangeSamples(s, i, j);
    s.relabelled[i] = s.relabelled[j] = 0;
    --counters->swaps_relabelled;
    partner_i = partner_j = -1;
    return;
  }
  // A pair another test already relabelled this frame is exchanged back to its labels
  // as captured: nothing to carry on.
  const bool undoes = s.relabelled[i] || s.relabelled[j];
  ExchangeSamples(s, i, j);
  ++counters->swaps_relabelled;
  if (remember && !undoes && partner_i < 0 && partner_j < 0 &&
      markers_.primary_joint(static_cast<int>(i)) != markers_.primary_joint(static_cast<int>(j))) {
    partner_i = static_cast<int>(j);
    partner_j = static_cast<int>(i);
  }
}

// Carries the remembered swaps into frame t, each unless the labels as captured now fit
// the markers' motion, or the last reference, clearly better than exchanged (the capture
// re-identified them; or the relabelling was wrong, which continuity alone would never
// show, as the relabelled trajectories are the continuous ones). A pair with neither
// sample present is forgotten: what returns is judged afresh.
void OutlierDetector::ApplyPersistentSwaps(CleanupWindow& window, int64_t t,
                                           CleanupCounters* counters) {
  WindowFrame& s = window.at(t);
  const bool has_previous = t > 0 && window.at(t - 1).frame == t - 1;
  const bool has_two_before = has_previous && t > 1 && window.at(t - 2).frame == t - 2;
  const WindowFrame& prev = window.at(t - 1 >= 0 ? t - 1 : 0);
  const WindowFrame& prev2 = window.at(t - 2 >= 0 ? t - 2 : 0);
  auto predicted = [&](size_t m) { return ExpectedSample(prev, prev2, has_two_before, m); };
  // How far the samples of i and j are from where each is expected: labelled as
  // captured, and exchanged.
  auto misfit = [&](size_t i, size_t j, const Vec3& expected_i, const Vec3& expected_j) {
    std::pair<double, double> distance{0.0, 0.0};
    if (s.valid[i]) {
      distance.first += (s.raw[i] - expected_i).norm();
      distance.second += (s.raw[i] - expected_j).norm();
    }
    if (s.valid[j]) {
      distance.first += (s.raw[j] - expected_j).norm();
      distance.second += (s.raw[j] - expected_i).norm();
    }
    return distance;
  };
  for (size_t i = 0; i < swap_partner_.size(); ++i) {
    const int partner = swap_partner_[i];
    if (partner < static_cast<int>(i)) continue;  // none, or seen from its partner
    const auto j = static_cast<size_t>(partner);
    if (!has_previous || (!s.valid[i] && !s.valid[j])) {
      swap_partner_[i] = swap_partner_[j] = -1;
      continue;
    }
    const auto [moved_as_captured, moved_exchanged] = misfit(i, j, predicted(i), predicted(j));
    const auto [as_captured, exchanged] = misfit(i, j, prev.reference[i], prev.reference[j]);
    if (moved_as_captured + options_.swap_margin_m < moved_exchanged ||
        as_captured + options_.swap_margin_m < exchanged) {
      swap_partner_[i] = swap_partner_[j] = -1;
      continue;
    }
    ExchangeSamples(s, i, j);
    ++counters->swaps_relabelled;
  }
}

// Relabels swapped pairs before the frame is solved, so the reference is computed from
// the corrected labels.
void OutlierDetector::RelabelSwaps(CleanupWindow& window, int64_t t, CleanupCounters* counters) {
  WindowFrame& s = window.at(t);
  const bool has_previous = t > 0 && window.at(t - 1).frame == t - 1;
  const WindowFrame& prev = window.at(t - 1 >= 0 ? t - 1 : 0);
  const auto m_count = static_cast<size_t>(markers_.num_markers());
  // Model distance between two markers rigidly on the same joint.
  auto RigidDistance = [&](size_t a, size_t b) {
    return (markers_.marker(static_cast<int>(a)).attachments[0].offset -
            markers_.marker(static_cast<int>(b)).attachments[0].offset)
        .norm();
  };
  // An exchange that would turn two samples where their markers' motion (or, for one
  // back from a gap, the last reference) expects them into two jumps. A capture's swap
  // starts with a jump in both, and once relabelled the exchange is the continuous
  // choice; two markers where they are expected are no swap, whatever the layout's
  // witnesses show. Judged on segments with four or more markers present, whose
  // near-mirror layouts (a head) mislead: a head with two stuck markers had its two
  // clean ones exchanged for 0.4 s, published 14 cm off. (On every segment it cost the
  // humanoid's heavy 60 Hz mean 2.06 -> 2.27 deg: a three-marker hand's swap resumed
  // after a frame the layout missed is continuous as captured.)
  const bool has_two_before = t > 1 && window.at(t - 2).frame == t - 2;
  const WindowFrame& before_prev = window.at(t - 2 >= 0 ? t - 2 : 0);
  // Not with relabelling off (the previous frame's swapped samples stay as captured, only
  // masked: predicted from, the swap would look continuous from its second frame), nor
  // across a re-sync or before a reference (nothing to expect a sample at).
  const bool can_expect =
      options_.relabel_swaps && has_previous && !s.resync && prev.reference_solved;
  const bool expect_on_motion = has_two_before && !prev.resync;
  auto layout_breaks_continuity = [&](size_t i, size_t j) {
    if (!can_expect) return false;
    const Vec3 predicted_i = ExpectedSample(prev, before_prev, expect_on_motion, i);
    const Vec3 predicted_j = ExpectedSample(prev, before_prev, expect_on_motion, j);
    const double straight = (s.raw[i] - predicted_i).norm() + (s.raw[j] - predicted_j).norm();
    const double crossed = (s.raw[j] - predicted_i).norm() + (s.raw[i] - predicted_j).norm();
    return crossed > straight + options_.swap_margin_m;
  };
  // Swaps first: a relabelled pair is fine for every other detector. Within one rigid
  // segment the layout's distances identify each marker: a pair whose exchanged labels
  // fit the distances to the segment's other markers clearly better is relabelled (below:
  // in which order).
  auto layout_gain = [&](size_t k, int* witnesses_out = nullptr) {
    const auto i = static_cast<size_t>(rigid_pairs_[k].first);
    const auto j = static_cast<size_t>(rigid_pairs_[k].second);
    if (!s.valid[i] || !s.valid[j] || s.relabelled[i] || s.relabelled[j]) return 0.0;
    // A marker judged frozen whose sample is still where it stuck is no member of a swap:
    // the layout, judged on the segment's few witnesses, once gave its clean neighbour's
    // label the stuck sample (the soak's actor3: a fallen-off foot marker lying still took
    // the clean one's label, the robust solve followed it and a frozen one, and the foot
    // was published 18.8 cm off). One that has moved off may be swapped (and re-identified).
    if (StuckWhereItFroze(s, i) || StuckWhereItFroze(s, j)) return 0.0;
    double straight = 0.0, crossed = 0.0;
    int witnesses = 0;
    for (int other :
         markers_of_joint_[static_cast<size_t>(markers_.primary_joint(static_cast<int>(i)))]) {
      const auto o = static_cast<size_t>(other);
      if (o == i || o == j || !s.valid[o] || markers_.marker(other).num_attachments != 1) continue;
      // A stuck sample is no witness: the segment moves away from it, so distances to it
      // cannot tell the segment's markers apart. (Markers judged stray, fallen off or off
      // their joint stay witnesses: dropping them too cost the synthesized humanoid's
      // medium 120 Hz take 1.16 -> 1.30-1.31 degrees.)
      if (tracks_[o].frozen) continue;
      const double di = (s.raw[i] - s.raw[o]).norm(), dj = (s.raw[j] - s.raw[o]).norm();
      const double mi = RigidDistance(i, o), mj = RigidDistance(j, o);
      straight += std::abs(di - mi) + std::abs(dj - mj);
      crossed += std::abs(dj - mi) + std::abs(di - mj);
      ++witnesses;
    }
    // Written to accept, so that a NaN rejects.
    const double gain = straight - crossed - options_.swap_margin_m * witnesses;
    if (witnesses_out) *witnesses_out = witnesses;
    return witnesses > 0 && gain > 0.0 ? gain : 0.0;
  };
  // On a segment with four or more markers present the pair whose exchange fits best goes
  // first, then the others are judged again. Only such a segment has two pairs with no
  // marker in common, and so a wrong exchange that makes another fit: taken in the order
  // of the labels, a swap of two head markers once made the exchange of the other two fit
  // (four markers round a head are nearly a mirror image of themselves), that pair went
  // first, and the head was published mirrored, 10 cm off. With fewer markers the label
  // order stays. (Best first on a three-marker hand as well changed which of two
  // overlapping pairs won against its one witness: in the soak's actor3 it put a stuck
  // sample under LHND2, the hand moved less than the 4 cm that convicts a still marker,
  // and once the forearm lost a marker the robust solve followed the stuck sample: an
  // 11 cm forearm for 0.8 s.)
  auto on_large_segment = [&](size_t k) {
    const auto first = static_cast<size_t>(rigid_pairs_[k].first);
    int present = s.valid[first] ? 1 : 0;
    for (int pair : pairs_of_marker_[first]) {
      const auto& [a, b] = rigid_pairs_[static_cast<size_t>(pair)];
      present += s.valid[static_cast<size_t>(static_cast<size_t>(a) == first ? b : a)] ? 1 : 0;
    }
    return present >= 4;
  };
  // On a smaller segment the layout's few witnesses can mislead while its pair stays put:
  // a foot back from a two-frame gap had its two clean markers exchanged because its third,
  // stuck but not yet judged frozen, was the only witness, and as the foot moved away from
  // it the distances came to favour the exchange. The robust solve followed, rejected
  // every foot marker, and the toe was published 9.4 cm off for 0.06 s (Bandai
  // walk_normal, 240 Hz). So a pair whose labels the layout fitted last frame, whose
  // samples both fitted their reference then, and which are where they were expected now
  // (no jump) keeps its labels: what changed is the witnesses. Both endorsements are
  // needed. A capture's swap back from a gap with no witness present is continuous as
  // captured and the layout never fitted it: exchanged once a witness returns (the
  // humanoid's heavy 240 Hz hands). One that a popped witness made the layout fit once
  // was rejected by the reference (the soak's actor4: without that check its hand was
  // published 8 cm off for 0.5 s).
  auto fitted_its_reference = [&](size_t m) {
    return prev.valid[m] && !prev.relabelled[m] && prev.mask[m] == MaskReason::kNone;
  };
  for (size_t k = 0; k < rigid_pairs_.size(); ++k) {
    if (on_large_segment(k)) continue;
    const auto i = static_cast<size_t>(rigid_pairs_[k].first);
    const auto j = static_cast<size_t>(rigid_pairs_[k].second);
    int witnesses = 0;
    const double gain = layout_gain(k, &witnesses);
    if (gain <= 0.0) {
      if (witnesses > 0) layout_fitted_frame_[k] = t;
    } else if (layout_fitted_frame_[k] == t - 1 && layout_breaks_continuity(i, j) &&
               fitted_its_reference(i) && fitted_its_reference(j)) {
      layout_fitted_frame_[k] = t;  // the labels stand as they were
    } else {
      Relabel(s, i, j, counters);
    }
  }
  // Each round relabels a pair (or, with relabel_swaps off, masks it kSwap, which is
  // why a masked pair is passed over), so no pair is chosen twice and the rounds end.
  for (size_t round = 0; round < rigid_pairs_.size(); ++round) {
    size_t best = rigid_pairs_.size();
    double best_gain = 0.0;
    for (size_t k = 0; k < rigid_pairs_.size(); ++k) {
      if (!on_large_segment(k) ||
          s.mask[static_cast<size_t>(rigid_pairs_[k].first)] == MaskReason::kSwap ||
          s.mask[static_cast<size_t>(rigid_pairs_[k].second)] == MaskReason::kSwap)
        continue;
      const double gain = layout_breaks_continuity(static_cast<size_t>(rigid_pairs_[k].first),
                                                   static_cast<size_t>(rigid_pairs_[k].second))
                              ? 0.0
                              : layout_gain(k);
      if (gain > best_gain) {
        best = k;
        best_gain = gain;
      }
    }
    if (best == rigid_pairs_.size()) break;
    Relabel(s, static_cast<size_t>(rigid_pairs_[best].first),
            static_cast<size_t>(rigid_pairs_[best].second), counters);
  }
  // Last frame's continuity relabels, kept for this frame's search (see below).
  continuity_partner_.swap(previous_continuity_partner_);
  if (continuity_frame_ != t - 1)
    std::fill(previous_continuity_partner_.begin(), previous_continuity_partner_.end(), -1);
  std::fill(continuity_partner_.begin(), continuity_partner_.end(), -1);
  continuity_frame_ = t;
  // Across segments, trajectory continuity decides most of them: each marker's sample is
  // compared with its own constant-velocity prediction, and a pair whose crossed
  // assignment fits clearly better is relabelled. A swap the reference can absorb (two
  // of three markers on a segment) is still a jump in both trajectories.
  if (has_previous && has_two_before) {
    const WindowFrame& prev2 = window.at(t - 2);
    // Only markers whose last two samples were fine can be predicted; gathering them and
    // their positions first keeps the pair search to a tight loop over few markers.
    // (A marker relabelled last frame was kept a candidate for its partner whatever its
    // masks, for a sword's two forearm markers whose relabelling stopped when the
    // reference rejected one relabelled sample: in the soak's actors it carried a frozen
    // marker and a swapped one on as a pair instead, feet and hands 6-9 cm off.)
    swap_candidates_.clear();
    for (size_t i = 0; i < m_count; ++i) {
      if (!s.valid[i] || prev.mask[i] != MaskReason::kNone || prev2.mask[i] != MaskReason::kNone)
        continue;
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
        const auto j = static_cast<size_t>(swap_candidates_[b]);
        // A pair relabelled last frame is judged again however far apart its markers
        // have moved since: markers swap where they pass close, and move apart with the
        // swap still on (a walk's swing toe swapped with the planted foot's marker as it
        // passed, relabelled while within the search, then carried under the wrong
        // label once 15 cm apart: the robust solve followed it, rejected the foot's clean
        // markers, and the foot was published 18 cm off).
        if ((candidate_previous_[a] - candidate_previous_[b]).squaredNorm() > search_sq &&
            previous_continuity_partner_[i] != static_cast<int>(j))
          continue;
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
        Relabel(s, i, j, counters);
        // Only across segments, as with the residual test's remembered swaps: within one,
        // the layout judges the pair afresh each frame, and a head's markers sit 15 cm
        // apart, so a wrong exchange carried on turned a head 14 cm off for 0.4 s.
        if (markers_.primary_joint(static_cast<int>(i)) !=
            markers_.primary_joint(static_cast<int>(j))) {
          continuity_partner_[i] = static_cast<int>(j);
          continuity_partner_[j] = static_cast<int>(i);
        }
        break;
      }
    }
  }
  if (has_previous && !s.resync) RelabelLoneSamples(window, t, counters);
}

// A capture can give a marker's label to a neighbour's trajectory while the neighbour's own
// label is occluded: one sample, jumped onto where the missing marker was expected. The
// pair tests above need both samples; on a segment with no other marker seen, the robust
// solve turns the segment to fit the jumped sample and no residual flags it (a hand's one
// seen marker carried its occluded neighbour's trajectory, 6.7 cm off, for 0.85 s). A sample
// far from where its own marker was expected and within the residual threshold of where a
// missing marker nearby was expected, by trajectory and by the last reference alike, is
// that marker's: moved to its label, judged again every frame.
void OutlierDetector::RelabelLoneSamples(CleanupWindow& window, int64_t t,
                                         CleanupCounters* counters) {
  WindowFrame& s = window.at(t);
  const WindowFrame& prev = window.at(t - 1);  // the caller saw frame t - 1 in the window
  // After a glitch frame (every sample taken as missing) each expectation would be a
  // reference up to glitch_resync_s old: nothing to judge a jump against.
  if (std::none_of(prev.valid.begin(), prev.valid.end(), [](uint8_t v) { return v != 0; })) return;
  const bool has_two_before = t > 1 && window.at(t - 2).frame == t - 2 && !prev.resync;
  const WindowFrame& prev2 = window.at(t - 2 >= 0 ? t - 2 : 0);
  auto fine = [](const WindowFrame& f, size_t m) {
    return f.valid[m] && f.mask[m] == MaskReason::kNone;
  };
  auto expected = [&](size_t m) -> Vec3 {
    if (!fine(prev, m)) return prev.reference[m];
    if (has_two_before && fine(prev2, m)) return 2.0 * prev.raw[m] - prev2.raw[m];
    return prev.raw[m];
  };
  const auto m_count = static_cast<size_t>(markers_.num_markers());
  const double search_sq = options_.swap_search_m * options_.swap_search_m;
  for (size_t i = 0; i < m_count; ++i) {
    // A stuck or fallen-off sample is nobody's trajectory: a missing marker's expected
    // position passing by it is no swap.
    if (!s.valid[i] || s.relabelled[i] || tracks_[i].frozen || tracks_[i].fallen) continue;
    // Each test is written to accept, so that a NaN anywhere rejects.
    const double off_own = (s.raw[i] - expected(i)).norm();
    if (!(off_own > ResidualThreshold(i) + options_.swap_margin_m)) continue;
    const double off_own_reference = (s.raw[i] - prev.reference[i]).norm();
    size_t best = m_count;
    double best_off = 0.0;
    for (size_t j = 0; j < m_count; ++j) {
      // Only a label missing as captured: not one a swap emptied (a remembered pair's, or
      // one this loop has moved a sample from).
      if (j == i || s.valid[j] || s.relabelled[j] || swap_partner_[j] >= 0 ||
          !((prev.reference[j] - prev.reference[i]).squaredNorm() <= search_sq))
        continue;
      const double off_other = (s.raw[i] - expected(j)).norm();
      const bool fits_other =
          off_other <= ResidualThreshold(j) && off_other + options_.swap_margin_m < off_own &&
          (s.raw[i] - prev.reference[j]).norm() + options_.swap_margin_m < off_own_reference;
      if (!fits_other) continue;
      if (best == m_count || off_other < best_off) {
        best = j;
        best_off = off_other;
      }
    }
    if (best == m_count) continue;
    if (!options_.relabel_swaps) {  // filled instead
      s.mask[i] = MaskReason::kSwap;
      continue;
    }
    ExchangeSamples(s, i, best);
    ++counters->swaps_relabelled;
  }
}

void OutlierDetector::Detect(CleanupWindow& window, int64_t t, int64_t first_unpublished,
                             CleanupCounters* counters) {
  WindowFrame& s = window.at(t);
  const bool has_previous = t > 0 && window.at(t - 1).frame == t - 1;
  const WindowFrame& prev = window.at(t - 1 >= 0 ? t - 1 : 0);
  const auto m_count = static_cast<size_t>(markers_.num_markers());
  const double alpha = rules_.statistics_weight;

  // Residuals against X^ and each marker's adaptive threshold.
  auto threshold = [&](size_t m) { return ResidualThreshold(m); };
  std::span<Vec3> residual(residual_.data(), m_count);
  for (size_t m = 0; m < m_count; ++m)
    residual[m] = s.valid[m] ? Vec3(s.raw[m] - s.reference[m]) : Vec3::Zero();

  // The rest: a pair that each fit the other's reference position.
  for (size_t i = 0; i < m_count; ++i) {
    if (!s.valid[i] || residual[i].norm() <= threshold(i)) continue;
    for (size_t j = i + 1; j < m_count; ++j) {
      if (!s.valid[j] || residual[j].norm() <= threshold(j)) continue;
      const double crossed_i = (s.raw[i] - s.reference[j]).norm();  // i's sample fits j
      const double crossed_j = (s.raw[j] - s.reference[i]).norm();
      if (crossed_i > threshold(j) || crossed_j > threshold(i)) continue;
      if (crossed_i + crossed_j + options_.swap_margin_m >= residual[i].norm() + residual[j].norm())
        continue;
      Relabel(s, i, j, counters, true);
      residual[i] = s.raw[i] - s.reference[i];
      residual[j] = s.raw[j] - s.reference[j];
      break;
    }
  }

  // Kinematic disagreement: a joint whose naive and robust solutions differ too much
  // marks every marker skinned to it.
  const KinematicsWorkspace& naive = naive_.kinematics();
  const KinematicsWorkspace& robust = robust_.kinematics();
  for (int j = 0; naive_solved_ && j < skeleton_.num_joints(); ++j) {
    if (skeleton_.joint(j).type == JointType::kFixed) continue;
    const auto uj = static_cast<size_t>(j);
    const double dp = (naive.p_WJ[uj] - robust.p_WJ[uj]).norm();
    const double cos_angle =
        std::clamp(0.5 * ((naive.R_WJ[uj].transpose() * robust.R_WJ[uj]).trace() - 1.0), -1.0, 1.0);
    if (dp <= options_.disagreement_position_m &&
        std::acos(cos_angle) <= options_.disagreement_rotation_rad)
      continue;
    for (int m : markers_of_joint_[uj]) {
      const auto um = static_cast<size_t>(m);
      if (s.valid[um] && s.mask[um] == MaskReason::kNone && !s.relabelled[um] &&
          residual[um].norm() > options_.disagreement_residual_m)
        s.mask[um] = MaskReason::kDisagreement;
    }
  }

  // The reference moving away from a still marker only convicts it if the segment's
  // motion is seen: another marker on the same joint fits its reference. (A planted
  // foot's markers stay still while a reference with no foot data drifts.)
  // A marker rigidly on its joint keeps its distance to the joint's origin, wherever the
  // segment turns; the origin is where the parent segment ends, so when the parent's own
  // samples fit their reference, a still marker whose distance to it has changed cannot be
  // on the segment any more: it is frozen, whatever the rest of its segment does (which
  // may be frozen with it, so no neighbour fits).
  const KinematicsWorkspace& pose = robust_.kinematics();
  auto parent_fits = [&](size_t m, int need = 1) {
    const int joint = markers_.primary_joint(static_cast<int>(m));
    const int parent = skeleton_.joint(joint).parent.value;
    if (parent < 0) return false;
    int fitting = 0;
    for (int other : markers_of_joint_[static_cast<size_t>(parent)]) {
      const auto o = static_cast<size_t>(other);
      if (s.valid[o] && !tracks_[o].frozen && s.mask[o] == MaskReason::kNone &&
          residual[o].norm() <= threshold(o))
        if (++fitting >= need) return true;
    }
    return false;
  };
  // A sample's distance to its joint's origin, where the robust solve puts it; NaN unless
  // the marker is rigidly on one joint and a marker of the parent fits (the origin is
  // where the parent segment ends: without the parent's data it is the solve's guess).
  auto distance_to_joint = [&](size_t m) {
    if (markers_.marker(static_cast<int>(m)).num_attachments != 1 || !parent_fits(m)) return kNaN;
    return JointOriginDistance(s, m, pose);
  };
  auto off_its_joint = [&](size_t m, double tolerance) {
    return OffItsJoint(distance_to_joint(m), m, tolerance);
  };
  // A still marker that a moving marker rigidly on its segment has left (their distance
  // changed, while the still one stayed put, by what a frozen marker's reference must
  // move): the segment moved and it did not (a toe marker frozen on a planted foot as the
  // foot lifts, its clean partner rising away from it). The reference cannot show it when
  // no other marker of the segment or its parent is seen: it has followed the still one.
  // The yardstick is the pair's distance the first time this rule looks at it in the
  // still run (once the marker has been still for frozen_s, with the partner moving), not
  // the model's: a scaled template's distances are off by centimetres from the start.
  // (Taken at the start of the still run instead, it cost the synthesized humanoid's
  // heavy 120 Hz take 2.15 -> 2.30 degrees.) A partner already judged off (stray, fallen
  // off, off its joint) or caught jumping this frame is no evidence; off its joint only
  // while two markers of its parent fit: one leaves the parent free to turn about it, and
  // the joint goes where the still marker pulls the segment (a toe marker frozen as the
  // foot lifted, one foot marker seen: the clean toe partner was judged off its joint,
  // the frozen one never convicted, and the toe published 47 cm off).
  auto left_by_a_moving_partner = [&](size_t m) {
    for (int k : pairs_of_marker_[m]) {
      const auto uk = static_cast<size_t>(k);
      const auto o = static_cast<size_t>(static_cast<size_t>(rigid_pairs_[uk].first) == m
                                             ? rigid_pairs_[uk].second
                                             : rigid_pairs_[uk].first);
      const Track& other = tracks_[o];
      if (!s.valid[o] || other.frozen || other.stray || other.fallen ||
          (other.off_joint && parent_fits(o, 2)) || s.mask[o] == MaskReason::kSpike ||
          s.mask[o] == MaskReason::kSwap ||
          (other.still_since >= 0 && t - other.still_since + 1 >= rules_.frozen_frames))
        continue;
      double& at_rest = DistanceAtRest(uk, m);
      const double distance = (s.raw[m] - s.raw[o]).norm();
      if (std::isnan(at_rest)) at_rest = distance;
      if (std::abs(distance - at_rest) > options_.frozen_reference_motion_m) return true;
    }
    return false;
  };
  // A marker rigidly on its segment keeps its distance to the joint's origin, however
  // the segment turns, to within soft tissue and noise: the radius that counts a marker
  // as still already allows for those. So a still marker whose distance to the origin (as
  // the robust solve places it, judged only while a marker of the parent fits) has
  // changed by more than that radius since it came to rest has been left by its segment.
  // The change, not the distance against the model's offset (off_its_joint): a scaled
  // template's offsets are centimetres off from the start, so that test needs a wide
  // tolerance, and a forearm's only seen marker, stuck, was published for 0.2 s while the
  // elbow moved away (the soak's actor4, a 16 cm hand). Only when no other marker of the
  // segment fits, which shows the segment's motion better: the origin comes through the
  // parent's bones, and with a subject calibrated from markers alone, centimetres off,
  // judging every still marker this way convicted clean ones (markers_only_accuracy,
  // Plug-in Gait: the kick's cleaned markers 39 -> 60 mm).
  auto left_by_its_joint = [&](size_t m) {
    double& at_rest = tracks_[m].joint_distance_at_rest;
    const double distance = distance_to_joint(m);
    if (std::isnan(distance)) return false;
    if (std::isnan(at_rest)) at_rest = distance;
    return std::abs(distance - at_rest) > options_.frozen_radius_m;
  };
  auto has_fitting_neighbour = [&](size_t m) {
    for (int other :
         markers_of_joint_[static_cast<size_t>(markers_.primary_joint(static_cast<int>(m)))]) {
      const auto o = static_cast<size_t>(other);
      if (o != m && s.valid[o] && !tracks_[o].frozen && residual[o].norm() <= threshold(o))
        return true;
    }
    return false;
  };
  for (size_t m = 0; m < m_count; ++m) {
    Track& track = tracks_[m];
    if (!s.valid[m]) {
      // The still run goes on through a gap of up to frozen_backdate_s: a marker back
      // where it stood (within the still radius of its anchor) has not moved, and a stuck
      // one back from a two-frame gap would otherwise wait frozen_s again while the robust
      // solve followed it and rejected its clean neighbours (a foot 6.4 cm off). After a
      // longer gap what the run recorded (its reference, its partners' distances) is too
      // old to judge by: as far back as a frozen verdict is carried, and no further (at
      // frozen_s instead, the soak's actor4 lost its gain: frames over 6 cm 192 -> 230).
      // Whether it is frozen is judged afresh on its return: a verdict kept through the
      // gap held clean still markers out longer (the humanoid's heavy 60 / 120 Hz
      // 1.88 / 1.72 -> 1.90 / 1.74 deg).
      track.frozen = false;
      track.off_joint = false;
      continue;
    }
    const double r = residual[m].norm();
    const double thr = threshold(m);
    // Off its joint (see CleanupOptions::off_joint_m): no rotation of the segment can
    // explain the sample, so it stays out of the next frame's Y^. Huber-bounded, it still
    // pulled a forearm whose hand was occluded to the chest, and its clean markers with
    // it. Judged afresh every frame: the joint is placed by the parent's pose, which can
    // be wrong too, and an exclusion kept until the sample fits again kept a clean toe out
    // of a reference that, without it, never came back to it (the soak's worst frame
    // 25.9 -> 31.4 cm).
    // One OverruleLoneSamples overruled this frame stays off, whatever the solve without it
    // shows of it: where another lone sample stood, Y^ still fits it.
    const bool overruled = track.overruled_frame == t;
    track.off_joint = overruled || (r > thr && options_.off_joint_m > 0.0 &&
                                    off_its_joint(m, options_.off_joint_m));
    if (overruled && s.mask[m] == MaskReason::kNone) s.mask[m] = MaskReason::kResidual;
    if (r > thr) {
      ++track.residual_run;
      if (s.mask[m] == MaskReason::kNone || s.mask[m] == MaskReason::kDisagreement)
        s.mask[m] = MaskReason::kResidual;
      // Fallen off: far from where it belongs (not a reference a few cm off) for long.
      if (track.residual_run >= rules_.fallen_frames && r > options_.fallen_residual_m) {
        track.fallen = true;
        s.mask[m] = MaskReason::kFallenOff;
      }
      if (track.residual_run >= rules_.stray_frames && r > options_.stray_residual_m)
        track.stray = true;
    } else {
      track.residual_run = 0;
      track.fallen = false;
      track.stray = false;
      // The running scale learns from good samples only (clipped at the threshold).
      track.residual_scale += alpha * (r - track.residual_scale);
    }
    // Frozen: at rest (within a radius, so jitter is not motion) while the reference
    // moves away; the run starts over wherever the marker leaves the radius, and when it
    // comes back from a gap longer than frozen_backdate_s (see above).
    const bool back_after_long_gap = t - track.last_seen - 1 > rules_.frozen_backdate_frames;
    track.last_seen = t;
    if (track.still_since < 0 || back_after_long_gap ||
        (s.raw[m] - track.still_anchor).norm() > options_.frozen_radius_m) {
      track.still_since = t;
      for (int k : pairs_of_marker_[m]) DistanceAtRest(static_cast<size_t>(k), m) = kNaN;
      // Where the run starts, so the origin's motion during the first frozen_s counts too
      // (if no marker of the parent fits then: when the rule first looks, after frozen_s).
      track.joint_distance_at_rest = distance_to_joint(m);
      track.still_anchor = s.raw[m];
      track.still_reference = s.reference[m];
      track.frozen = false;
    } else if (t - track.still_since + 1 >= rules_.frozen_frames &&
               (((s.reference[m] - track.still_reference).norm() >
                     options_.frozen_reference_motion_m &&
                 has_fitting_neighbour(m)) ||
                off_its_joint(m, options_.frozen_reference_motion_m) ||
                left_by_a_moving_partner(m) ||
                (!has_fitting_neighbour(m) && left_by_its_joint(m)))) {
      track.frozen = true;
    }
    if (track.frozen) {
      // Still and far from its reference for long is the more specific diagnosis (back
      // over the still run, as far as frozen_backdate_s).
      const int64_t from = std::max({first_unpublished, track.still_since,
                                     t - static_cast<int64_t>(rules_.frozen_backdate_frames)});
      for (int64_t f = from; f <= t; ++f)
        if (window.at(f).valid[m] && window.at(f).mask[m] != MaskReason::kFallenOff)
          window.at(f).mask[m] = MaskReason::kFrozen;
    }
    if (!has_previous || !prev.valid[m]) continue;
    // Spikes: this frame's displacement disagrees with the reference's, from a sample
    // that was itself fine (so the return from a pop is not a spike).
    const Vec3 moved = s.raw[m] - prev.raw[m];
    const Vec3 reference_moved = s.reference[m] - prev.reference[m];
    if (prev.mask[m] == MaskReason::kNone && s.mask[m] == MaskReason::kNone &&
        (moved - reference_moved).norm() > options_.spike_m)
      s.mask[m] = MaskReason::kSpike;
  }

  // Rigid segments: two markers on one joint that changed their distance; blame the one
  // that fits the reference worse.
  for (size_t k = 0; k < rigid_pairs_.size(); ++k) {
    const auto i = static_cast<size_t>(rigid_pairs_[k].first);
    const auto j = static_cast<size_t>(rigid_pairs_[k].second);
    if (!s.valid[i] || !s.valid[j] || s.mask[i] != MaskReason::kNone ||
        s.mask[j] != MaskReason::kNone)
      continue;
    if (std::abs((s.raw[i] - s.raw[j]).norm() - rigid_distance_[k]) <= options_.rigid_tolerance_m)
      continue;
    s.mask[residual[i].norm() >= residual[j].norm() ? i : j] = MaskReason::kRigidDistance;
  }
}

void OutlierDetector::CleanMask(CleanupWindow& window, int64_t t, int64_t first_unpublished) {
  const auto m_count = static_cast<size_t>(markers_.num_markers());
  const int64_t first = std::max<int64_t>(first_unpublished, 0);
  auto good = [&](int64_t f, size_t m) { return window.at(f).mask[m] == MaskReason::kNone; };
  // Most markers are fine over the whole window: neither rule can touch them, and one
  // pass over the window's masks finds them (the per-marker walks below are the costly
  // part).
  std::fill(marker_flags_.begin(), marker_flags_.end(), 0);
  for (int64_t f = std::max<int64_t>(first - 1, 0); f <= t; ++f) {
    const WindowFrame& frame = window.at(f);
    const bool has_previous = f >= first && f > 0;
    for (size_t m = 0; m < m_count; ++m)
      marker_flags_[m] |=
          frame.mask[m] != MaskReason::kNone ||
          (has_previous && (frame.raw[m] - window.at(f - 1).raw[m]).norm() > rules_.marker_jump_m);
  }
  for (size_t m = 0; m < m_count; ++m) {
    if (!marker_flags_[m]) continue;
    // Trim returning tracks whose slope disagrees with the reference's, frame by frame.
    for (int64_t g = first; g + 1 <= t; ++g) {
      if (g == 0 || good(g - 1, m) || !good(g, m)) continue;
      if (g - 1 < first - 1) continue;
      for (int n = 0; n < rules_.max_trim_frames && g + 1 <= t && good(g, m) && good(g + 1, m);
           ++n, ++g) {
        const WindowFrame& a = window.at(g);
        const WindowFrame& b = window.at(g + 1);
        const Vec3 slope = (b.raw[m] - a.raw[m]) - (b.reference[m] - a.reference[m]);
        if (slope.norm() <= rules_.trim_slope_m) break;
        window.at(g).mask[m] = MaskReason::kTrimmed;
      }
    }
    // Small tracks: a short observed run, all still unpublished, with a gap or a jump no
    // body makes on both sides. A pop on a limb with no other marker seen is taken by the
    // reference after its first frame (nothing holds the limb), and its samples then fit;
    // but it left with a jump and comes back with one (the soak's actor3: a hand marker
    // published 42 cm off for two frames at 240 Hz).
    // A frame with no sample at all is passed over: a frame lost before the cleanup ends
    // no marker's track (losing every other frame, each received sample sat between two
    // such holes, and nearly all were thrown away as small tracks). The jump allowance
    // grows with the frames passed over.
    auto jumped = [&](int64_t f, int64_t before) {
      return (window.at(f).raw[m] - window.at(before).raw[m]).norm() >
             rules_.marker_jump_m * static_cast<double>(f - before);
    };
    // Before the first unpublished frame, the last frame with any sample: what a run from
    // there follows (its mask is final, and the window still holds it).
    int64_t previous = first - 1;
    while (previous >= 0 && window.Holds(previous) && window.at(previous).blind) --previous;
    int64_t run_start = -1, before_run = -1;
    // The run [run_start, previous] ends: a small track if short (its own samples' span, not
    // the frames passed over after it) and it began after a gap or a jump.
    auto end_run = [&] {
      if (run_start >= 0 && before_run >= 0 && window.Holds(before_run) &&
          (!good(before_run, m) || jumped(run_start, before_run)) &&
          previous - run_start + 1 <= rules_.small_track_frames)
        for (int64_t g = run_start; g <= previous; ++g)
          if (!window.at(g).blind) window.at(g).mask[m] = MaskReason::kSmallTrack;
    };
    for (int64_t f = first; f <= t; ++f) {
      if (window.at(f).blind) continue;
      // Nothing before a resync carries over: a run does not reach across the glitch
      // frames passed over before it.
      if (window.at(f).resync && run_start >= 0) {
        end_run();
        run_start = -1;
        previous = f - 1;
      }
      const bool jump = run_start >= 0 && good(f, m) && jumped(f, previous);
      if (good(f, m) && !jump) {
        if (run_start < 0) {
          run_start = f;
          before_run = previous;
        }
        previous = f;
        continue;
      }
      end_run();
      run_start = jump ? f : -1;
      before_run = previous;
      previous = f;
    }
  }
}

}  // namespace mocapd
