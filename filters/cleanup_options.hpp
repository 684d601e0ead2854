// The cleanup pipeline's options: one struct, and one table of every scalar option with
// its bounds (and, for those a config file may set, its name, unit and section), from
// which Validate, the daemon's config reader and its reload fingerprint are all derived.
// How each default was measured is in bench/README.md ("Why the cleanup's defaults").
#pragma once

#include <cmath>
#include <span>
#include <variant>

#include "filters/ik_solver.hpp"

namespace mocapd {

/// The capture rates the cleanup runs at (rate_hz's bounds), which the file readers and
/// the synthesizer hold a take's rate to before any work is done on it.
inline constexpr double kMinCaptureRateHz = 1.0;
inline constexpr double kMaxCaptureRateHz = 10000.0;

struct CleanupOptions {
  double rate_hz = 120.0;
  int lookahead = 12;     ///< K: frames of delay; 0 allowed.
  double window_s = 1.0;  ///< W: time constant of the running statistics.

  // Ingest gates (filters/cleanup_pipeline.hpp).
  /// A sample further than this from the capture's origin along any axis is not a
  /// position (1e30, FLT_MAX, an exporter's sentinel): missing, kept out of every solve.
  double capture_volume_m = 100.0;
  /// A frame whose markers (the median of them) moved faster than this since the last
  /// frame taken is a capture glitch: all its samples are missing... (One marker moving
  /// this fast has jumped: a short run of its samples between such a jump and a gap or
  /// another jump is a small track, see small_track_s.)
  double glitch_speed_mps = 40.0;
  /// ...unless the jump persists this long: then it is a re-synchronisation (the world
  /// frame moved), taken as it is, the solves starting afresh.
  double glitch_resync_s = 0.1;

  // Detection (filters/outlier_detector.hpp).
  double disagreement_position_m = 0.10;                   ///< Delta P max (thesis: 10 cm).
  double disagreement_rotation_rad = 30.0 * M_PI / 180.0;  ///< Delta R max (thesis: 30 deg).
  /// Of the markers on a disagreeing joint, only those further than this from X^ are
  /// marked: the naive solve is pulled by a few bad markers, their neighbours are innocent.
  double disagreement_residual_m = 0.01;
  double residual_floor_m = 0.012;     ///< Residuals below this are never outliers.
  double residual_scale_factor = 5.0;  ///< Threshold = max(floor, factor x running residual scale).
  double spike_m = 0.03;  ///< Per-frame displacement differing from the reference's by more.
  double rigid_tolerance_m = 0.03;  ///< Distance change between two markers on one rigid segment.
  double swap_margin_m = 0.01;      ///< A swap must explain the data better by at least this.
  double swap_search_m = 0.15;      ///< Only markers this close in the previous frame can swap.
  bool relabel_swaps = true;  ///< Swap the labels back (every swap test) instead of filling both.
  /// Frozen: a marker staying within this distance of where it came to rest (wide enough
  /// for capture jitter, which a per-frame motion test mistakes for motion)... (A still
  /// marker whose distance to its joint's origin changes by more than this is frozen too:
  /// a marker on its segment keeps that distance, to within the same jitter.)
  double frozen_radius_m = 0.015;
  /// ...while its reference moves on this far (or a moving marker on its segment changes
  /// its distance to it this much)...
  double frozen_reference_motion_m = 0.04;
  double frozen_s = 0.05;  ///< ...and for at least this long.
  /// A marker judged frozen is masked back over its still run at most this far: further
  /// back it was most likely still with its segment (a planted foot), and masking it
  /// there cost a longer lookahead (Bandai medium, 120 Hz, K = 48: 1.42 against K = 12's
  /// 1.36 deg). 0.2 s is the whole K = 12 lookahead at 60 Hz.
  double frozen_backdate_s = 0.2;
  /// The reference starts cold only on half the marker set (robust_ik's
  /// cold_start_min_fraction) for this long after a frame first showed enough markers to
  /// solve; then on what there is (a take that labels fewer markers than its subject has).
  double reference_cold_start_wait_s = 0.25;
  /// A residual outlier this far off for stray_s in a row leaves the robust solve
  /// until it fits again: a swapped or stray sample on a segment whose neighbours are
  /// occluded would otherwise drag the reference, and the segment's good markers, along.
  double stray_residual_m = 0.20;
  double stray_s = 0.1;
  double fallen_s = 0.5;            ///< Residual outliers this long in a row...
  double fallen_residual_m = 0.10;  ///< ...and this far off: fallen off (excluded from Y^).
  /// A marker rigidly on a segment stays at its offset's distance from the segment's joint,
  /// however the segment turns; the joint is where the parent segment ends. While the
  /// parent's own samples fit, a sample this much nearer or farther from that joint is not
  /// on the segment (a ghost or another segment's trajectory under its label): it is kept
  /// out of the next frame's robust solve, judged again every frame. 0 disables.
  double off_joint_m = 0.05;
  // Mask clean-up, bounded by the lookahead.
  double small_gap_s = 0.042;  ///< Gaps up to this long between observed samples: plain Hermite.
  /// Observed runs up to this long between gaps (or jumps faster than glitch_speed_mps)
  /// are dropped.
  double small_track_s = 0.083;
  double trim_slope_mps = 1.2;  ///< A returning track is trimmed while its velocity differs more...
  double max_trim_s = 0.05;     ///< ...for at most this long.

  // Repair (filters/gap_repair.hpp).
  double max_offset_velocity_mps = 1.2;  ///< Clamp on boundary offset velocities.
  /// A fill follows its reference's path only up to this acceleration (m/s^2); beyond it
  /// the reference is snapping (a segment re-entering its solve), not moving. 0 disables.
  double fill_reference_acceleration_mps2 = 75.0;
  /// The snaps a one-sided fill has not followed are taken up with this time constant,
  /// so a reference that really moved fast is caught up smoothly (0: at once).
  double fill_snap_release_s = 0.079;
  /// A gap's fill starts from the offset velocity of the samples before it, smoothed with
  /// this time constant (0: the last frame's change alone, which carries the capture's
  /// noise into the whole fill: with 1 mm of noise that is most of a short gap's error)...
  double fill_start_velocity_s = 0.05;
  /// ...and ends on the returning track's offset velocity over up to this long.
  double fill_end_velocity_s = 0.05;
  /// A one-sided fill (its marker's return not in sight) eases its offset velocity out
  /// over this long; 0 holds the last offset from the gap's first frame. It was the
  /// lookahead's K + 1 frames (0.22 s at 60 Hz, 1 s at K = 240 and 240 Hz: a fill drifted);
  /// 0 and 0.05 s gave the same means and 0 up to 0.3 mm less RMSE on corrupted samples
  /// (Bandai medium, K = 0, 120 Hz: 10.5 against 10.7 mm); 0.1 s more.
  double fill_ease_s = 0.0;
  /// A fill turns toward its marker's return only once the return is this near (and in
  /// the lookahead). Over a longer stretch the path from the gap's start to the return
  /// was worse than the reference's: Bandai medium, 120 Hz, K = 48 gave corrupted samples
  /// 12.4 mm and 1.54 deg where K = 12 gave 10.4 mm and 1.36 deg; on a limb occluded whole
  /// too (its reference a guess), where a 34 cm frame came of it. Never shorter than
  /// small_gap_s (a shorter one is taken as small_gap_s), so a small gap's plain Hermite
  /// always sees its end. A run of frames with no valid sample at all (after the capture
  /// volume and glitch gates) counts as its first frame only: across it the reference is
  /// no guide, and a fill bridges it whole.
  double fill_interpolation_horizon_s = 0.1;

  // Final solve (filters/final_solve.hpp).
  /// Weight of a one-sided repair in the final solve (observed samples weigh 1): it is
  /// the reference's guess, which the solve's own priors already hold.
  double repaired_weight = 0.01;
  /// Weight of a sample filled between two known ends: an interpolation of real data,
  /// and what keeps the skeleton from jumping when a segment's markers come back.
  double interpolated_weight = 1.0;
  /// A repaired sample's weight may grow at most by this rate: by exp(rate x dt) per
  /// frame (0: no limit).
  double fill_weight_growth_per_s = 48.66;
  /// A captured sample is fitted through a target that starts at the skeleton's marker,
  /// moves with the sample's own motion and closes on it at this speed (0: the sample
  /// itself, its weight ramped like a fill's): a sample that comes back away from the
  /// skeleton is reached without a pop...
  double data_catchup_mps = 0.6;
  /// ...or, when further off, by the share of the distance this time constant closes in
  /// a frame (0: data_catchup_mps alone)...
  double data_catchup_time_s = 0.05;
  /// ...but never faster than this (at or below data_catchup_mps: that speed alone). A
  /// limb hidden whole comes back 10-20 cm from its clean markers; at 0.6 m/s it stayed
  /// that far off for a quarter of a second and more, at this speed it closes in about
  /// 0.1 s, still under what reads as a pop (a joint outrunning the truth by 2.4 m/s).
  double data_catchup_max_mps = 1.5;
  /// The sample's motion that the catch-up target follows accelerates at most this much
  /// (216 m/s^2 is past a punch): a swap or pop the detectors missed is a jump, not motion.
  double data_motion_acceleration_mps2 = 216.0;
  /// A repaired sample pulls the skeleton at most this speed times one frame's time away
  /// from the anchor, the pose the trusted samples alone give: a fill is a guess, and a
  /// guess can jump. A speed, not a distance, because the anchor restarts from the last
  /// frame's skeleton each frame: a fixed radius let a guess drag a limb four times as
  /// fast at 240 Hz as at 60 Hz. 0.24 m/s is 2 mm a frame at 120 Hz. 0: no anchor.
  double fill_anchor_speed_mps = 0.24;
  /// In the anchor, a limb with no trusted sample on it or below is held: its parent
  /// carries it along but turns it in the world at most unseen_limb_turn_radps. A thigh
  /// swinging over an occluded, planted lower leg does not swing the guessed foot; a
  /// parent that turns slowly takes its unseen limb with it, so a limb hidden for long
  /// goes where its parent goes rather than staying where it was last seen.
  bool anchor_holds_unseen_limbs = true;
  /// 1 rad/s moves the end of a 0.25-0.5 m limb at 0.25-0.5 m/s, about the speed a guess
  /// may drag the skeleton (fill_anchor_speed_mps). 0: the limb keeps its world
  /// orientation for as long as it is unseen.
  double unseen_limb_turn_radps = 1.0;
  /// The seconds of the subject's recent motion remembered (MotionMemory): a limb
  /// unseen for a while turns toward the pose it had when the rest of the body last
  /// moved as it does now, as far as the memory's own tests trust it over holding the
  /// limb. 0: off (held); otherwise at least MotionMemory::kMinUsefulSpanS. Used only
  /// with the anchor's held limbs (fill_anchor_speed_mps > 0, anchor_holds_unseen_limbs).
  /// 60 s is about 1.3 MB per subject of a 25-joint skeleton.
  double unseen_limb_memory_s = 60.0;
  /// How fast (rad/s) an unseen limb's joints may turn toward what the memory recalls:
  /// fast enough to follow a walking thigh's swing (about 3 rad/s at its fastest), slow
  /// enough that a recall that changes its mind is a turn, not a pop (at 8 rad/s the
  /// soak's actors had 3-9 pops each, at 5 rad/s 1-3).
  double unseen_limb_recall_turn_radps = 5.0;
  /// An interpolated sample (filled between known ends: the lookahead sees its marker
  /// return) on a segment with no trusted sample of its own may pull the skeleton this
  /// fast from the anchor instead of fill_anchor_speed_mps. The anchor only guesses that
  /// segment, and the interpolation leads to the data it is about to come back to: a
  /// forearm occluded through a fast move otherwise came back 40 cm from its clean
  /// markers and took 0.7 s to close on them. Per segment, not per limb: a seen foot
  /// fixes where a hidden shin ends, not how the knee swivels (a knee 5-7 cm off while
  /// its shin's fills were 0.7-2.6 cm off). 1 m/s is 1.7 cm a frame at 60 Hz, under what
  /// reads as a pop. A segment with a trusted sample keeps the slower speed: its anchor
  /// is data (applied to every interpolated sample, the humanoid's 60 Hz heavy mean rose
  /// 2.21 -> 2.30 deg); so does every fill in a frame whose trusted samples are too few
  /// to solve. Equal to fill_anchor_speed_mps: off; no effect without an anchor
  /// (fill_anchor_speed_mps 0).
  double unseen_limb_interpolation_speed_mps = 1.0;
  /// In the final solve, a leg with nothing seen on its thigh or shin but its foot seen
  /// has its knee turned about the hip-ankle line until the knee's bend axis is within
  /// this (rad) of the axis the leg has shown in its foot's frame (KneeSwivel; a leg that
  /// has shown none takes the other leg's, in the pelvis's frame). The two
  /// axes stay within 15 degrees in most bent frames of real takes and reach 70 in a
  /// dance; beyond this the knee is where no knee goes. 0: off. (In the reference too, it
  /// cost the humanoid's heavy fills 22.7 -> 23.9 mm; in the anchor it changed nothing.)
  double unseen_knee_tolerance_rad = 45.0 * M_PI / 180.0;
  /// ...turning the published skeleton's knee at most this fast (rad/s), so a knee found
  /// far off comes back without a pop (90 deg/s left the humanoid's medium worst frames
  /// 20-26 cm; 360: 12-17 cm, with no more pops).
  double unseen_knee_turn_radps = 360.0 * M_PI / 180.0;
  /// The final solve fits each captured sample smoothed over this much time either side
  /// (a local cubic through the captured samples around it, as far as the lookahead
  /// reaches on both sides; 0: as captured). Centred, so it filters capture noise without
  /// the lag that the solve's pull toward its prediction adds, which grows with the time
  /// between frames. Published samples stay as captured. (Bandai light, 60 / 120 / 240 Hz:
  /// 40 ms gave 1.11 / 0.77 / 0.60 deg, 50 ms 1.03 / 0.75 / 0.59, 80 ms bent a 60 Hz
  /// take's fast motion, 1.13 at 60 Hz.)
  double solve_smoothing_s = 0.05;

  // Solves.
  IkOptions naive_ik;   ///< Y: plain least squares.
  IkOptions robust_ik;  ///< Y^: Huber (4 mm), weak velocity prediction.
  IkOptions final_ik;   ///< Y-: decaying velocity prediction, so joints without data come to rest.
  IkOptions
      anchor_ik;  ///< The anchor (see fill_anchor_speed_mps): one iteration from last frame's Y-.
  CleanupOptions();
  /// Throws std::invalid_argument naming the field, its bounds and the value if an
  /// option is out of range (the bounds of CleanupOptionFields()).
  void Validate() const;
};

/// One scalar option of CleanupOptions: its bounds and how a config file names it. The
/// key carries the unit a person writes (spike_mm); a value in that unit times to_si is
/// the option's value (SI: m, rad, s).
struct CleanupOptionField {
  const char* name;  ///< The C++ member's name.
  const char*
      section;  ///< Config table ("pipeline", "pipeline.detectors"); nullptr: not in config files.
  const char* key;  ///< Config key, with its unit suffix.
  double to_si;     ///< Key's unit -> SI.
  double min, max;  ///< Bounds, in the key's unit.
  std::variant<double CleanupOptions::*, int CleanupOptions::*, bool CleanupOptions::*> member;
};

/// Every scalar option, in declaration order. The one place their bounds are written.
std::span<const CleanupOptionField> CleanupOptionFields();

/// The time-based options at a capture rate: every rule is stated in seconds (or m/s,
/// m/s^2) and converted here, once per rate, so the cleanup behaves alike at 60 and
/// 360 Hz.
struct CleanupFrameRules {
  double statistics_weight;  ///< The running statistics' weight per frame, 2 / (W + 1).
  int frozen_frames, frozen_backdate_frames, stray_frames, fallen_frames;
  int reference_cold_start_wait_frames;
  int small_gap_frames, small_track_frames, max_trim_frames;
  double trim_slope_m;                        ///< Per frame.
  double max_offset_velocity_m;               ///< Per frame.
  double fill_snap_release;                   ///< Share taken up per frame.
  double fill_start_velocity_weight;          ///< A new frame's share of the smoothed velocity.
  int fill_end_velocity_frames;               ///< At least 1.
  double fill_ease_frames;                    ///< 0: the offset is held exactly.
  int fill_interpolation_horizon_frames;      ///< At least 1 and small_gap_frames.
  double fill_weight_ramp;                    ///< Factor per frame (<= 1: no limit).
  double marker_jump_m;                       ///< Per frame (glitch_speed_mps).
  double data_catchup_m;                      ///< Per frame.
  double data_catchup_share;                  ///< Share of the distance closed per frame.
  double data_catchup_max_m;                  ///< Per frame.
  double data_motion_acceleration_m;          ///< Change of the per-frame motion, per frame.
  double fill_anchor_radius_m;                ///< Per frame.
  double unseen_limb_turn_rad;                ///< Per frame.
  double unseen_limb_recall_turn_rad;         ///< Per frame.
  double unseen_limb_interpolation_radius_m;  ///< Per frame.
  int solve_smoothing_frames;                 ///< Half-width of the final solve's smoothing.
};
/// The rules for options.rate_hz. The options must be valid.
CleanupFrameRules FrameRules(const CleanupOptions& options);
/// A solve's options with the cleanup's unseen-knee rule set: its tolerance and its turn
/// per frame at options.rate_hz.
IkOptions WithUnseenKneeRule(IkOptions ik, const CleanupOptions& options);

}  // namespace mocapd
