// The linear-blend-skinning (LBS) marker model: each marker rides on one joint, or
// on a blend of a joint and its parent, at fixed local offsets. Evaluates marker
// positions for a pose and their analytic Jacobian with respect to the pose step.
//
// p_WM = sum_k w_k (R_WJk * p_JkM + p_WJk), sum_k w_k = 1
// (Magnenat-Thalmann et al., "Joint-dependent local deformations", 1988; the thesis
// ch. 3 uses the same X = LBS(Y, offsets, weights)).
#pragma once

#include <array>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "filters/skeleton.hpp"

namespace mocapd {

struct MarkerAttachment {
  int joint = -1;
  double weight = 1.0;
  Vec3 offset = Vec3::Zero();  ///< p_JM: the marker in the joint's frame, metres.
};

struct MarkerDefinition {
  std::string name;
  int num_attachments = 1;  ///< 1, or 2 for a blend of a joint (first) and its parent (second).
  std::array<MarkerAttachment, 2> attachments;
};

/// An immutable marker set bound to one skeleton.
class MarkerSet {
 public:
  /// Validates and builds the set. Throws std::invalid_argument naming the marker if a
  /// name is empty or repeated, a joint index is out of range, a blend is not between a
  /// joint and its parent (either order is accepted and normalised), a weight is not
  /// positive, or the weights do not sum to 1.
  MarkerSet(const Skeleton& skeleton, std::vector<MarkerDefinition> markers);

  int num_markers() const { return static_cast<int>(markers_.size()); }
  const MarkerDefinition& marker(int m) const { return markers_[static_cast<size_t>(m)]; }
  std::span<const MarkerDefinition> markers() const { return markers_; }
  std::optional<MarkerIndex> FindMarker(std::string_view name) const;
  /// The joint whose motion carries the marker the most (its first attachment).
  int primary_joint(int m) const { return marker(m).attachments[0].joint; }

 private:
  std::vector<MarkerDefinition> markers_;
};

/// Writes p_WM for every marker (out.size() == num_markers). Does not allocate.
void EvaluateMarkers(const MarkerSet& markers, const KinematicsWorkspace& ws, std::span<Vec3> p_WM);

/// Returns p_WM for one marker. Does not allocate. Inline: it is the innermost loop of
/// every IK iteration.
inline Vec3 EvaluateMarker(const MarkerDefinition& marker, const KinematicsWorkspace& ws) {
  const MarkerAttachment& a = marker.attachments[0];
  const auto j = static_cast<size_t>(a.joint);
  Vec3 p = ws.R_WJ[j] * a.offset + ws.p_WJ[j];
  if (marker.num_attachments == 1) return p;
  const MarkerAttachment& b = marker.attachments[1];
  const auto k = static_cast<size_t>(b.joint);
  return a.weight * p + b.weight * (ws.R_WJ[k] * b.offset + ws.p_WJ[k]);
}

/// Writes the world-frame twists of joint j's DOF into the first DofCount columns of S.
/// A twist is (angular velocity; velocity of the world point `origin`), so a point x
/// moving with the joint moves at  w x (x - origin) + v  per unit DOF. Returns the DOF count.
int JointMotionSubspace(const Skeleton& skeleton, const KinematicsWorkspace& ws, int j,
                        const Vec3& origin, Mat6* S);

/// Computes the dense Jacobian d p_WM / d dq (3 * num_markers rows, num_dofs columns) of
/// the markers with respect to an IntegratePose step. Allocates; for tests, calibration
/// and diagnostics, not the per-frame path.
Eigen::MatrixXd MarkerJacobian(const Skeleton& skeleton, const MarkerSet& markers,
                               const KinematicsWorkspace& ws);

}  // namespace mocapd
