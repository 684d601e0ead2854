// Per-joint global position and rotation error statistics.
#include "filters/pose_error.hpp"

#include <algorithm>
#include <cmath>

namespace mocapd {

double Quantile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  const auto rank =
      static_cast<size_t>(std::clamp(std::ceil(q * static_cast<double>(values.size())) - 1.0, 0.0,
                                     static_cast<double>(values.size() - 1)));
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(rank),
                   values.end());
  return values[rank];
}

PoseErrorAccumulator::PoseErrorAccumulator(const Skeleton& skeleton) {
  for (int j = 0; j < skeleton.num_joints(); ++j)
    if (skeleton.joint(j).type != JointType::kFixed) joints_.push_back(j);
  position_.resize(joints_.size());
  rotation_.resize(joints_.size());
}

void PoseErrorAccumulator::Add(const KinematicsWorkspace& truth,
                               const KinematicsWorkspace& estimate) {
  for (size_t i = 0; i < joints_.size(); ++i) {
    const auto j = static_cast<size_t>(joints_[i]);
    position_[i].push_back((truth.p_WJ[j] - estimate.p_WJ[j]).norm());
    const Mat3 R = truth.R_WJ[j].transpose() * estimate.R_WJ[j];
    rotation_[i].push_back(std::acos(std::clamp(0.5 * (R.trace() - 1.0), -1.0, 1.0)));
  }
  ++frames_;
}

namespace {
double Mean(const std::vector<std::vector<double>>& samples) {
  double sum = 0.0;
  size_t n = 0;
  for (const auto& v : samples) {
    for (double x : v) sum += x;
    n += v.size();
  }
  return n == 0 ? 0.0 : sum / static_cast<double>(n);
}
double Max(const std::vector<std::vector<double>>& samples) {
  double m = 0.0;
  for (const auto& v : samples)
    for (double x : v) m = std::max(m, x);
  return m;
}
double WorstQuantile(const std::vector<std::vector<double>>& samples,
                     const std::vector<int>& joints, double q, int* worst) {
  double result = 0.0;
  for (size_t i = 0; i < samples.size(); ++i) {
    const double value = Quantile(samples[i], q);
    if (value >= result) {
      result = value;
      if (worst != nullptr) *worst = joints[i];
    }
  }
  return result;
}
}  // namespace

double PoseErrorAccumulator::mean_position_error_m() const { return Mean(position_); }
double PoseErrorAccumulator::max_position_error_m() const { return Max(position_); }
double PoseErrorAccumulator::mean_rotation_error_rad() const { return Mean(rotation_); }
double PoseErrorAccumulator::max_rotation_error_rad() const { return Max(rotation_); }
double PoseErrorAccumulator::worst_joint_rotation_quantile_rad(double q, int* worst_joint) const {
  return WorstQuantile(rotation_, joints_, q, worst_joint);
}
double PoseErrorAccumulator::worst_joint_position_quantile_m(double q, int* worst_joint) const {
  return WorstQuantile(position_, joints_, q, worst_joint);
}

std::vector<PoseErrorAccumulator::FrameError> PoseErrorAccumulator::FrameWorsts() const {
  std::vector<FrameError> out;
  out.reserve(static_cast<size_t>(frames_));
  for (int f = 0; f < frames_; ++f) {
    FrameError worst{f, -1, -1.0};
    for (size_t i = 0; i < position_.size(); ++i)
      if (position_[i][static_cast<size_t>(f)] > worst.error_m)
        worst = {f, joints_[i], position_[i][static_cast<size_t>(f)]};
    out.push_back(worst);
  }
  return out;
}

double PoseErrorAccumulator::frame_position_error_quantile_m(double q) const {
  std::vector<double> frame_errors;
  frame_errors.reserve(static_cast<size_t>(frames_));
  for (const FrameError& f : FrameWorsts()) frame_errors.push_back(std::max(f.error_m, 0.0));
  return Quantile(std::move(frame_errors), q);
}

int PoseErrorAccumulator::worst_frame(int* worst_joint) const {
  int frame = -1;
  double worst = -1.0;
  for (size_t i = 0; i < position_.size(); ++i) {
    for (size_t f = 0; f < position_[i].size(); ++f) {
      if (position_[i][f] > worst) {
        worst = position_[i][f];
        frame = static_cast<int>(f);
        if (worst_joint != nullptr) *worst_joint = joints_[i];
      }
    }
  }
  return frame;
}

std::vector<PoseErrorAccumulator::FrameError> PoseErrorAccumulator::frames_at_least(
    double threshold_m) const {
  std::vector<FrameError> out;
  for (const FrameError& f : FrameWorsts())
    if (f.joint >= 0 && f.error_m >= threshold_m) out.push_back(f);
  return out;
}

}  // namespace mocapd
