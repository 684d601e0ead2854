// Catch-up targets, weights, the anchor and the final solve (see the header).
#include "filters/final_solve.hpp"

#include <algorithm>

namespace mocapd {
namespace {

// Per joint: some marker lies on it or below it.
std::vector<uint8_t> SeeableJoints(const Skeleton& skeleton, const MarkerSet& markers) {
  std::vector<uint8_t> seeable(static_cast<size_t>(skeleton.num_joints()), 0);
  for (int marker = 0; marker < markers.num_markers(); ++marker)
    seeable[static_cast<size_t>(markers.primary_joint(marker))] = 1;
  for (int j = skeleton.num_joints() - 1; j > 0; --j)  // parents come first: children fold in
    if (seeable[static_cast<size_t>(j)])
      seeable[static_cast<size_t>(skeleton.joint(j).parent.value)] = 1;
  return seeable;
}

}  // namespace

FinalSolve::FinalSolve(const Skeleton& skeleton, const MarkerSet& markers,
                       const CleanupOptions& options)
    : skeleton_(skeleton),
      markers_(markers),
      options_(options),
      rules_(FrameRules(options)),
      final_ik_(WithUnseenKneeRule(options.final_ik, options)),
      final_(skeleton, markers),
      anchor_(skeleton, markers),
      seeable_(SeeableJoints(skeleton, markers)),
      // The memory serves the anchor's held limbs: without them it would only cost.
      memory_(skeleton, seeable_, options.rate_hz,
              options.fill_anchor_speed_mps > 0.0 && options.anchor_holds_unseen_limbs
                  ? options.unseen_limb_memory_s
                  : 0.0),
      held_kinematics_(skeleton) {
  const auto m = static_cast<size_t>(markers_.num_markers());
  tracks_.assign(m, Track{});
  weights_.assign(m, 0.0);
  anchor_weights_.assign(m, 0.0);
  solve_targets_.assign(m, Vec3::Constant(kNaN));
  limb_seen_.assign(static_cast<size_t>(skeleton_.num_joints()), 0);
  segment_seen_ = limb_seen_;
  recall_known_ = limb_seen_;
  held_pose_ = RestPose(skeleton_);
  previous_pose_ = recalled_ = held_pose_;
  held_markers_.assign(m, Vec3::Zero());
}

void FinalSolve::Reset() {
  std::fill(tracks_.begin(), tracks_.end(), Track{});
  blind_ = false;
  final_.Reset();
  memory_.Clear();
  has_previous_ = recalled_ok_ = false;
  frames_to_recall_ = 0;
}

void FinalSolve::Solve(CleanFrame* frame, CleanupCounters* counters,
                       std::span<const Vec3> captured_fit, std::span<const Vec3> return_motion) {
  const int64_t tau = frame->frame;
  const double catchup = rules_.data_catchup_m;
  // Back from frames with no captured sample at all (a feed outage bridged by inserted
  // frames, the whole body occluded) with most of the body seen again and most of it
  // further from the skeleton than the catch-up closes in a frame: nothing real led the
  // skeleton, and it is solved afresh on the data. Caught up, it stayed 5-47 cm behind the
  // markers for a third of a second after a 0.3-1.9 s outage, published as tracking. A
  // frame lost within the lookahead is interpolated and the skeleton already there: no
  // cold start (its hidden limbs would jump, and it costs a strict solve).
  size_t captured = 0, far = 0;
  for (size_t m = 0; m < tracks_.size(); ++m) {
    if (frame->source[m] != SampleSource::kCaptured) continue;
    ++captured;
    if (final_.has_solution() &&
        (frame->markers[m] - final_.predicted_markers()[m]).norm() > rules_.data_catchup_max_m)
      ++far;
  }
  const bool most_seen = 2 * captured >= tracks_.size() && captured > 0;
  if (blind_ && most_seen && 2 * far >= captured) {
    final_.Reset();
    for (Track& track : tracks_) track.weight = 1.0;
  }
  // Armed by a frame with nothing captured; a body coming back a few markers at a time
  // keeps it armed until most of it is seen.
  if (captured == 0) blind_ = true;
  if (most_seen) blind_ = false;
  for (size_t m = 0; m < tracks_.size(); ++m) {
    Track& track = tracks_[m];
    const MarkerStatus status = frame->status[m];
    const bool data = frame->source[m] == SampleSource::kCaptured;
    const Vec3& x = data && !captured_fit.empty() ? captured_fit[m] : frame->markers[m];
    // The final solve never takes a captured sample at one bound: it fits a target that
    // starts where the skeleton had the marker last frame, moves with the sample's own
    // motion (changing by at most data_motion_acceleration_m per frame, so a swap or pop
    // the detectors missed is not taken for motion) and closes on the sample by
    // data_catchup_m per frame, or when far off by the share of the distance
    // data_catchup_time_s closes in a frame, never more than data_catchup_max_m. A sample
    // the skeleton already fits is its own target; one that returns away from where the
    // skeleton had it is reached without a pop, and at full weight.
    Vec3 solve_x = x;
    const bool eased = data && catchup > 0.0 && final_.has_solution();
    track.catching_up = false;
    // On a sample's first frame back, its motion as the lookahead shows it
    // (return_motion), or none if it does not. Taken as still, a whole skeleton coming back
    // from a dropout was held back and caught up from there, and a returning limb lagged
    // its markers.
    const bool shown = !return_motion.empty() && return_motion[m].allFinite();
    if (eased) {
      Vec3 motion = shown ? return_motion[m] : Vec3::Zero();
      // Through a lost frame too: taken as still after each one, losing every other frame
      // left every captured sample 2.5 cm behind, caught up from rest.
      if (track.last_captured == tau - 1 || track.continuous_to == tau - 1)
        motion = track.data_motion + ClampNorm(Vec3(x - track.output - track.data_motion),
                                               rules_.data_motion_acceleration_m);
      track.data_motion = motion;
      const Vec3 from = final_.predicted_markers()[m] + motion;
      const double gap = (x - from).norm();
      const double step =
          std::max(catchup, std::min(gap * rules_.data_catchup_share, rules_.data_catchup_max_m));
      if (gap > step) {
        solve_x = from + ClampNorm(Vec3(x - from), step);
        track.catching_up = true;
      }
    } else if (data) {
      // Fitted as it is (the skeleton's first solution): the next frame's catch-up starts
      // from the motion the lookahead shows. Started from rest, a foot running from the
      // take's first frame lagged its markers by 3-4 cm for 20 frames at 240 Hz.
      track.data_motion = shown ? return_motion[m] : Vec3::Zero();
    }
    solve_targets_[m] = solve_x;
    if (status != MarkerStatus::kUnrecoverable) track.output = x;
    if (data) track.last_captured = tau;
    if (data || (captured == 0 && frame->source[m] == SampleSource::kInterpolated &&
                 track.continuous_to == tau - 1))
      track.continuous_to = tau;
    double weight = data                                              ? 1.0
                    : status == MarkerStatus::kUnrecoverable          ? 0.0
                    : frame->source[m] == SampleSource::kInterpolated ? options_.interpolated_weight
                                                                      : options_.repaired_weight;
    // A sample handed from a guess (a one-sided fill, weak) to data (an interpolation,
    // or a captured sample when the catch-up is off) gains weight gradually, so the final
    // solve does not snap to it in one frame.
    if (rules_.fill_weight_ramp > 1.0 && status != MarkerStatus::kUnrecoverable &&
        weight > track.weight && !eased)
      weight = std::min(weight,
                        std::max(track.weight, options_.repaired_weight) * rules_.fill_weight_ramp);
    track.weight = weight;
    weights_[m] = weight;
    frame->weight[m] = weight;
  }
  whole_ = false;
  if (rules_.fill_anchor_radius_m > 0.0 && final_.has_solution()) AnchorRepairs(*frame, counters);
  frame->final_solve = SolveIk(skeleton_, markers_, final_ik_, solve_targets_, weights_, &final_);
  counters->CountSolve(frame->final_solve);
  frame->pose = final_.pose();
  if (has_previous_) memory_.Observe(final_.pose(), previous_pose_, whole_);
  previous_pose_ = final_.pose();
  has_previous_ = final_.has_solution();
}

// Where the skeleton goes on the samples it can trust alone (captured, fitted, full
// weight): the anchor. A repaired sample may pull the skeleton at most
// fill_anchor_speed_mps times a frame's time from it (an interpolation on a segment with
// no trusted sample of its own: unseen_limb_interpolation_speed_mps). A fill is a guess,
// and a guess may jump (its reference re-acquiring a segment, an interpolation bending
// onto a returning track); the anchor moves only with real data, so how fast a guess can
// take the skeleton is bounded.
void FinalSolve::AnchorRepairs(const CleanFrame& frame, CleanupCounters* counters) {
  const size_t m_count = tracks_.size();
  for (size_t m = 0; m < m_count; ++m)
    anchor_weights_[m] =
        frame.source[m] == SampleSource::kCaptured && !tracks_[m].catching_up && weights_[m] >= 1.0
            ? 1.0
            : 0.0;
  anchor_.Reset(final_.pose());
  const IkSummary summary =
      SolveIk(skeleton_, markers_, options_.anchor_ik, solve_targets_, anchor_weights_, &anchor_);
  counters->CountSolve(summary);
  // Too few trusted samples to solve: the anchor is last frame's skeleton.
  const bool solved = summary.status != IkStatus::kTooFewMarkers;
  std::span<const Vec3> anchor = solved ? anchor_.predicted_markers() : final_.predicted_markers();
  if (solved) {
    MarkSeenLimbs();
    whole_ = std::equal(seeable_.begin(), seeable_.end(), limb_seen_.begin(),
                        [](uint8_t seeable, uint8_t seen) { return seen || !seeable; });
  }
  if (whole_) frames_to_recall_ = 0;
  if (solved && options_.anchor_holds_unseen_limbs && HoldUnseenLimbs()) anchor = held_markers_;
  for (size_t m = 0; m < m_count; ++m) {
    if (anchor_weights_[m] > 0.0 || weights_[m] <= 0.0 || tracks_[m].catching_up) continue;
    // With nothing trusted in the frame (every marker missing for a moment), the anchor
    // is only last frame's skeleton; an interpolation, between captured samples on both
    // sides, is the best the frame has. Held to the anchor, the whole skeleton stood still
    // through a 10-frame dropout and then caught up at data_catchup_mps: a hand 23 cm
    // behind its markers for 0.3 s (CMU 01_01).
    if (!solved && frame.source[m] == SampleSource::kInterpolated) continue;
    // An interpolation on a segment the anchor can only guess leads it to where its
    // markers come back; elsewhere the anchor is data, and a fill only nudges it. Per
    // segment, not per limb: a seen foot places the end of a hidden shin but not its
    // swivel, and held to the anchor a knee stayed 5-7 cm off for 10 frames while its
    // shin's fills were 0.7-2.6 cm off (kick 60 Hz medium, bench/README.md).
    const bool leads_unseen_limb =
        solved && frame.source[m] == SampleSource::kInterpolated &&
        !segment_seen_[static_cast<size_t>(markers_.primary_joint(static_cast<int>(m)))];
    const double radius =
        leads_unseen_limb ? rules_.unseen_limb_interpolation_radius_m : rules_.fill_anchor_radius_m;
    solve_targets_[m] = anchor[m] + ClampNorm(Vec3(solve_targets_[m] - anchor[m]), radius);
  }
}

// segment_seen_[j]: a trusted sample (anchor_weights_) on joint j itself; limb_seen_[j]:
// on joint j or below it.
void FinalSolve::MarkSeenLimbs() {
  std::fill(segment_seen_.begin(), segment_seen_.end(), 0);
  for (int m = 0; m < markers_.num_markers(); ++m)
    if (anchor_weights_[static_cast<size_t>(m)] > 0.0)
      segment_seen_[static_cast<size_t>(markers_.primary_joint(m))] = 1;
  std::copy(segment_seen_.begin(), segment_seen_.end(), limb_seen_.begin());
  for (int j = skeleton_.num_joints() - 1; j > 0; --j)  // parents come first: children fold in
    if (limb_seen_[static_cast<size_t>(j)])
      limb_seen_[static_cast<size_t>(skeleton_.joint(j).parent.value)] = 1;
}

// A limb with no trusted sample on it or below it (a lower leg and foot, a forearm and
// hand) is held in the anchor: its parent carries its root along, but turns it in the
// world at most unseen_limb_turn_radps. Held relative to its parent, a trusted thigh
// turning over an occluded, planted lower leg swung the guessed foot 2-3 cm a frame
// faster than the real one (bench/README.md); held in the world for as long as it was
// unseen, a foot under a shin that kept walking drifted 12 cm from the truth while its
// fills were 2-7 cm off. Needs limb_seen_ (MarkSeenLimbs). Returns false when every
// limb is seen (the anchor stands as solved).
bool FinalSolve::HoldUnseenLimbs() {
  const int joints = skeleton_.num_joints();
  const KinematicsWorkspace& now = anchor_.kinematics();
  const KinematicsWorkspace& before = final_.kinematics();
  bool held = false;
  for (int j = 1; j < joints; ++j) {
    const auto uj = static_cast<size_t>(j);
    const int parent = skeleton_.joint(j).parent.value;
    // Only a ball joint can take any orientation; the root of an unseen limb is an
    // unseen joint under a seen one.
    if (parent < 0 || limb_seen_[uj] || !limb_seen_[static_cast<size_t>(parent)] ||
        skeleton_.joint(j).type != JointType::kBall)
      continue;
    if (!held) held_pose_ = anchor_.pose();
    // Between keeping its world orientation and turning with its parent (the anchor's
    // own solution, warm-started from last frame), at most unseen_limb_turn_rad from the
    // first.
    const Quat in_world(now.R_WJ[static_cast<size_t>(parent)].transpose() * before.R_WJ[uj]);
    const Quat& with_parent = anchor_.pose().rotation[uj];
    const double turn = in_world.angularDistance(with_parent);
    held_pose_.rotation[uj] = turn <= rules_.unseen_limb_turn_rad
                                  ? with_parent
                                  : in_world.slerp(rules_.unseen_limb_turn_rad / turn, with_parent);
    held = true;
  }
  if (!whole_) {
    if (!held) held_pose_ = anchor_.pose();
    held = RecallUnseenLimbs() || held;
  }
  if (!held) return false;
  ForwardKinematics(skeleton_, held_pose_, &held_kinematics_);
  EvaluateMarkers(markers_, held_kinematics_, held_markers_);
  return true;
}

// An unseen limb's joints turn from where they were last published toward the pose the
// motion memory recalls for them (asked again every sample interval, not every frame:
// the search is the costly part), at most unseen_limb_recall_turn_rad a frame. Without a
// recall (memory off, or too little of it yet) the hold above stands.
bool FinalSolve::RecallUnseenLimbs() {
  if (!memory_.enabled() || !has_previous_) return false;
  // A joint hidden since the last recall has none yet: asked again now, not left to
  // turn toward a stale pose until the next interval.
  bool newly_hidden = false;
  for (size_t j = 0; j < limb_seen_.size(); ++j) newly_hidden |= !limb_seen_[j] && recall_known_[j];
  if (--frames_to_recall_ <= 0 || newly_hidden) {
    recalled_ok_ = memory_.Recall(anchor_.pose(), previous_pose_, limb_seen_, &recalled_);
    std::copy(limb_seen_.begin(), limb_seen_.end(), recall_known_.begin());
    frames_to_recall_ = memory_.sample_interval_frames();
  }
  if (!recalled_ok_) return false;
  const double max_turn = rules_.unseen_limb_recall_turn_rad;
  for (int j = 1; j < skeleton_.num_joints(); ++j) {
    const auto uj = static_cast<size_t>(j);
    if (limb_seen_[uj] || skeleton_.joint(j).type == JointType::kFixed) continue;
    const Quat& from = previous_pose_.rotation[uj];
    // As far toward the recall as the memory's own tests trust it for the limb hidden
    // (the one under the highest unseen joint), from the hold.
    int limb = j;
    // (The root is seen: HoldUnseenLimbs runs only on a solved anchor.)
    for (int parent = skeleton_.joint(limb).parent.value;
         parent >= 0 && !limb_seen_[static_cast<size_t>(parent)];
         parent = skeleton_.joint(limb).parent.value)
      limb = parent;
    const Quat to = held_pose_.rotation[uj].slerp(memory_.Trust(limb), recalled_.rotation[uj]);
    const double turn = from.angularDistance(to);
    held_pose_.rotation[uj] = turn <= max_turn ? to : from.slerp(max_turn / turn, to);
  }
  return true;
}

}  // namespace mocapd
