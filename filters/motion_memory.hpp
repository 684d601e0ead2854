// What a subject's own recent past says about a limb the cameras have lost: a bounded
// memory of the poses it was seen whole in, searched by the rest of the body.
//
// People repeat themselves (steps, arm swings, a dance's figures), and the seen part of
// the body tells where in such a cycle they are. A limb hidden for a second or more is
// then better guessed from the poses it had when the rest of the body last looked like
// this (its pose and its motion) than held where it was last seen. The memory keeps a
// pose every sample interval (1/30 s, whatever the capture rate) over a fixed span of
// seconds in a ring sized once, so nothing grows with the take and recall never
// allocates. Recall averages the few nearest poses: one nearest pose alone follows a
// single past moment and its quirks.
#pragma once

#include <array>
#include <cmath>
#include <span>
#include <vector>

#include "filters/skeleton.hpp"

namespace mocapd {

class MotionMemory {
 public:
  /// A memory of span_s seconds at rate_hz (span_s 0: it keeps nothing and recalls
  /// nothing). Sized here; never allocates after.
  MotionMemory(const Skeleton& skeleton, double rate_hz, double span_s);

  /// Called once per frame: pose is the frame's, previous the frame before's (their
  /// difference is the motion). Kept when whole (every limb seen) and a sample interval
  /// has passed since the last kept pose; each kept pose also tests the memory on one
  /// limb (Trust).
  void Observe(const Pose& pose, const Pose& previous, bool whole);
  /// Writes into guess the rotation of every joint j with known[j] == 0, the average
  /// of the remembered poses nearest to pose and its motion on the known joints.
  /// Returns false (guess untouched) while the memory holds under kMinSpanS of poses.
  bool Recall(const Pose& pose, const Pose& previous, std::span<const uint8_t> known, Pose* guess);
  /// How far a recall of the limb under this joint (the joint and all below it) can be
  /// trusted over holding it, 0 to 1, from the memory's own tests: each kept pose, one
  /// limb in turn is recalled as if it had been hidden for kTestHiddenS and compared with
  /// where it is and with where holding it would have left it. A subject whose limbs
  /// repeat with the rest of the body (a walk, a drill) earns trust; a limb that drifts
  /// on its own, or does what the body never did before, does not.
  double Trust(int limb) const;
  /// Forgets every pose and test (a capture restart).
  void Clear();

  int size() const { return count_; }
  bool enabled() const { return capacity_ > 0; }

  /// Poses averaged by Recall: one nearest pose alone follows a single past moment.
  static constexpr size_t kNearest = 8;
  /// Recall needs this much remembered motion (s): fewer poses are a few moments, not
  /// the subject's repertoire.
  static constexpr double kMinSpanS = 2.0;
  /// Time between kept poses (s).
  static constexpr double kSampleIntervalS = 1.0 / 30.0;
  /// The tests hide a limb this long (s): the middle of what occlusions last (a frame
  /// to two seconds).
  static constexpr double kTestHiddenS = 0.5;
  /// Each test's share of a limb's running errors: about the last 8 tests of it.
  static constexpr double kTestWeight = 1.0 / 8.0;
  /// A limb is trusted fully where its tests' recalls were off by at most this share of
  /// what holding it was, and not at all from kUntrustedRatio: only where the memory is
  /// clearly the better guess. Trusted as soon as it was better at all (full at half,
  /// none at parity), one recall of a dance's arm hidden 1.5 s took a hand 81 cm off
  /// where holding it left it 44 cm off (bench/README.md, session 48).
  static constexpr double kTrustedRatio = 0.3;
  static constexpr double kUntrustedRatio = 0.7;

 private:
  int MinCount() const { return static_cast<int>(std::ceil(kMinSpanS / kSampleIntervalS)); }
  void Features(const Pose& pose, const Pose& previous, float* rotation, float* velocity) const;
  Quat Remembered(int age, int joint) const;
  void TestOneLimb(const Pose& pose);
  /// The kNearest remembered poses to the query features on the known joints, leaving
  /// out the skip_newest newest.
  void Nearest(std::span<const uint8_t> known, int skip_newest);
  void Average(std::span<const uint8_t> known, Pose* guess) const;

  const Skeleton& skeleton_;
  const int joints_;
  const double rate_hz_;
  const int capacity_;
  const int interval_frames_;
  const int test_lag_;  // kTestHiddenS in kept poses
  int frames_since_kept_ = 0;
  int head_ = 0, count_ = 0;
  int next_test_joint_ = 1;
  std::vector<float> rotations_;   // capacity x joints x 4 (x, y, z, w)
  std::vector<float> velocities_;  // capacity x joints x 3, rad/s in the parent frame
  std::vector<float> query_rotation_, query_velocity_;
  std::array<float, kNearest> best_cost_{};
  std::array<int, kNearest> best_slot_{};
  std::vector<uint8_t> test_known_;
  Pose test_guess_;
  // Per limb (its top joint), running means of the summed joint errors (rad).
  std::vector<double> recall_error_, hold_error_;
};

}  // namespace mocapd
