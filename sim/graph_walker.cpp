// The motion graph's connectivity and its endless random walk.
#include "sim/graph_walker.hpp"

#include <algorithm>
#include <functional>
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
  // Tarjan's strongly connected components (the graph is small: recursion depth <= nodes).
  std::vector<int> index(static_cast<size_t>(c.nodes), -1), low(static_cast<size_t>(c.nodes), 0),
      component(static_cast<size_t>(c.nodes), -1);
  std::vector<bool> on_stack(static_cast<size_t>(c.nodes), false);
  std::vector<int> stack;
  int counter = 0, components = 0;
  std::function<void(int)> visit = [&](int v) {
    const auto uv = static_cast<size_t>(v);
    index[uv] = low[uv] = counter++;
    stack.push_back(v);
    on_stack[uv] = true;
    std::vector<int> next;
    if (c.skip[uv] >= 0) next.push_back(c.skip[uv]);
    for (const auto& [t, w] : c.leave[uv]) next.push_back(w);
    for (int w : next) {
      const auto uw = static_cast<size_t>(w);
      if (index[uw] < 0) {
        visit(w);
        low[uv] = std::min(low[uv], low[uw]);
      } else if (on_stack[uw]) {
        low[uv] = std::min(low[uv], index[uw]);
      }
    }
    if (low[uv] == index[uv]) {
      int w;
      do {
        w = stack.back();
        stack.pop_back();
        on_stack[static_cast<size_t>(w)] = false;
        component[static_cast<size_t>(w)] = components;
      } while (w != v);
      ++components;
    }
  };
  for (int v = 0; v < c.nodes; ++v)
    if (index[static_cast<size_t>(v)] < 0) visit(v);
  std::vector<int> size(static_cast<size_t>(components), 0);
  for (int v = 0; v < c.nodes; ++v) ++size[static_cast<size_t>(component[static_cast<size_t>(v)])];
  int largest = -1;
  for (int k = 0; k < components; ++k)
    if (size[static_cast<size_t>(k)] > 1 &&
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

Vec3 GraphWalker::RootAfter(const PathStep& step, const PlanarTransform& transform) const {
  if (step.transition < 0)
    return transform.Apply(lib_.root_position[static_cast<size_t>(step.take)]
                                             [static_cast<size_t>(step.first + step.count - 1)]);
  const GraphTransition& t = graph_.transitions[static_cast<size_t>(step.transition)];
  return transform.Compose(t.align).Apply(
      lib_.root_position[static_cast<size_t>(t.to_take)][static_cast<size_t>(t.entry_frame() - 1)]);
}

void GraphWalker::NextFrames(std::vector<Pose>* out, std::vector<uint8_t>* blended) {
  const auto un = static_cast<size_t>(node_);
  const int take = connectivity_.node_take[un];
  const int frame = connectivity_.node_frame[un];
  // The options: play on to the next branch point, or leave through a transition (each
  // followed by the play to the branch point after it); only into the walkable part.
  struct Option {
    int transition;  // -1: play on
    int next;
  };
  std::vector<Option> options;
  const int skip = connectivity_.skip[un];
  if (skip >= 0 && connectivity_.node_in_walk[static_cast<size_t>(skip)])
    options.push_back({-1, skip});
  for (const auto& [t, next] : connectivity_.leave[un])
    if (connectivity_.node_in_walk[static_cast<size_t>(next)]) options.push_back({t, next});
  // In the walkable part every node has a way on; this only guards a broken invariant.
  if (options.empty()) throw std::logic_error("graph walk: a walkable node has no way on");

  auto steps_of = [&](const Option& o) {
    std::vector<PathStep> steps;
    const int next_frame = connectivity_.node_frame[static_cast<size_t>(o.next)];
    if (o.transition < 0) {
      steps.push_back({take, frame, next_frame - frame, -1});
    } else {
      const GraphTransition& t = graph_.transitions[static_cast<size_t>(o.transition)];
      steps.push_back({-1, 0, 0, o.transition});
      if (next_frame > t.entry_frame())
        steps.push_back({t.to_take, t.entry_frame(), next_frame - t.entry_frame(), -1});
    }
    return steps;
  };
  size_t pick = 0;
  const Vec3 here =
      transform_.Apply(lib_.root_position[static_cast<size_t>(take)][static_cast<size_t>(frame)]);
  if (std::hypot(here.x(), here.z()) > options_.home_radius_m) {
    // Strayed: the option whose end lands nearest home.
    double best = 1e300;
    for (size_t k = 0; k < options.size(); ++k) {
      PlanarTransform t = transform_;
      Vec3 end = here;
      for (const PathStep& s : steps_of(options[k])) {
        end = RootAfter(s, t);
        if (s.transition >= 0)
          t = t.Compose(graph_.transitions[static_cast<size_t>(s.transition)].align);
      }
      const double d = std::hypot(end.x(), end.z());
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
  for (const PathStep& s : steps_of(options[pick])) {
    RenderStep(lib_, graph_, s, &transform_, out, blended);
    if (s.transition >= 0) ++transitions_;
  }
  node_ = options[pick].next;
}

}  // namespace mocapd
