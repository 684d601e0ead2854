// LBS marker evaluation and its analytic Jacobian.
#include "filters/marker_model.hpp"

#include <cmath>
#include <stdexcept>
#include <unordered_set>

namespace mocapd {

MarkerSet::MarkerSet(const Skeleton& skeleton, std::vector<MarkerDefinition> markers)
    : markers_(std::move(markers)) {
  std::unordered_set<std::string> names;
  for (MarkerDefinition& m : markers_) {
    const std::string where = "marker '" + m.name + "'";
    if (m.name.empty()) throw std::invalid_argument("marker set: a marker has an empty name");
    if (!names.insert(m.name).second)
      throw std::invalid_argument("marker set: " + where + " is repeated");
    if (m.num_attachments < 1 || m.num_attachments > 2)
      throw std::invalid_argument("marker set: " + where + " has " +
                                  std::to_string(m.num_attachments) +
                                  " attachments, expected 1 or 2");
    double sum = 0.0;
    for (int k = 0; k < m.num_attachments; ++k) {
      const MarkerAttachment& a = m.attachments[static_cast<size_t>(k)];
      if (a.joint < 0 || a.joint >= skeleton.num_joints())
        throw std::invalid_argument("marker set: " + where + " is attached to joint index " +
                                    std::to_string(a.joint) + ", expected 0.." +
                                    std::to_string(skeleton.num_joints() - 1));
      if (!(a.weight > 0.0))
        throw std::invalid_argument("marker set: " + where + " has a non-positive weight");
      if (!a.offset.allFinite())
        throw std::invalid_argument("marker set: " + where + " has a non-finite offset");
      sum += a.weight;
    }
    if (std::abs(sum - 1.0) > 1e-6)
      throw std::invalid_argument("marker set: weights of " + where + " sum to " +
                                  std::to_string(sum) + ", expected 1");
    if (m.num_attachments == 2) {
      auto& [first, second] = m.attachments;
      // Normalise to (child, parent): the IK's tree elimination relies on that order.
      if (skeleton.joint(second.joint).parent.value == first.joint) {
        std::swap(first, second);
      } else if (skeleton.joint(first.joint).parent.value != second.joint) {
        throw std::invalid_argument(
            "marker set: " + where + " blends joints '" + skeleton.joint(first.joint).name +
            "' and '" + skeleton.joint(second.joint).name + "', which are not parent and child");
      }
    }
  }
}

std::optional<MarkerIndex> MarkerSet::FindMarker(std::string_view name) const {
  for (size_t m = 0; m < markers_.size(); ++m)
    if (markers_[m].name == name) return MarkerIndex(static_cast<int>(m));
  return std::nullopt;
}

void EvaluateMarkers(const MarkerSet& markers, const KinematicsWorkspace& ws,
                     std::span<Vec3> p_WM) {
  for (int m = 0; m < markers.num_markers(); ++m)
    p_WM[static_cast<size_t>(m)] = EvaluateMarker(markers.marker(m), ws);
}

int JointMotionSubspace(const Skeleton& skeleton, const KinematicsWorkspace& ws, int j,
                        const Vec3& origin, Mat6* S) {
  const Joint& joint = skeleton.joint(j);
  const auto uj = static_cast<size_t>(j);
  const Mat3& R_WJ = ws.R_WJ[uj];
  const Vec3 pivot_from_origin = ws.p_WJ[uj] - origin;
  // A rotation about world axis u through the pivot moves the origin at u x (origin - pivot).
  auto rotation_column = [&](int col, const Vec3& u) {
    S->col(col).head<3>() = u;
    S->col(col).tail<3>() = pivot_from_origin.cross(u);
  };
  switch (joint.type) {
    case JointType::kFixed: return 0;
    case JointType::kHinge: rotation_column(0, R_WJ * joint.hinge_axis); return 1;
    case JointType::kBall:
      for (int i = 0; i < 3; ++i) rotation_column(i, R_WJ.col(i));
      return 3;
    case JointType::kFree: {
      const int parent = joint.parent.value;
      for (int i = 0; i < 3; ++i) {
        S->col(i).head<3>().setZero();
        S->col(i).tail<3>() =
            parent < 0 ? Vec3::Unit(i) : Vec3(ws.R_WJ[static_cast<size_t>(parent)].col(i));
      }
      for (int i = 0; i < 3; ++i) rotation_column(3 + i, R_WJ.col(i));
      return 6;
    }
  }
  return 0;
}

Eigen::MatrixXd MarkerJacobian(const Skeleton& skeleton, const MarkerSet& markers,
                               const KinematicsWorkspace& ws) {
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(3 * markers.num_markers(), skeleton.num_dofs());
  const Vec3 origin = Vec3::Zero();
  Mat6 S;
  for (int m = 0; m < markers.num_markers(); ++m) {
    const MarkerDefinition& def = markers.marker(m);
    for (int k = 0; k < def.num_attachments; ++k) {
      const MarkerAttachment& a = def.attachments[static_cast<size_t>(k)];
      const auto ja = static_cast<size_t>(a.joint);
      const Vec3 x = ws.R_WJ[ja] * a.offset + ws.p_WJ[ja];
      for (int j = a.joint; j >= 0; j = skeleton.joint(j).parent.value) {
        const int n = JointMotionSubspace(skeleton, ws, j, origin, &S);
        for (int c = 0; c < n; ++c) {
          const Vec3 w = S.col(c).head<3>();
          const Vec3 v = S.col(c).tail<3>();
          J.block<3, 1>(3 * m, skeleton.dof_offset(j) + c) += a.weight * (w.cross(x - origin) + v);
        }
      }
    }
  }
  return J;
}

}  // namespace mocapd
