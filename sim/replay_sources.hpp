// What the replay simulator plays: a take's markers in a subject's marker order, with the
// ground truth when it is known (the built-in humanoid, a BVH whose markers are
// synthesized) or without it (a recorded C3D).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "filters/marker_model.hpp"
#include "formats/c3d.hpp"
#include "sim/motion_graph.hpp"

namespace mocapd {

/// What to replay: markers in the subject's order, plus the truth when it is known.
struct ReplaySource {
  std::string description;
  std::shared_ptr<const Skeleton> skeleton;
  std::shared_ptr<const MarkerSet> markers;
  C3dTake take;
  std::vector<Pose> truth;  ///< Empty for a recorded C3D.
  double rate_hz = 120.0;
};

/// The built-in humanoid (config/demo_subject.toml) doing motion for seconds.
ReplaySource HumanoidReplaySource(const std::string& motion, double seconds, double rate_hz,
                                  double noise_mm, uint64_t seed);
/// A BVH: markers synthesized on the fly from its motion (default layout), resampled to
/// rate_hz (0: the file's rate); the truth is the motion.
ReplaySource BvhReplaySource(const std::string& path, double rate_hz, const std::string& units);
/// A recorded C3D: markers matched by label to the subject's (subject_path, or the
/// built-in humanoid when empty), or with marker_set (a built-in set's name or a set file),
/// sent in the set's order: what a daemon calibrating that subject live expects.
ReplaySource C3dReplaySource(const std::string& path, const std::string& subject_path,
                             const std::string& marker_set = "");

/// What a motion-graph stream plays: endless random walks over a graph (one per actor),
/// markers synthesized on the library's skeleton, the walk itself the truth.
struct GraphReplaySource {
  std::string description;
  std::shared_ptr<const MotionLibrary> library;
  std::shared_ptr<const MotionGraph> graph;
  std::shared_ptr<const MarkerSet> markers;
};

/// The markers a graph stream synthesizes on a library of takes: the default layout on
/// its skeleton (what `graph build --subject-out` writes for the daemon).
std::shared_ptr<const MarkerSet> GraphMarkers(const MotionLibrary& library);

/// "humanoid": a graph over the built-in humanoid's walk, turn, reach and mixed motion
/// (config/demo_subject.toml's skeleton and markers, so the demo daemon takes it); else a
/// graph file (markers: the default layout on the takes' skeleton, as for a BVH replay).
GraphReplaySource GraphSource(const std::string& graph);

}  // namespace mocapd
