// Tests for the motion memory: a limb that moves with the rest of the body is recalled
// from the subject's past and trusted; one that moves on its own is not; nothing is
// recalled before enough whole poses, from poses that were not whole, or after Clear.
#include "filters/motion_memory.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "filters/rotation.hpp"

namespace mocapd {
namespace {

constexpr double kRateHz = 120.0;

// A root, a torso that rocks, and an arm (upper arm, forearm) on the root.
Skeleton SmallBody() {
  std::vector<Joint> joints(4);
  joints[0] = Joint{.name = "root", .parent = {}, .type = JointType::kFree};
  joints[1] = Joint{.name = "torso", .parent = JointIndex(0), .offset = Vec3(0, 0.1, 0)};
  joints[2] = Joint{.name = "arm", .parent = JointIndex(0), .offset = Vec3(0.2, 0.4, 0)};
  joints[3] = Joint{.name = "forearm", .parent = JointIndex(2), .offset = Vec3(0.3, 0, 0)};
  return Skeleton(std::move(joints));
}

// The torso rocks at 1 Hz; the arm swings with it (in step) or drifts slowly on its own
// (in 20 s, never back where it was).
Pose PoseAt(const Skeleton& skeleton, double t, bool arm_in_step) {
  Pose pose = RestPose(skeleton);
  const double phase = 2.0 * M_PI * t;
  pose.rotation[1] = Quat(Eigen::AngleAxisd(0.4 * std::sin(phase), Vec3::UnitX()));
  const double arm_phase = arm_in_step ? phase + 1.0 : 0.3 + 0.06 * t;
  pose.rotation[2] = Quat(Eigen::AngleAxisd(0.8 * std::sin(arm_phase), Vec3::UnitZ()));
  pose.rotation[3] = Quat(Eigen::AngleAxisd(0.5 * std::sin(arm_phase + 0.5), Vec3::UnitZ()));
  return pose;
}

// Observes seconds of motion, every frame whole unless told.
void Observe(MotionMemory* memory, const Skeleton& skeleton, double seconds, bool arm_in_step,
             bool whole = true) {
  for (int f = 1; f < static_cast<int>(seconds * kRateHz); ++f)
    memory->Observe(PoseAt(skeleton, f / kRateHz, arm_in_step),
                    PoseAt(skeleton, (f - 1) / kRateHz, arm_in_step), whole);
}

const std::vector<uint8_t> kArmHidden = {1, 1, 0, 0};
const std::vector<uint8_t> kAllSeeable = {1, 1, 1, 1};

TEST(MotionMemoryTest, ALimbThatMovesWithTheBodyIsRecalledFromItsPastAndTrusted) {
  const Skeleton skeleton = SmallBody();
  MotionMemory memory(skeleton, kAllSeeable, kRateHz, 60.0);
  Observe(&memory, skeleton, 10.0, true);
  // A moment the memory never held (between its samples), the arm hidden.
  const double t = 10.3 + 0.5 / kRateHz;
  const Pose truth = PoseAt(skeleton, t, true);
  Pose guess = RestPose(skeleton);
  ASSERT_TRUE(memory.Recall(truth, PoseAt(skeleton, t - 1.0 / kRateHz, true), kArmHidden, &guess));
  EXPECT_LT(AngleBetween(guess.rotation[2], truth.rotation[2]), 0.1);
  EXPECT_LT(AngleBetween(guess.rotation[3], truth.rotation[3]), 0.1);
  // Holding the arm where it was half a second before is far worse.
  EXPECT_GT(AngleBetween(PoseAt(skeleton, t - 0.5, true).rotation[2], truth.rotation[2]), 0.3);
  // The known joints are left as they were.
  EXPECT_LT(AngleBetween(guess.rotation[1], Quat::Identity()), 1e-12);
  EXPECT_GT(memory.Trust(2), 0.8);  // the arm hidden whole
  EXPECT_GT(memory.Trust(3), 0.8);  // the forearm alone
}

TEST(MotionMemoryTest, ALimbThatDriftsOnItsOwnIsNotTrusted) {
  const Skeleton skeleton = SmallBody();
  MotionMemory memory(skeleton, kAllSeeable, kRateHz, 60.0);
  Observe(&memory, skeleton, 20.0, false);
  // Where the arm was half a second ago is a better guess than any pose it had when the
  // torso last rocked the same way.
  EXPECT_LT(memory.Trust(2), 0.2);
  // Nor is the forearm alone: it keeps to its arm, but the arm is somewhere it has never
  // been, so no remembered pose is nearer than the one held.
  EXPECT_LT(memory.Trust(3), 0.2);
}

TEST(MotionMemoryTest, NothingIsRecalledFromTooLittleMotionOrFromPosesThatWereNotWhole) {
  const Skeleton skeleton = SmallBody();
  const Pose pose = PoseAt(skeleton, 0.5, true);
  Pose guess = RestPose(skeleton);

  MotionMemory short_memory(skeleton, kAllSeeable, kRateHz, 60.0);
  Observe(&short_memory, skeleton, MotionMemory::kMinSpanS - 0.2, true);
  EXPECT_FALSE(short_memory.Recall(pose, pose, kArmHidden, &guess));

  MotionMemory unseen(skeleton, kAllSeeable, kRateHz, 60.0);
  Observe(&unseen, skeleton, 10.0, true, /*whole=*/false);
  EXPECT_EQ(unseen.size(), 0);
  EXPECT_FALSE(unseen.Recall(pose, pose, kArmHidden, &guess));
  EXPECT_EQ(unseen.Trust(2), 0.0);

  MotionMemory off(skeleton, kAllSeeable, kRateHz, 0.0);
  EXPECT_FALSE(off.enabled());
  Observe(&off, skeleton, 10.0, true);
  EXPECT_FALSE(off.Recall(pose, pose, kArmHidden, &guess));
  EXPECT_LT(AngleBetween(guess.rotation[2], Quat::Identity()), 1e-12);
}

TEST(MotionMemoryTest, KeepsOnePoseEachThirtiethOfASecondUpToItsSpanAtAnyRate) {
  const Skeleton skeleton = SmallBody();
  // 100 and 250 Hz are no whole number of frames per 1/30 s.
  for (const double rate : {60.0, 100.0, 120.0, 240.0, 250.0, 360.0}) {
    MotionMemory memory(skeleton, kAllSeeable, rate, 3.0);
    const Pose pose = RestPose(skeleton);
    for (int f = 0; f < static_cast<int>(2.0 * rate); ++f) memory.Observe(pose, pose, true);
    EXPECT_NEAR(memory.size(), 60, 1) << rate << " Hz";
    for (int f = 0; f < static_cast<int>(10.0 * rate); ++f) memory.Observe(pose, pose, true);
    EXPECT_EQ(memory.size(), 90) << rate << " Hz";  // 3 s at 30 per second, the ring full
  }
}

TEST(MotionMemoryTest, AFullRingStillRecallsAndTrustsFromItsNewestSeconds) {
  const Skeleton skeleton = SmallBody();
  MotionMemory memory(skeleton, kAllSeeable, kRateHz, 3.0);
  Observe(&memory, skeleton, 20.0, true);  // the ring has wrapped many times
  ASSERT_EQ(memory.size(), 90);
  const double t = 20.3 + 0.5 / kRateHz;
  const Pose truth = PoseAt(skeleton, t, true);
  Pose guess = RestPose(skeleton);
  ASSERT_TRUE(memory.Recall(truth, PoseAt(skeleton, t - 1.0 / kRateHz, true), kArmHidden, &guess));
  EXPECT_LT(AngleBetween(guess.rotation[2], truth.rotation[2]), 0.1);
  EXPECT_GT(memory.Trust(2), 0.8);
}

TEST(MotionMemoryTest, ASkeletonOfOneJointHasNoLimbToRecall) {
  std::vector<Joint> joints(1);
  joints[0] = Joint{.name = "prop", .parent = {}, .type = JointType::kFree};
  const Skeleton prop(std::move(joints));
  const std::vector<uint8_t> seeable = {1};
  MotionMemory memory(prop, seeable, kRateHz, 60.0);
  EXPECT_FALSE(memory.enabled());
  const Pose pose = RestPose(prop);
  for (int f = 0; f < 600; ++f) memory.Observe(pose, pose, true);
  Pose guess = pose;
  EXPECT_FALSE(memory.Recall(pose, pose, seeable, &guess));
}

TEST(MotionMemoryTest, AFewTestsEarnNoTrustAndALimbWithoutMarkersIsNeverTested) {
  const Skeleton skeleton = SmallBody();
  // The forearm has no marker (nor anything below it): it is not a limb the cameras see.
  const std::vector<uint8_t> seeable = {1, 1, 1, 0};
  MotionMemory memory(skeleton, seeable, kRateHz, 60.0);
  // The first test comes once 2 s are kept, and the seeable joints (torso, arm) are
  // tested in turn, one per kept pose: 2.1 s gives the arm at most one test.
  Observe(&memory, skeleton, 2.1, true);
  EXPECT_EQ(memory.Trust(2), 0.0);
  Observe(&memory, skeleton, 10.0, true);
  EXPECT_GT(memory.Trust(2), 0.8);
  EXPECT_EQ(memory.Trust(3), 0.0);
}

TEST(MotionMemoryTest, ClearForgetsEveryPoseAndTest) {
  const Skeleton skeleton = SmallBody();
  MotionMemory memory(skeleton, kAllSeeable, kRateHz, 60.0);
  Observe(&memory, skeleton, 10.0, true);
  ASSERT_GT(memory.Trust(2), 0.0);
  memory.Clear();
  EXPECT_EQ(memory.size(), 0);
  EXPECT_EQ(memory.Trust(2), 0.0);
  Pose guess = RestPose(skeleton);
  const Pose pose = PoseAt(skeleton, 0.5, true);
  EXPECT_FALSE(memory.Recall(pose, pose, kArmHidden, &guess));
}

}  // namespace
}  // namespace mocapd
