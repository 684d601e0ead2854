// Constrained synthesis on a motion graph: the path from a start frame (and optionally to
// an end frame) that lasts a given time and covers a given distance (the body root's
// horizontal path), with as few and as cheap transitions as that allows. Loops repeat as
// often as the constraints need.
//
// Method (an exact dynamic programme in place of the paper's walk enumeration and integer
// programme): time is counted in frames, so a path's duration is exact to a frame, and the
// distances a path can reach by each frame are kept as a bitset per graph node (bins of
// distance_bin_m; each edge's distance rounded to bins, so the sets are exact sums). The
// nodes are the frames where a transition leaves a take; an edge plays a take from one
// such frame to the next, or blends through a transition and plays on to the
// destination's next such frame. The path is rebuilt backwards along set bits, choosing
// at each step the edge whose rounding best cancels the rounding so far.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "sim/motion_graph.hpp"

namespace mocapd {

struct GraphPoint {
  int take = 0;
  int frame = 0;
};
/// Parses "TAKE:FRAME" (frame at the graph's rate; the take by name). Throws
/// std::invalid_argument naming what is wrong.
GraphPoint ParseGraphPoint(const MotionLibrary& library, const std::string& text);

struct SynthesisResult {
  GraphPath path;
  int frames = 0;
  double seconds = 0.0;          ///< frames / rate.
  double distance_m = 0.0;       ///< The rendered root path.
  double distance_miss_m = 0.0;  ///< distance_m - target.
  double time_miss_s = 0.0;      ///< seconds - target.
  int transitions = 0;
  double transition_cost_m = 0.0;  ///< Sum of the blends' distortions.
  bool exact_time = false;         ///< The path lasts the target time to the nearest frame.
  /// The smallest distance miss any path of that duration can have, as the programme
  /// sees it (to its 2 cm bins): above the tolerance, the graph cannot meet the target.
  double best_possible_miss_m = 0.0;
  double distance_bin_m = 0.0;  ///< The programme's bins (widened for long plans).
};

class GraphPlanner {
 public:
  /// max_table_bytes: the tables' budget; long times and distances widen the bins to fit.
  GraphPlanner(const MotionLibrary& library, const MotionGraph& graph, double distance_bin_m = 0.01,
               size_t max_table_bytes = size_t{256} << 20);

  /// Computes what can be reached from `from` (the first frame played) within max_seconds
  /// and max_distance_m, ending at `to` (the last frame played) if given. Throws
  /// std::invalid_argument for a point outside its take or limits out of range.
  void Prepare(GraphPoint from, std::optional<GraphPoint> to, double max_seconds,
               double max_distance_m);
  /// The path closest to the target (time first, then distance) among the prepared ones.
  /// Throws std::runtime_error if nothing is reachable at all.
  SynthesisResult Solve(double distance_m, double seconds) const;

  int num_nodes() const { return static_cast<int>(nodes_.size()); }
  size_t memory_bytes() const { return bits_.size() * sizeof(uint64_t); }

 private:
  struct Node {
    int take, frame;  ///< frame: the next to play (the start node: its first frame).
  };
  struct Edge {
    int from, to;
    int frames;
    double distance_m;
    long bins;       ///< distance_m rounded to bins: what the programme adds up.
    int transition;  ///< -1: a play within the take.
  };
  const uint64_t* Bits(int node, int t) const {
    return &bits_[(static_cast<size_t>(node) * static_cast<size_t>(horizon_ + 1) +
                   static_cast<size_t>(t)) *
                  static_cast<size_t>(words_)];
  }
  uint64_t* Bits(int node, int t) {
    return &bits_[(static_cast<size_t>(node) * static_cast<size_t>(horizon_ + 1) +
                   static_cast<size_t>(t)) *
                  static_cast<size_t>(words_)];
  }
  /// The set bin nearest to `bin` at (node, t) within max_offset, or -1.
  int NearestBin(int node, int t, long bin, int max_offset) const;
  /// The distance of playing `count` frames of take from `frame` on (the step into the
  /// first one counted unless it starts the path).
  double PlayDistance(int take, int frame, int count, bool starts_path) const;

  const MotionLibrary& lib_;
  const MotionGraph& graph_;
  double requested_bin_m_;
  size_t max_table_bytes_;
  double bin_m_;
  GraphPoint from_;
  std::optional<GraphPoint> to_;
  int horizon_ = 0;
  int words_ = 1;
  int bins_ = 64;
  int start_node_ = -1, end_node_ = -1;
  std::vector<Node> nodes_;
  std::vector<Edge> edges_;
  std::vector<std::vector<int>> in_edges_, out_edges_;
  std::vector<uint64_t> bits_;
  size_t Cell(int node, int t) const {
    return static_cast<size_t>(node) * static_cast<size_t>(horizon_ + 1) + static_cast<size_t>(t);
  }
  /// Per (node, t): the first and last words holding set bits (lo > hi: none).
  std::vector<uint16_t> word_lo_, word_hi_;
};

/// Plans one synthesis: first within the target's time and its distance plus 10 % (at
/// least 1 m); if nothing lasts the time there, again over 1.5 times the time and every
/// distance the takes' speeds allow (in wider bins), for the nearest path. Throws
/// std::invalid_argument for points outside their takes, std::runtime_error if the end
/// point cannot be reached at all.
SynthesisResult Synthesize(const MotionLibrary& library, const MotionGraph& graph, GraphPoint from,
                           std::optional<GraphPoint> to, double distance_m, double seconds,
                           double distance_bin_m = 0.01);

/// The motion of a synthesis result, and a BVH of it.
BvhTake SynthesisTake(const MotionLibrary& library, const MotionGraph& graph,
                      const GraphPath& path);
/// "walk 0-40 | blend walk:41->run:12 | run 18-60 ..." for reports.
std::string DescribePath(const MotionLibrary& library, const MotionGraph& graph,
                         const GraphPath& path);

}  // namespace mocapd
