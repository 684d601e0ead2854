// `mocapd process`: batch-cleans a recorded C3D through exactly the streaming pipeline
// the daemon runs (frame by frame, never looking further than the lookahead), writes the
// solved skeleton as BVH and optionally the cleaned markers as C3D, and reports what
// was repaired.
#pragma once

#include <cstdint>
#include <map>
#include <nlohmann/json_fwd.hpp>
#include <ostream>
#include <string>

#include "filters/cleanup_pipeline.hpp"

namespace mocapd {

struct ProcessCommandOptions {
  std::string subject;
  std::string input_c3d;
  std::string output_bvh;
  std::string output_c3d;   ///< Empty: not written.
  std::string report_json;  ///< Empty: not written.
  int lookahead = 12;
  bool progress = false;  ///< Draw a progress bar (on a terminal).
  std::string
      retarget_bvh;  ///< Character to retarget onto (its hierarchy and rest pose); empty: none.
  std::string output_character_bvh;              ///< With retarget_bvh: the character's motion.
  std::map<std::string, std::string> joint_map;  ///< Retarget overrides: role -> character joint.
  /// Write SVG plots here (created if missing): markers.svg (each marker's status over
  /// the take), solve.svg (residual and iterations per frame), and with truth_bvh
  /// joint_error.svg. Empty: none.
  std::string plot_dir;
  /// The take's true motion (mocap-sim synth --truth-bvh), frame for frame: the joint
  /// error over time is plotted and summarised. Empty: none.
  std::string truth_bvh;
  /// The truth BVH's length unit (mm, cm, m, in); empty: guessed from its bones, which
  /// cannot tell inches from centimetres.
  std::string truth_units;
  /// Solve a take that labels fewer than half the subject's markers (refused otherwise:
  /// most likely the wrong subject or marker set).
  bool allow_partial = false;
  std::string actor = {};  ///< Of a take holding several actors' markers: whose (label prefix).
};

/// Where the retargeted character is written: output_character_bvh, or beside the solved
/// BVH as SOLVED.character.bvh. Empty without retarget_bvh.
std::string CharacterOutputPath(const ProcessCommandOptions& options);

struct ProcessSummary {
  /// The solve was written turned from the capture's world into the one its subject's rest
  /// pose stands in (a Z-up capture, a Y-up subject).
  bool solve_turned = false;
  int frames = 0;
  int markers = 0;
  int matched_markers = 0;
  CleanupCounters counters;
  /// Repaired samples by where they came from: a capture relabelled, a fill between two
  /// captured ends, or a guess from one side (the counters' reasons say why a sample was
  /// repaired, not how much it rests on).
  int64_t repaired_captured = 0, repaired_interpolated = 0, repaired_extrapolated = 0;
  /// Markers in the take that no frame captures (every sample of them is a guess), and
  /// frames that capture none of the subject's markers (the longest run of them).
  std::vector<std::string> never_captured;
  int blank_frames = 0, longest_blank_run = 0;
  /// The longest such run with captured frames on both sides (what a lookahead bridges).
  int longest_blank_run_between_captures = 0;
  /// Frames the final solve could not solve (too few markers, or a failed solve), and
  /// how many of them came before the first solved one (those hold the first solved
  /// pose in the written BVH).
  int unsolved_frames = 0, frames_before_first_solve = 0;
  bool timed = false;  ///< False for a take no longer than the K + 1 cold-start frames.
  double mean_us = 0.0, p50_us = 0.0, p99_us = 0.0, max_us = 0.0;  ///< Per-frame pipeline time.
  double retarget_p50_us = 0.0, retarget_p99_us = 0.0;  ///< Per-frame retarget time, if any.
  /// How well the solved skeleton fits the captured samples it published as observed:
  /// per sample (median), and per marker (the RMS of each, their median and worst), mm.
  double residual_median_mm = 0.0, marker_rms_median_mm = 0.0, marker_rms_worst_mm = 0.0;
  /// With a truth: joint position error against it (joints matched by name), cm: the
  /// mean, and, a frame's error being its worst joint's (what a viewer sees), the
  /// frames' 99.9th percentile (nearest rank: the worst itself in a take of 1000 frames
  /// or fewer) and the worst frame: its index in the take (from 0), its number as the
  /// take numbers it (from C3dTake::first_frame), and its joint as the subject names it.
  bool has_truth = false;
  double truth_mean_cm = 0.0, truth_p999_cm = 0.0, truth_worst_cm = 0.0;
  int truth_worst_index = -1;
  int64_t truth_worst_frame = -1;
  std::string truth_worst_joint;
};

/// Runs the command, printing progress and the summary to out. Throws std::runtime_error
/// (or the readers' errors) for unreadable inputs or a subject the take does not match.
ProcessSummary RunProcessCommand(const ProcessCommandOptions& options, std::ostream& out);

/// The summary as JSON (what --report writes).
nlohmann::json ProcessSummaryJson(const ProcessSummary& summary,
                                  const ProcessCommandOptions& options);

}  // namespace mocapd
