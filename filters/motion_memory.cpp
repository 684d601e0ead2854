// The motion memory's ring, its nearest-pose search and its self-test (see the header).
#include "filters/motion_memory.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "filters/rotation.hpp"

namespace mocapd {
namespace {

// The motion's weight against the pose's (s): a joint turning 1 rad/s differently
// counts as much as one 0.1 rad away (a quaternion distance of about 0.0025).
constexpr float kVelocityWeightS = 0.05F;

}  // namespace

MotionMemory::MotionMemory(const Skeleton& skeleton, std::span<const uint8_t> seeable,
                           double rate_hz, double span_s)
    : skeleton_(skeleton),
      joints_(skeleton.num_joints()),
      rate_hz_(rate_hz),
      capacity_(span_s > 0.0 && joints_ > 1 ? static_cast<int>(std::ceil(span_s / kSampleIntervalS))
                                            : 0),
      interval_frames_(std::max(1, static_cast<int>(std::lround(rate_hz * kSampleIntervalS)))),
      test_lag_frames_(std::max<int64_t>(1, std::llround(kTestHiddenS * rate_hz))),
      seeable_(seeable.begin(), seeable.end()) {
  const auto j = static_cast<size_t>(joints_);
  rotations_.assign(static_cast<size_t>(capacity_) * j * 4, 0.0F);
  velocities_.assign(static_cast<size_t>(capacity_) * j * 3, 0.0F);
  kept_frame_.assign(static_cast<size_t>(capacity_), 0);
  query_rotation_.assign(j * 4, 0.0F);
  query_velocity_.assign(j * 3, 0.0F);
  test_known_.assign(j, 1);
  test_guess_ = RestPose(skeleton);
  recall_error_.assign(j, 0.0);
  hold_error_.assign(j, 0.0);
  tests_.assign(j, 0);
}

void MotionMemory::Clear() {
  head_ = count_ = 0;
  frame_ = 0;
  since_kept_s_ = 0.0;
  next_test_joint_ = 1;
  std::fill(recall_error_.begin(), recall_error_.end(), 0.0);
  std::fill(hold_error_.begin(), hold_error_.end(), 0.0);
  std::fill(tests_.begin(), tests_.end(), 0);
}

void MotionMemory::Features(const Pose& pose, const Pose& previous, float* rotation,
                            float* velocity) const {
  for (int j = 0; j < joints_; ++j) {
    const auto uj = static_cast<size_t>(j);
    const Quat& q = pose.rotation[uj];
    for (int c = 0; c < 4; ++c) rotation[4 * j + c] = static_cast<float>(q.coeffs()[c]);
    const Vec3 w = LogRotation(previous.rotation[uj].conjugate() * q) * rate_hz_;
    for (int c = 0; c < 3; ++c) velocity[3 * j + c] = static_cast<float>(w[c]);
  }
}

Quat MotionMemory::Remembered(int slot, int joint) const {
  const float* r = &rotations_[(static_cast<size_t>(slot) * static_cast<size_t>(joints_) +
                                static_cast<size_t>(joint)) *
                               4];
  Quat q;
  q.coeffs() << r[0], r[1], r[2], r[3];
  return q;
}

void MotionMemory::Observe(const Pose& pose, const Pose& previous, bool whole) {
  if (capacity_ == 0) return;
  ++frame_;
  since_kept_s_ += 1.0 / rate_hz_;
  // Kept by time, not every n frames: at 100 or 250 Hz a whole number of frames is not
  // 1/30 s, and the span and the tests' lag would drift from their seconds.
  if (!whole || since_kept_s_ < kSampleIntervalS - 0.5 / rate_hz_) return;
  since_kept_s_ = since_kept_s_ >= 2.0 * kSampleIntervalS ? 0.0 : since_kept_s_ - kSampleIntervalS;
  Features(pose, previous, query_rotation_.data(), query_velocity_.data());
  TestOneLimb(pose);
  const auto slot = static_cast<size_t>(head_);
  const auto j = static_cast<size_t>(joints_);
  std::copy_n(query_rotation_.begin(), query_rotation_.size(), &rotations_[slot * j * 4]);
  std::copy_n(query_velocity_.begin(), query_velocity_.size(), &velocities_[slot * j * 3]);
  kept_frame_[slot] = frame_;
  head_ = (head_ + 1) % capacity_;
  count_ = std::min(count_ + 1, capacity_);
}

// The memory's self-test, one seeable limb per kept pose in turn: the limb under joint r
// is recalled as if hidden, from the poses kept at least kTestHiddenS ago (as a limb
// hidden that long would be), and compared with the pose itself and with what holding it
// from then would give. Needs the query features set to this pose.
void MotionMemory::TestOneLimb(const Pose& pose) {
  if (count_ < MinCount()) return;
  int r = next_test_joint_;
  for (int tries = 0; tries < joints_ && !seeable_[static_cast<size_t>(r)]; ++tries)
    r = r + 1 < joints_ ? r + 1 : 1;
  next_test_joint_ = r + 1 < joints_ ? r + 1 : 1;
  if (!seeable_[static_cast<size_t>(r)]) return;
  // Holding starts from the newest pose at least the test's lag old; when the subject was
  // not whole around then (no pose kept), that pose is older and holding it would look
  // worse than it is: no test.
  int hold_slot = -1;
  for (int age = 0; age < count_; ++age)
    if (frame_ - kept_frame_[static_cast<size_t>(Slot(age))] >= test_lag_frames_) {
      hold_slot = Slot(age);
      break;
    }
  if (hold_slot < 0 || frame_ - kept_frame_[static_cast<size_t>(hold_slot)] >
                           test_lag_frames_ + 2 * interval_frames_)
    return;
  for (int j = 0; j < joints_; ++j)
    test_known_[static_cast<size_t>(j)] = !skeleton_.IsAncestorOrSelf(r, j);
  Nearest(test_known_, test_lag_frames_);
  if (best_slot_[0] < 0) return;
  Average(test_known_, &test_guess_);
  double recall = 0.0, hold = 0.0;
  for (int j = r; j < joints_; ++j) {  // parents first: r's limb lies after r
    const auto uj = static_cast<size_t>(j);
    if (test_known_[uj] || !seeable_[uj]) continue;
    recall += AngleBetween(test_guess_.rotation[uj], pose.rotation[uj]);
    hold += AngleBetween(Remembered(hold_slot, j), pose.rotation[uj]);
  }
  const auto ur = static_cast<size_t>(r);
  recall_error_[ur] += kTestWeight * (recall - recall_error_[ur]);
  hold_error_[ur] += kTestWeight * (hold - hold_error_[ur]);
  ++tests_[ur];
}

void MotionMemory::Nearest(std::span<const uint8_t> known, int64_t min_age_frames) {
  best_cost_.fill(std::numeric_limits<float>::infinity());
  best_slot_.fill(-1);
  const float w2 = kVelocityWeightS * kVelocityWeightS;
  for (int age = 0; age < count_; ++age) {
    const int e = Slot(age);
    if (frame_ - kept_frame_[static_cast<size_t>(e)] < min_age_frames) continue;
    const float* r = &rotations_[static_cast<size_t>(e) * static_cast<size_t>(joints_) * 4];
    const float* v = &velocities_[static_cast<size_t>(e) * static_cast<size_t>(joints_) * 3];
    float cost = 0.0F;
    // The root's rotation is left out: which way the subject faces in the room says
    // nothing of how its limbs move.
    for (int j = 1; j < joints_ && cost < best_cost_.back(); ++j) {
      const auto uj = static_cast<size_t>(j);
      if (!known[uj] || !seeable_[uj] || skeleton_.joint(j).type == JointType::kFixed) continue;
      const float* qr = &query_rotation_[static_cast<size_t>(4 * j)];
      const float* qv = &query_velocity_[static_cast<size_t>(3 * j)];
      const float dot =
          qr[0] * r[4 * j] + qr[1] * r[4 * j + 1] + qr[2] * r[4 * j + 2] + qr[3] * r[4 * j + 3];
      const float dx = qv[0] - v[3 * j], dy = qv[1] - v[3 * j + 1], dz = qv[2] - v[3 * j + 2];
      cost += 2.0F - 2.0F * std::fabs(dot) + w2 * (dx * dx + dy * dy + dz * dz);
    }
    if (cost >= best_cost_.back()) continue;
    size_t i = kNearest - 1;
    for (; i > 0 && best_cost_[i - 1] > cost; --i) {
      best_cost_[i] = best_cost_[i - 1];
      best_slot_[i] = best_slot_[i - 1];
    }
    best_cost_[i] = cost;
    best_slot_[i] = e;
  }
}

void MotionMemory::Average(std::span<const uint8_t> known, Pose* guess) const {
  for (int j = 0; j < joints_; ++j) {
    if (known[static_cast<size_t>(j)]) continue;
    Eigen::Vector4d sum = Eigen::Vector4d::Zero(), first = Eigen::Vector4d::Zero();
    for (size_t k = 0; k < kNearest && best_slot_[k] >= 0; ++k) {
      const Eigen::Vector4d q = Remembered(best_slot_[k], j).coeffs();
      if (k == 0) first = q;
      // q and -q are one rotation: each is added on the first one's side.
      sum += q.dot(first) < 0.0 ? Eigen::Vector4d(-q) : q;
    }
    const double n = sum.norm();
    if (n > 1e-9) guess->rotation[static_cast<size_t>(j)].coeffs() = sum / n;
  }
}

double MotionMemory::Trust(int limb) const {
  const auto ul = static_cast<size_t>(limb);
  // Untested (or never moving): no trust.
  if (tests_[ul] < kMinTests || hold_error_[ul] <= 1e-6) return 0.0;
  const double ratio = recall_error_[ul] / hold_error_[ul];
  return std::clamp((kUntrustedRatio - ratio) / (kUntrustedRatio - kTrustedRatio), 0.0, 1.0);
}

bool MotionMemory::Recall(const Pose& pose, const Pose& previous, std::span<const uint8_t> known,
                          Pose* guess) {
  if (capacity_ == 0 || count_ < MinCount()) return false;
  Features(pose, previous, query_rotation_.data(), query_velocity_.data());
  Nearest(known, 0);
  if (best_slot_[0] < 0) return false;
  Average(known, guess);
  return true;
}

}  // namespace mocapd
