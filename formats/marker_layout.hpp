// Virtual marker sets on any humanoid skeleton: finds the body segments by joint name
// (Bandai, CMU, Mixamo, Unreal naming) and the tree structure, then places a
// production-like layout (~55-60 markers, >= 3 per major segment, 3-8 cm off the bone,
// not mirror-symmetric, knee and elbow markers blended across the joint).
#pragma once

#include <map>
#include <span>
#include <string>
#include <vector>

#include "filters/marker_model.hpp"
#include "formats/bvh.hpp"

namespace mocapd {

/// One marker of a layout, placed relative to a segment's bone.
struct LayoutMarker {
  std::string name;
  std::string segment;         ///< A role (pelvis, chest, thigh_l ...) or an exact joint name.
  double along = 0.5;          ///< Position along the bone, as a fraction of its length.
  double angle_deg = 0.0;      ///< Direction around the bone.
  double radius_m = 0.05;      ///< Distance off the bone axis.
  double parent_weight = 0.0;  ///< > 0: blend with the segment's parent joint (near a joint).
};

/// The built-in layout (see marker_layout.cpp for the list).
std::vector<LayoutMarker> DefaultMarkerLayout();

/// Reads a layout from TOML ([[marker]] tables with name, segment, along, angle_deg,
/// radius_m, optional parent_weight). Throws std::runtime_error naming file, line, field.
std::vector<LayoutMarker> ReadMarkerLayout(const std::string& path);

/// Body segments found on a skeleton: role name -> joint index.
struct HumanoidRoles {
  std::map<std::string, int> joint_of_role;
  /// Joints strictly between pelvis and neck, bottom first; none that sits on its parent,
  /// unless leaving those out would leave a single joint.
  std::vector<int> spine_chain;
  /// One line per role: "thigh_l -> UpperLeg_L".
  std::string Describe(const Skeleton& skeleton) const;
};

/// Finds the roles on a humanoid skeleton. Throws std::invalid_argument listing the
/// required roles that could not be found (pelvis, head, and per side: upper_arm,
/// forearm, hand, thigh, shin, foot).
HumanoidRoles MatchHumanoidRoles(const Skeleton& skeleton);

/// The bone of a role's segment: the vector, in the rest pose's world frame, from the
/// role's joint to where its segment ends (the next joint along the limb or spine, an End
/// Site, or a nominal length along the parent's bone scaled by height / 1.75 m).
/// is_nominal (if given) is set to whether it is that nominal guess.
Vec3 SegmentBoneWorld(const Skeleton& skeleton, const HumanoidRoles& roles,
                      const KinematicsWorkspace& rest, std::span<const BvhEndSite> end_sites,
                      const std::string& role, int joint, double height, bool* nominal = nullptr);

/// One End Site per leaf joint (a joint with no child), continuing its segment as
/// SegmentBoneWorld would with no End Site: the nominal length of a head, hand, toe or
/// foot (0.08 m otherwise) scaled by the rest pose's height, along its parent's bone. A
/// BVH closes every leaf with one, and read back these give the same marker placement as
/// having none. Never throws: a skeleton that is no humanoid gets the 0.08 m length.
std::vector<BvhEndSite> NominalLeafEndSites(const Skeleton& skeleton);

/// Places a layout on the skeleton's rest pose. end_sites (may be empty) give bone
/// directions for end segments. Throws std::invalid_argument naming the marker whose
/// segment is unknown. Markers on optional roles the skeleton lacks are skipped.
std::vector<MarkerDefinition> PlaceMarkers(const Skeleton& skeleton, const HumanoidRoles& roles,
                                           std::span<const LayoutMarker> layout,
                                           std::span<const BvhEndSite> end_sites);

}  // namespace mocapd
