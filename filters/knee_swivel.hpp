// Which way a knee points when nothing on the thigh or shin is seen. With the hip and a
// seen foot fixed, the knee may sit anywhere on a circle about the hip-ankle line, and no
// marker cost tells the places apart: a warm start drifts round it over a long gap, and a
// cold start may put the knee behind the leg. Anatomy fixes it: the knee and the ankle
// are nearly parallel hinges, so the knee's bend axis is nearly constant in the foot's
// frame (within 15 degrees in most bent frames of the twelve Bandai takes, 70 at worst
// in a dance; bench/README.md). Each leg learns that axis wherever its thigh or shin is seen and
// bent; before it has, a rest pose whose toes point away from the leg gives it (the knee bends
// toward the toes), or failing that, the other leg's, taken in the pelvis (both knees bend
// about the body's left-right axis). An unseen knee whose axis strays further than a tolerance is
// turned about the hip-ankle line back to the tolerance, its foot keeping its world orientation.
#pragma once

#include <span>
#include <vector>

#include "filters/marker_model.hpp"
#include "filters/skeleton.hpp"

namespace mocapd {

/// A leg: hip, knee, ankle and toe joints, each the only child of the one before, and the
/// joint the leg's chain branches from (the pelvis, shared by both legs even where a hip
/// hangs from a joint of its own, as in CMU's LHipJoint).
struct LegChain {
  int hip = -1, knee = -1, ankle = -1, toe = -1;
  int pelvis = -1;
};

/// The skeleton's legs: the unbranched chains, ending in a leaf, that hang from the
/// root-most branching joint (the pelvis; arms hang from the chest), at least four joints
/// long; the last four are hip, knee, ankle and toe. A chain whose hip, knee or ankle is
/// not a ball joint is left out (a hinge knee bends one way already).
std::vector<LegChain> FindLegChains(const Skeleton& skeleton);

class KneeSwivel {
 public:
  /// Sized once here; Update never allocates.
  KneeSwivel(const Skeleton& skeleton, const MarkerSet& markers);

  /// After a solve: learns each leg whose thigh or shin has at least two usable markers
  /// seen (weight >= 0.5: a one-sided fill's weight is a guess's) and whose knee is bent;
  /// turns each leg with none there, two seen foot markers and a known axis (its own, or
  /// failing that another leg's in the pelvis: BorrowedAxisInPelvis), if its axis
  /// is more than tolerance_rad off (tolerance <= 0: only learns), toward the tolerance by
  /// at most max_turn_rad (0: all the way). Updates pose and ws, and turns `previous` (the
  /// solve's last pose, which its velocity prediction uses) alike: a turn is no motion to
  /// carry into the next frame. Returns how many legs were turned.
  int Update(const Skeleton& skeleton, std::span<const Vec3> observed,
             std::span<const double> weights, double tolerance_rad, double max_turn_rad, Pose* pose,
             KinematicsWorkspace* ws, Pose* previous = nullptr);

  int num_legs() const { return static_cast<int>(legs_.size()); }
  const LegChain& leg(int i) const { return legs_[static_cast<size_t>(i)]; }
  /// The leg's knee bend axis in its foot's (ankle joint's) frame, unit; zero if unknown.
  Vec3 AxisInFoot(int leg) const;
  /// For a leg with no axis of its own: another leg's learned axis in the frame of the
  /// joint both branch from (LegChain::pelvis), unit; zero if no leg sharing it has
  /// learned one.
  Vec3 BorrowedAxisInPelvis(int leg) const;

 private:
  struct LegState {
    Vec3 learned_sum = Vec3::Zero();            // sum of unit axes seen, foot frame...
    Vec3 learned_in_pelvis_sum = Vec3::Zero();  // ...and in the hip's parent's frame
    Vec3 rest_axis = Vec3::Zero();              // from the rest pose, unit, or zero
  };
  std::vector<LegChain> legs_;
  std::vector<LegState> state_;
  std::vector<int> marker_leg_;   // per marker: the leg it is on, or -1
  std::vector<uint8_t> on_foot_;  // per marker: on the ankle or toe (else thigh or shin)
  std::vector<int> seen_limb_, seen_foot_;
};

}  // namespace mocapd
