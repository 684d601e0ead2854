// Retrieval on a motion graph: the graph path that best follows a query motion, of any
// humanoid skeleton ("drive the library with this performance"). Poses are compared by
// role (pelvis, limbs, head: found by name on both rigs), in each body's own heading
// frame and scaled by its leg length, with their velocities. A trellis over every graph
// frame per query frame, with steps that play on in a take or blend through a graph
// transition, is solved for the shortest path: retrieval cost plus transition cost.
#pragma once

#include <vector>

#include "formats/bvh.hpp"
#include "sim/motion_graph.hpp"

namespace mocapd {

struct MatchOptions {
  /// What a blend costs beyond its frames' retrieval cost, per unit of its distortion
  /// (distortion / leg length, counted over the blend's frames).
  double transition_weight = 1.0;
  double velocity_weight_s = 0.1;
};

struct MatchResult {
  GraphPath path;
  int query_frames = 0;  ///< At the graph's rate.
  int jumps = 0;         ///< Blends taken.
  /// Mean over frames and roles of |v_query - v_retrieved|, each body's joints in its own
  /// heading frame, at the graph's rate, in the query's scale: cm per frame.
  double velocity_difference_cm = 0.0;
  double worst_velocity_difference_cm = 0.0;  ///< The worst frame's mean over roles.
};

/// Throws std::invalid_argument naming the missing roles if either skeleton is not a
/// recognisable humanoid, or if the query is shorter than 2 frames.
MatchResult MatchQuery(const MotionLibrary& library, const MotionGraph& graph, const BvhTake& query,
                       const MatchOptions& options = {});

}  // namespace mocapd
