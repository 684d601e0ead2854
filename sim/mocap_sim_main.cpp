// mocap-sim: the replay simulator's command line. Subcommands:
//   info   summarise a C3D or BVH take or a recording
//   synth  place a virtual marker set on a BVH (or the built-in humanoid) and write the marker take
//   replay publish a take's (or a recording's) marker frames to the daemon in real time and measure
//          what comes back
//   record subscribe to a capture publisher and record its stream with timing
//   graph  motion graphs: build one over takes, synthesize under constraints, retrieve
#include <CLI/CLI.hpp>
#include <atomic>
#include <csignal>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <random>
#include <stdexcept>

#include "filters/cleanup_options.hpp"
#include "formats/bvh.hpp"
#include "formats/c3d.hpp"
#include "formats/file_paths.hpp"
#include "formats/marker_layout.hpp"
#include "formats/marker_set.hpp"
#include "formats/subject_file.hpp"
#include "formats/take_frames.hpp"
#include "sim/cli_checks.hpp"
#include "sim/corruption.hpp"
#include "sim/graph_command.hpp"
#include "sim/humanoid.hpp"
#include "sim/recording.hpp"
#include "sim/replay.hpp"
#include "sim/synthesis.hpp"
#include "sim/take_info.hpp"

namespace {

// Names in the JSON outputs come from files and senders: bytes that are no UTF-8 are
// written as U+FFFD rather than failing the whole output.
constexpr auto kReplaceInvalidUtf8 = nlohmann::json::error_handler_t::replace;

struct SynthOptions {
  std::string bvh;
  std::string humanoid_motion;
  double seconds = 10.0;
  std::string out;
  double rate_hz = 0.0;
  std::string subject_out;
  std::string layout;
  std::string marker_set;
  double soft_tissue_mm = 0.0;
  std::string truth_bvh;
  std::string bvh_units;
  double noise_mm = 0.0;
  uint64_t seed = 1;
  std::string corrupt;
  std::string truth_mask;
};

// A marker-set name (cmu-41) is no file; a set file is an input like any other.
std::string MarkerSetFile(const std::string& set) {
  return std::filesystem::is_regular_file(set) ? set : "";
}

int RunSynth(const SynthOptions& o) {
  const mocapd::NamedPath inputs[] = {
      {"--bvh", o.bvh}, {"--layout", o.layout}, {"--marker-set", MarkerSetFile(o.marker_set)}};
  const mocapd::NamedPath outputs[] = {{"--out", o.out},
                                       {"--subject-out", o.subject_out},
                                       {"--truth-bvh", o.truth_bvh},
                                       {"--truth", o.truth_mask}};
  mocapd::CheckOutputPaths(inputs, outputs);
  mocapd::BvhTake source;
  if (!o.bvh.empty()) {
    mocapd::BvhReadOptions read;
    read.units = o.bvh_units;
    source = mocapd::ReadBvh(o.bvh, read);
    if (source.frames.empty())
      throw std::runtime_error(o.bvh +
                               ": the take has no frames (Frames: 0): no motion to place "
                               "markers on");
  } else {
    const double rate = o.rate_hz > 0 ? o.rate_hz : 120.0;
    mocapd::Skeleton sk = mocapd::MakeHumanoidSkeleton();
    auto frames = mocapd::MakeHumanoidMotion(sk, mocapd::ParseHumanoidMotion(o.humanoid_motion),
                                             o.seconds, rate);
    source = mocapd::MakeBvhTake(std::move(sk), std::move(frames), 1.0 / rate, "cm");
  }
  const double rate = o.rate_hz > 0 ? o.rate_hz : source.rate_hz();
  // The reader holds a take of several frames to the cleanup's rates; one frame has no
  // rate to judge, and its Frame Time would become the C3D's.
  if (!(rate >= mocapd::kMinCaptureRateHz && rate <= mocapd::kMaxCaptureRateHz)) {
    char text[64];
    std::snprintf(text, sizeof(text), "%.6g", rate);
    throw std::runtime_error(o.bvh + ": a rate of " + text +
                             " Hz (its Frame Time); give the take's rate with --rate");
  }
  std::vector<mocapd::Pose> motion =
      mocapd::ResampleMotion(source.skeleton, source.frames, source.rate_hz(), rate);
  mocapd::HumanoidRoles roles;
  try {
    roles = mocapd::MatchHumanoidRoles(source.skeleton);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error((o.bvh.empty() ? "the built-in humanoid" : o.bvh) + ": " + e.what());
  }
  std::shared_ptr<const mocapd::MarkerSet> markers;
  if (!o.marker_set.empty()) {
    markers = std::make_shared<const mocapd::MarkerSet>(
        source.skeleton,
        mocapd::PlaceMarkerSet(source.skeleton, roles, mocapd::FindMarkerSet(o.marker_set),
                               source.end_sites));
  } else {
    const auto layout =
        o.layout.empty() ? mocapd::DefaultMarkerLayout() : mocapd::ReadMarkerLayout(o.layout);
    markers = std::make_shared<const mocapd::MarkerSet>(
        source.skeleton, mocapd::PlaceMarkers(source.skeleton, roles, layout, source.end_sites));
  }
  mocapd::SynthesisNoise noise;
  noise.noise_sigma_m = o.noise_mm * 1e-3;
  noise.soft_tissue_m = o.soft_tissue_mm * 1e-3;
  noise.seed = o.seed;
  mocapd::C3dTake take = mocapd::SynthesizeMarkers(source.skeleton, *markers, motion, rate, noise);
  if (!o.corrupt.empty()) {
    mocapd::CorruptionOptions corruption;
    corruption.severity = mocapd::ParseCorruptionSeverity(o.corrupt);
    corruption.seed = o.seed;
    mocapd::CorruptedTake corrupted = mocapd::CorruptTake(take, markers.get(), corruption);
    std::cout << "corrupted " << 100.0 * corrupted.corrupted_fraction << " % of marker-samples ("
              << corrupted.events.size() << " events, " << o.corrupt << ", seed " << o.seed
              << ")\n";
    if (!o.truth_mask.empty()) {
      std::ofstream(o.truth_mask) << mocapd::CorruptionTruthJson(corrupted, corruption)
                                         .dump(1, ' ', false, kReplaceInvalidUtf8)
                                  << "\n";
      std::cout << "wrote " << o.truth_mask << "\n";
    }
    take = std::move(corrupted.take);
  }
  mocapd::WriteC3d(o.out, take);
  std::cout << "wrote " << o.out << ": " << take.num_frames << " frames at " << rate << " Hz, "
            << markers->num_markers() << " markers\n";
  if (source.units_guessed && !o.bvh.empty())
    std::cout << "note: " << o.bvh << "'s length unit taken as " << source.units
              << ", guessed from its bones (--bvh-units says otherwise: a guess cannot tell in "
                 "from cm)\n";
  if (!o.subject_out.empty()) {
    mocapd::SubjectModel model;
    model.name = "synthetic";
    model.bvh_units = source.units;
    model.skeleton = std::make_shared<const mocapd::Skeleton>(source.skeleton);
    model.markers = markers;
    mocapd::WriteSubjectModel(o.subject_out, model);
    std::cout << "wrote " << o.subject_out << "\n";
  }
  if (!o.truth_bvh.empty()) {
    mocapd::BvhTake truth = source;
    truth.frames = std::move(motion);
    truth.frame_time_s = 1.0 / rate;
    mocapd::WriteBvh(o.truth_bvh, truth);
    std::cout << "wrote " << o.truth_bvh << " (ground-truth motion at " << rate << " Hz)\n";
  }
  return 0;
}

struct ReplayCommand {
  std::string take;
  std::string humanoid;
  std::string graph;
  double seconds = 30.0;
  double synth_rate_hz = 120.0;
  double noise_mm = 0.5;
  std::string subject;
  std::string marker_set;
  std::string bvh_units;
  std::string rate = "realtime";
  std::string report;
  std::string plot;
  mocapd::ReplayOptions options;
};

std::atomic<bool> g_stop{false};

int RunReplayCommand(ReplayCommand& c) {
  std::vector<mocapd::NamedPath> inputs = {{"TAKE", c.take},
                                           {"--graph", c.graph},
                                           {"--subject", c.subject},
                                           {"--marker-set", MarkerSetFile(c.marker_set)},
                                           {"--curve-key", c.options.curve_key_file},
                                           {"--curve-server-key", c.options.curve_server_key_file}};
  const mocapd::NamedPath outputs[] = {{"--report", c.report}, {"--plot", c.plot}};
  mocapd::CheckOutputPaths(inputs, outputs);
  mocapd::ReplaySource source;
  if (!c.take.empty() + !c.humanoid.empty() + !c.graph.empty() > 1)
    throw std::invalid_argument("replay: give one of a TAKE file, --humanoid or --graph");
  mocapd::GraphReplaySource graph_source;
  if (!c.graph.empty()) {
    if (c.options.loops != 1)
      throw std::invalid_argument("replay: a graph stream never loops; --seconds sets its length");
    graph_source = mocapd::GraphSource(c.graph);
    // The takes the graph names are read as it plays: inputs too.
    for (const mocapd::GraphTakeRef& take : graph_source.graph->takes)
      inputs.push_back({"--graph " + c.graph + "'s take", take.path});
    mocapd::CheckOutputPaths(inputs, outputs);
  }
  const bool recording = !c.take.empty() && mocapd::IsRecordingFile(c.take);
  if (recording) {
    if (c.rate != "realtime" && c.rate != "max")
      throw std::invalid_argument(
          "replay: a recording plays at --rate realtime (its own timing) or max");
    if (!c.options.corrupt.empty() || c.options.subjects != 1 || c.options.loops != 1)
      throw std::invalid_argument(
          "replay: --corrupt, --subjects and --loop apply to takes, not recordings");
  } else if (!c.graph.empty()) {
    // The graph stream is made while it plays.
  } else if (c.take.empty()) {
    source = mocapd::HumanoidReplaySource(c.humanoid.empty() ? "mixed" : c.humanoid, c.seconds,
                                          c.synth_rate_hz, c.noise_mm, c.options.seed);
  } else if (c.take.size() > 4 && c.take.substr(c.take.size() - 4) == ".bvh") {
    source = mocapd::BvhReplaySource(c.take, c.synth_rate_hz, c.bvh_units);
  } else {
    source = mocapd::C3dReplaySource(c.take, c.subject, c.marker_set);
    // As `mocapd process` refuses it: most likely the wrong subject or marker set, and
    // the daemon would clean frames of mostly missing markers without a word.
    const mocapd::TakeMarkerMap map(*source.markers, source.take);
    const int subject_markers = source.markers->num_markers();
    if (2 * map.matched() < subject_markers)
      std::cout << "warning: only " << map.matched() << " of the subject's " << subject_markers
                << " markers ("
                << (!c.marker_set.empty() ? "marker set " + c.marker_set
                    : c.subject.empty()   ? std::string("the built-in humanoid")
                                          : c.subject)
                << ") are labelled in " << c.take
                << "; the rest stay missing in every frame: is --subject (or --marker-set) "
                   "the take's?\n";
  }
  if (c.rate == "realtime")
    c.options.rate_hz = 0.0;
  else if (c.rate == "max")
    c.options.rate_hz = -1.0;
  else {
    try {
      size_t used = 0;
      c.options.rate_hz = std::stod(c.rate, &used);
      if (used != c.rate.size()) throw std::invalid_argument("trailing text");  // "120x"
    } catch (const std::exception&) {
      throw std::invalid_argument("replay: --rate must be realtime, max or a rate in Hz, got '" +
                                  c.rate + "'");
    }
    if (!(c.options.rate_hz > 0 && c.options.rate_hz <= 100000))
      throw std::invalid_argument("replay: --rate out of range: " + c.rate);
  }
  c.options.stop = &g_stop;
  c.options.on_status = [](const std::string& line) {
    std::cout << "  " << line << "\n" << std::flush;
  };
  std::signal(SIGINT, [](int) { g_stop = true; });
  std::signal(SIGTERM, [](int) { g_stop = true; });
  if (!c.graph.empty())
    std::cout << "replaying " << graph_source.description << ": " << c.seconds << " s at "
              << c.synth_rate_hz << " Hz to " << c.options.to << " (" << c.options.subjects
              << " subject(s), each on its own walk, "
              << (c.options.corrupt.empty() ? "clean" : c.options.corrupt + " corruption") << ")\n"
              << std::flush;
  else if (!recording)
    std::cout << "replaying " << source.description << " to " << c.options.to << " ("
              << c.options.subjects << " subject(s), " << c.options.loops << " loop(s), "
              << (c.options.corrupt.empty() ? "clean" : c.options.corrupt + " corruption") << ")\n"
              << std::flush;
  mocapd::ReplayReport report;
  if (recording) {
    const mocapd::Recording rec = mocapd::ReadRecording(c.take);
    if (rec.ignored_tail_bytes > 0)
      std::cout << "note: " << c.take << " ends in an interrupted record ("
                << rec.ignored_tail_bytes << " bytes ignored)\n";
    std::cout << "replaying recording " << c.take << " (" << rec.messages.size() << " messages) to "
              << c.options.to << "\n"
              << std::flush;
    report = mocapd::RunRecordingReplay(rec, c.take, c.options);
  } else if (!c.graph.empty()) {
    report = mocapd::RunGraphReplay(graph_source, c.seconds, c.synth_rate_hz, c.options);
  } else {
    report = mocapd::RunReplay(source, c.options);
  }
  std::cout << "\n" << report.FormatTable();
  if (!c.report.empty()) {
    std::ofstream out(c.report);
    out << report.ToJson().dump(2, ' ', false, kReplaceInvalidUtf8) << "\n";
    if (!out) throw std::runtime_error(c.report + ": cannot write");
    std::cout << "wrote " << c.report << "\n";
  }
  if (!c.plot.empty()) {
    std::ofstream out(c.plot);
    out << mocapd::LatencyHistogramSvg(
        report.processing_ms,
        "mocapd processing latency, " + std::to_string(report.processing.count) + " frames");
    if (!out) throw std::runtime_error(c.plot + ": cannot write");
    std::cout << "wrote " << c.plot << "\n";
  }
  return report.frames_lost == 0 || c.options.from.empty() ? 0 : 2;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"mocap-sim - motion-capture take tools and replay simulator"};
  app.require_subcommand(1);

  std::string info_path;
  bool info_json = false;
  CLI::App* info = app.add_subcommand("info", "Summarise a C3D or BVH take or a recording");
  info->add_option("FILE", info_path, "Take file (.c3d or .bvh) or recording (mocap-sim record)")
      ->required()
      ->check(mocapd::kExistingFile);
  info->add_flag("--json", info_json, "Print JSON instead of a table");

  SynthOptions synth;
  CLI::App* synth_cmd =
      app.add_subcommand("synth", "Synthesize a marker take (C3D) from skeletal motion");
  auto* bvh_opt = synth_cmd->add_option("--bvh", synth.bvh, "Source motion (any humanoid BVH)")
                      ->check(mocapd::kExistingFile);
  synth_cmd
      ->add_option("--humanoid", synth.humanoid_motion,
                   "Use the built-in humanoid: walk | reach | turn | mixed | rom (range of "
                   "motion, for calibration)")
      ->check(CLI::IsMember({"walk", "reach", "turn", "mixed", "rom"}))
      ->excludes(bvh_opt);
  // A BVH's length is its own: --seconds beside it was ignored.
  synth_cmd->add_option("--seconds", synth.seconds, "Length of built-in humanoid motion")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str()
      ->excludes(bvh_opt);
  synth_cmd->add_option("--out", synth.out, "Marker take to write (.c3d)")
      ->required()
      ->check(mocapd::kNonEmptyPath);
  synth_cmd
      ->add_option("--rate", synth.rate_hz,
                   "Output rate in Hz (default: the source's); motion is slerp-resampled")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(1.0, 2000.0));
  synth_cmd
      ->add_option("--subject-out", synth.subject_out,
                   "Also write the subject model (skeleton + markers)")
      ->check(mocapd::kNonEmptyPath);
  synth_cmd
      ->add_option("--layout", synth.layout,
                   "Marker layout TOML (default: built-in ~60-marker set)")
      ->check(mocapd::kExistingFile);
  auto* set_opt = synth_cmd
                      ->add_option("--marker-set", synth.marker_set,
                                   "Place an industry marker set instead of a layout: "
                                   "plug-in-gait-full, plug-in-gait-lower, "
                                   "cmu-41, optitrack-baseline, qualisys-sports, or a set file")
                      ->check(mocapd::kNonEmptyValue);
  set_opt->excludes("--layout");
  synth_cmd
      ->add_option("--soft-tissue-mm", synth.soft_tissue_mm,
                   "Soft-tissue wobble of markers on fleshy segments, mm (pose-correlated)")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.0, 100.0));
  synth_cmd
      ->add_option("--truth-bvh", synth.truth_bvh, "Also write the resampled ground-truth motion")
      ->check(mocapd::kNonEmptyPath);
  synth_cmd
      ->add_option("--bvh-units", synth.bvh_units,
                   "BVH length unit: mm, cm, m or in (default: guess)")
      ->check(mocapd::kLengthUnit);
  synth_cmd->add_option("--noise-mm", synth.noise_mm, "Gaussian marker noise (sigma, mm)")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.0, 100.0));
  synth_cmd->add_option("--seed", synth.seed, "Noise and corruption seed")->capture_default_str();
  synth_cmd
      ->add_option("--corrupt", synth.corrupt,
                   "Corrupt the take: light | medium | heavy (about 5 / 15 / 30 % of samples)")
      ->check(CLI::IsMember({"light", "medium", "heavy"}));
  synth_cmd
      ->add_option("--truth", synth.truth_mask,
                   "With --corrupt: write the ground-truth corruption mask (JSON)")
      ->check(mocapd::kNonEmptyPath)
      ->needs("--corrupt");

  ReplayCommand replay;
  CLI::App* replay_cmd = app.add_subcommand(
      "replay", "Publish a take's marker frames to the daemon and measure latency and accuracy");
  // Scripts pass defaults that a user's later arguments override.
  replay_cmd->option_defaults()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  replay_cmd
      ->add_option("TAKE", replay.take,
                   "Take to replay: .c3d (recorded markers) or .bvh (markers synthesized); "
                   "default: --humanoid")
      ->check(mocapd::kExistingFile);
  replay_cmd
      ->add_option("--humanoid", replay.humanoid,
                   "Replay the built-in humanoid: walk | reach | turn | mixed")
      ->check(CLI::IsMember({"walk", "reach", "turn", "mixed"}));
  replay_cmd
      ->add_option("--graph", replay.graph,
                   "Stream endless motion from a motion graph (a file from `graph build`, or "
                   "'humanoid' for one over the built-in humanoid's motions): each subject on its "
                   "own seeded walk, for --seconds at --synth-rate")
      ->check(mocapd::kExistingFile | CLI::IsMember({"humanoid"}));
  replay_cmd
      ->add_option("--seconds", replay.seconds,
                   "Length of the built-in humanoid's take (or the graph stream)")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str();
  replay_cmd
      ->add_option("--synth-rate", replay.synth_rate_hz,
                   "Rate markers are synthesized at (humanoid, BVH), Hz")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(1.0, 2000.0))
      ->capture_default_str();
  replay_cmd
      ->add_option("--noise-mm", replay.noise_mm,
                   "Marker noise of the built-in humanoid's take (sigma)")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.0, 100.0))
      ->capture_default_str();
  replay_cmd
      ->add_option("--subject", replay.subject,
                   "Subject model giving a C3D's marker order (default: the built-in humanoid)")
      ->check(mocapd::kExistingFile);
  replay_cmd
      ->add_option("--marker-set", replay.marker_set,
                   "Send a C3D's markers in this set's order (a daemon calibrating the subject "
                   "live with this marker_set expects it): plug-in-gait-full, cmu-41, ... or a "
                   "set file")
      ->excludes("--subject")
      ->check(mocapd::kNonEmptyValue);
  replay_cmd
      ->add_option("--bvh-units", replay.bvh_units,
                   "BVH length unit: mm, cm, m or in (default: guess)")
      ->check(mocapd::kLengthUnit);
  replay_cmd
      ->add_option("--to", replay.options.to,
                   "Endpoint for marker frames (PUB binds; with --push, connects)")
      ->capture_default_str()
      ->check(mocapd::kNonEmptyEndpoint);
  replay_cmd->add_flag("--push", replay.options.push,
                       "PUSH to a daemon whose input is a PULL socket");
  bool no_end_of_stream = false;
  replay_cmd->add_flag("--no-end-of-stream", no_end_of_stream,
                       "Stop without an end of stream, as a capture that is cut off would");
  replay_cmd
      ->add_option("--from", replay.options.from,
                   "The daemon's output endpoint to measure (\"\" to not listen)")
      ->capture_default_str();
  replay_cmd->add_option("--rate", replay.rate, "realtime (the take's rate) | max | HZ")
      ->capture_default_str();
  replay_cmd
      ->add_option("--corrupt", replay.options.corrupt,
                   "Corrupt each actor's copy: light | medium | heavy")
      ->check(CLI::IsMember({"light", "medium", "heavy"}));
  replay_cmd
      ->add_option("--seed", replay.options.seed,
                   "Corruption (and noise) seed; actor k uses seed + k")
      ->capture_default_str();
  replay_cmd
      ->add_option("--subjects", replay.options.subjects,
                   "Actors at once (actor1 .. actorN, 2.5 m apart)")
      ->check(CLI::TypeValidator<int>())
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  replay_cmd
      ->add_option("--subject-prefix", replay.options.subject_prefix,
                   "Actor names are PREFIX1 .. PREFIXN")
      ->capture_default_str();
  replay_cmd->add_option("--loop", replay.options.loops, "Play the take this many times")
      ->check(CLI::TypeValidator<int>())
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  replay_cmd
      ->add_option("--protocol", replay.options.protocol_version,
                   "Wire version of the marker frames: 2 adds a capture session, the exact "
                   "rate and timecode (checked in the daemon's echo); 1 for older daemons")
      ->check(CLI::TypeValidator<int>())
      ->check(CLI::Range(1, 2))
      ->capture_default_str();
  replay_cmd
      ->add_option("--timecode", replay.options.timecode_fps,
                   "Stamp frames with non-drop SMPTE timecode at this many fps (protocol 2)")
      ->check(CLI::TypeValidator<int>())
      ->check(CLI::Range(0, 256));
  replay_cmd->add_option("--report", replay.report, "Write the report as JSON")
      ->check(mocapd::kNonEmptyPath);
  replay_cmd->add_option("--plot", replay.plot, "Write a processing-latency histogram (SVG)")
      ->check(mocapd::kNonEmptyPath);
  replay_cmd
      ->add_option("--connect-timeout", replay.options.connect_timeout_s,
                   "Seconds to wait for the daemon")
      ->capture_default_str()
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.0, 1e6));
  replay_cmd
      ->add_option("--drain-timeout", replay.options.drain_timeout_s,
                   "Seconds to wait for the last skeletons")
      ->capture_default_str()
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.0, 1e6));

  replay_cmd
      ->add_option("--latency-interval", replay.options.latency_interval_s,
                   "Also report processing latency per this many seconds (a soak's drift)")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::NonNegativeNumber);
  replay_cmd
      ->add_option("--curve-key", replay.options.curve_key_file,
                   "CURVE: this replay's key pair (FILE.key_secret from mocapd keygen)")
      ->check(mocapd::kExistingFile);
  replay_cmd
      ->add_option("--curve-server-key", replay.options.curve_server_key_file,
                   "CURVE: the daemon's public key (FILE.key); needs --curve-key")
      ->check(mocapd::kExistingFile);

  mocapd::RecordOptions record;
  std::string record_subjects;
  CLI::App* record_cmd = app.add_subcommand(
      "record", "Record a capture publisher's marker stream with its timing (crash-safe)");
  record_cmd->add_option("--from", record.from, "The capture publisher (PUB) to subscribe to")
      ->capture_default_str()
      ->check(mocapd::kNonEmptyEndpoint);
  record_cmd->add_option("--out", record.out, "Recording to write (.mcr)")
      ->required()
      ->check(mocapd::kNonEmptyPath);
  record_cmd->add_option("--subjects", record_subjects,
                         "Comma-separated subjects to record (default: all)");
  record_cmd
      ->add_option("--seconds", record.seconds, "Stop after this long (default: until Ctrl-C)")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::NonNegativeNumber);
  record_cmd
      ->add_option("--curve-key", record.curve_key_file,
                   "CURVE: this recorder's key pair (FILE.key_secret from mocapd keygen)")
      ->check(mocapd::kExistingFile);
  record_cmd
      ->add_option("--curve-server-key", record.curve_server_key_file,
                   "CURVE: the publisher's public key (FILE.key); needs --curve-key")
      ->check(mocapd::kExistingFile);

  mocapd::GraphCommands graph_commands(app);

  CLI11_PARSE(app, argc, argv);
  try {
    if (graph_commands.Selected()) return graph_commands.Run();
    if (*info) {
      const mocapd::TakeInfo ti = mocapd::InspectTake(info_path);
      if (info_json)
        std::cout << mocapd::TakeInfoJson(ti).dump(2, ' ', false, kReplaceInvalidUtf8) << "\n";
      else
        std::cout << mocapd::FormatTakeInfo(ti);
      return 0;
    }
    replay.options.end_of_stream = !no_end_of_stream;
    if (*synth_cmd) {
      if (synth.bvh.empty() && synth.humanoid_motion.empty())
        throw std::invalid_argument("synth needs --bvh FILE or --humanoid MOTION");
      return RunSynth(synth);
    }
    if (*replay_cmd) return RunReplayCommand(replay);
    if (*record_cmd) {
      for (size_t a = 0, b; a < record_subjects.size(); a = b + 1) {
        b = record_subjects.find(',', a);
        if (b == std::string::npos) b = record_subjects.size();
        if (b > a) record.subjects.push_back(record_subjects.substr(a, b - a));
      }
      std::signal(SIGINT, [](int) { g_stop = true; });
      std::signal(SIGTERM, [](int) { g_stop = true; });
      record.stop = &g_stop;
      std::cout << "recording " << record.from << " to " << record.out << "\n" << std::flush;
      const uint64_t n = mocapd::RecordStream(record, [](const std::string& line) {
        std::cout << "  " << line << "\n" << std::flush;
      });
      std::cout << "wrote " << record.out << ": " << n << " messages\n";
      return 0;
    }
  } catch (const std::exception& e) {
    std::cerr << "mocap-sim: error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
