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
#include <cstdlib>
#include <memory>
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
  double distance_bin_m = 0.0;  ///< The programme's bins (widened for long plans; 0: none).
  /// What the planner summed for the path (its edges' distances): equals distance_m.
  double planned_distance_m = 0.0;
};

class GraphPlanner {
 public:
  /// max_table_bytes: the tables' budget; long times and distances widen the bins to fit.
  GraphPlanner(const MotionLibrary& library, const MotionGraph& graph, double distance_bin_m = 0.01,
               size_t max_table_bytes = size_t{256} << 20);

  /// Computes what can be reached from `from` (the first frame played) within max_seconds
  /// and max_distance_m, ending at `to` (the last frame played) if given. Throws
  /// std::invalid_argument for a point outside its take or limits out of range (4 h,
  /// 100 km), std::runtime_error if the tables cannot fit the budget.
  void Prepare(GraphPoint from, std::optional<GraphPoint> to, double max_seconds,
               double max_distance_m);
  /// The path closest to the target among the prepared ones: at the target's time if any
  /// path lasts it, else (other_times) the nearest time. Throws std::runtime_error if no
  /// path ends at a time it may take.
  SynthesisResult Solve(double distance_m, double seconds, bool other_times = true) const;

  /// Instead of distance sets, only the shortest and longest path to each branch point
  /// and frame: exact and small, for the nearest path when a target cannot be met.
  void PrepareExtremes(GraphPoint from, std::optional<GraphPoint> to, double max_seconds);
  /// The nearest path by the extremes: at the target's time if any path lasts it, else
  /// the nearest time. *inside is set when some path's range of distances at that time
  /// holds the target (the sets can then meet it: Prepare and Solve at that time).
  SynthesisResult SolveExtremes(double distance_m, double seconds, bool* inside) const;

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
  /// One way to end a path: after reaching (node, t), blend through `transition` (or
  /// not: -1) and play `play` frames, covering extra_m.
  struct Ending {
    int node, t;
    double extra_m;
    int transition;
    int play;
  };
  void BuildGraph(GraphPoint from, std::optional<GraphPoint> to, double max_seconds);
  bool Reached(int node, int t) const;
  /// Calls consider(Ending) for every way a path of n frames can end.
  template <typename F>
  void ForEachEnding(int n, F&& consider) const;
  /// The result of the path made of edges (last first) and an ending.
  SynthesisResult Finish(const std::vector<int>& edges_last_first, const Ending& ending,
                         double distance_m, double seconds, int frames) const;
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
  /// calloc'd: the system hands out zero pages that cost nothing until a bit lands on
  /// them, and most never get one (a plan's early frames reach only short distances).
  struct FreeBits {
    void operator()(uint64_t* p) const { std::free(p); }
  };
  std::unique_ptr<uint64_t[], FreeBits> bits_;
  size_t Cell(int node, int t) const {
    return static_cast<size_t>(node) * static_cast<size_t>(horizon_ + 1) + static_cast<size_t>(t);
  }
  /// Per (node, t): the first and last words holding set bits (lo > hi: none).
  std::vector<uint16_t> word_lo_, word_hi_;
  /// Per node: every transition leaving at its frame (also those with no branch point
  /// after their arrival, for endings).
  std::vector<std::vector<int>> exits_;
  /// PrepareExtremes: per (node, t) the shortest and longest distance (inf / -inf: not
  /// reached) and the edge each came by (-2: the start).
  bool extremes_ = false;
  std::vector<float> min_m_, max_m_;
  std::vector<int32_t> min_via_, max_via_;
};

/// Plans one synthesis: first the distance sets over the target's time and its distance
/// plus 10 % (at least 1 m); if no path lasts the time there, the extremes (over 1.5 times
/// the time with an end point) find the nearest path, or the time nearest the target at
/// which the sets are run again. Throws std::invalid_argument for points outside their
/// takes, std::runtime_error (saying where the graph enters the take) if the end point
/// cannot be reached at all.
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
