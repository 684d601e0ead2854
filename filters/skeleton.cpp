// Skeleton validation, forward kinematics and exponential-map pose updates.
#include "filters/skeleton.hpp"

#include <stdexcept>
#include <unordered_set>

#include "filters/rotation.hpp"

namespace mocapd {

const char* to_string(JointType type) {
  switch (type) {
    case JointType::kFixed: return "fixed";
    case JointType::kHinge: return "hinge";
    case JointType::kBall: return "ball";
    case JointType::kFree: return "free";
  }
  return "?";
}

int DofCount(JointType type) {
  switch (type) {
    case JointType::kFixed: return 0;
    case JointType::kHinge: return 1;
    case JointType::kBall: return 3;
    case JointType::kFree: return 6;
  }
  return 0;
}

Skeleton::Skeleton(std::vector<Joint> joints) : joints_(std::move(joints)) {
  if (joints_.empty()) throw std::invalid_argument("skeleton: no joints");
  std::unordered_set<std::string> names;
  int roots = 0;
  children_.resize(joints_.size());
  for (size_t j = 0; j < joints_.size(); ++j) {
    const Joint& joint = joints_[j];
    if (joint.name.empty())
      throw std::invalid_argument("skeleton: joint " + std::to_string(j) + " has an empty name");
    if (!names.insert(joint.name).second)
      throw std::invalid_argument("skeleton: joint name '" + joint.name + "' is repeated");
    if (!joint.parent.is_valid()) {
      ++roots;
      if (j != 0)
        throw std::invalid_argument("skeleton: joint '" + joint.name +
                                    "' has no parent but is not the first joint");
    } else {
      if (joint.parent.value >= static_cast<int>(j))
        throw std::invalid_argument("skeleton: joint '" + joint.name + "' has parent index " +
                                    std::to_string(joint.parent.value) +
                                    ", expected a joint listed before it");
      children_[static_cast<size_t>(joint.parent.value)].push_back(static_cast<int>(j));
    }
    if (joint.type == JointType::kHinge && std::abs(joint.hinge_axis.norm() - 1.0) > 1e-9)
      throw std::invalid_argument("skeleton: hinge axis of joint '" + joint.name +
                                  "' is not unit length");
    if (!joint.offset.allFinite())
      throw std::invalid_argument("skeleton: joint '" + joint.name + "' has a non-finite offset");
    dof_offset_.push_back(num_dofs_);
    num_dofs_ += DofCount(joint.type);
  }
  if (roots != 1)
    throw std::invalid_argument("skeleton: expected exactly one root joint, found " +
                                std::to_string(roots));
}

std::optional<JointIndex> Skeleton::FindJoint(std::string_view name) const {
  for (size_t j = 0; j < joints_.size(); ++j)
    if (joints_[j].name == name) return JointIndex(static_cast<int>(j));
  return std::nullopt;
}

bool Skeleton::IsAncestorOrSelf(int a, int b) const {
  for (int j = b; j >= 0; j = joints_[static_cast<size_t>(j)].parent.value)
    if (j == a) return true;
  return false;
}

Pose RestPose(const Skeleton& skeleton) {
  Pose pose;
  pose.rotation.reserve(static_cast<size_t>(skeleton.num_joints()));
  pose.translation.reserve(static_cast<size_t>(skeleton.num_joints()));
  for (const Joint& joint : skeleton.joints()) {
    pose.rotation.push_back(joint.rest_rotation);
    pose.translation.push_back(joint.offset);
  }
  return pose;
}

KinematicsWorkspace::KinematicsWorkspace(const Skeleton& skeleton)
    : R_WJ(static_cast<size_t>(skeleton.num_joints()), Mat3::Identity()),
      p_WJ(static_cast<size_t>(skeleton.num_joints()), Vec3::Zero()) {}

void ForwardKinematics(const Skeleton& skeleton, const Pose& pose, KinematicsWorkspace* ws) {
  const int n = skeleton.num_joints();
  for (int j = 0; j < n; ++j) {
    const auto uj = static_cast<size_t>(j);
    const Mat3 R_PJ = pose.rotation[uj].toRotationMatrix();
    const Vec3& p_PJ = LocalTranslation(skeleton, pose, j);
    const int parent = skeleton.joint(j).parent.value;
    if (parent < 0) {
      ws->R_WJ[uj] = R_PJ;
      ws->p_WJ[uj] = p_PJ;
    } else {
      const auto up = static_cast<size_t>(parent);
      ws->R_WJ[uj].noalias() = ws->R_WJ[up] * R_PJ;
      ws->p_WJ[uj] = ws->p_WJ[up] + ws->R_WJ[up] * p_PJ;
    }
  }
}

void IntegratePose(const Skeleton& skeleton, const Eigen::Ref<const Eigen::VectorXd>& dq,
                   Pose* pose) {
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    const Joint& joint = skeleton.joint(j);
    const auto uj = static_cast<size_t>(j);
    const int k = skeleton.dof_offset(j);
    switch (joint.type) {
      case JointType::kFixed: break;
      case JointType::kHinge:
        pose->rotation[uj] =
            (pose->rotation[uj] * ExpRotation(joint.hinge_axis * dq[k])).normalized();
        break;
      case JointType::kBall:
        pose->rotation[uj] = (pose->rotation[uj] * ExpRotation(dq.segment<3>(k))).normalized();
        break;
      case JointType::kFree:
        pose->translation[uj] += dq.segment<3>(k);
        pose->rotation[uj] = (pose->rotation[uj] * ExpRotation(dq.segment<3>(k + 3))).normalized();
        break;
    }
  }
}

void PoseDifference(const Skeleton& skeleton, const Pose& a, const Pose& b,
                    Eigen::Ref<Eigen::VectorXd> dq) {
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    const Joint& joint = skeleton.joint(j);
    const auto uj = static_cast<size_t>(j);
    const int k = skeleton.dof_offset(j);
    const Vec3 w = LogRotation(a.rotation[uj].conjugate() * b.rotation[uj]);
    switch (joint.type) {
      case JointType::kFixed: break;
      case JointType::kHinge: dq[k] = joint.hinge_axis.dot(w); break;
      case JointType::kBall: dq.segment<3>(k) = w; break;
      case JointType::kFree:
        dq.segment<3>(k) = b.translation[uj] - a.translation[uj];
        dq.segment<3>(k + 3) = w;
        break;
    }
  }
}

void ApplyJointLimits(const Skeleton& skeleton, Pose* pose) {
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    const Joint& joint = skeleton.joint(j);
    if (joint.type == JointType::kFixed || joint.max_angle_rad >= 1e8) continue;
    const auto uj = static_cast<size_t>(j);
    const Vec3 w = LogRotation(joint.rest_rotation.conjugate() * pose->rotation[uj]);
    const double angle = w.norm();
    if (angle > joint.max_angle_rad)
      pose->rotation[uj] = joint.rest_rotation * ExpRotation(w * (joint.max_angle_rad / angle));
  }
}

}  // namespace mocapd
