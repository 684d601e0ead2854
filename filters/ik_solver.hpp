// Per-frame, warm-started inverse kinematics: fits a skeleton pose to observed
// marker positions by Levenberg-Marquardt on the pose step (root translation plus
// joint rotation vectors, applied with the exponential map).
//
// Each iteration solves the damped Gauss-Newton system exactly, but never forms it:
// joints are eliminated from the leaves to the root, each carrying a 6x6 quadratic in
// its world twist, so the cost is O(joints * 6^3 + markers) instead of O(dofs^3).
// This is the least-squares analogue of Featherstone's articulated-body recursion
// (Featherstone, "Rigid Body Dynamics Algorithms", 2008, ch. 7), exact because the
// normal matrix couples two joints only through the twist of their common ancestor.
//
// Objective, with r_m = y_m - p_WM(q), over rotational DOF only for the priors:
//   sum_m w_m rho(|r_m|)  +  1/2 a_t |q (-) q_prior|^2  +  1/2 a_r |q (-) q_rest|^2
// rho is 1/2 r^2, or Huber (IRLS re-weighting each iteration) for the robust reference
// solve; q_prior is the warm start (previous solution, or its constant-velocity
// extrapolation). Levenberg-Marquardt: Marquardt, SIAM J. Appl. Math. 11(2), 1963.
#pragma once

#include <span>
#include <vector>

#include "filters/knee_swivel.hpp"
#include "filters/marker_model.hpp"
#include "filters/skeleton.hpp"

namespace mocapd {

struct IkOptions {
  int max_iterations = 3;              ///< Per warm-started frame.
  int cold_start_max_iterations = 60;  ///< When there is no previous solution.
  double initial_damping = 1e-4;       ///< LM factor on diag(H).
  double function_tolerance = 1e-2;  ///< Converged when the cost drops by less than this fraction.
  double step_tolerance = 1e-5;  ///< Converged when every step component is below this (rad or m).
  /// Converged when the weighted RMS marker residual (priors included) is below this, m:
  /// refining a fit far inside the capture's own precision buys nothing.
  double residual_tolerance_m = 5e-5;
  double huber_delta_m = 0.0;  ///< Huber threshold in metres; 0 disables the robust loss.
  /// With the Huber loss, a cold start is solved twice from the aligned rest pose, under
  /// the robust loss alone and under least squares first, and keeps the lower robust cost
  /// (see SolveIk). Off, only the first: a template still being fitted (subject
  /// calibration) is tracked robustly throughout.
  bool cold_start_least_squares_first = false;
  bool predict_constant_velocity = true;
  /// Fraction of the last frame-to-frame motion carried into the prediction (0..1). Below
  /// 1 the velocity decays, so a joint whose markers have all vanished comes to rest
  /// instead of turning at its last speed for the whole gap.
  double prediction_velocity_gain = 1.0;
  double temporal_weight = 3e-4;  ///< a_t, m^2 per rad^2, on rotations, toward the warm start.
  double rest_weight = 1e-7;      ///< a_r, m^2 per rad^2, toward the rest pose.
  int min_markers = 3;            ///< Fewer usable markers than this: no solve.
  /// A cold start (no previous solution) needs at least this fraction of the marker set
  /// usable: three markers hold a pose the solve can keep, not one it can find.
  double cold_start_min_fraction = 0.0;
  bool apply_joint_limits = true;
  /// A leg with no marker seen on its thigh or shin but two on its foot has its knee turned
  /// about the hip-ankle line until its bend axis is within this of the axis the leg has
  /// shown in its foot's frame, or failing that the other leg's in the pelvis's frame (see
  /// KneeSwivel); 0 leaves it where the solve put it, and
  /// the solve learns no axes.
  double unseen_knee_tolerance_rad = 0.0;
  double unseen_knee_max_turn_rad = 0.0;  ///< ...by at most this per solve; 0: no limit.
  /// Throws std::invalid_argument naming the field if an option is out of range.
  void Validate() const;
};

enum class IkStatus { kConverged, kMaxIterations, kTooFewMarkers, kNumericalFailure };
const char* to_string(IkStatus status);

struct IkSummary {
  IkStatus status = IkStatus::kConverged;
  int iterations = 0;
  double initial_cost = 0.0;
  double final_cost = 0.0;
  double rms_residual_m = 0.0;  ///< Over the markers used, unweighted.
  int markers_used = 0;
  bool cold_start = false;
  int knees_turned = 0;  ///< Unseen knees turned back toward their axis (KneeSwivel).
};

/// Everything one subject's solve keeps between frames. Sized once at construction;
/// SolveIk never allocates afterwards.
class IkState {
 public:
  IkState(const Skeleton& skeleton, const MarkerSet& markers);

  /// The latest solution (the rest pose before the first solve).
  const Pose& pose() const { return pose_; }
  /// World joint transforms of pose().
  const KinematicsWorkspace& kinematics() const { return ws_; }
  /// Model marker positions for pose(), world frame, metres.
  std::span<const Vec3> predicted_markers() const { return predicted_; }
  bool has_solution() const { return history_ > 0; }
  /// Takes other's solutions (the last two) as this state's, so that the next solve starts
  /// where other's next one will: to solve one frame twice. The knees' learnt axes stay.
  void CopyHistoryFrom(const IkState& other) {
    pose_ = other.pose_;
    previous_ = other.previous_;
    history_ = other.history_;
    ever_solved_ = other.ever_solved_;
  }
  /// Forgets the history: the next solve starts cold (e.g. after a lost subject).
  void Reset();
  /// Seeds the next solve with this pose as if it were the previous solution.
  void Reset(const Pose& pose);

  /// Per-joint elimination storage: the 6x6 quadratic in the joint's world twist and
  /// the blocks that blended (joint + parent) markers add.
  struct JointBlock {
    Mat6 Q, BB, BG, GG, S, K;
    Vec6 b, Br, Gr, k, V;
    Mat3 L = Mat3::Identity();       // ball joints: Cholesky factor of the joint's system...
    Vec3 L_inv_diag = Vec3::Ones();  // ...and the reciprocals of its diagonal
    // Rigidly attached markers, as weighted moments about the pivot: their quadratic is
    // [tr(M2) I - M2, [m1]x; -[m1]x, m0 I] with gradient (sum w x cross r, sum w r).
    Mat3 M2 = Mat3::Zero();
    Vec3 m1 = Vec3::Zero(), xr = Vec3::Zero(), wr = Vec3::Zero();
    double m0 = 0.0;
    int dofs = 0;
    bool has_blend = false;
  };

 private:
  friend IkSummary SolveIk(const Skeleton&, const MarkerSet&, const IkOptions&,
                           std::span<const Vec3>, std::span<const double>, IkState*);
  friend bool ComputeIkStep(const Skeleton&, const MarkerSet&, const IkOptions&,
                            std::span<const Vec3>, std::span<const double>, const Pose&, double,
                            IkState*, Eigen::VectorXd*);
  Pose pose_, previous_, trial_, rest_, cold_best_;
  int history_ = 0;
  bool ever_solved_ = false;  // kept through Reset(): has any pose left this state yet
  KinematicsWorkspace ws_, trial_ws_;
  std::vector<Vec3> predicted_, trial_predicted_, rest_markers_;
  std::vector<JointBlock> blocks_;
  Eigen::VectorXd dq_, step_total_, trial_total_, rest_error_, prior_mask_, prior_h_, prior_g_,
      local_step_;
  int first_free_joint_ = -1;
  KneeSwivel knee_swivel_;
};

/// Solves one frame. observed holds p_WM per marker (metres); weights per marker, 0 for
/// missing (a non-finite observation is also skipped). Warm-starts from the state and
/// leaves the solution in it. Never throws, never allocates; not thread-safe per state.
IkSummary SolveIk(const Skeleton& skeleton, const MarkerSet& markers, const IkOptions& options,
                  std::span<const Vec3> observed, std::span<const double> weights, IkState* state);

/// Computes one damped Gauss-Newton step dq (size num_dofs, local axes as IntegratePose
/// takes it) from `pose`, with the priors centred on `pose` itself. With damping = 0 the
/// step solves  (J'WJ + (a_t + a_r) M) dq = J'W r - a_r M (pose (-) rest)  exactly, M the
/// rotational-DOF mask (rotations about world axes at each joint, which leaves the
/// isotropic priors unchanged); damping > 0 adds Marquardt damping on each joint's
/// reduced diagonal. Uses state only as scratch space. Returns false on a numerical
/// failure. Exposed for tests and diagnostics; SolveIk iterates it.
bool ComputeIkStep(const Skeleton& skeleton, const MarkerSet& markers, const IkOptions& options,
                   std::span<const Vec3> observed, std::span<const double> weights,
                   const Pose& pose, double damping, IkState* state, Eigen::VectorXd* dq);

}  // namespace mocapd
