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

}  // namespace mocapd
