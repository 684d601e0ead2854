// What a subject's own recent past says about a limb the cameras have lost: a bounded
// memory of the poses it was seen whole in, searched by the rest of the body.
//
// People repeat themselves (steps, arm swings, a dance's figures), and the seen part of
// the body tells where in such a cycle they are. A limb hidden for a second or more is
// then better guessed from the poses it had when the rest of the body last looked like
// this (its pose and its motion) than held where it was last seen, but only where the
// subject does repeat itself: the memory tests itself on the limbs it sees and says how
// far each can be trusted. It keeps a pose every sample interval (1/30 s, whatever the
// capture rate) over a fixed span of seconds in a ring sized once, so nothing grows with
// the take and neither recall nor test allocates.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

#include "filters/skeleton.hpp"

namespace mocapd {

class MotionMemory {
 public:
  /// A memory of span_s seconds at rate_hz; span_s 0 (or a skeleton of one joint: no
  /// limb to recall) keeps nothing and recalls nothing. seeable[j] (one per joint): some
  /// marker lies on joint j or below it; only such limbs are tested, and only such joints
  /// describe the body. Sized here; never allocates after.
  MotionMemory(const Skeleton& skeleton, std::span<const uint8_t> seeable, double rate_hz,
               double span_s);

  /// Called once per frame, in order: pose is the frame's, previous the frame before's
  /// (their difference is the motion). Kept when whole (every seeable limb seen) and a
  /// sample interval has passed since the last kept pose; each kept pose also tests the
  /// memory on one limb (Trust).
  void Observe(const Pose& pose, const Pose& previous, bool whole);
  /// Writes into guess the rotation of every joint j with known[j] == 0, the average
  /// of the remembered poses nearest to pose and its motion on the known seeable joints.
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
  /// Frames between kept poses at this rate, about (a recall needs asking no oftener).
  int sample_interval_frames() const { return interval_frames_; }

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
  /// A span shorter than this could never test (0 aside, CleanupOptions refuses it).
  static constexpr double kMinUsefulSpanS = kMinSpanS + kTestHiddenS;
  /// Each test's share of a limb's running errors: about the last 8 tests of it.
  static constexpr double kTestWeight = 1.0 / 8.0;
  /// One test says little: a limb is not trusted before this many. (Every seeable joint
  /// is tested in turn, about once a second on a humanoid: a third test would leave a
  /// walk untrusted for its first 3-4 s.)
  static constexpr int kMinTests = 2;
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
  int Slot(int age) const { return ((head_ - 1 - age) % capacity_ + capacity_) % capacity_; }
  Quat Remembered(int slot, int joint) const;
  void TestOneLimb(const Pose& pose);
  /// The kNearest remembered poses to the query features on the known seeable joints,
  /// leaving out those kept less than min_age_frames ago.
  void Nearest(std::span<const uint8_t> known, int64_t min_age_frames);
  void Average(std::span<const uint8_t> known, Pose* guess) const;

  const Skeleton& skeleton_;
  const int joints_;
  const double rate_hz_;
  const int capacity_;
  const int interval_frames_;
  const int64_t test_lag_frames_;  // kTestHiddenS in frames
  std::vector<uint8_t> seeable_;
  int64_t frame_ = 0;          // frames observed
  double since_kept_s_ = 0.0;  // time since the last kept pose, less what was owed
  int head_ = 0, count_ = 0;
  int next_test_joint_ = 1;
  std::vector<float> rotations_;     // capacity x joints x 4 (x, y, z, w)
  std::vector<float> velocities_;    // capacity x joints x 3, rad/s in the parent frame
  std::vector<int64_t> kept_frame_;  // per slot, the frame it was kept at
  std::vector<float> query_rotation_, query_velocity_;
  std::array<float, kNearest> best_cost_{};
  std::array<int, kNearest> best_slot_{};
  std::vector<uint8_t> test_known_;
  Pose test_guess_;
  // Per limb (its top joint): running means of the summed joint errors (rad) and tests.
  std::vector<double> recall_error_, hold_error_;
  std::vector<int> tests_;
};

}  // namespace mocapd
