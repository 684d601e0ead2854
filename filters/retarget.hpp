// Live retargeting of a solved actor onto a character of other proportions and
// topology, after Perepichka 2020, ch. 4: both rigs get "skin" points sampled around
// their bones (BVH carries no mesh, so a capsule scaled to each bone stands in for it,
// evenly subsampled by farthest-point sampling, thesis Algorithm 5), corresponding by
// bone and by position along / around the bone. Each frame a warm-started damped
// least-squares IK on the character (thesis Algorithm 6, here the project's LM solver,
// whose temporal prior toward the warm start is the DLS damping) makes
//  - end-effector points (hands, feet, toes, head) track the actor's, positions scaled
//    by the leg-length ratio (the pelvis's standing height, or hip to ankle along the
//    bones for a rig whose rest pose does not stand) about the floor origin;
//  - torso and limb points track the actor's surface normals (the blend mask), through
//    a lever point one normal_lever_m out along each normal, anchored at the target
//    joint's origin as the actor's motion moves it (so no lag and no self-feedback);
//  - feet that the actor has planted stay planted (no sliding) and are released
//    smoothly.
// No per-clip parameters: everything follows from the two rest poses.
#pragma once

#include <array>
#include <memory>
#include <string>
#include <vector>

#include "filters/ik_solver.hpp"

namespace mocapd {

enum class RetargetRegion : uint8_t {
  kEndEffector,  ///< Positions tracked.
  kTorso,        ///< Normals tracked, full weight.
  kLimb,         ///< Normals tracked, lower weight.
};

/// One corresponding bone of the two rigs.
struct RetargetBone {
  std::string role;  ///< e.g. "forearm_l", for reports.
  int source_joint = -1;
  int target_joint = -1;
  Vec3 source_bone = Vec3::UnitY();  ///< Rest pose, world frame: joint origin to segment end.
  Vec3 target_bone = Vec3::UnitY();
  /// The body's forward and left in each rig's rest pose, world frame, as this bone's half
  /// of the body shows them: the angle around the bone is measured from them, so the two
  /// rigs' surface points correspond wherever either rest pose faces and whichever way is up.
  Vec3 source_forward = Vec3::UnitZ(), source_left = Vec3::UnitX();
  Vec3 target_forward = Vec3::UnitZ(), target_left = Vec3::UnitX();
  RetargetRegion region = RetargetRegion::kLimb;
  int foot_side = -1;  ///< 0 left, 1 right for foot and toe bones (contacts); -1 otherwise.
};

struct RetargetMap {
  std::vector<RetargetBone> bones;
  int source_root = 0;  ///< The pelvis joints.
  int target_root = 0;
  double source_leg_length_m = 1.0;  ///< Pelvis standing height, or hip to ankle (bones).
  double target_leg_length_m = 1.0;
  std::array<int, 2> source_ankles{-1, -1};  ///< Per side, for contact detection.
  std::array<int, 2> target_ankles{-1, -1};  ///< Per side: where a planted foot is held.
  /// The world axis the character stands on in its rest pose (+Y unless its rest pose
  /// stands on another): its output is in its own world, whatever the actor's is.
  Vec3 target_up = Vec3::UnitY();
  /// The actor's way up from its hips, in the pelvis's frame: posed, it shows which world
  /// axis the capture stands on (a Vicon capture: +Z).
  Vec3 source_hips_up = Vec3::UnitY();
  std::string report;  ///< Human-readable: what matched what, what was left at rest.
};

/// Whether a character can travel: a joint translates with nothing but fixed joints above
/// it (a root with position channels, or a pelvis under a fixed root). One that cannot is
/// retargeted in place.
bool CharacterTravels(const Skeleton& character);

/// The world axis nearest a direction, signed (+Z for a capture's slightly tilted up).
Vec3 NearestAxis(const Vec3& direction);
/// An axis as "+x", "-z"...: the nearest axis to `direction`.
std::string AxisName(const Vec3& direction);

/// The rotation from the world a posed actor stands in into a rig's: the actor's hips'
/// way up (map.source_hips_up turned by its pelvis, map.source_root, in source_posed),
/// snapped to the nearest axis, onto map.target_up, by the least rotation. A Vicon
/// capture stands on +Z, a BVH rig on +Y.
Mat3 CaptureToTargetWorld(const RetargetMap& map, const KinematicsWorkspace& source_posed);

/// Turns a posed skeleton's world by `world` (positions and orientations both): the root,
/// or where the root is fixed the joints it carries. For writing a solve in the world its
/// rig's rest pose stands in.
void TurnPoseWorld(const Skeleton& skeleton, const Mat3& world, Pose* pose);

struct RetargetOptions {
  double rate_hz = 120.0;
  int points_per_bone = 8;                ///< Kept by farthest-point sampling (of 32 candidates).
  double surface_radius_fraction = 0.15;  ///< Capsule radius / bone length (clamped 2-12 cm).
  double normal_lever_m = 0.10;
  double end_effector_weight = 1.0;
  double torso_weight = 1.0;
  double limb_weight = 0.3;
  double root_weight = 0.5;  ///< The pelvis origin toward the scaled actor pelvis.
  /// DLS damping lambda (m per rad): the IK's pull toward the previous frame's pose,
  /// a_t = lambda^2. The thesis's 5.0 is in its own units; this is ours, chosen on the
  /// benchmark.
  double damping = 0.03;
  /// ...toward the previous pose itself (0), or carried on at this share of its last
  /// frame-to-frame motion. The goals already move with the actor; the solve's own
  /// velocity fed back lets a joint with two near-equal placements swing between them: a
  /// toe of a character whose feet are built otherwise than the actor's turned 8-30
  /// degrees a frame on a planted foot (CMU 01_01 onto Mixamo; Bandai's walk 27 degrees),
  /// 21 at 0.5, and a test rig's 35 degrees a frame at 0.25. At 0 it stays, at the cost
  /// of a lag: 2.8 degrees on the fastest joint of a uniformly scaled rig (under 2 at 1).
  double prediction_velocity_gain = 0.0;
  int max_iterations = 3;
  /// Where a hand goes: the actor's wrist scaled about the floor origin (0), or its reach
  /// from the shoulder, the arm's extension kept as a share of the arm's length, from the
  /// character's own shoulder (1), or between. Scaled alone, a character whose shoulders
  /// sit elsewhere than the actor's must bend an arm the actor holds straight, and a bent
  /// elbow's swivel is left to the arm's weak lever points: the CMU actor's characters
  /// flipped an upper arm 25 degrees a frame. Reach alone keeps the arm but not where the
  /// hand is in the world (a clap, a hand on a hip).
  double hand_reach_share = 0.5;
  // Foot contacts, from the actor's ankle: planted while within contact_height_m of the
  // lowest ankle height seen so far and slower than contact_speed_m_s horizontally
  // (leaving takes 1.5x either). Measured on the 12 Bandai takes: 0.15 m/s holds feet
  // (slide 0.18-0.27 cm per contact) without dragging the body; at 0.2 m/s contacts run
  // into the actor's own foot roll and the end-effector error grows to 1.3 cm.
  double contact_height_m = 0.04;
  double contact_speed_m_s = 0.15;
  /// A lifted foot eases from its lock back onto tracking over this long (it was 8
  /// frames: 67 ms at 120 Hz, but 0.27 s at 30 Hz and 22 ms at 360 Hz).
  double release_s = 0.07;
  double contact_weight_gain = 10.0;  ///< A planted foot's points weigh this much more.
  /// Re-anchoring solves on the first frame (after a reset), at most... (each about 40 us
  /// on a 21-joint rig, 80 us on a 68-joint Mixamo one: a one-off cost on the data plane
  /// at a stream's start; 60 settled a CMU actor's forearm, 100 changed nothing more)
  int first_frame_passes = 60;
  /// ...stopping once a pass moves no joint more than this, nor is estimated to have more
  /// than this still to go.
  double first_frame_settled_m = 1e-4;
  /// Throws std::invalid_argument naming the field.
  void Validate() const;
};

struct RetargetSummary {
  IkSummary ik;
  std::array<bool, 2> planted{false, false};
};

class Retargeter {
 public:
  /// Builds the surface points of both rigs. Throws std::invalid_argument if the map is
  /// empty or names joints outside the skeletons.
  Retargeter(std::shared_ptr<const Skeleton> source, std::shared_ptr<const Skeleton> target,
             RetargetMap map, const RetargetOptions& options);

  /// Retargets one source pose (the actor's solved skeleton). Warm-started from the
  /// previous call; never allocates.
  const Pose& Retarget(const Pose& source_pose);
  const Pose& pose() const { return state_.pose(); }
  const KinematicsWorkspace& kinematics() const { return state_.kinematics(); }
  const RetargetSummary& summary() const { return summary_; }
  const RetargetMap& map() const { return map_; }
  const Skeleton& target() const { return *target_; }
  /// The virtual markers on the target (surface points, normal levers, root) and this
  /// frame's goals and weights for them: for diagnostics.
  const MarkerSet& surface_markers() const { return *markers_; }
  std::span<const Vec3> goals() const { return goals_; }
  std::span<const double> weights() const { return weights_; }
  /// The leg-length ratio target / source.
  double scale() const { return scale_; }
  /// The character has no joint that translates (its root only turns): the actor's pelvis
  /// is held where the character's stands, and the body moves about it (its travel, and
  /// its rise and fall, left out).
  bool in_place() const { return in_place_; }
  /// Forgets the history (contacts, warm start, the actor's world).
  void Reset();
  /// The rotation from the actor's world into the character's, found on the first pose
  /// not at rest (identity until then).
  const Mat3& to_character_world() const { return to_character_world_; }

 private:
  struct SurfacePoint {
    int bone = 0;
    Vec3 source_offset, source_normal, source_axis;  ///< In the source joint's frame.
    double target_along_m = 0.0;                     ///< How far along the target bone.
    int marker = -1;                                 ///< The target's virtual marker for it.
    /// Tracked at the actor's point's scaled position (a foot's or toe's surface point, a
    /// hand's joint origin); otherwise a lever point that turns the bone as the actor's.
    bool position = false;
    /// A hand's origin: the upper arm's joint on each rig (-1: none) and the ratio of the
    /// character's shoulder-to-wrist length to the actor's (RetargetOptions::hand_reach_share).
    int shoulder_source = -1, shoulder_target = -1;
    double arm_ratio = 1.0;
  };
  void ComputeGoals(bool predict);
  void ForgetMotion();
  // The actor's world into the character's: which axis the capture stands on, seen on the
  // first pose not at rest (at rest, a live subject before its first solve, the pose says
  // nothing of the capture).
  void FindCharacterWorld();

  std::shared_ptr<const Skeleton> source_, target_;
  RetargetMap map_;
  RetargetOptions options_;
  double scale_ = 1.0;
  bool in_place_ = false;
  Vec3 target_root_rest_ = Vec3::Zero();  ///< Where an in-place character's pelvis stands.
  std::vector<SurfacePoint> points_;
  std::unique_ptr<MarkerSet> markers_;  ///< Virtual markers on the target.
  int root_marker_ = -1;
  IkOptions ik_, settle_ik_;
  IkState state_;
  KinematicsWorkspace source_fk_;
  std::vector<Vec3> goals_;
  std::vector<Vec3> source_origin_before_;  ///< The actor's joint origins last frame.
  std::vector<Vec3> settle_before_;         ///< The character's joints before a settling pass.
  std::vector<double> weights_, base_weights_;
  // Contacts per side.
  std::array<bool, 2> planted_{false, false};
  std::array<int, 2> since_release_{1 << 20, 1 << 20};
  std::array<Vec3, 2> previous_ankle_{Vec3::Zero(), Vec3::Zero()};
  /// Where a planted foot's reference stays (across the floor: no component along up).
  std::array<Vec3, 2> lock_{Vec3::Zero(), Vec3::Zero()};
  std::array<Vec3, 2> foot_correction_{Vec3::Zero(), Vec3::Zero()};
  std::array<Vec3, 2> release_correction_{Vec3::Zero(), Vec3::Zero()};
  double floor_height_ = 1e9;  ///< The actor's lowest ankle height, along target_up.
  Mat3 to_character_world_ = Mat3::Identity();
  bool world_found_ = false;
  Mat3 source_root_rest_ = Mat3::Identity();  ///< The actor's pelvis at rest, world frame.
  int frames_ = 0;
  RetargetSummary summary_;
};

}  // namespace mocapd
