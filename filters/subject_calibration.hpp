// Calibrating a subject from markers alone: the skeleton's joint centres (bone lengths)
// and every marker's bone and offset, from labelled marker trajectories and a template
// (a role-named skeleton with each marker's segment and a guess of its offset).
//
// Method: one robust bundle adjustment over the poses of a varied subset of frames,
// the joint offsets and the marker offsets, by alternation:
//  - poses: warm-started IK per selected frame on the current subject;
//  - structure: with the joints' world rotations fixed, every marker's position is linear
//    in the joint offsets and marker offsets (p_m(t) = p_root(t) + sum over the chain of
//    R_W,parent(j)(t) o_j + R_W,J(t) a_m), so all of them come from one weighted linear
//    least-squares problem (the root translation of each frame eliminated), with Huber
//    weights on the markers' residuals, weak priors toward the template's offsets, soft
//    left/right symmetry, and the pelvis origin held midway between the hip centres.
// With rotations fixed this is the SCoRE system (Ehrig et al. 2006) for every joint at
// once: a centre is found where both adjacent segments agree on it. How well the motion
// determines each joint centre (its coverage) is read off the data-only information
// matrix: its marginal covariance per joint gives the centre's uncertainty per principal
// direction; a direction the motion did not excite (a hinge's axis, a hip in gait) is held
// by the prior and reported as such.
// The take is solved whole and on interleaved subsets of its frames, and the offsets are
// the solves' mean: one solve stops wherever the adjustment left what the motion barely
// determines, and the solves' scatter is reported beside the motion's own sigmas.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "filters/ik_solver.hpp"

namespace mocapd {

// Beyond this each subset holds too few frames apart to be a solve of its own.
inline constexpr int kMaxInterleavedSolves = 16;

struct SubjectCalibrationOptions {
  int max_frames = 160;  ///< Poses solved in the bundle adjustment (a varied subset).
  /// The take is solved whole and again on this many interleaved subsets of its frames
  /// (every 4th frame from the 1st, 2nd, ...), and the offsets are the mean of the solves.
  /// One solve lands wherever the adjustment stopped along what the motion barely
  /// determines (a spine, a one-marker clavicle): leaving one frame of CMU 01_01 out moved
  /// bones by up to 35 mm. Fewer subsets when the take has fewer than max_frames frames
  /// per subset; 1: one solve. At most kMaxInterleavedSolves.
  int interleaved_solves = 4;
  double min_valid_fraction = 0.6;     ///< A frame needs this share of its markers to be used.
  int iterations = 15;                 ///< Alternations of poses and structure at most...
  double converged_m = 2e-5;           ///< ...stopping once no offset moves more than this.
  double huber_m = 0.01;               ///< Marker residuals beyond this weigh less (Huber IRLS).
  double joint_prior_sigma_m = 0.03;   ///< Template joint offsets: a weak prior.
  double marker_prior_sigma_m = 0.05;  ///< Template marker offsets: weaker still.
  double symmetry_sigma_m = 0.01;      ///< Left and right joint offsets mirror each other.
  /// Landmarks: a template marker within this of a joint centre (an epicondyle beside
  /// the knee, a malleolus beside the ankle) holds the centre's position relative to it
  /// with landmark_sigma_m. Along a hinge's axis (the knee, the elbow) nothing else can:
  /// the motion does not show it, and a prior on the centre in its parent's frame would
  /// carry that frame's own uncertainty times the bone's length.
  double landmark_radius_m = 0.09;
  double landmark_sigma_m = 0.01;
  /// A centre's direction counts as determined by the motion when its data-only standard
  /// deviation is below this.
  double covered_sigma_m = 0.004;
  /// ...and the joint turned through at least this much (2nd-98th percentile range,
  /// degrees) about the axes that determine it: a small range fits any centre along it
  /// (soft tissue makes a gait's few degrees of hip abduction worthless).
  double covered_rotation_deg = 10.0;
  void Validate() const;
};

/// What a calibration starts from.
struct CalibrationTemplate {
  Skeleton skeleton{{Joint{.name = "root", .parent = {}}}};  ///< Role names; root free.
  std::vector<MarkerDefinition> markers;  ///< Rigid, one per observed marker, template offsets.
  /// Per marker (may be empty): the standard deviation of its template offset's prior
  /// (<= 0: options.marker_prior_sigma_m), and whether the offset is unknown altogether
  /// (a studio's own marker: left out of the first tracking, its offset then taken from
  /// the tracked poses, with no prior).
  std::vector<double> marker_prior_sigma_m;
  std::vector<uint8_t> offset_unknown;
  /// Per marker (may be empty): the offset is a guess from the body's shape (a set nobody
  /// described), good to start the tracking from but no landmark for a joint centre.
  std::vector<uint8_t> offset_guessed;
  /// Per joint: its prior offset (default: the skeleton's) and that prior's standard
  /// deviation (<= 0: options.joint_prior_sigma_m).
  std::vector<Vec3> joint_prior;
  std::vector<double> joint_prior_sigma_m;
  /// Per joint, its mirror image (thigh_l <-> thigh_r), or -1.
  std::vector<int> mirror;
  /// The two joints whose centres the root's origin lies midway between (the hips), or -1.
  int gauge_left = -1, gauge_right = -1;
};

struct JointCalibrationReport {
  std::string name;
  /// "functional", "functional+prior", "prior", "fixed", or "chain": beside a segment
  /// fewer than two known markers ride, placed by the motion only with the chain's other
  /// joints (directions_covered and the sigmas are the chain's).
  std::string method;
  /// The centre's standard deviation from the motion alone along its three principal
  /// directions, smallest first (metres; large where the motion did not excite it).
  Vec3 data_sigma_m = Vec3::Zero();
  /// How far the joint turned about its three principal axes, most first (2nd-98th
  /// percentile range, degrees): Shogun's "coverage".
  Vec3 rotation_spread_deg = Vec3::Zero();
  int directions_covered = 0;
  /// Of the result, worst direction: motion and prior, or the solves' spread over the root
  /// of their count, whichever is larger.
  double uncertainty_m = 0.0;
  /// How far the solves' centres scatter about their mean (standard deviation, metres; 0
  /// for one solve): what the motion leaves to where an adjustment stops.
  double solves_sigma_m = 0.0;
  double bone_length_m = 0.0;  ///< |offset|.
};

struct SubjectCalibrationResult {
  Skeleton skeleton{{Joint{.name = "root", .parent = {}}}};
  std::vector<MarkerDefinition> markers;
  std::vector<double> marker_rms_m;  ///< Per marker, over the frames used.
  std::vector<int> marker_frames;    ///< Per marker, samples used.
  std::vector<JointCalibrationReport> joints;
  std::vector<int> frames_used;  ///< Frame indices of the selected poses.
  double rms_m = 0.0;            ///< Over every residual used.
  double median_residual_m = 0.0;
  int iterations = 0;  ///< Of the whole take's solve.
  int solves = 1;      ///< Averaged: the whole take and its interleaved subsets.
};

/// Calibrates. observed: frame-major positions (observed[f * M + m], metres, NaN when
/// missing) of the template's M markers over `frames` frames. Allocates; offline; the
/// same input gives the same result bit for bit. Throws std::invalid_argument for
/// mismatched sizes, too few usable frames (no motion, NaN-only markers) or a template
/// the IK cannot solve.
SubjectCalibrationResult CalibrateSubject(const CalibrationTemplate& tmpl,
                                          std::span<const Vec3> observed, int frames,
                                          const SubjectCalibrationOptions& options = {});

}  // namespace mocapd
