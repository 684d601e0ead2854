// The motion graph's connectivity and its endless random walk.
#include "sim/graph_walker.hpp"

#include <algorithm>
#include <stdexcept>

namespace mocapd {

GraphConnectivity AnalyseConnectivity(const MotionLibrary& lib, const MotionGraph& graph) {
  GraphConnectivity c;
  std::vector<std::vector<std::pair<int, int>>> events(static_cast<size_t>(lib.num_takes()));
  for (const GraphTransition& t : graph.transitions) {
    auto& list = events[static_cast<size_t>(t.from_take)];
    if (std::none_of(list.begin(), list.end(),
                     [&](const auto& e) { return e.first == t.exit_frame(); })) {
      list.emplace_back(t.exit_frame(), static_cast<int>(c.node_take.size()));
      c.node_take.push_back(t.from_take);
      c.node_frame.push_back(t.exit_frame());
    }
  }
  for (auto& list : events) std::sort(list.begin(), list.end());
  c.nodes = static_cast<int>(c.node_take.size());
  const auto at_or_after = [&](int take, int frame, bool strict) {
    for (const auto& [f, id] : events[static_cast<size_t>(take)])
      if (f > frame || (!strict && f == frame)) return id;
    return -1;
  };
  c.skip.assign(static_cast<size_t>(c.nodes), -1);
  c.leave.assign(static_cast<size_t>(c.nodes), {});
  for (int n = 0; n < c.nodes; ++n)
    c.skip[static_cast<size_t>(n)] = at_or_after(c.node_take[static_cast<size_t>(n)],
                                                 c.node_frame[static_cast<size_t>(n)], true);
  for (size_t k = 0; k < graph.transitions.size(); ++k) {
    const GraphTransition& t = graph.transitions[k];
    const int from = at_or_after(t.from_take, t.exit_frame(), false);
    const int to = at_or_after(t.to_take, t.entry_frame(), false);
    if (to >= 0) c.leave[static_cast<size_t>(from)].emplace_back(static_cast<int>(k), to);
  }
  // Tarjan's strongly connected components, iteratively (a graph over long takes has
  // branch points by the hundred thousand: too deep to recurse).
  const auto successors = [&](int v) {
    std::vector<int> next;
    if (c.skip[static_cast<size_t>(v)] >= 0) next.push_back(c.skip[static_cast<size_t>(v)]);
    for (const auto& [t, w] : c.leave[static_cast<size_t>(v)]) next.push_back(w);
    return next;
  };
  std::vector<int> index(static_cast<size_t>(c.nodes), -1), low(static_cast<size_t>(c.nodes), 0),
      component(static_cast<size_t>(c.nodes), -1);
  std::vector<bool> on_stack(static_cast<size_t>(c.nodes), false),
      self_loop(static_cast<size_t>(c.nodes), false);
  std::vector<int> stack;
  int counter = 0, components = 0;
  struct Visit {
    int v;
    std::vector<int> next;
    size_t at = 0;
  };
  for (int root = 0; root < c.nodes; ++root) {
    if (index[static_cast<size_t>(root)] >= 0) continue;
    std::vector<Visit> calls;
    auto enter = [&](int v) {
      const auto uv = static_cast<size_t>(v);
      index[uv] = low[uv] = counter++;
      stack.push_back(v);
      on_stack[uv] = true;
      calls.push_back({v, successors(v), 0});
      for (int w : calls.back().next) self_loop[uv] = self_loop[uv] || w == v;
    };
    enter(root);
    while (!calls.empty()) {
      Visit& call = calls.back();
      const auto uv = static_cast<size_t>(call.v);
      if (call.at < call.next.size()) {
        const int w = call.next[call.at++];
        const auto uw = static_cast<size_t>(w);
        if (index[uw] < 0) {
          enter(w);  // invalidates `call`; the loop takes it up again
        } else if (on_stack[uw]) {
          low[uv] = std::min(low[uv], index[uw]);
        }
        continue;
      }
      if (low[uv] == index[uv]) {
        int w;
        do {
          w = stack.back();
          stack.pop_back();
          on_stack[static_cast<size_t>(w)] = false;
          component[static_cast<size_t>(w)] = components;
        } while (w != call.v);
        ++components;
      }
      const int v = call.v;
      calls.pop_back();
      if (!calls.empty()) {
        const auto up = static_cast<size_t>(calls.back().v);
        low[up] = std::min(low[up], low[static_cast<size_t>(v)]);
      }
    }
  }
  std::vector<int> size(static_cast<size_t>(components), 0);
  for (int v = 0; v < c.nodes; ++v) ++size[static_cast<size_t>(component[static_cast<size_t>(v)])];
  // A lone branch point loops only through a transition back to itself.
  std::vector<bool> loops(static_cast<size_t>(components), false);
  for (int v = 0; v < c.nodes; ++v)
    if (size[static_cast<size_t>(component[static_cast<size_t>(v)])] > 1 ||
        self_loop[static_cast<size_t>(v)])
      loops[static_cast<size_t>(component[static_cast<size_t>(v)])] = true;
  int largest = -1;
  for (int k = 0; k < components; ++k)
    if (loops[static_cast<size_t>(k)] &&
        (largest < 0 || size[static_cast<size_t>(k)] > size[static_cast<size_t>(largest)]))
      largest = k;
  c.node_in_walk.assign(static_cast<size_t>(c.nodes), false);
  c.take_in_walk.assign(static_cast<size_t>(lib.num_takes()), false);
  for (int v = 0; v < c.nodes; ++v) {
    if (largest < 0 || component[static_cast<size_t>(v)] != largest) continue;
    c.node_in_walk[static_cast<size_t>(v)] = true;
    ++c.walk_nodes;
    c.take_in_walk[static_cast<size_t>(c.node_take[static_cast<size_t>(v)])] = true;
  }
  c.walk_takes = static_cast<int>(std::count(c.take_in_walk.begin(), c.take_in_walk.end(), true));
  return c;
}

GraphWalker::GraphWalker(const MotionLibrary& lib, const MotionGraph& graph,
                         const WalkOptions& options)
    : lib_(lib),
      graph_(graph),
      options_(options),
      connectivity_(AnalyseConnectivity(lib, graph)),
      rng_(options.seed) {
  std::vector<int> walk;
  for (int v = 0; v < connectivity_.nodes; ++v)
    if (connectivity_.node_in_walk[static_cast<size_t>(v)]) walk.push_back(v);
  if (walk.empty())
    throw std::runtime_error(
        "the motion graph has no loop to walk: its transitions never lead "
        "back (build it over more takes, or with a larger --max-cost-m)");
  node_ = walk[std::uniform_int_distribution<size_t>(0, walk.size() - 1)(rng_)];
  // Start facing where the take faces, at the origin.
  const int take = connectivity_.node_take[static_cast<size_t>(node_)];
  const int frame = connectivity_.node_frame[static_cast<size_t>(node_)];
  const Vec3 root = lib.root_position[static_cast<size_t>(take)][static_cast<size_t>(frame)];
  transform_.shift_x = -root.x();
  transform_.shift_z = -root.z();
}

PlanarTransform GraphWalker::Follow(const Option& option, const PlanarTransform& transform) const {
  return option.transition < 0
             ? transform
             : transform.Compose(graph_.transitions[static_cast<size_t>(option.transition)].align);
}

double GraphWalker::HomeScore(int node, const PlanarTransform& transform) const {
  const auto take = static_cast<size_t>(connectivity_.node_take[static_cast<size_t>(node)]);
  const auto frame = static_cast<size_t>(connectivity_.node_frame[static_cast<size_t>(node)]);
  const Vec3 p = transform.Apply(lib_.root_position[take][frame]);
  // Where the walk would be after going on a little in the direction the body faces:
  // near home and facing it scores best, so a turn towards home counts before the walk back.
  const double heading = lib_.root_yaw[take][frame] + transform.yaw_rad + lib_.forward_yaw_offset;
  const double ahead = std::min(std::hypot(p.x(), p.z()), options_.home_radius_m);
  return std::hypot(p.x() + ahead * std::sin(heading), p.z() + ahead * std::cos(heading));
}

std::vector<GraphWalker::Option> GraphWalker::OptionsAt(int node) const {
  const auto un = static_cast<size_t>(node);
  std::vector<Option> options;
  const int skip = connectivity_.skip[un];
  if (skip >= 0 && connectivity_.node_in_walk[static_cast<size_t>(skip)])
    options.push_back({-1, skip});
  for (const auto& [t, next] : connectivity_.leave[un])
    if (connectivity_.node_in_walk[static_cast<size_t>(next)]) options.push_back({t, next});
  // In the walkable part every node has a way on; this only guards a broken invariant.
  if (options.empty()) throw std::logic_error("graph walk: a walkable node has no way on");
  return options;
}

std::vector<PathStep> GraphWalker::StepsOf(int node, const Option& o) const {
  const int take = connectivity_.node_take[static_cast<size_t>(node)];
  const int frame = connectivity_.node_frame[static_cast<size_t>(node)];
  const int next_frame = connectivity_.node_frame[static_cast<size_t>(o.next)];
  std::vector<PathStep> steps;
  if (o.transition < 0) {
    steps.push_back({take, frame, next_frame - frame, -1});
  } else {
    const GraphTransition& t = graph_.transitions[static_cast<size_t>(o.transition)];
    steps.push_back({-1, 0, 0, o.transition});
    if (next_frame > t.entry_frame())
      steps.push_back({t.to_take, t.entry_frame(), next_frame - t.entry_frame(), -1});
  }
  return steps;
}

double GraphWalker::ClosestToHome(int node, const PlanarTransform& transform, int depth) const {
  double best = HomeScore(node, transform);
  if (depth <= 0) return best;
  for (const Option& o : OptionsAt(node))
    best = std::min(best, ClosestToHome(o.next, Follow(o, transform), depth - 1));
  return best;
}

void GraphWalker::NextFrames(std::vector<Pose>* out, std::vector<uint8_t>* blended) {
  const int take = connectivity_.node_take[static_cast<size_t>(node_)];
  const int frame = connectivity_.node_frame[static_cast<size_t>(node_)];
  const std::vector<Option> options = OptionsAt(node_);
  size_t pick = 0;
  const Vec3 here =
      transform_.Apply(lib_.root_position[static_cast<size_t>(take)][static_cast<size_t>(frame)]);
  if (std::hypot(here.x(), here.z()) > options_.home_radius_m) {
    // Strayed: the option from which the walk can best head home within a few branch
    // points (one step ahead is not enough where the way back starts with a turn).
    double best = 1e300;
    for (size_t k = 0; k < options.size(); ++k) {
      const double d =
          ClosestToHome(options[k].next, Follow(options[k], transform_), kLookahead - 1);
      if (d < best) {
        best = d;
        pick = k;
      }
    }
  } else {
    const bool has_play = options.front().transition < 0;
    std::uniform_real_distribution<double> coin(0.0, 1.0);
    const bool leave =
        !has_play || (options.size() > 1 && coin(rng_) < options_.transition_probability);
    if (leave) {
      const size_t first = has_play ? 1 : 0;
      pick = first + std::uniform_int_distribution<size_t>(0, options.size() - 1 - first)(rng_);
    }
  }
  for (const PathStep& s : StepsOf(node_, options[pick])) {
    RenderStep(lib_, graph_, s, &transform_, out, blended);
    if (s.transition >= 0) ++transitions_;
  }
  node_ = options[pick].next;
}

}  // namespace mocapd
