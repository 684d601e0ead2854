// Outlier detection, the first stage of the cleanup (Perepichka 2020, ch. 3, streamed):
// for the newest frame of the window it
//  - relabels swapped pairs (rigid-segment distances, trajectory continuity, and a pair
//    that each fit the other's reference position; a pair of that last kind on two
//    segments is remembered until the labels as captured fit again or both vanish), and a
//    lone sample that jumped onto where a missing neighbour was expected;
//  - solves the robust reference Y^ (Huber IRLS, temporal prior, frozen / fallen-off /
//    stray markers and samples off their joint's distance excluded, unless they are all a segment
//    has and keep its rigid distances: then they are the segment, and taken back) and writes X^ =
//    LBS(Y^) into the window, and the naive Y (plain IK on the markers as they are) on frames where
//    some sample is off X^;
//  - marks bad samples with a reason: missing, kinematic disagreement of Y and Y^ per
//    joint mapped to markers through skin weights, residual against X^ beyond an adaptive
//    threshold, velocity spikes against the reference, rigid-segment distance violations,
//    frozen and fallen-off markers;
//  - cleans the mask over the unpublished frames: returning tracks are trimmed until
//    their slope agrees with the reference's, and short tracks between gaps are dropped.
// Per-marker state is sized at construction; Process never allocates.
#pragma once

#include <algorithm>
#include <array>
#include <memory>
#include <utility>
#include <vector>

#include "filters/cleanup_options.hpp"
#include "filters/cleanup_window.hpp"

namespace mocapd {

class OutlierDetector {
 public:
  /// The options must be valid (CleanupOptions::Validate); skeleton and markers must
  /// outlive the detector.
  OutlierDetector(const Skeleton& skeleton, const MarkerSet& markers,
                  const CleanupOptions& options);

  /// Processes frame t, the newest in the window (its raw samples and validity filled):
  /// relabels swaps in it, solves Y^ (filling its reference) and Y, writes its mask, and
  /// cleans the masks of frames [first_unpublished, t]. Never allocates or throws.
  void Process(CleanupWindow& window, int64_t t, int64_t first_unpublished,
               CleanupCounters* counters);
  /// Forgets all state (a capture restart).
  void Reset();

  /// Y^ after the last Process.
  const IkState& reference() const { return robust_; }
  /// True if marker m is kept out of Y^ (frozen, fallen off, stray or off its joint).
  bool excluded(int m) const {
    const Track& t = tracks_[static_cast<size_t>(m)];
    return t.frozen || t.fallen || t.stray || t.off_joint;
  }

 private:
  struct Track {
    double residual_scale = 0.0;           // running robust residual scale, metres
    int residual_run = 0;                  // consecutive residual outliers
    int64_t still_since = -1;              // first frame of the current still run (-1: none)
    int64_t last_seen = -1;                // the last frame with a sample
    Vec3 still_anchor = Vec3::Zero();      // where the marker came to rest ...
    Vec3 still_reference = Vec3::Zero();   // ... and its reference then
    bool frozen = false;                   // excluded from Y^ while it stays put
    bool fallen = false;                   // excluded from Y^ until it fits again
    bool stray = false;                    // far off for a while: excluded until it fits again
    bool off_joint = false;                // off its joint's distance: out of the next Y^
    double joint_distance_at_rest = kNaN;  // to its joint's origin, in the still run
    int64_t overruled_frame = -1;          // last frame it pulled its parent off (see Detect)
  };

  void ApplyPersistentSwaps(CleanupWindow& window, int64_t t, CleanupCounters* counters);
  void RelabelSwaps(CleanupWindow& window, int64_t t, CleanupCounters* counters);
  void RelabelLoneSamples(CleanupWindow& window, int64_t t, CleanupCounters* counters);
  void Relabel(WindowFrame& s, size_t i, size_t j, CleanupCounters* counters,
               bool remember = false);
  /// True if marker m is judged frozen and its sample in s is still where it stuck.
  bool StuckWhereItFroze(const WindowFrame& s, size_t m) const {
    return tracks_[m].frozen &&
           (s.raw[m] - tracks_[m].still_anchor).norm() <= options_.frozen_radius_m;
  }
  /// Marker m's residual outlier threshold: the floor or a multiple of its running scale.
  double ResidualThreshold(size_t m) const {
    return std::max(options_.residual_floor_m,
                    options_.residual_scale_factor * tracks_[m].residual_scale);
  }
  void SolveReferences(WindowFrame& s, CleanupCounters* counters);
  void OverruleLoneSamples(const WindowFrame& s, const IkOptions& robust_ik,
                           CleanupCounters* counters);
  /// Marker m's sample in s from its joint's origin in `joints` (m rigidly on one joint).
  double JointOriginDistance(const WindowFrame& s, size_t m,
                             const KinematicsWorkspace& joints) const;
  /// True if that distance is off the model's by more than tolerance (never for NaN).
  bool OffItsJoint(double distance, size_t m, double tolerance) const;
  /// True if marker m's sample in frame t is in a still run of frozen_s or longer, seen
  /// within frozen_backdate_s, with its distance to its joint's origin at rest known.
  bool StillForFrozenS(const WindowFrame& s, size_t m, int64_t t) const;
  void ReadmitConsistentSegments(const WindowFrame& s);
  void Detect(CleanupWindow& window, int64_t t, int64_t first_unpublished,
              CleanupCounters* counters);
  void CleanMask(CleanupWindow& window, int64_t t, int64_t first_unpublished);
  Track FreshTrack() const;
  /// Rigid pair k's distance_at_rest_ slot for its marker m's still run.
  double& DistanceAtRest(size_t k, size_t m) {
    return distance_at_rest_[k][static_cast<size_t>(rigid_pairs_[k].first) == m ? 0 : 1];
  }

  const Skeleton& skeleton_;
  const MarkerSet& markers_;
  const CleanupOptions options_;
  const CleanupFrameRules rules_;
  IkState naive_, robust_;
  IkState without_lone_;         ///< Y^'s start, solved again without lone samples (see .cpp)
  IkOptions robust_ik_on_any_;   ///< robust_ik starting cold on as few markers as it solves.
  int64_t unsolved_since_ = -1;  ///< First frame with enough markers and no Y^ yet (-1: none).
  bool naive_solved_ = false;    // Y was solved for the newest frame
  bool naive_fresh_ = false;     // Y's warm start is the previous frame's solution
  std::vector<Track> tracks_;
  std::vector<int> swap_partner_;  // per marker: the label its samples are carried under, or -1
  // Per marker, the partner the continuity test relabelled it with in frame
  // continuity_frame_ (-1: none), and in the frame before that.
  std::vector<int> continuity_partner_, previous_continuity_partner_;
  int64_t continuity_frame_ = -1;
  std::vector<std::pair<int, int>> rigid_pairs_;   // markers rigidly on one joint...
  std::vector<double> rigid_distance_;             // ...and their distance in the model
  std::vector<std::vector<int>> pairs_of_marker_;  // indices into rigid_pairs_
  // Per rigid pair, the pair's distance during each of its markers' (first, second) still
  // run, taken when the frozen rule first looks at the pair in that run (NaN: not yet).
  std::vector<std::array<double, 2>> distance_at_rest_;
  // Per rigid pair on a segment of fewer than four markers present, the last frame whose
  // layout had a witness and found no exchange clearly better (within swap_margin_m), or
  // whose exchange the continuity veto turned down (-1: none).
  std::vector<int64_t> layout_fitted_frame_;
  std::vector<std::vector<int>> markers_of_joint_;
  std::vector<double> weights_;
  std::vector<int> trusted_on_joint_;  // ReadmitConsistentSegments scratch: trusted samples...
  std::vector<int> readmit_on_joint_;  // ...and 1 readmit / -1 a pair disagrees / 0 no pair
  std::vector<Vec3> residual_;         // per marker, of the newest frame
  std::vector<double> weights_without_lone_;  // OverruleLoneSamples scratch...
  std::vector<int> lone_samples_;             // ...and the lone samples left out
  std::vector<uint8_t> marker_flags_;         // CleanMask scratch
  std::vector<int>
      swap_candidates_;  // RelabelSwaps scratch: markers predictable from fine samples...
  std::vector<Vec3> candidate_previous_;  // ...and their previous positions, packed
};

}  // namespace mocapd
