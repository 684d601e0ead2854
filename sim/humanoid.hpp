// The project's own humanoid: a 21-joint skeleton (Y up, metres, T-pose at rest) and
// procedural motion (walk, reach, turn), so tests, benchmarks and the demo need no
// outside data.
#pragma once

#include <string>
#include <vector>

#include "filters/skeleton.hpp"

namespace mocapd {

/// Returns the humanoid skeleton scaled to the given standing height (metres).
/// Joint names follow the Mixamo/CMU convention (Hips, LeftUpLeg, LeftArm, ...).
Skeleton MakeHumanoidSkeleton(double height_m = 1.75);

/// kRom: a calibration's range of motion (hip star arcs, knee bends, shoulder circles,
/// elbow bends, trunk twists, nods, ankle circles), standing in place.
enum class HumanoidMotion { kWalk, kReach, kTurn, kMixed, kRom };
/// Parses walk|reach|turn|mixed|rom; throws std::invalid_argument otherwise.
HumanoidMotion ParseHumanoidMotion(const std::string& name);

/// Generates `seconds` of motion at `rate_hz` for MakeHumanoidSkeleton's skeleton.
/// Deterministic; kMixed walks, turns and reaches in one take.
std::vector<Pose> MakeHumanoidMotion(const Skeleton& skeleton, HumanoidMotion motion,
                                     double seconds, double rate_hz);

}  // namespace mocapd
