// Least-squares marker-to-joint calibration.
#include "filters/calibration.hpp"

#include <Eigen/Cholesky>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace mocapd {
namespace {

struct RigidFit {
  Vec3 offset = Vec3::Zero();
  double rms = std::numeric_limits<double>::infinity();
};

RigidFit FitRigid(std::span<const KinematicsWorkspace> frames, const std::vector<int>& valid,
                  std::span<const Vec3> y, size_t stride, size_t m, int j) {
  const auto uj = static_cast<size_t>(j);
  RigidFit fit;
  Vec3 sum = Vec3::Zero();
  for (int f : valid) {
    const auto uf = static_cast<size_t>(f);
    sum += frames[uf].R_WJ[uj].transpose() * (y[uf * stride + m] - frames[uf].p_WJ[uj]);
  }
  fit.offset = sum / static_cast<double>(valid.size());
  double sq = 0.0;
  for (int f : valid) {
    const auto uf = static_cast<size_t>(f);
    sq +=
        (frames[uf].R_WJ[uj] * fit.offset + frames[uf].p_WJ[uj] - y[uf * stride + m]).squaredNorm();
  }
  fit.rms = std::sqrt(sq / static_cast<double>(valid.size()));
  return fit;
}

struct BlendFit {
  Vec3 a = Vec3::Zero(), b = Vec3::Zero();  // y = R_C a + R_P b + p_P
  double rms = std::numeric_limits<double>::infinity();
};

BlendFit FitBlend(std::span<const KinematicsWorkspace> frames, const std::vector<int>& valid,
                  std::span<const Vec3> y, size_t stride, size_t m, int child, int parent) {
  const auto uc = static_cast<size_t>(child), up = static_cast<size_t>(parent);
  Mat6 H = Mat6::Zero();
  Vec6 g = Vec6::Zero();
  for (int f : valid) {
    const auto uf = static_cast<size_t>(f);
    Eigen::Matrix<double, 3, 6> A;
    A.leftCols<3>() = frames[uf].R_WJ[uc];
    A.rightCols<3>() = frames[uf].R_WJ[up];
    H.noalias() += A.transpose() * A;
    g.noalias() += A.transpose() * (y[uf * stride + m] - frames[uf].p_WJ[up]);
  }
  BlendFit fit;
  // A hinge-like joint leaves the offsets' components along its axis indistinguishable
  // (R_C u = R_P u for u on the axis); a tiny ridge picks the minimum-norm split, which
  // gives the same marker positions.
  H.diagonal().array() += 1e-9 * std::max(H.trace(), 1e-12);
  const Eigen::LDLT<Mat6> ldlt(H);
  const Vec6 x = ldlt.solve(g);
  if (ldlt.info() != Eigen::Success || !x.allFinite()) return fit;
  fit.a = x.head<3>();
  fit.b = x.tail<3>();
  double sq = 0.0;
  for (int f : valid) {
    const auto uf = static_cast<size_t>(f);
    sq += (frames[uf].R_WJ[uc] * fit.a + frames[uf].R_WJ[up] * fit.b + frames[uf].p_WJ[up] -
           y[uf * stride + m])
              .squaredNorm();
  }
  fit.rms = std::sqrt(sq / static_cast<double>(valid.size()));
  return fit;
}

}  // namespace

void CalibrationOptions::Validate() const {
  if (!(max_rms_m > 0.0)) throw std::invalid_argument("CalibrationOptions.max_rms_m: expected > 0");
  if (!(blend_improvement > 0.0 && blend_improvement <= 1.0))
    throw std::invalid_argument("CalibrationOptions.blend_improvement: expected (0, 1]");
  if (!(blend_parent_weight > 0.0 && blend_parent_weight < 1.0))
    throw std::invalid_argument("CalibrationOptions.blend_parent_weight: expected (0, 1)");
  if (min_frames < 1) throw std::invalid_argument("CalibrationOptions.min_frames: expected >= 1");
}

std::vector<MarkerCalibration> CalibrateMarkers(const Skeleton& skeleton,
                                                std::span<const KinematicsWorkspace> joint_frames,
                                                std::span<const std::string> names,
                                                std::span<const Vec3> observed,
                                                const CalibrationOptions& options) {
  options.Validate();
  const size_t stride = names.size();
  if (observed.size() != joint_frames.size() * stride)
    throw std::invalid_argument("calibration: " + std::to_string(observed.size()) +
                                " observations for " + std::to_string(joint_frames.size()) +
                                " frames x " + std::to_string(stride) + " markers");
  std::vector<MarkerCalibration> out;
  for (size_t m = 0; m < stride; ++m) {
    MarkerCalibration cal;
    cal.name = names[m];
    std::vector<int> valid;
    for (size_t f = 0; f < joint_frames.size(); ++f)
      if (observed[f * stride + m].allFinite()) valid.push_back(static_cast<int>(f));
    cal.frames_used = static_cast<int>(valid.size());
    if (cal.frames_used < options.min_frames) {
      cal.reason = "only " + std::to_string(cal.frames_used) + " valid frames (need " +
                   std::to_string(options.min_frames) + ")";
      out.push_back(cal);
      continue;
    }
    int best = -1;
    RigidFit best_fit;
    for (int j = 0; j < skeleton.num_joints(); ++j) {
      const RigidFit fit = FitRigid(joint_frames, valid, observed, stride, m, j);
      if (fit.rms < best_fit.rms) {
        best_fit = fit;
        best = j;
      }
    }
    cal.rms_m = best_fit.rms;
    cal.definition.name = cal.name;
    cal.definition.attachments[0] = {best, 1.0, best_fit.offset};
    if (best_fit.rms > options.min_rigid_rms_for_blend_m) {
      // Try blends across the joints next to the best one: (best, parent) and (child, best).
      std::vector<std::pair<int, int>> pairs;
      if (skeleton.joint(best).parent.is_valid())
        pairs.emplace_back(best, skeleton.joint(best).parent.value);
      for (int c : skeleton.children(best)) pairs.emplace_back(c, best);
      BlendFit best_blend;
      std::pair<int, int> best_pair{-1, -1};
      for (const auto& [c, p] : pairs) {
        if (skeleton.joint(c).type == JointType::kFree)
          continue;  // its offset moves; no fixed blend
        const BlendFit fit = FitBlend(joint_frames, valid, observed, stride, m, c, p);
        if (fit.rms < best_blend.rms) {
          best_blend = fit;
          best_pair = {c, p};
        }
      }
      if (best_pair.first >= 0 && best_blend.rms < options.blend_improvement * best_fit.rms) {
        const double w = options.blend_parent_weight;
        const Vec3& t_c = skeleton.joint(best_pair.first).offset;
        cal.definition.num_attachments = 2;
        cal.definition.attachments[0] = {best_pair.first, 1.0 - w, best_blend.a / (1.0 - w)};
        cal.definition.attachments[1] = {best_pair.second, w, (best_blend.b - (1.0 - w) * t_c) / w};
        cal.rms_m = best_blend.rms;
      }
    }
    if (cal.rms_m > options.max_rms_m) {
      char buf[160];
      std::snprintf(buf, sizeof(buf),
                    "best fit (joint '%s') leaves %.1f mm RMS, above the %.1f mm limit",
                    skeleton.joint(cal.definition.attachments[0].joint).name.c_str(),
                    cal.rms_m * 1e3, options.max_rms_m * 1e3);
      cal.reason = buf;
    } else {
      cal.accepted = true;
    }
    out.push_back(cal);
  }
  return out;
}

}  // namespace mocapd
