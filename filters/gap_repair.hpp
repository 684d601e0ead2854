// Gap repair, the second stage of the cleanup (Perepichka 2020, ch. 3, streamed): decides
// every marker's published sample for the frame leaving the lookahead. A fine sample is
// published exactly as captured. A bad one is filled with a cubic Hermite offset onto the
// reference path X^: from the last published offset and velocity to the returning
// track's once its end is within fill_interpolation_horizon_s and the lookahead
// (two-sided, which is also the no-pop re-entry blend), or easing to a constant offset
// while the gap is still open or its end further off (one-sided). The reference's path
// is taken without its snaps (accelerations beyond a limb's), so a guessed segment
// snapping back to returning markers moves no fill, and a one-sided fill takes up what
// it held back a little each frame. Short gaps right after a captured sample get a plain
// Hermite on the raw path. Per-marker state is sized at construction; Repair never
// allocates.
#pragma once

#include <limits>
#include <vector>

#include "filters/cleanup_options.hpp"
#include "filters/cleanup_window.hpp"

namespace mocapd {

class GapRepair {
 public:
  /// The options must be valid (CleanupOptions::Validate).
  GapRepair(int markers, const CleanupOptions& options);

  /// Fills out's markers, status, reason and source for frame tau from the window, which
  /// holds frames up to `newest` (the lookahead the repair may use). Frames must come in
  /// order, tau = the previous call's + 1 (or 0 after Reset). Never allocates or throws.
  void Repair(const CleanupWindow& window, int64_t tau, int64_t newest, CleanFrame* out,
              CleanupCounters* counters);
  /// Forgets all state (a capture restart).
  void Reset();

 private:
  struct Track {
    bool has_published = false;
    // Frame of the last published captured sample; never one less than a frame number.
    int64_t last_observed = std::numeric_limits<int64_t>::min();
    Vec3 offset = Vec3::Zero();              // last published X- - X^ ...
    Vec3 offset_velocity = Vec3::Zero();     // ... and its per-frame change
    Vec3 output = Vec3::Zero();              // last published X- ...
    Vec3 output_velocity = Vec3::Zero();     // ... and its per-frame change
    Vec3 reference_velocity = Vec3::Zero();  // X^'s per-frame change, snaps taken out
    Vec3 held_snap = Vec3::Zero();           // snaps a one-sided fill has not followed yet
  };

  const CleanupOptions options_;
  const CleanupFrameRules rules_;
  std::vector<Track> tracks_;
};

}  // namespace mocapd
