// The per-subject streaming cleanup pipeline: push marker frame t, get frame t-K out once
// it is final. Follows Perepichka 2020, ch. 3 ("Robust marker trajectory repair using
// kinematic reference"), turned from a batch method into a streaming one:
//  - two solutions per frame: the naive Y (plain IK on the markers as they are) and the
//    robust reference Y^ (Huber IRLS, temporal prior, persistent outliers excluded), with
//    X^ = LBS(Y^) the reference marker positions;
//  - detectors that each write a reason into one per-marker mask (missing, kinematic
//    disagreement of Y and Y^ per joint mapped to markers through skin weights, residual
//    against X^ beyond an adaptive threshold, velocity spikes against the reference,
//    rigid-segment distance violations, swaps, frozen and fallen-off markers);
//  - mask clean-up within the lookahead (small tracks removed, returning tracks trimmed
//    until their slope agrees with the reference);
//  - repair of each bad sample by a cubic Hermite offset onto the reference path, from
//    the last published state (position and velocity) to the returning track when it is
//    within the lookahead (two-sided; this is also the no-pop re-entry blend), or easing
//    to a constant offset while the gap is still open (one-sided); the reference's path
//    is taken without its snaps (accelerations beyond a human limb's), so a guessed
//    segment snapping back to returning markers moves no fill; short gaps between
//    observed samples get a plain Hermite on the raw path;
//  - the final solve Y- on the repaired markers, warm-started, made pop-free by bounding
//    how fast anything can move the skeleton beyond real motion: a captured sample is
//    fitted through a target that starts at the skeleton's marker, follows the sample's
//    own (acceleration-limited) motion and closes on it at a few mm per frame; a repaired
//    sample may pull the skeleton only a few mm from the anchor, the pose the trusted
//    samples alone give with every unseen limb keeping its world orientation.
// Samples that were fine are published exactly as they came in. Memory is fixed at
// construction (a ring of K + 3 frames and per-marker running statistics over an
// exponential window of W frames); Push and Flush never allocate.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "filters/ik_solver.hpp"

namespace mocapd {

/// Why a sample was masked. kNone: fine.
enum class MaskReason : uint8_t {
  kNone,
  kMissing,
  kDisagreement,
  kResidual,
  kSpike,
  kRigidDistance,
  kSwap,
  kFrozen,
  kFallenOff,
  kSmallTrack,
  kTrimmed,
};
inline constexpr int kMaskReasonCount = 11;
const char* to_string(MaskReason reason);

enum class MarkerStatus : uint8_t {
  kObserved,       ///< Published exactly as captured.
  kRepaired,       ///< Filled or relabelled; the reason says which detector.
  kUnrecoverable,  ///< No data to repair from (never seen yet): not published.
};
const char* to_string(MarkerStatus status);

struct CleanupOptions {
  double rate_hz = 120.0;
  int lookahead = 12;  ///< K: frames of delay; 0 allowed.
  int window = 120;    ///< W: time constant, in frames, of the running statistics.
  // Detection.
  double disagreement_position_m = 0.10;          ///< Delta P max (thesis: 10 cm).
  double disagreement_rotation_rad = 30.0 * M_PI / 180.0;  ///< Delta R max (thesis: 30 deg).
  /// Of the markers on a disagreeing joint, those further than this from X^ are marked
  /// (the naive solve is pulled by a few bad markers; their neighbours are innocent).
  double disagreement_residual_m = 0.01;
  double residual_floor_m = 0.012;  ///< Residuals below this are never outliers.
  double residual_scale_factor = 5.0;  ///< Threshold = max(floor, factor x running residual scale).
  double spike_m = 0.03;            ///< Per-frame displacement differing from the reference's by more.
  double rigid_tolerance_m = 0.03;  ///< Distance change between two markers on one rigid segment.
  double swap_margin_m = 0.01;      ///< A swap must explain the data better by at least this.
  double swap_search_m = 0.15;      ///< Only markers this close in the previous frame can swap.
  bool relabel_swaps = true;        ///< Swap the labels back instead of filling both.
  /// Frozen: a marker staying within this distance of where it came to rest (wide enough
  /// for 2 mm of capture jitter, which a per-frame motion test mistakes for motion)...
  double frozen_radius_m = 0.015;
  double frozen_reference_motion_m = 0.04;  ///< ...while its reference moves on this far...
  int frozen_frames = 6;                    ///< ...and for at least this many frames.
  /// A residual outlier this far from its reference for stray_frames in a row leaves the
  /// robust solve until it fits again: a swapped or stray sample on a segment with few
  /// other markers (its neighbour occluded) would otherwise drag the reference after it,
  /// and the segment's good markers out of tolerance. Measured (12 Bandai takes x 2
  /// seeds): medium pops K = 12 34 -> 8, K = 4 52 -> 33, K = 0 62 -> 40, rotation 2.46 ->
  /// 2.44 deg; heavy K = 12 70 -> 71 pops, 5.43 -> 5.63 deg; light unchanged.
  double stray_residual_m = 0.20;
  int stray_frames = 12;
  int fallen_frames = 60;  ///< Residual outliers this long in a row...
  double fallen_residual_m = 0.10;  ///< ...and this far off: fallen off (excluded from Y^).
  // Mask clean-up, bounded by the lookahead.
  int small_gap_frames = 5;     ///< Gaps up to this long between observed samples: plain Hermite.
  int small_track_frames = 10;  ///< Observed runs up to this long between gaps are dropped.
  double trim_slope_m = 0.01;   ///< A returning track is trimmed while its per-frame slope differs more.
  int max_trim_frames = 6;
  // Repair.
  double max_offset_velocity_m = 0.01;  ///< Clamp on boundary offset velocities, m per frame.
  /// A fill follows its reference's path only up to this acceleration (m/s^2); beyond it
  /// the reference is snapping (a segment's markers re-entering its solve after a guess,
  /// a guessed segment swinging), not moving, and the fill keeps its own course. 0
  /// disables. Measured (12 Bandai takes x 2 seeds, K = 12, with the release below):
  /// pops medium 73 -> 34, heavy 297 -> 70, light 1 -> 0; rotation error medium 2.52 ->
  /// 2.46 deg, heavy 5.59 -> 5.43 deg; position error and repaired-marker RMSE unchanged.
  /// (100 m/s^2: more pops; 50: fills lag real fast motion.)
  double fill_reference_acceleration_mps2 = 75.0;
  /// The fraction of the snaps a one-sided fill has not followed that it takes up each
  /// frame, so a reference that was really moving fast is caught up smoothly (without
  /// it, a kicking foot's fill fell 60 cm behind and pounced at re-entry; 0.1 brought the
  /// repaired-marker RMSE back from 24.1 to 19.0 mm).
  double fill_snap_release = 0.1;
  /// Weight of a repaired sample in the final solve (observed samples weigh 1). Small:
  /// a filled sample carries the reference's guess, which the final solve's own priors
  /// already hold; measured best at 0.01 on the Bandai takes.
  double repaired_weight = 0.01;
  /// Weight of a sample filled between two known ends (short gaps, gaps whose end is in
  /// the lookahead, re-entry blends): an interpolation of real data, and what keeps the
  /// skeleton from jumping when a segment's markers come back.
  double interpolated_weight = 1.0;
  /// A repaired sample's weight may grow by at most this factor per frame (<= 1: no limit).
  /// Measured on the 12 Bandai takes x 2 seeds, K = 12: medium pops 91 -> 78, 3.08 ->
  /// 2.91 deg; heavy 431 -> 375 pops, 6.64 -> 6.28 deg.
  double fill_weight_ramp = 1.5;
  /// The final solve fits a captured sample through a target that starts where the
  /// skeleton had the marker last frame, moves with the sample's own motion and closes
  /// on it by at most this much per frame (m; 0: the sample itself, its weight ramped
  /// like a fill's). The sample is published untouched. A fitted sample is its own
  /// target; one that comes back away from the skeleton (after a gap, a swap, a repair
  /// whose end the lookahead did not see) is reached without a pop.
  double data_catchup_m = 0.005;
  /// The sample's motion that the catch-up target follows may change by at most this
  /// much per frame (m; 1.5 cm at 120 Hz is 216 m/s^2, past a punch): a swap or pop the
  /// detectors missed is a jump, not motion, and is closed on at data_catchup_m.
  double data_motion_acceleration_m = 0.015;
  /// A repaired sample pulls the skeleton at most this far (m) from the anchor: the pose
  /// the trusted samples alone give (captured, fitted, at full weight), started from last
  /// frame's skeleton. A fill is a guess and a guess can jump; the anchor moves with real
  /// data only. 0 disables (no anchor solve).
  /// Measured (12 Bandai takes x 5 seeds, K = 0 / 4 / 12): 1 cm: medium 0 / 0 / 0 pops,
  /// 2.51 / 2.51 / 2.48 deg, heavy 14 / 14 / 15 pops, 5.18 / 5.15 / 5.10 deg; 5 mm: medium
  /// 0 / 0 / 1, heavy 11 / 10 / 12, 5.03 / 4.99 / 4.92 deg; 2 mm: medium 0 / 0 / 2 (2.0
  /// and 2.1 cm), 2.43 / 2.42 / 2.40 deg, heavy 11 / 10 / 12, 4.92 / 4.89 / 4.83 deg.
  /// The trusted samples and the held limbs are a better guess of the pose than the
  /// fills: a fill's own path is for the published markers.
  double fill_anchor_radius_m = 0.002;
  /// In the anchor, a limb with no trusted sample on it or below keeps its world
  /// orientation (its parent carries it along without swinging it); false: it keeps its
  /// orientation relative to its parent.
  bool anchor_holds_unseen_limbs = true;
  // Solves.
  IkOptions naive_ik;   ///< Y: plain least squares.
  IkOptions robust_ik;  ///< Y^: Huber (huber_delta_m = 4 mm, weak velocity prediction by default).
  IkOptions final_ik;   ///< Y-: decaying velocity prediction, so joints without data come to rest.
  IkOptions anchor_ik;  ///< The anchor (see fill_anchor_radius_m): one iteration from last frame's Y-.
  CleanupOptions();
  /// Throws std::invalid_argument naming the field if an option is out of range.
  void Validate() const;
};

/// One published frame. Owned by the pipeline; valid until the next Push/Flush.
struct CleanFrame {
  int64_t frame = -1;
  std::vector<Vec3> markers;  ///< X-: repaired positions (NaN where unrecoverable), metres.
  std::vector<MarkerStatus> status;
  std::vector<MaskReason> reason;  ///< Why a repaired sample was repaired (kNone if observed).
  std::vector<double> weight;      ///< Each marker's weight in the final solve.
  Pose pose;                       ///< Y-: the final solve.
  IkSummary final_solve;
};

struct CleanupCounters {
  int64_t frames_in = 0;
  int64_t frames_out = 0;
  int64_t samples_out = 0;
  std::array<int64_t, kMaskReasonCount> repaired_by{};  ///< Published repaired samples, per reason.
  int64_t unrecoverable = 0;
  int64_t swaps_relabelled = 0;
  int64_t cold_starts = 0;         ///< IK solves (of the three per frame) that started cold.
  int64_t solve_failures = 0;      ///< IK solves that reported a numerical failure.
  int64_t solve_iterations = 0;    ///< LM iterations over all solves.
};

class CleanupPipeline {
 public:
  /// Throws std::invalid_argument if the options are invalid.
  CleanupPipeline(std::shared_ptr<const Skeleton> skeleton, std::shared_ptr<const MarkerSet> markers, const CleanupOptions& options);
  ~CleanupPipeline();
  CleanupPipeline(const CleanupPipeline&) = delete;
  CleanupPipeline& operator=(const CleanupPipeline&) = delete;

  /// Pushes the next frame: p_WM per marker in the subject's marker order, metres; a
  /// non-finite position is a missing sample. Returns true if a frame became final
  /// (read it with output()). Never allocates or throws.
  bool Push(std::span<const Vec3> p_WM);
  /// At the end of a take: publishes the next pending frame with no more future to see.
  /// Returns false when nothing is pending.
  bool Flush();
  const CleanFrame& output() const { return out_; }
  const CleanupCounters& counters() const { return counters_; }
  const CleanupOptions& options() const { return options_; }
  /// Forgets all state (a capture restart); counters are kept.
  void Reset();

  struct Slot;  // one buffered frame, defined in the .cpp
  struct MarkerTrack;

 private:
  void RelabelSwaps(int64_t t);
  void CountSolve(const IkSummary& summary);
  void Detect(int64_t t);
  void CleanMask(int64_t t);
  void Publish(int64_t tau, int64_t newest);
  void AnchorRepairs(const Slot& s);
  bool HoldUnseenLimbs();
  Slot& slot(int64_t frame);

  std::shared_ptr<const Skeleton> skeleton_;
  std::shared_ptr<const MarkerSet> markers_;
  CleanupOptions options_;
  std::vector<Slot> ring_;
  std::vector<MarkerTrack> tracks_;
  std::vector<std::pair<int, int>> rigid_pairs_;
  std::vector<double> rigid_distance_;
  std::vector<std::vector<int>> markers_of_joint_;
  IkState naive_, robust_, final_, anchor_;
  std::vector<double> weights_, anchor_weights_;
  std::vector<uint8_t> limb_seen_;      ///< per joint: a trusted sample on it or below (HoldUnseenLimbs)
  Pose held_pose_;                      ///< the anchor with its unseen limbs held in the world...
  KinematicsWorkspace held_kinematics_;
  std::vector<Vec3> held_markers_;      ///< ...and its markers
  std::vector<Vec3> scratch_;
  std::vector<uint8_t> marker_flags_;  ///< per-marker scratch of CleanMask
  std::vector<int> swap_candidates_;       ///< RelabelSwaps scratch: markers predictable from fine samples...
  std::vector<Vec3> candidate_previous_;  ///< ...and their previous positions, packed
  std::vector<Vec3> solve_targets_;       ///< what the final solve fits (X-, but returning samples eased in)
  CleanFrame out_;
  CleanupCounters counters_;
  bool naive_solved_ = false;  ///< Y was solved for the newest frame.
  bool naive_fresh_ = false;   ///< Y's warm start is the previous frame's solution.
  int64_t next_in_ = 0;   ///< Frame number of the next Push.
  int64_t next_out_ = 0;  ///< Frame number of the next publication.
};

}  // namespace mocapd
