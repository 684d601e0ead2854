// Motion graph benchmark (issue "Endless, varied test streams"): builds a graph over the
// takes (default: ../shared/data/bandai-namco-1, else the built-in humanoid's walk, turn
// and reach written as BVH), checks its file round-trips, and measures
//  - constrained synthesis as in Huang et al.'s Table III: per start/end pair a grid of
//    targets (distance 1-20 m by 1 m, time 1-40 s by 1 s), the min / RMS / max misses of
//    distance and time, and the time per synthesis;
//  - transitions' smoothness: over a seeded random walk, the joints' acceleration and the
//    feet's slide on blended frames against the 99th percentile inside the source takes;
//  - retrieval: each take as a query against the graph of the others (leave one out),
//    and the humanoid's walk (another skeleton), by the per-joint velocity difference.
// Usage: motion_graph_bench [--max-cost-m C] [--per-pair N] [--walk-seconds S] [--quick] [TAKE.bvh
// ...]
// --quick: a 5 x 10 grid instead of 20 x 40 (for a fast look).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "bench/bench_takes.hpp"
#include "sim/graph_match.hpp"
#include "sim/graph_planner.hpp"
#include "sim/graph_walker.hpp"
#include "sim/humanoid.hpp"
#include "sim/motion_graph.hpp"

using namespace mocapd;

namespace {

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[static_cast<size_t>(q * static_cast<double>(v.size() - 1))];
}

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// The humanoid's motions as BVH files in a temporary folder: a library with no outside data.
std::vector<std::string> HumanoidTakes(const std::string& folder) {
  std::filesystem::create_directories(folder);
  std::vector<std::string> paths;
  const Skeleton sk = MakeHumanoidSkeleton();
  for (const char* motion : {"walk", "turn", "reach", "mixed"}) {
    const std::string path = folder + "/humanoid_" + motion + ".bvh";
    WriteBvh(path, MakeBvhTake(sk, MakeHumanoidMotion(sk, ParseHumanoidMotion(motion), 20.0, 30.0),
                               1.0 / 30.0));
    paths.push_back(path);
  }
  return paths;
}

// The pairs of the constraint benchmark: from the first frames of the locomotion takes
// (any end, and back to the same take's late frame) where the graph can walk.
struct Pair {
  GraphPoint from;
  std::optional<GraphPoint> to;
};

std::vector<Pair> ChoosePairs(const MotionLibrary& lib, const GraphConnectivity& c) {
  std::vector<Pair> pairs;
  std::vector<int> walk_takes;
  for (int t = 0; t < lib.num_takes(); ++t)
    if (c.take_in_walk[static_cast<size_t>(t)]) walk_takes.push_back(t);
  // Prefer takes that travel: the fastest three of the walkable ones.
  std::sort(walk_takes.begin(), walk_takes.end(), [&](int a, int b) {
    return lib.path_m[static_cast<size_t>(a)].back() / lib.num_frames(a) >
           lib.path_m[static_cast<size_t>(b)].back() / lib.num_frames(b);
  });
  for (size_t k = 0; k < walk_takes.size() && k < 3; ++k) {
    const int t = walk_takes[k];
    // Start at the take's first walkable branch point, end at its last one.
    int first = -1, last = -1;
    for (int v = 0; v < c.nodes; ++v) {
      if (!c.node_in_walk[static_cast<size_t>(v)] || c.node_take[static_cast<size_t>(v)] != t)
        continue;
      const int f = c.node_frame[static_cast<size_t>(v)];
      if (first < 0 || f < first) first = f;
      if (last < 0 || f > last) last = f;
    }
    pairs.push_back({{t, first}, std::nullopt});
    if (k < 2) pairs.push_back({{t, first}, GraphPoint{t, last - 1}});
  }
  return pairs;
}

}  // namespace

int RunProgram(int argc, char** argv) {
  GraphBuildOptions build;
  double walk_seconds = 600.0;
  bool quick = false;
  std::vector<std::string> paths;
  for (int a = 1; a < argc; ++a) {
    if (!std::strcmp(argv[a], "--max-cost-m") && a + 1 < argc) {
      build.max_cost_m = std::atof(argv[++a]);
    } else if (!std::strcmp(argv[a], "--per-pair") && a + 1 < argc) {
      build.transitions_per_pair = std::atoi(argv[++a]);
    } else if (!std::strcmp(argv[a], "--walk-seconds") && a + 1 < argc) {
      walk_seconds = std::atof(argv[++a]);
    } else if (!std::strcmp(argv[a], "--quick")) {
      quick = true;
    } else if (argv[a][0] == '-') {
      std::fprintf(
          stderr,
          "usage: motion_graph_bench [--max-cost-m C] [--per-pair N] [--walk-seconds S] [--quick] "
          "[TAKE.bvh ...]\n");
      return 2;
    } else {
      paths.push_back(argv[a]);
    }
  }
  if (paths.empty()) paths = bench::SharedBvhTakes();
  const std::string tmp =
      (std::filesystem::temp_directory_path() / "mocapd_motion_graph_bench").string();
  if (paths.empty()) {
    std::printf("(no ../shared data: the built-in humanoid's takes)\n");
    paths = HumanoidTakes(tmp);
  }
  std::filesystem::create_directories(tmp);

  // Build and round trip.
  auto t0 = std::chrono::steady_clock::now();
  const MotionLibrary lib = LoadMotionLibrary(paths, 0.0);
  const double load_s = Seconds(t0);
  GraphBuildReport report;
  const MotionGraph graph = BuildMotionGraph(lib, build, &report);
  const std::string graph_path = tmp + "/graph.json";
  WriteMotionGraph(graph_path, graph);
  const MotionGraph again = ReadMotionGraph(graph_path);
  bool same = again.transitions.size() == graph.transitions.size();
  for (size_t k = 0; same && k < graph.transitions.size(); ++k) {
    const GraphTransition &a = graph.transitions[k], &b = again.transitions[k];
    same = a.from_take == b.from_take && a.from_frame == b.from_frame && a.to_take == b.to_take &&
           a.to_frame == b.to_frame && a.half_window == b.half_window &&
           std::abs(a.cost_m - b.cost_m) < 1e-12 &&
           std::abs(a.align.yaw_rad - b.align.yaw_rad) < 1e-12;
  }
  const GraphConnectivity c = AnalyseConnectivity(lib, graph);
  int frames = 0;
  for (int t = 0; t < lib.num_takes(); ++t) frames += lib.num_frames(t);
  std::printf(
      "graph: %d takes, %d frames at %.0f Hz; read and resampled in %.2f s, built in %.2f s "
      "(%d candidates, %d transitions at <= %.2f m); endless part %d of %d branch points "
      "in %d takes; file round trip %s\n\n",
      lib.num_takes(), frames, lib.rate_hz, load_s, report.seconds, report.candidates, report.kept,
      build.max_cost_m, c.walk_nodes, c.nodes, c.walk_takes, same ? "identical" : "DIFFERS");

  // Table III.
  const int max_d = quick ? 5 : 20, max_t = quick ? 10 : 40;
  std::printf("constrained synthesis: distance 1-%d m x time 1-%d s (%d targets per pair)\n", max_d,
              max_t, max_d * max_t);
  std::printf("  %-44s %22s %22s %18s %8s\n", "pair", "distance miss m", "time miss s",
              "ms per synthesis", "met");
  std::printf("  %-44s %22s %22s %18s\n", "", "min / RMS / max", "min / RMS / max",
              "shared / alone,met");
  std::vector<double> all_d, all_t, feasible_d;
  for (const Pair& p : ChoosePairs(lib, c)) {
    const auto prep = std::chrono::steady_clock::now();
    GraphPlanner planner(lib, graph);
    planner.Prepare(p.from, p.to, max_t + 1.0, max_d * 1.25 + 2.0);
    const double prep_s = Seconds(prep);
    std::vector<double> dm, tm, dm_feasible, tm_feasible;
    int met = 0;
    long transitions = 0;
    double solve_s = 0.0;
    for (int d = 1; d <= max_d; ++d)
      for (int t = 1; t <= max_t; ++t) {
        const auto s0 = std::chrono::steady_clock::now();
        SynthesisResult r;
        try {
          r = planner.Solve(d, t);
        } catch (const std::exception&) {
          r = Synthesize(lib, graph, p.from, p.to, d, t);
        }
        solve_s += Seconds(s0);
        dm.push_back(std::abs(r.distance_miss_m));
        tm.push_back(std::abs(r.time_miss_s));
        // Targets some path of the graph meets (the programme's own verdict, to a bin).
        if (r.exact_time && r.best_possible_miss_m <= 0.1) {
          dm_feasible.push_back(dm.back());
          tm_feasible.push_back(tm.back());
        }
        met += std::abs(r.distance_miss_m) <= 0.2 && std::abs(r.time_miss_s) <= 0.1;
        transitions += r.transitions;
      }
    // Syntheses alone, as `mocap-sim graph synth` runs them (its own programme each, and
    // a wider second one when the target cannot be met): the slowest of a spread of targets.
    double alone_ms = 0.0, alone_unmet_ms = 0.0;
    for (int d = max_d / 4; d <= max_d; d += std::max(1, max_d / 4))
      for (int t = max_t / 8; t <= max_t; t += std::max(1, max_t / 8)) {
        const auto s1 = std::chrono::steady_clock::now();
        const SynthesisResult r = Synthesize(lib, graph, p.from, p.to, d, t);
        const double ms = Seconds(s1) * 1e3;
        if (r.exact_time && std::abs(r.distance_miss_m) <= 0.2)
          alone_ms = std::max(alone_ms, ms);
        else
          alone_unmet_ms = std::max(alone_unmet_ms, ms);
      }
    auto stats = [](const std::vector<double>& v) {
      double sq = 0.0;
      for (double x : v) sq += x * x;
      char buf[64];
      std::snprintf(buf, sizeof(buf), "%.3f / %.3f / %.3f", *std::min_element(v.begin(), v.end()),
                    std::sqrt(sq / static_cast<double>(v.size())),
                    *std::max_element(v.begin(), v.end()));
      return std::string(buf);
    };
    std::string name = lib.names[static_cast<size_t>(p.from.take)] + ":" +
                       std::to_string(p.from.frame) +
                       (p.to ? " -> " + std::to_string(p.to->frame) : " -> any");
    std::printf("  %-44s %22s %22s %8.2f / %7.1f %4d/%zu\n", name.c_str(), stats(dm).c_str(),
                stats(tm).c_str(), (prep_s + solve_s) * 1e3 / static_cast<double>(dm.size()),
                alone_ms, met, dm.size());
    if (!dm_feasible.empty())
      std::printf(
          "  %-44s %22s %22s   (the %zu targets the graph can meet; alone, unmet %.0f ms)\n", "",
          stats(dm_feasible).c_str(), stats(tm_feasible).c_str(), dm_feasible.size(),
          alone_unmet_ms);
    std::printf("  %-44s %.1f transitions per synthesis on average\n", "",
                static_cast<double>(transitions) / static_cast<double>(dm.size()));
    feasible_d.insert(feasible_d.end(), dm_feasible.begin(), dm_feasible.end());
    all_d.insert(all_d.end(), dm.begin(), dm.end());
    all_t.insert(all_t.end(), tm.begin(), tm.end());
  }
  std::printf("  misses over all pairs: distance p50 %.3f p99 %.3f max %.3f m; time max %.3f s\n",
              Percentile(all_d, 0.5), Percentile(all_d, 0.99), Percentile(all_d, 1.0),
              Percentile(all_t, 1.0));
  std::printf("  over the %zu of %zu targets the graph can meet: distance max %.3f m\n\n",
              feasible_d.size(), all_d.size(), Percentile(feasible_d, 1.0));

  // Smoothness: a random walk's blended frames against the source takes.
  std::vector<double> src_acc, src_slide;
  for (int t = 0; t < lib.num_takes(); ++t) {
    const MotionSmoothness m = MeasureSmoothness(lib, lib.takes[static_cast<size_t>(t)]);
    src_acc.insert(src_acc.end(), m.acceleration.begin() + 1, m.acceleration.end() - 1);
    src_slide.insert(src_slide.end(), m.foot_slide.begin() + 1, m.foot_slide.end() - 1);
  }
  GraphWalker walker(lib, graph, WalkOptions{});
  std::vector<Pose> walk;
  std::vector<uint8_t> blended;
  while (walk.size() < static_cast<size_t>(walk_seconds * lib.rate_hz))
    walker.NextFrames(&walk, &blended);
  const MotionSmoothness m = MeasureSmoothness(lib, walk);
  double farthest = 0.0;
  for (const Pose& p : walk) {
    const Vec3 root = lib.parent_position +
                      lib.parent_rotation * p.translation[static_cast<size_t>(lib.body_root)];
    farthest = std::max(farthest, std::hypot(root.x(), root.z()));
  }
  std::vector<double> acc, slide;
  for (size_t f = 1; f + 1 < walk.size(); ++f)
    if (blended[f]) {
      acc.push_back(m.acceleration[f]);
      slide.push_back(m.foot_slide[f]);
    }
  const double acc99 = Percentile(src_acc, 0.99), slide99 = Percentile(src_slide, 0.99);
  auto above = [](const std::vector<double>& v, double limit) {
    return 100.0 *
           static_cast<double>(
               std::count_if(v.begin(), v.end(), [&](double x) { return x > limit; })) /
           static_cast<double>(std::max<size_t>(1, v.size()));
  };
  std::printf(
      "transitions (%.0f s random walk, %d blends, %zu blended frames; farthest from home %.1f "
      "m):\n",
      walk_seconds, walker.transitions_taken(), acc.size(), farthest);
  std::printf(
      "  joint acceleration m/s^2: source p50 %.2f p99 %.2f | blended p50 %.2f p99 %.2f max %.2f; "
      "%.2f %% of blended frames above the source p99\n",
      Percentile(src_acc, 0.5), acc99, Percentile(acc, 0.5), Percentile(acc, 0.99),
      Percentile(acc, 1.0), above(acc, acc99));
  std::printf(
      "  foot slide m/s:           source p50 %.3f p99 %.3f | blended p50 %.3f p99 %.3f max %.3f; "
      "%.2f %% of blended frames above the source p99\n\n",
      Percentile(src_slide, 0.5), slide99, Percentile(slide, 0.5), Percentile(slide, 0.99),
      Percentile(slide, 1.0), above(slide, slide99));

  // Retrieval: leave one out, and the humanoid's walk.
  std::printf("retrieval (joint velocity difference, cm/frame at %.0f Hz):\n", lib.rate_hz);
  if (lib.num_takes() >= 3) {
    for (int q = 0; q < lib.num_takes(); ++q) {
      std::vector<std::string> others;
      for (int t = 0; t < lib.num_takes(); ++t)
        if (t != q) others.push_back(paths[static_cast<size_t>(t)]);
      const MotionLibrary rest = LoadMotionLibrary(others, lib.rate_hz);
      const MotionGraph g = BuildMotionGraph(rest, build);
      const BvhTake query = ReadBvh(paths[static_cast<size_t>(q)]);
      const auto s = std::chrono::steady_clock::now();
      const MatchResult r = MatchQuery(rest, g, query);
      std::printf("  %-36s mean %.2f  worst frame %.2f  (%d jumps, %.0f ms)\n",
                  lib.names[static_cast<size_t>(q)].c_str(), r.velocity_difference_cm,
                  r.worst_velocity_difference_cm, r.jumps, Seconds(s) * 1e3);
    }
  }
  const Skeleton sk = MakeHumanoidSkeleton();
  const BvhTake humanoid_walk =
      MakeBvhTake(sk, MakeHumanoidMotion(sk, HumanoidMotion::kWalk, 10.0, 30.0), 1.0 / 30.0);
  const MatchResult r = MatchQuery(lib, graph, humanoid_walk);
  std::printf("  %-36s mean %.2f  worst frame %.2f  (%d jumps)\n", "humanoid walk (other skeleton)",
              r.velocity_difference_cm, r.worst_velocity_difference_cm, r.jumps);
  return 0;
}

int main(int argc, char** argv) {
  return mocapd::bench::RunReportingErrors("motion_graph_bench", RunProgram, argc, argv);
}
