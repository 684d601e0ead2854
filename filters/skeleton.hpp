// The immutable skeleton model (joints, parents, rest offsets, rotational DOF),
// the per-frame pose, and forward kinematics into a per-subject workspace.
//
// Frames: X_PJ, the pose of joint J in its parent P, is
//   p_PJ = (type == kFree ? pose.translation[J] : joint.offset),
//   R_PJ = pose.rotation[J].
// World quantities are suffixed _W: R_WJ = R_WP * R_PJ, p_WJ = p_WP + R_WP * p_PJ.
// Units are SI (metres, radians).
#pragma once

#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "filters/types.hpp"

namespace mocapd {

enum class JointType {
  kFixed,  ///< No DOF: rotation stays at the pose's value (rest rotation by default).
  kHinge,  ///< One rotational DOF about hinge_axis (joint frame).
  kBall,   ///< Three rotational DOF.
  kFree,   ///< Three translational DOF (in the parent frame) plus three rotational.
};

const char* to_string(JointType type);

/// Returns the number of velocity DOF a joint of this type contributes (0, 1, 3 or 6).
int DofCount(JointType type);

struct Joint {
  std::string name;
  JointIndex parent;           ///< Invalid for the root.
  Vec3 offset = Vec3::Zero();  ///< Rest translation of the joint origin in the parent frame, m.
  Quat rest_rotation = Quat::Identity();
  JointType type = JointType::kBall;
  Vec3 hinge_axis = Vec3::UnitX();  ///< Unit axis in the joint frame, used when type == kHinge.
  /// Joint-limit hook: the rotation's angle away from rest_rotation is clamped to this (rad).
  double max_angle_rad = 1e9;
};

/// An immutable kinematic tree. Joints are stored parents-first (parent index < child
/// index), which every algorithm relies on to sweep the tree with a plain loop.
class Skeleton {
 public:
  /// Validates and builds a skeleton. Throws std::invalid_argument if joints is empty,
  /// a name is empty or repeated, a parent index does not precede its child, there is not
  /// exactly one root, or a hinge axis is not unit length.
  explicit Skeleton(std::vector<Joint> joints);

  int num_joints() const { return static_cast<int>(joints_.size()); }
  const Joint& joint(int j) const { return joints_[static_cast<size_t>(j)]; }
  std::span<const Joint> joints() const { return joints_; }
  /// Total velocity DOF (the IK step size): the sum of DofCount over joints.
  int num_dofs() const { return num_dofs_; }
  /// Index of the joint's first DOF in the step vector.
  int dof_offset(int j) const { return dof_offset_[static_cast<size_t>(j)]; }
  const std::vector<int>& children(int j) const { return children_[static_cast<size_t>(j)]; }
  /// Returns the joint with this exact name, if any.
  std::optional<JointIndex> FindJoint(std::string_view name) const;
  /// True if a is b or an ancestor of b.
  bool IsAncestorOrSelf(int a, int b) const;

 private:
  std::vector<Joint> joints_;
  std::vector<int> dof_offset_;
  std::vector<std::vector<int>> children_;
  int num_dofs_ = 0;
};

/// One frame of joint configuration. Rotations are local (R_PJ); translations are
/// meaningful only for kFree joints and are in the parent frame, metres.
struct Pose {
  std::vector<Quat> rotation;
  std::vector<Vec3> translation;
};

/// Returns the rest pose: rest rotations, rest offsets as translations.
Pose RestPose(const Skeleton& skeleton);

/// Per-subject storage for forward kinematics, sized once from the skeleton.
struct KinematicsWorkspace {
  explicit KinematicsWorkspace(const Skeleton& skeleton);
  std::vector<Mat3> R_WJ;
  std::vector<Vec3> p_WJ;
};

/// Computes every joint's world rotation and position. Does not allocate.
/// Precondition: pose and workspace were sized for this skeleton.
void ForwardKinematics(const Skeleton& skeleton, const Pose& pose, KinematicsWorkspace* ws);

/// Returns p_PJ for joint j in this pose (free translation or fixed offset).
inline const Vec3& LocalTranslation(const Skeleton& skeleton, const Pose& pose, int j) {
  return skeleton.joint(j).type == JointType::kFree ? pose.translation[static_cast<size_t>(j)]
                                                    : skeleton.joint(j).offset;
}

/// Applies a step dq (size num_dofs) to the pose with the exponential map: for each joint,
/// R_PJ <- R_PJ * Exp(rotation part), translation += translation part. Does not allocate.
void IntegratePose(const Skeleton& skeleton, const Eigen::Ref<const Eigen::VectorXd>& dq,
                   Pose* pose);

/// Writes into dq (size num_dofs) the step that takes pose a to pose b: the inverse of
/// IntegratePose. Does not allocate.
void PoseDifference(const Skeleton& skeleton, const Pose& a, const Pose& b,
                    Eigen::Ref<Eigen::VectorXd> dq);

/// Clamps every joint's rotation to its max_angle_rad away from its rest rotation.
void ApplyJointLimits(const Skeleton& skeleton, Pose* pose);

}  // namespace mocapd
