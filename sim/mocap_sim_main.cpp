// mocap-sim: the replay simulator's command line. Subcommands:
//   info   summarise a C3D or BVH take
//   synth  place a virtual marker set on a BVH (or the built-in humanoid) and write the marker take
#include <CLI/CLI.hpp>
#include <exception>
#include <iostream>
#include <nlohmann/json.hpp>
#include <fstream>
#include <random>

#include "sim/bvh.hpp"
#include "sim/c3d.hpp"
#include "sim/corruption.hpp"
#include "sim/humanoid.hpp"
#include "sim/marker_layout.hpp"
#include "sim/subject_file.hpp"
#include "sim/synthesis.hpp"
#include "sim/take_info.hpp"

namespace {

struct SynthOptions {
  std::string bvh;
  std::string humanoid_motion;
  double seconds = 10.0;
  std::string out;
  double rate_hz = 0.0;
  std::string subject_out;
  std::string layout;
  std::string truth_bvh;
  std::string bvh_units;
  double noise_mm = 0.0;
  uint64_t seed = 1;
  std::string corrupt;
  std::string truth_mask;
};

int RunSynth(const SynthOptions& o) {
  mocapd::BvhTake source;
  if (!o.bvh.empty()) {
    mocapd::BvhReadOptions read;
    read.units = o.bvh_units;
    source = mocapd::ReadBvh(o.bvh, read);
  } else {
    const double rate = o.rate_hz > 0 ? o.rate_hz : 120.0;
    mocapd::Skeleton sk = mocapd::MakeHumanoidSkeleton();
    auto frames = mocapd::MakeHumanoidMotion(sk, mocapd::ParseHumanoidMotion(o.humanoid_motion), o.seconds, rate);
    source = mocapd::MakeBvhTake(std::move(sk), std::move(frames), 1.0 / rate, "cm");
  }
  const double rate = o.rate_hz > 0 ? o.rate_hz : source.rate_hz();
  std::vector<mocapd::Pose> motion = mocapd::ResampleMotion(source.skeleton, source.frames, source.rate_hz(), rate);
  const auto roles = mocapd::MatchHumanoidRoles(source.skeleton);
  const auto layout = o.layout.empty() ? mocapd::DefaultMarkerLayout() : mocapd::ReadMarkerLayout(o.layout);
  auto markers = std::make_shared<const mocapd::MarkerSet>(
      source.skeleton, mocapd::PlaceMarkers(source.skeleton, roles, layout, source.end_sites));
  std::mt19937_64 rng(o.seed);
  mocapd::C3dTake take = mocapd::SynthesizeMarkers(source.skeleton, *markers, motion, rate, o.noise_mm * 1e-3, &rng);
  if (!o.corrupt.empty()) {
    mocapd::CorruptionOptions corruption;
    corruption.severity = mocapd::ParseCorruptionSeverity(o.corrupt);
    corruption.seed = o.seed;
    mocapd::CorruptedTake corrupted = mocapd::CorruptTake(take, markers.get(), corruption);
    std::cout << "corrupted " << 100.0 * corrupted.corrupted_fraction << " % of marker-samples (" << corrupted.events.size()
              << " events, " << o.corrupt << ", seed " << o.seed << ")\n";
    if (!o.truth_mask.empty()) {
      std::ofstream(o.truth_mask) << mocapd::CorruptionTruthJson(corrupted, corruption).dump(1) << "\n";
      std::cout << "wrote " << o.truth_mask << "\n";
    }
    take = std::move(corrupted.take);
  }
  mocapd::WriteC3d(o.out, take);
  std::cout << "wrote " << o.out << ": " << take.num_frames << " frames at " << rate << " Hz, " << markers->num_markers()
            << " markers\n";
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

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"mocap-sim - motion-capture take tools and replay simulator"};
  app.require_subcommand(1);

  std::string info_path;
  bool info_json = false;
  CLI::App* info = app.add_subcommand("info", "Summarise a C3D or BVH take");
  info->add_option("FILE", info_path, "Take file (.c3d or .bvh)")->required()->check(CLI::ExistingFile);
  info->add_flag("--json", info_json, "Print JSON instead of a table");

  SynthOptions synth;
  CLI::App* synth_cmd = app.add_subcommand("synth", "Synthesize a marker take (C3D) from skeletal motion");
  auto* bvh_opt = synth_cmd->add_option("--bvh", synth.bvh, "Source motion (any humanoid BVH)")->check(CLI::ExistingFile);
  synth_cmd->add_option("--humanoid", synth.humanoid_motion, "Use the built-in humanoid: walk | reach | turn | mixed")
      ->check(CLI::IsMember({"walk", "reach", "turn", "mixed"}))
      ->excludes(bvh_opt);
  synth_cmd->add_option("--seconds", synth.seconds, "Length of built-in humanoid motion")->check(CLI::Range(0.1, 3600.0))->capture_default_str();
  synth_cmd->add_option("--out", synth.out, "Marker take to write (.c3d)")->required();
  synth_cmd->add_option("--rate", synth.rate_hz, "Output rate in Hz (default: the source's); motion is slerp-resampled")
      ->check(CLI::Range(1.0, 2000.0));
  synth_cmd->add_option("--subject-out", synth.subject_out, "Also write the subject model (skeleton + markers)");
  synth_cmd->add_option("--layout", synth.layout, "Marker layout TOML (default: built-in ~60-marker set)")->check(CLI::ExistingFile);
  synth_cmd->add_option("--truth-bvh", synth.truth_bvh, "Also write the resampled ground-truth motion");
  synth_cmd->add_option("--bvh-units", synth.bvh_units, "BVH length unit: mm, cm, m or in (default: guess)");
  synth_cmd->add_option("--noise-mm", synth.noise_mm, "Gaussian marker noise (sigma, mm)")->check(CLI::Range(0.0, 100.0));
  synth_cmd->add_option("--seed", synth.seed, "Noise and corruption seed")->capture_default_str();
  synth_cmd->add_option("--corrupt", synth.corrupt, "Corrupt the take: light | medium | heavy (about 5 / 15 / 30 % of samples)")
      ->check(CLI::IsMember({"light", "medium", "heavy"}));
  synth_cmd->add_option("--truth", synth.truth_mask, "With --corrupt: write the ground-truth corruption mask (JSON)");

  CLI11_PARSE(app, argc, argv);
  try {
    if (*info) {
      const mocapd::TakeInfo ti = mocapd::InspectTake(info_path);
      if (info_json) std::cout << mocapd::TakeInfoJson(ti).dump(2) << "\n";
      else std::cout << mocapd::FormatTakeInfo(ti);
      return 0;
    }
    if (*synth_cmd) {
      if (synth.bvh.empty() && synth.humanoid_motion.empty()) throw std::invalid_argument("synth needs --bvh FILE or --humanoid MOTION");
      return RunSynth(synth);
    }
  } catch (const std::exception& e) {
    std::cerr << "mocap-sim: error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
