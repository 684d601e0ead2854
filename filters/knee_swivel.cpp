// Knee swivel: leg chains, the learned knee axis, and the turn (see the header).
#include "filters/knee_swivel.hpp"

#include <algorithm>
#include <cmath>

namespace mocapd {
namespace {

// Below this knee bend the hip-knee-ankle plane, and so the axis, is not defined well.
constexpr double kMinBendRad = 20.0 * M_PI / 180.0;
constexpr double kMinTurnBendRad = 5.0 * M_PI / 180.0;
// A guess (a one-sided fill weighs a hundredth of data in the final solve) shows nothing
// of where the knee is.
constexpr double kSeenWeight = 0.5;

// The knee's bend axis, world frame: the normal of the hip-knee-ankle plane, oriented by
// the bend; zero when the leg is nearly straight.
Vec3 BendAxis(const KinematicsWorkspace& ws, const LegChain& leg, double min_bend = kMinBendRad) {
  const Vec3 thigh = ws.p_WJ[static_cast<size_t>(leg.knee)] - ws.p_WJ[static_cast<size_t>(leg.hip)];
  const Vec3 shin =
      ws.p_WJ[static_cast<size_t>(leg.ankle)] - ws.p_WJ[static_cast<size_t>(leg.knee)];
  const Vec3 normal = thigh.cross(shin);
  const double lengths = thigh.norm() * shin.norm();
  if (lengths <= 0.0 || normal.norm() < std::sin(min_bend) * lengths) return Vec3::Zero();
  return normal.normalized();
}

bool IsBall(const Skeleton& skeleton, int j) { return skeleton.joint(j).type == JointType::kBall; }

}  // namespace

std::vector<LegChain> FindLegChains(const Skeleton& skeleton) {
  std::vector<LegChain> legs;
  int pelvis = 0;
  while (skeleton.children(pelvis).size() == 1) pelvis = skeleton.children(pelvis)[0];
  for (const int start : skeleton.children(pelvis)) {
    std::vector<int> chain{start};
    while (skeleton.children(chain.back()).size() == 1)
      chain.push_back(skeleton.children(chain.back())[0]);
    if (!skeleton.children(chain.back()).empty() || chain.size() < 4) continue;
    const size_t n = chain.size();
    const LegChain leg{chain[n - 4], chain[n - 3], chain[n - 2], chain[n - 1], pelvis};
    if (IsBall(skeleton, leg.hip) && IsBall(skeleton, leg.knee) && IsBall(skeleton, leg.ankle))
      legs.push_back(leg);
  }
  return legs;
}

KneeSwivel::KneeSwivel(const Skeleton& skeleton, const MarkerSet& markers)
    : legs_(FindLegChains(skeleton)) {
  state_.assign(legs_.size(), LegState{});
  marker_leg_.assign(static_cast<size_t>(markers.num_markers()), -1);
  on_foot_.assign(marker_leg_.size(), 0);
  seen_limb_.assign(legs_.size(), 0);
  seen_foot_.assign(legs_.size(), 0);
  for (int m = 0; m < markers.num_markers(); ++m) {
    const int joint = markers.primary_joint(m);
    for (size_t i = 0; i < legs_.size(); ++i) {
      const LegChain& leg = legs_[i];
      if (joint == leg.hip || joint == leg.knee || joint == leg.ankle || joint == leg.toe) {
        marker_leg_[static_cast<size_t>(m)] = static_cast<int>(i);
        on_foot_[static_cast<size_t>(m)] = joint == leg.ankle || joint == leg.toe;
      }
    }
  }
  // In a rest pose with the foot pointing away from the leg, the knee bends toward the
  // toes: its axis is toes x leg. A rest pose with every bone on one line says nothing.
  KinematicsWorkspace rest(skeleton);
  ForwardKinematics(skeleton, RestPose(skeleton), &rest);
  for (size_t i = 0; i < legs_.size(); ++i) {
    const LegChain& leg = legs_[i];
    const Vec3 down =
        rest.p_WJ[static_cast<size_t>(leg.ankle)] - rest.p_WJ[static_cast<size_t>(leg.hip)];
    const Vec3 toes =
        rest.p_WJ[static_cast<size_t>(leg.toe)] - rest.p_WJ[static_cast<size_t>(leg.ankle)];
    const Vec3 axis = toes.cross(down);
    if (axis.norm() >= std::sin(kMinBendRad) * toes.norm() * down.norm() && axis.norm() > 0.0)
      state_[i].rest_axis =
          rest.R_WJ[static_cast<size_t>(leg.ankle)].transpose() * axis.normalized();
  }
}

Vec3 KneeSwivel::AxisInFoot(int leg) const {
  const LegState& s = state_[static_cast<size_t>(leg)];
  if (s.learned_sum.norm() > 0.0) return s.learned_sum.normalized();
  return s.rest_axis;
}

Vec3 KneeSwivel::BorrowedAxisInPelvis(int leg) const {
  const int pelvis = legs_[static_cast<size_t>(leg)].pelvis;
  for (size_t i = 0; i < legs_.size(); ++i)
    if (static_cast<int>(i) != leg && legs_[i].pelvis == pelvis &&
        state_[i].learned_in_pelvis_sum.norm() > 0.0)
      return state_[i].learned_in_pelvis_sum.normalized();
  return Vec3::Zero();
}

int KneeSwivel::Update(const Skeleton& skeleton, std::span<const Vec3> observed,
                       std::span<const double> weights, double tolerance_rad, double max_turn_rad,
                       Pose* pose, KinematicsWorkspace* ws, Pose* previous) {
  if (legs_.empty()) return 0;
  std::fill(seen_limb_.begin(), seen_limb_.end(), 0);
  std::fill(seen_foot_.begin(), seen_foot_.end(), 0);
  for (size_t m = 0; m < marker_leg_.size(); ++m) {
    const int leg = marker_leg_[m];
    if (leg < 0 || !(weights[m] >= kSeenWeight) || !observed[m].allFinite()) continue;
    ++(on_foot_[m] ? seen_foot_ : seen_limb_)[static_cast<size_t>(leg)];
  }
  // Every seen leg learns before any unseen one is turned: a leg unseen from the take's
  // first frame borrows the other's axis from that frame on (it was learned only after
  // the unseen leg had been passed over, and a running knee stayed 30 cm behind the leg).
  for (size_t i = 0; i < legs_.size(); ++i) {
    if (seen_limb_[i] < 2) continue;
    const LegChain& leg = legs_[i];
    const Vec3 axis = BendAxis(*ws, leg, kMinBendRad);
    if (axis.norm() == 0.0) continue;
    state_[i].learned_sum += ws->R_WJ[static_cast<size_t>(leg.ankle)].transpose() * axis;
    state_[i].learned_in_pelvis_sum += ws->R_WJ[static_cast<size_t>(leg.pelvis)].transpose() * axis;
  }
  int turned = 0;
  for (size_t i = 0; i < legs_.size(); ++i) {
    if (seen_limb_[i] > 0 || seen_foot_[i] < 2 || tolerance_rad <= 0.0) continue;
    const LegChain& leg = legs_[i];
    // A nearly straight unseen knee is still kept to its side: it bends from there.
    const Vec3 axis = BendAxis(*ws, leg, kMinTurnBendRad);
    if (axis.norm() == 0.0) continue;
    const Mat3& R_WA = ws->R_WJ[static_cast<size_t>(leg.ankle)];
    const Mat3& R_W_pelvis = ws->R_WJ[static_cast<size_t>(leg.pelvis)];
    const Vec3 own = AxisInFoot(static_cast<int>(i));
    const Vec3 wanted_world = own.norm() > 0.0
                                  ? Vec3(R_WA * own)
                                  : Vec3(R_W_pelvis * BorrowedAxisInPelvis(static_cast<int>(i)));
    if (wanted_world.norm() == 0.0) continue;
    const Vec3 hip = ws->p_WJ[static_cast<size_t>(leg.hip)];
    const Vec3 line = (ws->p_WJ[static_cast<size_t>(leg.ankle)] - hip).normalized();
    // The axis the foot (or the pelvis) asks for, in the plane the knee can turn in.
    Vec3 wanted = wanted_world;
    wanted -= line * line.dot(wanted);
    if (wanted.norm() < 0.5) continue;  // the foot's axis lies near the leg: no say
    wanted.normalize();
    const double off = std::atan2(line.dot(axis.cross(wanted)), axis.dot(wanted));
    if (std::abs(off) <= tolerance_rad) continue;
    double turn = off - std::copysign(tolerance_rad, off);
    if (max_turn_rad > 0.0) turn = std::clamp(turn, -max_turn_rad, max_turn_rad);
    // Turn the thigh about the hip-ankle line; the ankle stays put, and the foot is given
    // back the world orientation it had.
    const Mat3 R_turn = Eigen::AngleAxisd(turn, line).toRotationMatrix();
    const int parent = skeleton.joint(leg.hip).parent.value;
    const Mat3 R_WP = parent >= 0 ? ws->R_WJ[static_cast<size_t>(parent)] : Mat3::Identity();
    const Mat3 R_WH = R_turn * ws->R_WJ[static_cast<size_t>(leg.hip)];
    const Mat3 R_WK = R_WH * pose->rotation[static_cast<size_t>(leg.knee)].toRotationMatrix();
    const Quat hip_before = pose->rotation[static_cast<size_t>(leg.hip)];
    const Quat ankle_before = pose->rotation[static_cast<size_t>(leg.ankle)];
    pose->rotation[static_cast<size_t>(leg.hip)] = Quat(R_WP.transpose() * R_WH).normalized();
    pose->rotation[static_cast<size_t>(leg.ankle)] = Quat(R_WK.transpose() * R_WA).normalized();
    if (previous != nullptr) {
      previous->rotation[static_cast<size_t>(leg.hip)] =
          (pose->rotation[static_cast<size_t>(leg.hip)] * hip_before.conjugate() *
           previous->rotation[static_cast<size_t>(leg.hip)])
              .normalized();
      previous->rotation[static_cast<size_t>(leg.ankle)] =
          (pose->rotation[static_cast<size_t>(leg.ankle)] * ankle_before.conjugate() *
           previous->rotation[static_cast<size_t>(leg.ankle)])
              .normalized();
    }
    ForwardKinematics(skeleton, *pose, ws);
    ++turned;
  }
  return turned;
}

}  // namespace mocapd
