// The final solve, the last stage of the cleanup: the skeleton Y- fitted to the frame's
// published samples, warm-started, and made pop-free by bounding how fast anything can
// move the skeleton beyond real motion:
//  - a captured sample is fitted through a target that starts where the skeleton had the
//    marker last frame, follows the sample's own (acceleration-limited) motion and closes
//    on it at a few mm per frame, or a share of the distance when far off (at most
//    1.5 m/s), so a sample that returns away from the skeleton (after a gap, a swap, a
//    repair whose end the lookahead did not see) is reached, not jumped to;
//  - a repaired sample weighs by where it came from (interpolated between known ends:
//    much; extrapolated from one side: little), its weight grows gradually, and it may
//    pull the skeleton only a few mm from the anchor: the pose the trusted samples alone
//    give, with every limb that has no trusted sample turned by its parent only slowly,
//    or toward the pose the subject's own recent motion recalls for it (MotionMemory)
//    where the memory has shown itself the better guess;
//    an interpolated sample on such a limb may pull it faster, toward where its markers
//    come back.
// Per-marker state is sized at construction; Solve never allocates.
#pragma once

#include <limits>
#include <span>
#include <vector>

#include "filters/cleanup_options.hpp"
#include "filters/cleanup_window.hpp"
#include "filters/motion_memory.hpp"

namespace mocapd {

class FinalSolve {
 public:
  /// The options must be valid (CleanupOptions::Validate); skeleton and markers must
  /// outlive the solver.
  FinalSolve(const Skeleton& skeleton, const MarkerSet& markers, const CleanupOptions& options);

  /// Solves the frame whose markers, status and source the repair filled (frames in
  /// order); writes its weight, pose and final_solve. captured_fit, if given (one per
  /// marker), is what to fit for captured samples instead of frame->markers (their
  /// smoothed positions). return_motion, if given, is per marker the motion per frame of
  /// a captured sample back from a gap, as the lookahead shows it (NaN: not shown). Never
  /// allocates or throws.
  void Solve(CleanFrame* frame, CleanupCounters* counters, std::span<const Vec3> captured_fit = {},
             std::span<const Vec3> return_motion = {});
  /// Forgets all state (a capture restart).
  void Reset();

 private:
  struct Track {
    double weight = 1.0;              // last final-solve weight
    bool catching_up = false;         // the target is still closing on the sample
    Vec3 data_motion = Vec3::Zero();  // the sample's motion as the catch-up last took it
    Vec3 output = Vec3::Zero();       // last published sample ...
    // ... and the frame of the last captured one (never one less than a frame number).
    int64_t last_captured = std::numeric_limits<int64_t>::min();
    // The last frame whose sample was captured, or interpolated between captured ones in
    // a frame with nothing captured at all (a frame lost before the cleanup): the sample's
    // motion carries through such frames.
    int64_t continuous_to = std::numeric_limits<int64_t>::min();
  };

  void AnchorRepairs(const CleanFrame& frame, CleanupCounters* counters);
  void MarkSeenLimbs();
  bool HoldUnseenLimbs();
  bool RecallUnseenLimbs();

  const Skeleton& skeleton_;
  const MarkerSet& markers_;
  const CleanupOptions options_;
  const CleanupFrameRules rules_;
  const IkOptions final_ik_;  // options_.final_ik with the unseen-knee rule
  IkState final_, anchor_;
  std::vector<Track> tracks_;
  bool blind_ = false;  // a frame had no captured sample, and none since saw most markers
  std::vector<double> weights_, anchor_weights_;
  std::vector<Vec3> solve_targets_;    // what the solve fits: X-, captured samples eased in
  std::vector<uint8_t> segment_seen_;  // per joint: a trusted sample on it
  std::vector<uint8_t> limb_seen_;     // per joint: a trusted sample on it or below
  std::vector<uint8_t> seeable_;       // per joint: a marker on it or below
  bool whole_ = false;                 // this frame's anchor saw every seeable limb
  MotionMemory memory_;                // the subject's recent whole poses
  Pose previous_pose_;                 // last frame's published pose
  bool has_previous_ = false;
  Pose recalled_;                      // what memory_ last recalled for the unseen limbs...
  std::vector<uint8_t> recall_known_;  // ...on the joints then seen...
  bool recalled_ok_ = false;
  int frames_to_recall_ = 0;  // ...and the frames until it is asked again
  Pose held_pose_;            // the anchor with its unseen limbs held (turned slowly)...
  KinematicsWorkspace held_kinematics_;
  std::vector<Vec3> held_markers_;  // ...and its markers
};

}  // namespace mocapd
