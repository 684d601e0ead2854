// mocapd: the motion-capture cleanup daemon's command line. Subcommands:
//   demo       synthesize a take and solve it live (the README's main job)
//   calibrate  build a subject model from labelled markers alone (or a BVH and its C3D)
//   process    clean a recorded C3D through the streaming pipeline; write BVH (+ C3D)
//   run        the daemon: marker frames in over ZeroMQ, cleaned skeletons out
//   keygen     a CURVE key pair for the daemon, a capture bridge or a consumer
#include <CLI/CLI.hpp>
#include <exception>
#include <iostream>

#include <spdlog/spdlog.h>

#include "protocol/curve.hpp"
#include "runtime/calibrate_command.hpp"
#include "runtime/daemon.hpp"
#include "runtime/process_command.hpp"
#include "sim/cli_checks.hpp"
#include "sim/demo_command.hpp"

#include <unistd.h>

int main(int argc, char** argv) {
  CLI::App app{"mocapd - real-time motion-capture cleanup daemon"};
  app.require_subcommand(1);

  mocapd::DemoOptions demo;
  CLI::App* demo_cmd = app.add_subcommand(
      "demo", "Synthesize a take from the built-in humanoid and solve it frame by frame");
  demo_cmd->add_option("--seconds", demo.seconds, "Take length")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str();
  demo_cmd->add_option("--rate", demo.rate_hz, "Capture rate, Hz")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(1.0, 2000.0))
      ->capture_default_str();
  demo_cmd->add_option("--noise-mm", demo.noise_mm, "Gaussian marker noise (sigma, mm)")
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::Range(0.0, 100.0))
      ->capture_default_str();
  demo_cmd->add_option("--motion", demo.motion, "walk | reach | turn | mixed")
      ->check(CLI::IsMember({"walk", "reach", "turn", "mixed"}))
      ->capture_default_str();
  demo_cmd->add_option("--seed", demo.seed, "Noise seed")->capture_default_str();

  mocapd::CalibrateCommandOptions cal;
  double max_rms_mm = cal.calibration.max_rms_m * 1e3;
  CLI::App* cal_cmd = app.add_subcommand(
      "calibrate",
      "Build a subject model (skeleton + markers) from labelled markers alone, or from a BVH "
      "skeleton and the C3D of the same take");
  cal_cmd
      ->add_option("--markers", cal.markers_c3d,
                   "C3D marker take(s) of the actor (repeat for several takes)")
      ->required()
      ->check(mocapd::kExistingFile);
  cal_cmd
      ->add_option("--actor", cal.actor,
                   "Of takes holding several actors' markers (Justin:LASI, Copy:LASI): "
                   "whose to use, by label prefix")
      ->check(mocapd::kNonEmptyValue);
  cal_cmd
      ->add_option("--marker-set", cal.marker_set,
                   "auto (recognise from the labels; labels of no set are placed by "
                   "clustering), none (clustering alone), a built-in set (plug-in-gait-full, "
                   "plug-in-gait-lower, cmu-41, optitrack-baseline, qualisys-sports) or a set "
                   "file")
      ->capture_default_str()
      ->check(mocapd::kNonEmptyValue);
  cal_cmd
      ->add_option("--subsets", cal.interleaved_solves,
                   "Markers alone: also solve this many interleaved subsets of the frames and "
                   "average them with the whole take's solve (steadier bones; at most one "
                   "subset per 160 frames; 1: one solve, about 3.5 times quicker than 4)")
      ->check(CLI::TypeValidator<int>())
      ->check(CLI::Range(1, mocapd::kMaxInterleavedSolves))
      ->capture_default_str();
  cal_cmd
      ->add_option("--report", cal.report_json,
                   "Markers alone: write the calibration report (JSON)")
      ->check(mocapd::kNonEmptyPath);
  CLI::Option* skeleton_option =
      cal_cmd
          ->add_option("--skeleton", cal.skeleton_bvh,
                       "Optional: BVH with the hierarchy and the motion of the captured take")
          ->check(mocapd::kExistingFile);
  cal_cmd->add_option("--out", cal.out_subject, "Subject model to write (TOML)")
      ->required()
      ->check(mocapd::kNonEmptyPath);
  cal_cmd->add_option("--name", cal.subject_name, "Subject name (default: the output file's stem)")
      ->check(mocapd::kNonEmptyValue);
  // Both concern the --skeleton calibration alone: given without it they were ignored.
  cal_cmd
      ->add_option("--bvh-units", cal.bvh_units,
                   "With --skeleton: its length unit, mm, cm, m or in (default: guess)")
      ->needs(skeleton_option)
      ->check(mocapd::kLengthUnit);
  cal_cmd
      ->add_option("--max-residual-mm", max_rms_mm,
                   "With --skeleton: reject markers whose best fit leaves more RMS than this")
      ->needs(skeleton_option)
      ->check(mocapd::kFiniteNumber)
      ->check(CLI::PositiveNumber)
      ->capture_default_str();

  mocapd::ProcessCommandOptions proc;
  CLI::App* proc_cmd =
      app.add_subcommand("process", "Clean a recorded take frame by frame and solve the skeleton");
  proc_cmd->add_option("--subject", proc.subject, "Subject model (TOML)")
      ->required()
      ->check(mocapd::kExistingFile);
  proc_cmd->add_option("--in", proc.input_c3d, "Marker take (C3D)")
      ->required()
      ->check(mocapd::kExistingFile);
  proc_cmd
      ->add_option("--actor", proc.actor,
                   "Of a take holding several actors' markers (Justin:LASI, Copy:LASI): "
                   "whose to solve, by label prefix (--out-c3d then holds that actor's)")
      ->check(mocapd::kNonEmptyValue);
  proc_cmd->add_option("--out-bvh", proc.output_bvh, "Solved skeleton to write (BVH)")
      ->required()
      ->check(mocapd::kNonEmptyPath);
  proc_cmd
      ->add_option("--out-c3d", proc.output_c3d,
                   "Cleaned markers to write (C3D; untouched samples are kept bit for bit)")
      ->check(mocapd::kNonEmptyPath);
  proc_cmd->add_option("--lookahead", proc.lookahead, "Frames of lookahead K (delay)")
      ->check(CLI::TypeValidator<int>())
      ->check(CLI::Range(0, 1000))
      ->capture_default_str();
  proc_cmd->add_option("--report", proc.report_json, "Write the summary as JSON")
      ->check(mocapd::kNonEmptyPath);
  proc_cmd
      ->add_option("--retarget", proc.retarget_bvh,
                   "Also retarget onto this character (BVH: hierarchy and rest pose)")
      ->check(mocapd::kExistingFile);
  CLI::Option* retarget_option = proc_cmd->get_option("--retarget");
  proc_cmd
      ->add_option("--out-character-bvh", proc.output_character_bvh,
                   "The retargeted character's motion (BVH; default SOLVED.character.bvh "
                   "beside --out-bvh)")
      ->needs(retarget_option)
      ->check(mocapd::kNonEmptyPath);
  proc_cmd->add_flag("--allow-partial", proc.allow_partial,
                     "Solve a take that labels fewer than half the subject's markers (refused "
                     "otherwise: most likely the wrong subject or marker set)");
  proc_cmd
      ->add_option("--plot", proc.plot_dir,
                   "Write SVG plots to this directory: markers.svg, solve.svg (and "
                   "joint_error.svg with --truth-bvh)")
      ->check(mocapd::kNonEmptyPath);
  CLI::Option* truth_option =
      proc_cmd
          ->add_option("--truth-bvh", proc.truth_bvh,
                       "The take's true motion (mocap-sim synth --truth-bvh): report and plot the "
                       "joint error")
          ->check(mocapd::kExistingFile);
  proc_cmd
      ->add_option("--truth-units", proc.truth_units,
                   "The truth BVH's length unit: mm, cm, m or in (default: guessed from its "
                   "bones, which cannot tell in from cm; mocap-sim synth writes the truth in "
                   "the subject's bvh_units)")
      ->needs(truth_option)
      ->check(mocapd::kLengthUnit);
  std::vector<std::string> joint_map_args;
  proc_cmd
      ->add_option("--joint-map", joint_map_args,
                   "Retarget overrides ROLE=JOINT (e.g. hand_l=L_Wrist), comma-separated")
      ->delimiter(',')
      ->needs(retarget_option);

  std::string run_config = "config/mocapd.toml";
  std::string log_level = "info";
  CLI::App* run_cmd =
      app.add_subcommand("run", "Run the daemon: clean and solve live marker frames from ZeroMQ");
  run_cmd->add_option("--config", run_config, "Daemon config (TOML)")
      ->check(mocapd::kExistingFile)
      ->capture_default_str();
  run_cmd->add_option("--log-level", log_level, "trace | debug | info | warn | error")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}))
      ->capture_default_str();

  std::string keygen_out;
  CLI::App* keygen_cmd = app.add_subcommand(
      "keygen",
      "Write a CURVE key pair: OUT.key (public: give it to the peers) and OUT.key_secret "
      "(secret, mode 0600), ZeroMQ certificates as czmq and pyzmq's zmq.auth read them");
  keygen_cmd->add_option("--out", keygen_out, "Path without extension, e.g. keys/mocapd")
      ->required()
      ->check(mocapd::kNonEmptyPath);

  CLI11_PARSE(app, argc, argv);
  try {
    if (*demo_cmd) return mocapd::RunDemoCommand(demo, std::cout);
    if (*cal_cmd) {
      cal.calibration.max_rms_m = max_rms_mm * 1e-3;
      mocapd::RunCalibrateCommand(cal, std::cout);
      return 0;
    }
    if (*keygen_cmd) {
      const mocapd::curve::KeyPair keys = mocapd::curve::GenerateKeyPair();
      mocapd::curve::WriteCertificates(keygen_out, keys);
      std::cout << "public key " << keys.public_key << "\n  " << keygen_out
                << ".key         give it to the peers that must trust this one\n  " << keygen_out
                << ".key_secret  keep it here (mode 0600)\n";
      return 0;
    }
    if (*run_cmd) {
      spdlog::set_level(spdlog::level::from_str(log_level));
      mocapd::Daemon daemon(mocapd::LoadDaemonConfig(run_config), run_config);
      daemon.Run(/*handle_signals=*/true);
      return daemon.Stats().Balanced() ? 0 : 3;
    }
    if (*proc_cmd) {
      for (const std::string& pair : joint_map_args) {
        const size_t eq = pair.find('=');
        if (eq == std::string::npos || eq == 0 || eq + 1 == pair.size())
          throw std::invalid_argument("--joint-map: expected ROLE=JOINT, got '" + pair + "'");
        proc.joint_map[pair.substr(0, eq)] = pair.substr(eq + 1);
      }
      proc.progress = ::isatty(STDOUT_FILENO) != 0;
      mocapd::RunProcessCommand(proc, std::cout);
      return 0;
    }
  } catch (const std::exception& e) {
    std::cerr << "mocapd: error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
