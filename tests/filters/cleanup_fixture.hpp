// The cleanup tests' fixture: 8 s of the built-in humanoid's mixed motion at 120 Hz with
// the default marker set, frames to corrupt by hand, the pipeline run over them, and
// measures of what came out (a marker's or joint's step beyond the truth's).
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <string>
#include <vector>

#include "filters/cleanup_pipeline.hpp"
#include "sim/synthesis.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {

class CleanupFixture : public ::testing::Test {
 protected:
  CleanupFixture() : fixture_(testing::MakeHumanoidFixture("mixed", 8.0, 120.0)) {
    frames_.resize(static_cast<size_t>(fixture_.take.num_frames));
    for (int f = 0; f < fixture_.take.num_frames; ++f)
      for (int m = 0; m < fixture_.take.num_points(); ++m)
        frames_[static_cast<size_t>(f)].push_back(fixture_.take.at(f, m));
  }
  int Marker(const char* name) const { return fixture_.markers->FindMarker(name)->value; }
  Vec3& Sample(int frame, int marker) {
    return frames_[static_cast<size_t>(frame)][static_cast<size_t>(marker)];
  }
  Vec3 Truth(int frame, int marker) const { return fixture_.take.at(frame, marker); }

  // Runs every frame through a pipeline and keeps every published frame.
  std::vector<CleanFrame> Run(const CleanupOptions& options) {
    CleanupPipeline dut(fixture_.skeleton, fixture_.markers, options);
    std::vector<CleanFrame> out;
    for (const auto& frame : frames_)
      if (dut.Push(frame)) out.push_back(dut.output());
    while (dut.Flush()) out.push_back(dut.output());
    counters_ = dut.counters();
    return out;
  }
  // How much further a published marker moved into frame f than the truth did, metres.
  double ExtraStep(const std::vector<CleanFrame>& out, int f, int m) const {
    const auto uf = static_cast<size_t>(f), um = static_cast<size_t>(m);
    return (out[uf].markers[um] - out[uf - 1].markers[um]).norm() -
           (Truth(f, m) - Truth(f - 1, m)).norm();
  }
  // How much further a joint of the published skeleton moved in one frame than it did in
  // `truth`, at worst over frames [from, to), metres.
  double WorstExtraJointStep(const std::vector<CleanFrame>& out, const std::vector<Pose>& truth,
                             const char* joint_name, int from, int to) const {
    const auto joint = static_cast<size_t>(fixture_.skeleton->FindJoint(joint_name)->value);
    KinematicsWorkspace t(*fixture_.skeleton), t_before(*fixture_.skeleton), e(*fixture_.skeleton),
        e_before(*fixture_.skeleton);
    double worst = 0.0;
    for (int f = from; f < to; ++f) {
      const auto uf = static_cast<size_t>(f);
      ForwardKinematics(*fixture_.skeleton, truth[uf - 1], &t_before);
      ForwardKinematics(*fixture_.skeleton, truth[uf], &t);
      ForwardKinematics(*fixture_.skeleton, out[uf - 1].pose, &e_before);
      ForwardKinematics(*fixture_.skeleton, out[uf].pose, &e);
      worst = std::max(worst, (e.p_WJ[joint] - e_before.p_WJ[joint]).norm() -
                                  (t.p_WJ[joint] - t_before.p_WJ[joint]).norm());
    }
    return worst;
  }
  // How far a joint of the published skeleton was from the fixture's motion, at worst
  // over frames [from, to), metres.
  double WorstJointError(const std::vector<CleanFrame>& out, const char* joint_name, int from,
                         int to) const {
    return WorstJointError(out, fixture_.motion, joint_name, from, to);
  }
  // ...from `truth`.
  double WorstJointError(const std::vector<CleanFrame>& out, const std::vector<Pose>& truth,
                         const char* joint_name, int from, int to) const {
    const auto joint = static_cast<size_t>(fixture_.skeleton->FindJoint(joint_name)->value);
    KinematicsWorkspace solved(*fixture_.skeleton), truth_now(*fixture_.skeleton);
    double worst = 0.0;
    for (int f = from; f < to; ++f) {
      ForwardKinematics(*fixture_.skeleton, out[static_cast<size_t>(f)].pose, &solved);
      ForwardKinematics(*fixture_.skeleton, truth[static_cast<size_t>(f)], &truth_now);
      worst = std::max(worst, (solved.p_WJ[joint] - truth_now.p_WJ[joint]).norm());
    }
    return worst;
  }
  static constexpr const char* kLeftForearm[] = {"LFRM1", "LFRM2", "LHND1", "LHND2", "LHND3"};
  // From frame 300 the left elbow bends a further 90 degrees over 100 frames while the
  // forearm and hand markers are occluded; they come back at frame 420 on the bent arm.
  // Returns the bent motion (the truth).
  std::vector<Pose> BendElbowWhileForearmIsOccluded() {
    std::vector<Pose> bent = fixture_.motion;
    const auto elbow = static_cast<size_t>(fixture_.skeleton->FindJoint("LeftForeArm")->value);
    for (size_t f = 300; f < bent.size(); ++f) {
      const double bend = M_PI / 2 * std::min(1.0, static_cast<double>(f - 300) / 100.0);
      bent[f].rotation[elbow] =
          bent[f].rotation[elbow] * Quat(Eigen::AngleAxisd(bend, Vec3::UnitZ()));
    }
    const C3dTake moved = SynthesizeMarkers(*fixture_.skeleton, *fixture_.markers, bent, 120.0);
    for (int f = 300; f < static_cast<int>(frames_.size()); ++f)
      for (const char* name : kLeftForearm)
        Sample(f, Marker(name)) = f < 420 ? Vec3::Constant(kNaN) : moved.at(f, Marker(name));
    return bent;
  }
  // RFOT2 stuck where it was at frame 699 for 60 frames, with Gaussian jitter of sigma
  // metres, the other detectors blind: how many of those frames come out as frozen.
  int FramesFoundFrozen(double jitter_sigma) {
    const int m = Marker("RFOT2");
    std::mt19937 rng(3);
    std::normal_distribution<double> jitter(0.0, jitter_sigma > 0.0 ? jitter_sigma : 1.0);
    for (int f = 700; f < 760; ++f)
      Sample(f, m) =
          Truth(699, m) +
          (jitter_sigma > 0.0 ? Vec3(jitter(rng), jitter(rng), jitter(rng)) : Vec3::Zero());
    CleanupOptions options = Blind();
    options.frozen_s = 0.05;
    const auto out = Run(options);
    int frozen = 0;
    for (int f = 700; f < 760; ++f)
      frozen += out[static_cast<size_t>(f)].reason[static_cast<size_t>(m)] == MaskReason::kFrozen;
    return frozen;
  }
  // Options with every outlier detector made blind, to test one at a time.
  static CleanupOptions Blind() {
    CleanupOptions o;
    o.residual_floor_m = 10.0;
    o.disagreement_position_m = 10.0;
    o.disagreement_rotation_rad = 10.0;
    o.spike_m = 10.0;
    o.rigid_tolerance_m = 10.0;
    o.swap_margin_m = 10.0;
    o.frozen_s = 1e4;
    return o;
  }

  testing::HumanoidFixture fixture_;
  std::vector<std::vector<Vec3>> frames_;
  CleanupCounters counters_;
};

}  // namespace mocapd
