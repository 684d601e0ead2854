// What the cleanup's stages share: why a sample was masked, what was published for it,
// the window of buffered frames (the K-frame lookahead plus the frames before it that
// slopes and trajectory continuity need), and the counters every stage adds to.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "filters/ik_solver.hpp"

namespace mocapd {

/// Why a sample was masked. kNone: fine.
enum class MaskReason : uint8_t {
  kNone,
  kMissing,
  kDisagreement,
  kResidual,
  kSpike,
  kRigidDistance,
  kSwap,
  kFrozen,
  kFallenOff,
  kSmallTrack,
  kTrimmed,
};
inline constexpr int kMaskReasonCount = 11;
const char* to_string(MaskReason reason);

enum class MarkerStatus : uint8_t {
  kObserved,       ///< Published exactly as captured.
  kRepaired,       ///< Filled or relabelled; the reason says which detector.
  kUnrecoverable,  ///< No data to repair from (never seen yet): not published.
};
const char* to_string(MarkerStatus status);

/// Where a published sample came from, which sets its weight in the final solve.
enum class SampleSource : uint8_t {
  kCaptured,      ///< The capture's sample (relabelled or not).
  kInterpolated,  ///< Filled between two known ends (a short gap, a gap whose end is in the
                  ///< lookahead).
  kExtrapolated,  ///< Filled from one side only: a guess on the reference.
  kNone,          ///< Unrecoverable: nothing published.
};

/// One published frame.
struct CleanFrame {
  int64_t frame = -1;
  std::vector<Vec3> markers;  ///< X-: repaired positions (NaN where unrecoverable), metres.
  std::vector<MarkerStatus> status;
  std::vector<MaskReason> reason;    ///< Why a repaired sample was repaired (kNone if observed).
  std::vector<SampleSource> source;  ///< Where each sample came from.
  std::vector<double> weight;        ///< Each marker's weight in the final solve.
  Pose pose;                         ///< Y-: the final solve.
  IkSummary final_solve;
};

struct CleanupCounters {
  int64_t frames_in = 0;
  int64_t frames_out = 0;
  int64_t samples_out = 0;
  std::array<int64_t, kMaskReasonCount> repaired_by{};  ///< Published repaired samples, per reason.
  int64_t unrecoverable = 0;
  /// Pairs relabelled and lone samples moved to a missing neighbour's label, once per
  /// frame each (a remembered pair every frame).
  int64_t swaps_relabelled = 0;
  /// A segment's only sample that pulled its parent off the parent's clean markers, left
  /// out of the reference (once per frame each).
  int64_t lone_samples_overruled = 0;
  int64_t samples_out_of_volume = 0;  ///< Samples beyond the capture volume: taken as missing.
  int64_t glitch_frames = 0;          ///< Whole frames taken as missing (a jump no body makes).
  int64_t resyncs = 0;                ///< Jumps that persisted: taken, the solves started afresh.
  int64_t cold_starts = 0;            ///< IK solves that started cold.
  int64_t solve_failures = 0;         ///< IK solves that reported a numerical failure.
  int64_t solve_iterations = 0;       ///< LM iterations over all solves.
  void CountSolve(const IkSummary& summary) {
    cold_starts += summary.cold_start;
    solve_failures += summary.status == IkStatus::kNumericalFailure;
    solve_iterations += summary.iterations;
  }
};

/// One buffered frame; every vector has one entry per marker.
struct WindowFrame {
  int64_t frame = -1;          ///< -1: the slot holds no frame.
  std::vector<Vec3> raw;       ///< As captured (metres), after swap relabelling; NaN where missing.
  std::vector<uint8_t> valid;  ///< A sample was captured (for the label after relabelling).
  std::vector<uint8_t> relabelled;
  std::vector<MaskReason> mask;
  std::vector<Vec3> reference;  ///< X^ = LBS(Y^), metres.
  /// Y^ is a solution (this frame's, or one held over a frame with too few markers), not
  /// the rest pose of a subject never solved since the take began or re-synchronised.
  bool reference_solved = false;
  bool resync = false;  ///< The capture re-synchronised here: nothing before carries over.
  /// No sample was taken at all (a frame lost before the cleanup and bridged, a gated
  /// glitch): a hole in the capture, not in any one marker's track.
  bool blind = false;
};

/// A ring of frames addressed by frame number, allocated once.
class CleanupWindow {
 public:
  CleanupWindow(int markers, int capacity) : frames_(static_cast<size_t>(capacity)) {
    const auto m = static_cast<size_t>(markers);
    for (WindowFrame& f : frames_) {
      f.raw.assign(m, Vec3::Constant(kNaN));
      f.valid.assign(m, 0);
      f.relabelled.assign(m, 0);
      f.mask.assign(m, MaskReason::kMissing);
      f.reference.assign(m, Vec3::Zero());
    }
  }
  /// The slot of frame number `frame` (>= 0), whichever frame it holds now.
  WindowFrame& at(int64_t frame) { return frames_[Index(frame)]; }
  const WindowFrame& at(int64_t frame) const { return frames_[Index(frame)]; }
  /// True if the window holds exactly this frame.
  bool Holds(int64_t frame) const { return frame >= 0 && at(frame).frame == frame; }
  /// Forgets every frame.
  void Clear() {
    for (WindowFrame& f : frames_) f.frame = -1;
  }

 private:
  size_t Index(int64_t frame) const {
    return static_cast<size_t>(frame % static_cast<int64_t>(frames_.size()));
  }
  std::vector<WindowFrame> frames_;
};

}  // namespace mocapd
