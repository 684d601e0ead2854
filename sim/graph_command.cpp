// The motion graph's command-line verbs.
#include "sim/graph_command.hpp"

#include <chrono>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>

#include "formats/bvh.hpp"
#include "formats/file_paths.hpp"
#include "formats/subject_file.hpp"
#include "sim/cli_checks.hpp"
#include "sim/graph_match.hpp"
#include "sim/graph_planner.hpp"
#include "sim/graph_walker.hpp"
#include "sim/motion_graph.hpp"
#include "sim/replay_sources.hpp"

namespace mocapd {

struct GraphCommands::State {
  CLI::App* graph = nullptr;
  CLI::App* build = nullptr;
  CLI::App* synth = nullptr;
  CLI::App* match = nullptr;
  // build
  std::vector<std::string> takes;
  std::string out;
  double rate_hz = 0.0;
  std::string units;
  GraphBuildOptions options;
  // synth / match
  std::string graph_path;
  double distance_m = 0.0;
  double seconds = 0.0;
  std::string from, to;
  std::string path_out;
  std::string query;
  std::string query_units;
  std::string subject_out;
};

GraphCommands::GraphCommands(CLI::App& app) : state_(std::make_unique<State>()) {
  State& s = *state_;
  s.graph = app.add_subcommand("graph", "Motion graphs: endless, steerable motion from takes");
  s.graph->require_subcommand(1);

  s.build = s.graph->add_subcommand("build", "Build a motion graph over BVH takes of one skeleton");
  s.build->add_option("TAKES", s.takes, "BVH takes")->required()->check(kExistingFile);
  s.build->add_option("--out", s.out, "Graph file to write (JSON)")
      ->required()
      ->check(kNonEmptyPath);
  s.build->add_option("--rate", s.rate_hz, "Graph rate in Hz (default: the first take's)")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(1.0, 1000.0));
  s.build->add_option("--units", s.units, "BVH length unit: mm, cm, m or in (default: guess)")
      ->check(kLengthUnit);
  s.build
      ->add_option("--subject-out", s.subject_out,
                   "Also write the subject a daemon needs for `replay --graph` of this graph "
                   "(the takes' skeleton with the default marker layout)")
      ->check(kNonEmptyPath);
  s.build
      ->add_option("--transitions-per-pair", s.options.transitions_per_pair,
                   "Best transitions kept per ordered pair of takes")
      ->check(CLI::TypeValidator<int>())
      ->check(CLI::Range(1, 100))
      ->capture_default_str();
  s.build
      ->add_option("--max-cost-m", s.options.max_cost_m,
                   "Largest blend distortion kept (weighted RMS joint distance, m)")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.001, 10.0))
      ->capture_default_str();
  s.build
      ->add_option("--max-window-s", s.options.max_window_s,
                   "Longest blend half-window L (the blend spans 2L)")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.02, 0.99))
      ->capture_default_str();

  s.synth = s.graph->add_subcommand(
      "synth", "Synthesize motion covering a distance in a time, from and to given frames");
  s.synth->add_option("--graph", s.graph_path, "Graph file")->required()->check(kExistingFile);
  s.synth->add_option("--distance", s.distance_m, "Distance the root travels, metres")
      ->required()
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.0, 5000.0));
  s.synth->add_option("--time", s.seconds, "Duration, seconds")
      ->required()
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.01, 3600.0));
  s.synth->add_option("--from", s.from,
                      "First frame, TAKE:FRAME (default: the first take's frame 0)");
  s.synth->add_option("--to", s.to, "Last frame, TAKE:FRAME (default: anywhere)");
  s.synth->add_option("--out", s.out, "BVH to write")->required()->check(kNonEmptyPath);
  s.synth->add_option("--path-out", s.path_out, "Also write the path taken (JSON)")
      ->check(kNonEmptyPath);

  s.match = s.graph->add_subcommand(
      "match", "Retrieve the graph path that best follows a query motion (any humanoid skeleton)");
  s.match->add_option("QUERY", s.query, "Query BVH")->required()->check(kExistingFile);
  s.match->add_option("--graph", s.graph_path, "Graph file")->required()->check(kExistingFile);
  s.match->add_option("--query-units", s.query_units, "Query BVH unit (default: guess)")
      ->check(kLengthUnit);
  s.match->add_option("--out", s.out, "BVH of the retrieved motion to write")
      ->required()
      ->check(kNonEmptyPath);
  s.match->add_option("--path-out", s.path_out, "Also write the path taken (JSON)")
      ->check(kNonEmptyPath);
}

GraphCommands::~GraphCommands() = default;

bool GraphCommands::Selected() const { return state_->graph->parsed(); }

namespace {

// A synthesis within this of its distance (and on the frame of its time) meets its target.
constexpr double kMetDistanceM = 0.2;

nlohmann::json PathJson(const MotionLibrary& lib, const MotionGraph& graph, const GraphPath& path) {
  nlohmann::json steps = nlohmann::json::array();
  for (const PathStep& s : path) {
    if (s.transition >= 0) {
      const GraphTransition& t = graph.transitions[static_cast<size_t>(s.transition)];
      steps.push_back({{"blend", s.transition},
                       {"from", lib.names[static_cast<size_t>(t.from_take)]},
                       {"from_frame", t.exit_frame()},
                       {"to", lib.names[static_cast<size_t>(t.to_take)]},
                       {"to_frame", t.entry_frame() - 1},
                       {"frames", t.blend_frames()},
                       {"cost_m", t.cost_m}});
    } else {
      steps.push_back({{"take", lib.names[static_cast<size_t>(s.take)]},
                       {"first", s.first},
                       {"count", s.count}});
    }
  }
  return steps;
}

void WriteJson(const std::string& path, const nlohmann::json& j) {
  std::ofstream out(path);
  out << j.dump(1) << "\n";
  if (!out) throw std::runtime_error(path + ": cannot write");
}

}  // namespace

int GraphCommands::Run() {
  State& s = *state_;
  std::vector<NamedPath> inputs = {{"--graph", s.graph_path}, {"QUERY", s.query}};
  for (const std::string& take : s.takes) inputs.push_back({"TAKES", take});
  // synth and match read every take the graph names: a source take is an input too.
  if (!s.build->parsed())
    for (const GraphTakeRef& take : ReadMotionGraph(s.graph_path).takes)
      inputs.push_back({"--graph " + s.graph_path + "'s take", take.path});
  const NamedPath outputs[] = {
      {"--out", s.out}, {"--subject-out", s.subject_out}, {"--path-out", s.path_out}};
  CheckOutputPaths(inputs, outputs);
  if (s.build->parsed()) {
    const MotionLibrary lib = LoadMotionLibrary(s.takes, s.rate_hz, s.units);
    GraphBuildReport report;
    MotionGraph graph = BuildMotionGraph(lib, s.options, &report);
    graph.units = s.units;
    WriteMotionGraph(s.out, graph);
    const GraphConnectivity connectivity = AnalyseConnectivity(lib, graph);
    int frames = 0;
    for (int t = 0; t < lib.num_takes(); ++t) frames += lib.num_frames(t);
    std::printf("graph over %d takes, %d frames at %.0f Hz (%.1f s of motion)\n", lib.num_takes(),
                frames, lib.rate_hz, frames / lib.rate_hz);
    std::printf(
        "  %d candidate transitions (local minima), %d kept (best %d per pair, blend "
        "distortion <= %.3f m); built in %.2f s\n",
        report.candidates, report.kept, s.options.transitions_per_pair, s.options.max_cost_m,
        report.seconds);
    for (int t = 0; t < lib.num_takes(); ++t) {
      int out = 0, in = 0;
      for (const GraphTransition& tr : graph.transitions) {
        out += tr.from_take == t;
        in += tr.to_take == t;
      }
      std::printf(
          "  %-32s %5d frames  %3d out  %3d in%s\n", lib.names[static_cast<size_t>(t)].c_str(),
          lib.num_frames(t), out, in,
          connectivity.take_in_walk[static_cast<size_t>(t)] ? "" : "  (not in the endless part)");
    }
    std::printf("  endless part (largest strongly connected): %d of %d branch points, %d takes\n",
                connectivity.walk_nodes, connectivity.nodes, connectivity.walk_takes);
    if (connectivity.walk_nodes == 0)
      std::printf(
          "warning: no walk can loop through this graph, so `replay --graph` cannot use it "
          "and syntheses are as long as the takes; check --units, or allow looser "
          "transitions (--max-cost-m, --transitions-per-pair)\n");
    std::printf("wrote %s\n", s.out.c_str());
    if (!s.subject_out.empty()) {
      SubjectModel model;
      model.name = "graph";
      model.bvh_units = lib.layout.units;
      model.skeleton = lib.skeleton;
      model.markers = GraphMarkers(lib);
      WriteSubjectModel(s.subject_out, model);
      std::printf("wrote %s (the subject for `mocap-sim replay --graph %s`)\n",
                  s.subject_out.c_str(), s.out.c_str());
    }
    return 0;
  }
  const MotionGraph graph = ReadMotionGraph(s.graph_path);
  const MotionLibrary lib = LoadGraphLibrary(graph, s.graph_path);
  if (s.synth->parsed()) {
    GraphPoint from{0, 0};
    if (s.from.empty()) {
      // The first take a walk can loop through: from there every target has a chance.
      const GraphConnectivity c = AnalyseConnectivity(lib, graph);
      for (int t = 0; t < lib.num_takes(); ++t)
        if (c.take_in_walk[static_cast<size_t>(t)]) {
          from.take = t;
          break;
        }
      std::printf("from %s:0 (no --from: the first take a walk can loop through)\n",
                  lib.names[static_cast<size_t>(from.take)].c_str());
    } else {
      from = ParseGraphPoint(lib, s.from);
    }
    std::optional<GraphPoint> to;
    if (!s.to.empty()) to = ParseGraphPoint(lib, s.to);
    const auto start = std::chrono::steady_clock::now();
    const SynthesisResult r = Synthesize(lib, graph, from, to, s.distance_m, s.seconds);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    WriteBvh(s.out, SynthesisTake(lib, graph, r.path));
    std::printf("path: %s\n", DescribePath(lib, graph, r.path).c_str());
    std::printf(
        "distance %.3f m (target %.3f, miss %+.3f m), time %.3f s (target %.3f, miss %+.3f s)\n",
        r.distance_m, s.distance_m, r.distance_miss_m, r.seconds, s.seconds, r.time_miss_s);
    std::printf("%d transitions (distortion %.3f m in all), planned in %.1f ms\n", r.transitions,
                r.transition_cost_m, ms);
    const bool met = r.exact_time && std::abs(r.distance_miss_m) <= kMetDistanceM;
    if (!met)
      std::printf(
          "note: no path meets the constraints (within %.1f m and a frame); this is the "
          "nearest one (exit status 2)\n",
          kMetDistanceM);
    if (r.distance_bin_m > 0.011)
      std::printf("note: planned in %.0f cm distance steps (a long plan widens them)\n",
                  r.distance_bin_m * 100.0);
    std::printf("wrote %s (%d frames)\n", s.out.c_str(), r.frames);
    if (!s.path_out.empty()) {
      WriteJson(s.path_out, {{"distance_m", r.distance_m},
                             {"target_distance_m", s.distance_m},
                             {"seconds", r.seconds},
                             {"target_seconds", s.seconds},
                             {"frames", r.frames},
                             {"rate_hz", lib.rate_hz},
                             {"steps", PathJson(lib, graph, r.path)}});
      std::printf("wrote %s\n", s.path_out.c_str());
    }
    return met ? 0 : 2;
  }
  if (s.match->parsed()) {
    BvhReadOptions read;
    read.units = s.query_units;
    const BvhTake query = ReadBvh(s.query, read);
    const auto start = std::chrono::steady_clock::now();
    const MatchResult r = MatchQuery(lib, graph, query);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    WriteBvh(s.out, SynthesisTake(lib, graph, r.path));
    std::printf("path: %s\n", DescribePath(lib, graph, r.path).c_str());
    std::printf(
        "query %d frames -> %d frames, %d jumps; joint velocity difference mean %.2f "
        "cm/frame, worst frame %.2f cm/frame (at %.0f Hz, query's scale); %.0f ms\n",
        r.query_frames, PathFrames(graph, r.path), r.jumps, r.velocity_difference_cm,
        r.worst_velocity_difference_cm, lib.rate_hz, ms);
    std::printf("wrote %s\n", s.out.c_str());
    if (!s.path_out.empty()) {
      WriteJson(s.path_out, {{"velocity_difference_cm_per_frame", r.velocity_difference_cm},
                             {"steps", PathJson(lib, graph, r.path)}});
      std::printf("wrote %s\n", s.path_out.c_str());
    }
    return 0;
  }
  return 1;
}

}  // namespace mocapd
