// Constrained synthesis on a motion graph: a frame-exact reachability programme over
// distance bitsets, then a backward search with the exact remaining distance.
#include "sim/graph_planner.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace mocapd {
namespace {

// The planner's limits: beyond them a table cannot stay within any sensible budget.
constexpr double kMaxSeconds = 4 * 3600.0;
constexpr double kMaxDistanceM = 100000.0;

}  // namespace

GraphPoint ParseGraphPoint(const MotionLibrary& lib, const std::string& text) {
  const size_t colon = text.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == text.size())
    throw std::invalid_argument("'" + text + "' is not TAKE:FRAME");
  GraphPoint p;
  p.take = lib.TakeIndex(text.substr(0, colon));
  const std::string frame = text.substr(colon + 1);
  size_t used = 0;
  try {
    p.frame = std::stoi(frame, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != frame.size() || p.frame < 0 || p.frame >= lib.num_frames(p.take))
    throw std::invalid_argument("'" + text + "': frame must be 0 .. " +
                                std::to_string(lib.num_frames(p.take) - 1) + " (at " +
                                std::to_string(static_cast<int>(lib.rate_hz)) + " Hz)");
  return p;
}

GraphPlanner::GraphPlanner(const MotionLibrary& library, const MotionGraph& graph, double bin_m,
                           size_t max_table_bytes)
    : lib_(library),
      graph_(graph),
      requested_bin_m_(bin_m),
      max_table_bytes_(max_table_bytes),
      bin_m_(bin_m) {
  if (!(bin_m > 0)) throw std::invalid_argument("planner: distance bin must be > 0");
}

double GraphPlanner::PlayDistance(int take, int frame, int count, bool starts_path) const {
  if (count <= 0) return 0.0;
  const auto& p = lib_.path_m[static_cast<size_t>(take)];
  const double inside = p[static_cast<size_t>(frame + count - 1)] - p[static_cast<size_t>(frame)];
  return inside + (starts_path ? 0.0 : lib_.Step(take, frame));
}

void GraphPlanner::BuildGraph(GraphPoint from, std::optional<GraphPoint> to, double max_seconds) {
  auto check = [&](const GraphPoint& p, const char* what) {
    if (p.take < 0 || p.take >= lib_.num_takes() || p.frame < 0 ||
        p.frame >= lib_.num_frames(p.take))
      throw std::invalid_argument(std::string("planner: the ") + what +
                                  " point is outside its take");
  };
  check(from, "start");
  if (to) check(*to, "end");
  if (!(max_seconds > 0) || max_seconds > kMaxSeconds)
    throw std::invalid_argument("planner: time must be > 0 and at most 4 hours");
  from_ = from;
  to_ = to;
  horizon_ = std::max(1, static_cast<int>(std::lround(max_seconds * lib_.rate_hz)));

  // Nodes: the start, then every frame where a transition leaves a take, and the frame
  // after the end point.
  nodes_.clear();
  edges_.clear();
  nodes_.push_back({from.take, from.frame});
  start_node_ = 0;
  std::vector<std::vector<std::pair<int, int>>> events(static_cast<size_t>(lib_.num_takes()));
  auto add_event = [&](int take, int frame) {
    auto& list = events[static_cast<size_t>(take)];
    for (const auto& [f, id] : list)
      if (f == frame) return id;
    nodes_.push_back({take, frame});
    list.emplace_back(frame, static_cast<int>(nodes_.size()) - 1);
    return static_cast<int>(nodes_.size()) - 1;
  };
  for (const GraphTransition& t : graph_.transitions) add_event(t.from_take, t.exit_frame());
  end_node_ = to ? add_event(to->take, to->frame + 1) : -1;
  for (auto& list : events) std::sort(list.begin(), list.end());
  // The first event at or after frame (strictly after when strict), or -1.
  auto next_event = [&](int take, int frame, bool strict) {
    for (const auto& [f, id] : events[static_cast<size_t>(take)])
      if (f > frame || (!strict && f == frame)) return id;
    return -1;
  };
  for (int u = 0; u < static_cast<int>(nodes_.size()); ++u) {
    const Node n = nodes_[static_cast<size_t>(u)];
    const bool start = u == start_node_;
    const int skip = next_event(n.take, n.frame, true);
    if (skip >= 0) {
      const int frames = nodes_[static_cast<size_t>(skip)].frame - n.frame;
      const double d = PlayDistance(n.take, n.frame, frames, start);
      edges_.push_back({u, skip, frames, d, 0, -1});
    }
    for (size_t k = 0; k < graph_.transitions.size(); ++k) {
      const GraphTransition& t = graph_.transitions[k];
      if (t.from_take != n.take || t.exit_frame() != n.frame) continue;
      const int arrive = next_event(t.to_take, t.entry_frame(), false);
      if (arrive < 0) continue;
      const int play = nodes_[static_cast<size_t>(arrive)].frame - t.entry_frame();
      const double d = (start ? 0.0 : lib_.Step(n.take, n.frame)) + t.blend_path_m +
                       PlayDistance(t.to_take, t.entry_frame(), play, false);
      edges_.push_back({u, arrive, t.blend_frames() + play, d, 0, static_cast<int>(k)});
    }
  }
  exits_.assign(nodes_.size(), {});
  for (int u = 0; u < static_cast<int>(nodes_.size()); ++u)
    for (size_t k = 0; k < graph_.transitions.size(); ++k)
      if (graph_.transitions[k].from_take == nodes_[static_cast<size_t>(u)].take &&
          graph_.transitions[k].exit_frame() == nodes_[static_cast<size_t>(u)].frame)
        exits_[static_cast<size_t>(u)].push_back(static_cast<int>(k));
  in_edges_.assign(nodes_.size(), {});
  out_edges_.assign(nodes_.size(), {});
  for (size_t e = 0; e < edges_.size(); ++e) {
    in_edges_[static_cast<size_t>(edges_[e].to)].push_back(static_cast<int>(e));
    out_edges_[static_cast<size_t>(edges_[e].from)].push_back(static_cast<int>(e));
  }
}

void GraphPlanner::Prepare(GraphPoint from, std::optional<GraphPoint> to, double max_seconds,
                           double max_distance_m) {
  if (!(max_distance_m >= 0) || max_distance_m > kMaxDistanceM)
    throw std::invalid_argument("planner: distance must be 0 .. 100 km");
  BuildGraph(from, to, max_seconds);
  extremes_ = false;
  min_m_.clear();
  max_m_.clear();
  min_via_.clear();
  max_via_.clear();
  bin_m_ = requested_bin_m_;

  // The tables hold a bitset per node and frame: keep them within max_table_bytes_ by
  // widening the bins when a long time and distance would need more.
  const size_t cells = nodes_.size() * static_cast<size_t>(horizon_ + 1);
  // Per cell: the words, and the two word indices of the range that holds bits.
  const size_t fixed = cells * 2 * sizeof(uint16_t);
  const size_t max_words =
      fixed < max_table_bytes_ ? (max_table_bytes_ - fixed) / (cells * sizeof(uint64_t)) : 0;
  if (max_words < 1)
    throw std::runtime_error("planner: " + std::to_string(max_seconds) +
                             " s is too long for this graph's " + std::to_string(nodes_.size()) +
                             " branch points (the tables would exceed " +
                             std::to_string(max_table_bytes_ >> 20) + " MB)");
  const double wanted_words = std::ceil((max_distance_m / bin_m_ + 2.0) / 64.0);
  if (wanted_words > static_cast<double>(std::min<size_t>(max_words, 65535)))
    bin_m_ =
        max_distance_m / (static_cast<double>(std::min<size_t>(max_words, 65535)) * 64.0 - 2.0);
  bins_ = static_cast<int>(std::ceil(max_distance_m / bin_m_)) + 2;
  words_ = (bins_ + 63) / 64;
  bins_ = words_ * 64;
  for (Edge& e : edges_) e.bins = std::lround(e.distance_m / bin_m_);
  bits_.reset();
  const size_t bits_words = cells * static_cast<size_t>(words_);
  bits_.reset(static_cast<uint64_t*>(std::calloc(bits_words, sizeof(uint64_t))));
  if (!bits_)
    throw std::runtime_error("planner: cannot allocate " + std::to_string(bits_words >> 17) +
                             " MB");
  // Per cell, the words that hold bits [lo, hi]: early on only short distances are
  // reachable, so most of each bitset stays empty and is skipped.
  word_lo_.assign(cells, std::numeric_limits<uint16_t>::max());
  word_hi_.assign(cells, 0);
  Bits(start_node_, 0)[0] = 1;
  word_lo_[Cell(start_node_, 0)] = word_hi_[Cell(start_node_, 0)] = 0;
  for (int t = 0; t <= horizon_; ++t) {
    for (int u = 0; u < static_cast<int>(nodes_.size()); ++u) {
      const size_t cell = Cell(u, t);
      if (word_lo_[cell] > word_hi_[cell]) continue;
      const uint64_t* src = Bits(u, t);
      const int lo = word_lo_[cell], hi = word_hi_[cell];
      for (int e : out_edges_[static_cast<size_t>(u)]) {
        const Edge& edge = edges_[static_cast<size_t>(e)];
        const int t2 = t + edge.frames;
        if (t2 > horizon_) continue;
        const long shift = edge.bins;
        if (shift >= bins_) continue;
        const int word_shift = static_cast<int>(shift / 64),
                  bit_shift = static_cast<int>(shift % 64);
        uint64_t* dst = Bits(edge.to, t2);
        const int first = lo + word_shift;
        const int last = std::min(words_ - 1, hi + word_shift + (bit_shift > 0 ? 1 : 0));
        int new_lo = std::numeric_limits<int>::max(), new_hi = -1;
        for (int w = first; w <= last; ++w) {
          uint64_t v = w - word_shift <= hi ? src[w - word_shift] << bit_shift : 0;
          if (bit_shift > 0 && w - word_shift - 1 >= lo)
            v |= src[w - word_shift - 1] >> (64 - bit_shift);
          if (v == 0) continue;
          dst[w] |= v;
          new_lo = std::min(new_lo, w);
          new_hi = w;
        }
        if (new_hi < 0) continue;
        const size_t dst_cell = Cell(edge.to, t2);
        word_lo_[dst_cell] = static_cast<uint16_t>(std::min<int>(word_lo_[dst_cell], new_lo));
        word_hi_[dst_cell] = static_cast<uint16_t>(std::max<int>(word_hi_[dst_cell], new_hi));
      }
    }
  }
}

int GraphPlanner::NearestBin(int node, int t, long bin, int max_offset) const {
  if (t < 0 || t > horizon_) return -1;
  const size_t cell = Cell(node, t);
  if (word_lo_[cell] > word_hi_[cell]) return -1;
  const uint64_t* b = Bits(node, t);
  const long lo_bit = static_cast<long>(word_lo_[cell]) * 64,
             hi_bit = static_cast<long>(word_hi_[cell]) * 64 + 63;
  // The nearest set bit at or above `from`, and at or below it, a word at a time.
  auto up = [&](long from) -> long {
    for (long k = std::max(from, lo_bit); k <= hi_bit;) {
      const uint64_t w = b[k / 64] >> (k % 64);
      if (w) return k + std::countr_zero(w);
      k = (k / 64 + 1) * 64;
    }
    return -1;
  };
  auto down = [&](long from) -> long {
    for (long k = std::min(from, hi_bit); k >= lo_bit;) {
      const int shift = 63 - static_cast<int>(k % 64);
      const uint64_t w = b[k / 64] << shift;
      if (w) return k - std::countl_zero(w);
      k = (k / 64) * 64 - 1;
    }
    return -1;
  };
  const long above = up(std::max(bin, 0L));
  const long below = bin >= 0 ? down(std::min(bin, static_cast<long>(bins_) - 1)) : -1;
  long best = -1;
  if (above >= 0) best = above;
  if (below >= 0 && (best < 0 || bin - below <= best - bin)) best = below;
  if (best < 0 || std::abs(best - bin) > max_offset) return -1;
  return static_cast<int>(best);
}

bool GraphPlanner::Reached(int node, int t) const {
  if (t < 0 || t > horizon_) return false;
  const size_t cell = Cell(node, t);
  return extremes_ ? std::isfinite(min_m_[cell]) : word_lo_[cell] <= word_hi_[cell];
}

template <typename F>
void GraphPlanner::ForEachEnding(int n, F&& consider) const {
  if (to_) {
    if (Reached(end_node_, n)) consider(Ending{end_node_, n, 0.0, -1, 0});
    return;
  }
  for (int u = 0; u < static_cast<int>(nodes_.size()); ++u) {
    const Node node = nodes_[static_cast<size_t>(u)];
    const bool start = u == start_node_;
    for (int t = 0; t < n; ++t) {
      if (!Reached(u, t)) continue;
      const int k = n - t;
      if (node.frame + k <= lib_.num_frames(node.take))
        consider(Ending{u, t, PlayDistance(node.take, node.frame, k, start), -1, k});
      for (int tr : exits_[static_cast<size_t>(u)]) {
        const GraphTransition& g = graph_.transitions[static_cast<size_t>(tr)];
        const int rest = n - t - g.blend_frames();
        if (rest < 0 || g.entry_frame() + rest > lib_.num_frames(g.to_take)) continue;
        consider(Ending{u, t,
                        (start ? 0.0 : lib_.Step(node.take, node.frame)) + g.blend_path_m +
                            PlayDistance(g.to_take, g.entry_frame(), rest, false),
                        tr, rest});
      }
    }
  }
}

SynthesisResult GraphPlanner::Finish(const std::vector<int>& edges_last_first, const Ending& ending,
                                     double distance_m, double seconds, int frames) const {
  GraphPath path;
  auto play = [&](int take, int first, int count) {
    if (count <= 0) return;
    if (!path.empty() && path.back().transition < 0 && path.back().take == take &&
        path.back().first + path.back().count == first) {
      path.back().count += count;
      return;
    }
    path.push_back({take, first, count, -1});
  };
  double planned = ending.extra_m;
  for (auto it = edges_last_first.rbegin(); it != edges_last_first.rend(); ++it) {
    const Edge& edge = edges_[static_cast<size_t>(*it)];
    planned += edge.distance_m;
    const Node& a = nodes_[static_cast<size_t>(edge.from)];
    const Node& b = nodes_[static_cast<size_t>(edge.to)];
    if (edge.transition < 0) {
      play(a.take, a.frame, b.frame - a.frame);
    } else {
      const GraphTransition& t = graph_.transitions[static_cast<size_t>(edge.transition)];
      path.push_back({-1, 0, 0, edge.transition});
      play(t.to_take, t.entry_frame(), b.frame - t.entry_frame());
    }
  }
  const Node& last = nodes_[static_cast<size_t>(ending.node)];
  if (ending.transition >= 0) {
    const GraphTransition& t = graph_.transitions[static_cast<size_t>(ending.transition)];
    path.push_back({-1, 0, 0, ending.transition});
    play(t.to_take, t.entry_frame(), ending.play);
  } else {
    play(last.take, last.frame, ending.play);
  }
  SynthesisResult result;
  result.path = path;
  result.frames = PathFrames(graph_, path);
  result.seconds = result.frames / lib_.rate_hz;
  result.distance_m = PathDistance(lib_, graph_, path);
  result.planned_distance_m = planned;
  result.distance_miss_m = result.distance_m - distance_m;
  result.time_miss_s = result.seconds - seconds;
  result.exact_time = frames == static_cast<int>(std::lround(seconds * lib_.rate_hz));
  result.distance_bin_m = extremes_ ? 0.0 : bin_m_;
  for (const PathStep& st : path)
    if (st.transition >= 0) {
      ++result.transitions;
      result.transition_cost_m += graph_.transitions[static_cast<size_t>(st.transition)].cost_m;
    }
  return result;
}

SynthesisResult GraphPlanner::Solve(double distance_m, double seconds, bool other_times) const {
  if (nodes_.empty() || extremes_) throw std::runtime_error("planner: Prepare was not called");
  const int target_frames = static_cast<int>(std::lround(seconds * lib_.rate_hz));
  struct BinnedEnding {
    Ending ending;
    double miss;  ///< |nearest reachable distance - target| in the bins, for ordering.
    int bin;      ///< The reachable bin at (node, t) the path is rebuilt from.
  };
  std::vector<BinnedEnding> endings;
  int frames = -1;
  for (int off = 0; off <= (other_times ? horizon_ : 0) && endings.empty(); ++off) {
    for (int sign : {0, -1, 1}) {
      if ((off == 0) != (sign == 0)) continue;
      const int n = target_frames + sign * off;
      if (n < 1 || n > horizon_) continue;
      ForEachEnding(n, [&](const Ending& e) {
        const double r = (distance_m - e.extra_m) / bin_m_;
        const int nb = NearestBin(e.node, e.t, std::lround(r), bins_);
        if (nb < 0) return;
        endings.push_back({e, std::abs(nb * bin_m_ + e.extra_m - distance_m), nb});
        // A free end can end in millions of ways over a long plan: keep the best few.
        if (endings.size() >= 4096) {
          std::nth_element(
              endings.begin(), endings.begin() + 64, endings.end(),
              [](const BinnedEnding& a, const BinnedEnding& b) { return a.miss < b.miss; });
          endings.resize(64);
        }
      });
      if (!endings.empty()) {
        frames = n;
        break;
      }
    }
  }
  if (endings.empty())
    throw std::runtime_error("no path from the start point reaches " +
                             std::string(to_ ? "the end point" : "any frame") +
                             " within the prepared time and distance");
  std::stable_sort(
      endings.begin(), endings.end(), [](const BinnedEnding& a, const BinnedEnding& b) {
        return a.miss != b.miss ? a.miss < b.miss : a.ending.transition < b.ending.transition;
      });

  // Rebuild paths backwards from the best endings. The bits are exact sums of the edges'
  // binned distances, so every set bit leads back to the start: from (node, t, bin) any
  // edge whose source holds bin - its bins at t - its frames is a step of a real path.
  // Among those steps, the one that keeps the exact distance closest to the target (the
  // bins' rounding then cancels instead of adding up), staying in a take unless a
  // transition is worth it.
  constexpr size_t kEndingsTried = 16;
  // What a transition is worth in distance: a path with one more must come this much
  // closer to the target (a blend is never as good as the take's own motion).
  constexpr double kTransitionWorthM = 0.01;
  // Rebuilds from (node, t, bin); returns the edges (end first) and the signed miss of the
  // whole path against the target.
  auto rebuild = [&](const BinnedEnding& ending, long end_bin, std::vector<int>* chosen) {
    int node = ending.ending.node, t = ending.ending.t;
    long bin = end_bin;
    double miss = static_cast<double>(end_bin) * bin_m_ + ending.ending.extra_m - distance_m;
    while (!(node == start_node_ && t == 0)) {
      int pick = -1;
      double pick_score = std::numeric_limits<double>::infinity(), pick_miss = 0.0;
      for (int e : in_edges_[static_cast<size_t>(node)]) {
        const Edge& edge = edges_[static_cast<size_t>(e)];
        const int t0 = t - edge.frames;
        const long b0 = bin - edge.bins;
        if (t0 < 0 || b0 < 0 || NearestBin(edge.from, t0, b0, 0) != b0) continue;
        const double m = miss + edge.distance_m - static_cast<double>(edge.bins) * bin_m_;
        const double score = std::abs(m) + (edge.transition >= 0 ? kTransitionWorthM : 0.0);
        if (score < pick_score) {
          pick_score = score;
          pick = e;
          pick_miss = m;
        }
      }
      // A set bit always has a predecessor; this guards a broken invariant.
      if (pick < 0) throw std::logic_error("planner: a reachable state has no predecessor");
      const Edge& edge = edges_[static_cast<size_t>(pick)];
      chosen->push_back(pick);
      node = edge.from;
      t -= edge.frames;
      bin -= edge.bins;
      miss = pick_miss;
    }
    return miss;
  };
  std::vector<int> best_edges;
  const BinnedEnding* best_ending = nullptr;
  double best_score = std::numeric_limits<double>::infinity();
  for (size_t k = 0; k < endings.size() && k < kEndingsTried; ++k) {
    const BinnedEnding& ending = endings[k];
    if (ending.miss > best_score + bin_m_) break;
    // A loop repeated many times repeats its rounding too, which no choice of steps can
    // cancel: aim the next try that much the other way, where such a path exists.
    long end_bin = ending.bin;
    for (int attempt = 0; attempt < 4; ++attempt) {
      std::vector<int> chosen;
      const double miss = rebuild(ending, end_bin, &chosen);
      // Fewer transitions win over a closer distance, up to kTransitionWorthM each.
      double score = std::abs(miss) + (ending.ending.transition >= 0 ? kTransitionWorthM : 0.0);
      for (int e : chosen)
        if (edges_[static_cast<size_t>(e)].transition >= 0) score += kTransitionWorthM;
      if (score < best_score) {
        best_score = score;
        best_edges = std::move(chosen);
        best_ending = &ending;
      }
      const long next = end_bin - std::lround(miss / bin_m_);
      if (std::abs(miss) <= 0.5 * bin_m_ || next == end_bin || next < 0 ||
          NearestBin(ending.ending.node, ending.ending.t, next, 0) != next)
        break;
      end_bin = next;
    }
  }
  if (!best_ending) throw std::runtime_error("planner: no path could be rebuilt");
  SynthesisResult result = Finish(best_edges, best_ending->ending, distance_m, seconds, frames);
  result.best_possible_miss_m = endings.front().miss;
  return result;
}

void GraphPlanner::PrepareExtremes(GraphPoint from, std::optional<GraphPoint> to,
                                   double max_seconds) {
  BuildGraph(from, to, max_seconds);
  extremes_ = true;
  bits_.reset();
  word_lo_.clear();
  word_hi_.clear();
  const size_t cells = nodes_.size() * static_cast<size_t>(horizon_ + 1);
  if (cells * 2 * (sizeof(float) + sizeof(int32_t)) > max_table_bytes_)
    throw std::runtime_error("planner: " + std::to_string(static_cast<int>(max_seconds)) +
                             " s is too long for this graph's " + std::to_string(nodes_.size()) +
                             " branch points (the tables would exceed " +
                             std::to_string(max_table_bytes_ >> 20) + " MB)");
  const float inf = std::numeric_limits<float>::infinity();
  min_m_.assign(cells, inf);
  max_m_.assign(cells, -inf);
  min_via_.assign(cells, -1);
  max_via_.assign(cells, -1);
  const size_t start = Cell(start_node_, 0);
  min_m_[start] = max_m_[start] = 0.0f;
  min_via_[start] = max_via_[start] = -2;
  for (int t = 0; t <= horizon_; ++t)
    for (int u = 0; u < static_cast<int>(nodes_.size()); ++u) {
      const size_t cell = Cell(u, t);
      if (!std::isfinite(min_m_[cell])) continue;
      for (int e : out_edges_[static_cast<size_t>(u)]) {
        const Edge& edge = edges_[static_cast<size_t>(e)];
        const int t2 = t + edge.frames;
        if (t2 > horizon_) continue;
        const size_t to_cell = Cell(edge.to, t2);
        const auto d = static_cast<float>(edge.distance_m);
        if (min_m_[cell] + d < min_m_[to_cell]) {
          min_m_[to_cell] = min_m_[cell] + d;
          min_via_[to_cell] = e;
        }
        if (max_m_[cell] + d > max_m_[to_cell]) {
          max_m_[to_cell] = max_m_[cell] + d;
          max_via_[to_cell] = e;
        }
      }
    }
}

SynthesisResult GraphPlanner::SolveExtremes(double distance_m, double seconds, bool* inside) const {
  if (nodes_.empty() || !extremes_)
    throw std::runtime_error("planner: PrepareExtremes was not called");
  const int target_frames = static_cast<int>(std::lround(seconds * lib_.rate_hz));
  // The ending whose range of distances comes nearest the target, at the nearest time.
  Ending best{};
  double best_gap = std::numeric_limits<double>::infinity();
  double best_nearer = std::numeric_limits<double>::infinity();
  bool longest = false;
  int frames = -1;
  for (int off = 0; off <= horizon_ && frames < 0; ++off) {
    for (int sign : {0, -1, 1}) {
      if ((off == 0) != (sign == 0)) continue;
      const int n = target_frames + sign * off;
      if (n < 1 || n > horizon_) continue;
      ForEachEnding(n, [&](const Ending& e) {
        const size_t cell = Cell(e.node, e.t);
        const double lo = min_m_[cell] + e.extra_m, hi = max_m_[cell] + e.extra_m;
        const double gap =
            distance_m < lo ? lo - distance_m : (distance_m > hi ? distance_m - hi : 0.0);
        // Inside the range, the extreme nearer the target is what these tables can give.
        const double nearer = std::min(std::abs(distance_m - lo), std::abs(distance_m - hi));
        if (gap < best_gap || (gap == 0.0 && best_gap == 0.0 && nearer < best_nearer)) {
          best_gap = gap;
          best_nearer = nearer;
          best = e;
          longest = std::abs(distance_m - hi) < std::abs(distance_m - lo);
          frames = n;
        }
      });
      if (frames >= 0) break;
    }
  }
  if (frames < 0)
    throw std::runtime_error("no path from the start point reaches " +
                             std::string(to_ ? "the end point" : "any frame") +
                             " within the prepared time");
  *inside = best_gap == 0.0;
  std::vector<int> edges;
  const std::vector<int32_t>& via = longest ? max_via_ : min_via_;
  for (int node = best.node, t = best.t; via[Cell(node, t)] != -2;) {
    const int e = via[Cell(node, t)];
    edges.push_back(e);
    node = edges_[static_cast<size_t>(e)].from;
    t -= edges_[static_cast<size_t>(e)].frames;
  }
  SynthesisResult result = Finish(edges, best, distance_m, seconds, frames);
  result.best_possible_miss_m = best_gap;
  return result;
}

BvhTake SynthesisTake(const MotionLibrary& lib, const MotionGraph& graph, const GraphPath& path) {
  BvhTake take = lib.layout;
  take.skeleton = *lib.skeleton;
  take.frames = RenderPath(lib, graph, path);
  take.frame_time_s = 1.0 / lib.rate_hz;
  return take;
}

std::string DescribePath(const MotionLibrary& lib, const MotionGraph& graph,
                         const GraphPath& path) {
  std::string out;
  for (const PathStep& s : path) {
    if (!out.empty()) out += " | ";
    if (s.transition >= 0) {
      const GraphTransition& t = graph.transitions[static_cast<size_t>(s.transition)];
      out += "blend " + lib.names[static_cast<size_t>(t.from_take)] + ":" +
             std::to_string(t.exit_frame()) + "->" + lib.names[static_cast<size_t>(t.to_take)] +
             ":" + std::to_string(t.entry_frame() - 1);
    } else {
      out += lib.names[static_cast<size_t>(s.take)] + " " + std::to_string(s.first) + "-" +
             std::to_string(s.first + s.count - 1);
    }
  }
  return out;
}

}  // namespace mocapd

namespace mocapd {

SynthesisResult Synthesize(const MotionLibrary& lib, const MotionGraph& graph, GraphPoint from,
                           std::optional<GraphPoint> to, double distance_m, double seconds,
                           double bin_m) {
  // Of two answers, the one that lasts the time, then the one nearer the distance.
  const auto better = [](const SynthesisResult& a, const SynthesisResult& b) {
    if (a.exact_time != b.exact_time) return a.exact_time;
    if (std::abs(a.time_miss_s) != std::abs(b.time_miss_s))
      return std::abs(a.time_miss_s) < std::abs(b.time_miss_s);
    return std::abs(a.distance_miss_m) < std::abs(b.distance_miss_m);
  };
  std::optional<SynthesisResult> sets;
  {
    GraphPlanner planner(lib, graph, bin_m);
    // Only distances near the target matter here: what lies beyond is the extremes'.
    planner.Prepare(from, to, seconds + 1.0, distance_m + std::max(1.0, 0.1 * distance_m));
    try {
      sets = planner.Solve(distance_m, seconds, /*other_times=*/false);
      // A long plan's widened bins are coarse: the extremes may still do better.
      if (std::abs(sets->distance_miss_m) <= std::max(0.05, sets->distance_bin_m)) return *sets;
    } catch (const std::runtime_error&) {
    }
  }
  // No path lasts the time within that distance: the shortest or longest path that does
  // (or, with an end point, the nearest time at which one arrives) is the nearest.
  GraphPlanner extremes(lib, graph, bin_m);
  const double horizon = to ? std::min(1.5 * seconds + 5.0, kMaxSeconds) : seconds + 1.0;
  extremes.PrepareExtremes(from, to, horizon);
  bool inside = false;
  SynthesisResult r;
  try {
    r = extremes.SolveExtremes(distance_m, seconds, &inside);
  } catch (const std::runtime_error&) {
    if (!to) throw;
    // The end frame is never reached: say where the graph enters its take.
    const std::string end =
        lib.names[static_cast<size_t>(to->take)] + ":" + std::to_string(to->frame);
    int earliest = -1;
    for (const GraphTransition& t : graph.transitions)
      if (t.to_take == to->take && (earliest < 0 || t.entry_frame() - 1 < earliest))
        earliest = t.entry_frame() - 1;
    if (from.take == to->take && from.frame <= to->frame) earliest = from.frame;
    if (earliest < 0)
      throw std::runtime_error("no path reaches " + end + ": no transition enters take '" +
                               lib.names[static_cast<size_t>(to->take)] + "'");
    if (earliest > to->frame)
      throw std::runtime_error("no path reaches " + end + ": the graph enters take '" +
                               lib.names[static_cast<size_t>(to->take)] + "' at frame " +
                               std::to_string(earliest) +
                               " at the earliest; choose a later --to frame");
    throw std::runtime_error("no path from " + lib.names[static_cast<size_t>(from.take)] + ":" +
                             std::to_string(from.frame) + " reaches " + end + " within " +
                             std::to_string(static_cast<int>(std::ceil(horizon))) +
                             " s (the start may not lead to that part of the graph)");
  }
  if (inside && !r.exact_time) {
    // At the nearest time the graph can cover the distance: the sets find it there.
    GraphPlanner planner(lib, graph, bin_m);
    planner.Prepare(from, to, r.seconds + 1.0, distance_m + std::max(1.0, 0.1 * distance_m));
    SynthesisResult at = planner.Solve(distance_m, r.seconds, /*other_times=*/false);
    at.exact_time = false;
    at.time_miss_s = at.seconds - seconds;
    if (better(at, r)) r = at;
  }
  if (sets && better(*sets, r)) return *sets;
  return r;
}

}  // namespace mocapd
