// Matching an actor's skeleton to a character's for retargeting: humanoid roles found by
// name on both rigs (CMU, Bandai, Mixamo, Unreal mannequin and similar schemes; see
// MatchHumanoidRoles), optional per-role overrides from config, each matched role a
// corresponding bone with its region (end effector, torso or limb), and a report.
#pragma once

#include <map>
#include <span>
#include <string>

#include "filters/retarget.hpp"
#include "formats/bvh.hpp"

namespace mocapd {

/// overrides: role (e.g. "hand_l", "chest") -> character joint name. Throws
/// std::invalid_argument naming what is missing (a rig that is not a humanoid, an
/// override naming an unknown joint or role).
RetargetMap MakeRetargetMap(const Skeleton& source, std::span<const BvhEndSite> source_end_sites,
                            const Skeleton& target, std::span<const BvhEndSite> target_end_sites,
                            const std::map<std::string, std::string>& overrides = {});

/// Where a retargeted character goes: a BVH file, or the wire, whose local block carries
/// joint 0's translation only (see protocol/README.md).
enum class CharacterOutput { kFile, kWire };

/// The skeleton a character file gives the retargeter. A file of one frame (or none)
/// shows no motion, so its reader types the joints by their channels: the top joint with
/// position channels translates. Above a pelvis with position channels of its own
/// (Bandai's floor-level joint_Root over its Hips), that put the character's travel on a
/// joint its own takes keep still, the Hips held metres from it; for a file, the pelvis
/// translates instead (the retargeter then holds the joints above it at rest). A file
/// whose motion never moves its pelvis types it a fixed frame or a ball; where that leaves
/// no joint that translates, the pelvis does if it has position channels (for the wire,
/// only when it is joint 0).
Skeleton CharacterSkeleton(const BvhTake& character,
                           CharacterOutput output = CharacterOutput::kFile);

}  // namespace mocapd
