// Endless motion from a motion graph: a seeded random walk over the graph's largest
// strongly connected part (from there every branch point can be left again, so the walk
// never runs into the end of a take), kept near the origin by preferring, once it strays,
// the branches that lead back. For long replays and soaks: new motion for as long as
// wanted, always with its ground truth, and no loop-boundary jump.
#pragma once

#include <cstdint>
#include <random>
#include <vector>

#include "sim/motion_graph.hpp"

namespace mocapd {

/// The graph's branch points (frames where a transition leaves a take) and which of them
/// a walk can use forever.
struct GraphConnectivity {
  int nodes = 0;
  int walk_nodes = 0;  ///< In the largest strongly connected part.
  int walk_takes = 0;
  std::vector<bool> take_in_walk;
  std::vector<int> node_take, node_frame;
  std::vector<bool> node_in_walk;
  /// Per node: the node reached by playing on in the take (-1: the take ends first), and
  /// per transition leaving there, (transition, node reached after its blend).
  std::vector<int> skip;
  std::vector<std::vector<std::pair<int, int>>> leave;
};

GraphConnectivity AnalyseConnectivity(const MotionLibrary& library, const MotionGraph& graph);

struct WalkOptions {
  uint64_t seed = 1;
  double transition_probability = 0.5;  ///< At a branch point, leave the take this often.
  double home_radius_m = 3.0;           ///< Beyond this from the origin, branches leading back win.
};

class GraphWalker {
 public:
  /// Throws std::runtime_error if the graph has no strongly connected part to walk.
  GraphWalker(const MotionLibrary& library, const MotionGraph& graph, const WalkOptions& options);

  /// Appends the walk's next frames (one play or blend-and-play, at the graph's rate).
  /// blended (optional) gets a flag per frame: 1 inside a blend.
  void NextFrames(std::vector<Pose>* out, std::vector<uint8_t>* blended = nullptr);
  /// Steps taken so far (plays merge; blends are listed).
  int transitions_taken() const { return transitions_; }

 private:
  struct Option {
    int transition;  ///< -1: play on in the take.
    int next;        ///< The branch point it leads to.
  };
  /// Branch points looked ahead when steering home.
  static constexpr int kLookahead = 4;

  /// The running transform after taking an option.
  PlanarTransform Follow(const Option& option, const PlanarTransform& transform) const;
  /// How well a branch point (under a transform) heads home: the distance from home after
  /// going on a little the way the body faces.
  double HomeScore(int node, const PlanarTransform& transform) const;
  /// The ways on from a branch point, into the walkable part: play on, or each transition
  /// (then the play to the branch point after it).
  std::vector<Option> OptionsAt(int node) const;
  std::vector<PathStep> StepsOf(int node, const Option& option) const;
  /// The best HomeScore the walk can reach within depth more steps.
  double ClosestToHome(int node, const PlanarTransform& transform, int depth) const;

  const MotionLibrary& lib_;
  const MotionGraph& graph_;
  WalkOptions options_;
  GraphConnectivity connectivity_;
  std::mt19937_64 rng_;
  int node_ = -1;  ///< The branch point the walk is at.
  PlanarTransform transform_;
  int transitions_ = 0;
};

}  // namespace mocapd
