// The per-subject streaming cleanup pipeline: push marker frame t, get frame t-K out once
// it is final. Follows Perepichka 2020, ch. 3 ("Robust marker trajectory repair using
// kinematic reference"), turned from a batch method into a streaming one. Each frame
// first passes the ingest gates: a sample beyond the capture volume (1e30, FLT_MAX) is
// missing, and a whole frame that jumped further than a body moves (a capture glitch) is
// missing too, unless the jump persists (a re-synchronisation, taken afresh). The
// pipeline keeps the window of buffered frames and calls three stages in order:
//  - OutlierDetector (filters/outlier_detector.hpp) on each frame as it arrives: swap
//    relabelling, the naive Y and robust reference Y^ (X^ = LBS(Y^)), the detectors that
//    mask bad samples, and the mask clean-up over the lookahead;
//  - GapRepair (filters/gap_repair.hpp) on the frame leaving the lookahead: every bad
//    sample filled by a cubic Hermite offset onto the reference path;
//  - FinalSolve (filters/final_solve.hpp): the skeleton Y- on the repaired markers,
//    warm-started and pop-free.
// Samples that were fine are published exactly as they came in; the final solve fits
// them smoothed over the frames around them (solve_smoothing_s). Memory is fixed at
// construction (a ring of K + 3 frames plus the smoothing's reach back, and per-marker
// state in each stage); Push and Flush never allocate.
#pragma once

#include <memory>
#include <span>
#include <vector>

#include "filters/cleanup_options.hpp"
#include "filters/cleanup_window.hpp"
#include "filters/final_solve.hpp"
#include "filters/gap_repair.hpp"
#include "filters/outlier_detector.hpp"

namespace mocapd {

class CleanupPipeline {
 public:
  /// Throws std::invalid_argument if the options are invalid.
  CleanupPipeline(std::shared_ptr<const Skeleton> skeleton,
                  std::shared_ptr<const MarkerSet> markers, const CleanupOptions& options);
  CleanupPipeline(const CleanupPipeline&) = delete;
  CleanupPipeline& operator=(const CleanupPipeline&) = delete;

  /// Pushes the next frame: p_WM per marker in the subject's marker order, metres; a
  /// non-finite position is a missing sample. Returns true if a frame became final
  /// (read it with output()). Never allocates or throws.
  bool Push(std::span<const Vec3> p_WM);
  /// At the end of a take: publishes the next pending frame with no more future to see.
  /// Returns false when nothing is pending.
  bool Flush();
  const CleanFrame& output() const { return out_; }
  const CleanupCounters& counters() const { return counters_; }
  /// Carries on the counts of the pipeline this one replaces (a subject swapped in).
  void AdoptCounters(const CleanupCounters& counters) { counters_ = counters; }
  const CleanupOptions& options() const { return options_; }
  /// Forgets all state (a capture restart); counters are kept.
  void Reset();

 private:
  void Publish(int64_t tau, int64_t newest);
  void GateGlitch(WindowFrame& s);
  void SmoothCapturedSamples(int64_t tau, int64_t newest);

  std::shared_ptr<const Skeleton> skeleton_;
  std::shared_ptr<const MarkerSet> markers_;
  CleanupOptions options_;
  int smoothing_frames_;  ///< Half-width of the final solve's smoothing (FrameRules).
  CleanupWindow window_;
  OutlierDetector detector_;
  GapRepair repair_;
  FinalSolve final_;
  CleanFrame out_;
  CleanupCounters counters_;
  std::vector<Vec3>
      last_taken_;  ///< Per marker, its last sample in a frame taken (the glitch gate).
  std::vector<uint8_t> has_last_taken_;
  std::vector<int64_t> last_taken_at_;  ///< Per marker, the frame of its last_taken_.
  std::vector<Vec3> glitch_last_;       ///< The last frame a glitch gated, as captured.
  std::vector<double> displacement_;    ///< GateGlitch's scratch.
  /// Savitzky-Golay (cubic) centre weights: row n (a half-width of n frames) holds the
  /// weights of offsets 0..n.
  std::vector<double> smoothing_weights_;
  std::vector<Vec3> solve_samples_;  ///< What the final solve fits for captured samples.
  std::vector<Vec3> return_motion_;  ///< A sample's motion back from a gap (NaN: not shown).
  int64_t last_taken_frame_ = -1;
  int64_t glitch_since_ = -1;
  int64_t next_in_ = 0;   ///< Frame number of the next Push.
  int64_t next_out_ = 0;  ///< Frame number of the next publication.
};

}  // namespace mocapd
