// Accuracy metrics for a solved skeleton against ground truth: per-joint global
// position error (m) and global rotation error (rad), accumulated over a take.
// Evaluation code, not for the per-frame path (it stores every sample for percentiles).
#pragma once

#include <vector>

#include "filters/skeleton.hpp"

namespace mocapd {

class PoseErrorAccumulator {
 public:
  /// Joints of type kFixed are left out: they cannot be wrong, and would dilute the mean.
  explicit PoseErrorAccumulator(const Skeleton& skeleton);

  /// Adds one frame: truth and estimate are FK results of the same skeleton.
  void Add(const KinematicsWorkspace& truth, const KinematicsWorkspace& estimate);

  int frames() const { return frames_; }
  double mean_position_error_m() const;
  double max_position_error_m() const;
  double mean_rotation_error_rad() const;
  double max_rotation_error_rad() const;
  /// The largest, over joints, of each joint's q-quantile rotation error (q in [0, 1]).
  double worst_joint_rotation_quantile_rad(double q, int* worst_joint = nullptr) const;
  double worst_joint_position_quantile_m(double q, int* worst_joint = nullptr) const;
  /// A frame's position error is its worst joint's (what a viewer sees): the q-quantile
  /// of that over the frames added.
  double frame_position_error_quantile_m(double q) const;
  /// The frame (in the order added) with the largest position error, and its joint; -1
  /// when no frame was added.
  int worst_frame(int* worst_joint = nullptr) const;
  /// A frame's error and the joint it comes from.
  struct FrameError {
    int frame;  ///< In the order added.
    int joint;
    double error_m;
  };
  /// Every frame whose position error is at least threshold_m, in the order added: what
  /// makes up a tail (the frames at or above a quantile) and which joints it comes from.
  std::vector<FrameError> frames_at_least(double threshold_m) const;

 private:
  /// Each frame's worst joint and its error (joint -1 when no joint is evaluated).
  std::vector<FrameError> FrameWorsts() const;

  std::vector<int> joints_;
  std::vector<std::vector<double>> position_, rotation_;  // per evaluated joint
  int frames_ = 0;
};

/// Returns the q-quantile (q in [0, 1], nearest rank) of values; 0 if empty. Copies.
double Quantile(std::vector<double> values, double q);

}  // namespace mocapd
