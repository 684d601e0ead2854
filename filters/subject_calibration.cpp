// Bundle adjustment of a subject from markers alone (see the header).
#include "filters/subject_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <stdexcept>
#include <utility>

#include <Eigen/Dense>

#include "filters/rotation.hpp"
#include "filters/skeleton.hpp"

namespace mocapd {
namespace {

using Matrix = Eigen::MatrixXd;
using Vector = Eigen::VectorXd;

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const auto mid = v.begin() + static_cast<long>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

// The working model: the template's skeleton and markers with the current offsets.
struct Model {
  std::shared_ptr<const Skeleton> skeleton;
  std::shared_ptr<const MarkerSet> markers;
};

Model MakeModel(const Skeleton& base, const std::vector<Vec3>& joint_offsets,
                const std::vector<MarkerDefinition>& base_markers,
                const std::vector<Vec3>& marker_offsets) {
  std::vector<Joint> joints(base.joints().begin(), base.joints().end());
  for (size_t j = 1; j < joints.size(); ++j) joints[j].offset = joint_offsets[j];
  Model m;
  m.skeleton = std::make_shared<const Skeleton>(std::move(joints));
  std::vector<MarkerDefinition> defs = base_markers;
  for (size_t k = 0; k < defs.size(); ++k) defs[k].attachments[0].offset = marker_offsets[k];
  m.markers = std::make_shared<const MarkerSet>(*m.skeleton, std::move(defs));
  return m;
}

// Huber weight of a residual of norm r.
double HuberWeight(double r, double delta) { return r <= delta ? 1.0 : delta / r; }

// Picks up to count frames of varied poses: for every joint in turn, the frames that
// spread its own rotation furthest (farthest-point sampling on its rotation vector), so a
// joint that moves in a few seconds of a long take (a star arc of the hip) gets its
// extremes; then, to fill the count, the frames farthest from those chosen over all
// joints. Independent poses, not many frames of one pose, carry the calibration.
std::vector<int> SelectVariedFrames(const std::vector<int>& candidates,
                                    const std::vector<Pose>& poses,
                                    const std::vector<int>& valid_count, int count) {
  const size_t n = candidates.size();
  if (n <= static_cast<size_t>(count)) return candidates;
  const size_t joints = poses[static_cast<size_t>(candidates[0])].rotation.size();
  std::vector<std::vector<Vec3>> turn(joints, std::vector<Vec3>(n));
  for (size_t i = 0; i < n; ++i)
    for (size_t j = 1; j < joints; ++j)
      turn[j][i] = LogRotation(poses[static_cast<size_t>(candidates[i])].rotation[j]);
  size_t first = 0;
  for (size_t i = 1; i < n; ++i)
    if (valid_count[static_cast<size_t>(candidates[i])] >
        valid_count[static_cast<size_t>(candidates[first])])
      first = i;
  std::vector<uint8_t> chosen(n, 0);
  chosen[first] = 1;
  int total = 1;
  // Farthest-point sampling from the chosen frames, by a distance between two frames.
  auto sample = [&](int budget, const std::function<double(size_t, size_t)>& distance) {
    std::vector<double> nearest(n, std::numeric_limits<double>::infinity());
    for (size_t c = 0; c < n; ++c)
      if (chosen[c])
        for (size_t i = 0; i < n; ++i) nearest[i] = std::min(nearest[i], distance(i, c));
    for (int k = 0; k < budget && total < count; ++k) {
      size_t next = 0;
      for (size_t i = 1; i < n; ++i)
        if (nearest[i] > nearest[next]) next = i;
      if (nearest[next] <= 1e-12) break;
      chosen[next] = 1;
      ++total;
      for (size_t i = 0; i < n; ++i) nearest[i] = std::min(nearest[i], distance(i, next));
    }
  };
  const int per_joint =
      std::max(3, count / (2 * static_cast<int>(std::max<size_t>(1, joints - 1))));
  for (size_t j = 1; j < joints; ++j)
    sample(per_joint, [&](size_t a, size_t b) { return (turn[j][a] - turn[j][b]).squaredNorm(); });
  sample(count, [&](size_t a, size_t b) {
    double d = 0.0;
    for (size_t j = 1; j < joints; ++j) d += (turn[j][a] - turn[j][b]).squaredNorm();
    return d;
  });
  std::vector<int> out;
  for (size_t i = 0; i < n; ++i)
    if (chosen[i]) out.push_back(candidates[i]);
  return out;
}

}  // namespace

void SubjectCalibrationOptions::Validate() const {
  auto require = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("SubjectCalibrationOptions.") + what);
  };
  require(max_frames >= 10, "max_frames: expected >= 10");
  require(min_valid_fraction > 0.0 && min_valid_fraction <= 1.0,
          "min_valid_fraction: expected (0, 1]");
  require(iterations >= 1, "iterations: expected >= 1");
  require(interleaved_solves >= 1 && interleaved_solves <= kMaxInterleavedSolves,
          "interleaved_solves: expected 1 to 16");
  require(converged_m > 0.0, "converged_m: expected > 0");
  require(huber_m > 0.0, "huber_m: expected > 0");
  require(joint_prior_sigma_m > 0.0 && marker_prior_sigma_m > 0.0 && symmetry_sigma_m > 0.0,
          "prior sigmas: expected > 0");
  require(covered_sigma_m > 0.0, "covered_sigma_m: expected > 0");
}

namespace {

// Where a solve starts from instead of the template: the joint and marker offsets of
// earlier solves, averaged. The bundle adjustment is then skipped: the solve only tracks
// the take with them and reports.
struct FixedStructure {
  std::vector<Vec3> joint_offset, marker_offset;
};

SubjectCalibrationResult SolveOnce(const CalibrationTemplate& tmpl, std::span<const Vec3> observed,
                                   int frames, const SubjectCalibrationOptions& options,
                                   const FixedStructure* fixed) {
  const Skeleton& base = tmpl.skeleton;
  const int J = base.num_joints();
  const int M = static_cast<int>(tmpl.markers.size());
  const auto uM = static_cast<size_t>(M);
  if (M < 3) throw std::invalid_argument("calibration: fewer than 3 markers");
  if (frames < 1 || observed.size() != static_cast<size_t>(frames) * uM)
    throw std::invalid_argument("calibration: observations do not match frames x markers");
  for (const MarkerDefinition& d : tmpl.markers)
    if (d.num_attachments != 1 || d.attachments[0].joint < 0 || d.attachments[0].joint >= J)
      throw std::invalid_argument("calibration: template marker '" + d.name +
                                  "' is not rigid on a joint");
  auto at = [&](int f, int m) -> const Vec3& {
    return observed[static_cast<size_t>(f) * uM + static_cast<size_t>(m)];
  };

  // Usable frames: enough of the markers seen.
  std::vector<int> valid_count(static_cast<size_t>(frames), 0);
  std::vector<int> usable;
  for (int f = 0; f < frames; ++f) {
    for (int m = 0; m < M; ++m) valid_count[static_cast<size_t>(f)] += at(f, m).allFinite();
    if (valid_count[static_cast<size_t>(f)] >=
        std::max(3, static_cast<int>(std::ceil(options.min_valid_fraction * M))))
      usable.push_back(f);
  }
  if (usable.size() < 10)
    throw std::invalid_argument("calibration: only " + std::to_string(usable.size()) +
                                " frames see at least " +
                                std::to_string(static_cast<int>(options.min_valid_fraction * 100)) +
                                " % of the markers (10 needed)");

  // The template scaled to the subject: the median ratio of the distances between markers
  // on one segment, captured against template.
  std::vector<double> ratios;
  for (int a = 0; a < M; ++a) {
    for (int b = a + 1; b < M; ++b) {
      const MarkerAttachment& ta = tmpl.markers[static_cast<size_t>(a)].attachments[0];
      const MarkerAttachment& tb = tmpl.markers[static_cast<size_t>(b)].attachments[0];
      if (ta.joint != tb.joint) continue;
      const double model = (ta.offset - tb.offset).norm();
      if (model < 0.03) continue;
      std::vector<double> d;
      for (int f : usable)
        if (at(f, a).allFinite() && at(f, b).allFinite()) d.push_back((at(f, a) - at(f, b)).norm());
      if (d.size() >= 5) ratios.push_back(Median(d) / model);
    }
  }
  const double scale = ratios.empty() ? 1.0 : std::clamp(Median(ratios), 0.3, 3.0);
  std::vector<Vec3> joint_offset(static_cast<size_t>(J)), joint_prior(static_cast<size_t>(J));
  std::vector<double> joint_sigma(static_cast<size_t>(J), options.joint_prior_sigma_m);
  for (int j = 0; j < J; ++j) {
    const auto uj = static_cast<size_t>(j);
    joint_prior[uj] =
        (uj < tmpl.joint_prior.size() ? tmpl.joint_prior[uj] : base.joint(j).offset) * scale;
    if (uj < tmpl.joint_prior_sigma_m.size() && tmpl.joint_prior_sigma_m[uj] > 0.0)
      joint_sigma[uj] = tmpl.joint_prior_sigma_m[uj];
    joint_offset[uj] = fixed != nullptr ? fixed->joint_offset[uj] : base.joint(j).offset * scale;
  }
  std::vector<Vec3> marker_offset(uM), marker_prior(uM);
  std::vector<double> marker_sigma(uM, options.marker_prior_sigma_m);
  auto unknown = [&](size_t m) {
    return m < tmpl.offset_unknown.size() && tmpl.offset_unknown[m] != 0;
  };
  for (size_t m = 0; m < uM; ++m) {
    marker_prior[m] = marker_offset[m] = tmpl.markers[m].attachments[0].offset * scale;
    if (m < tmpl.marker_prior_sigma_m.size() && tmpl.marker_prior_sigma_m[m] > 0.0)
      marker_sigma[m] = tmpl.marker_prior_sigma_m[m];
    if (unknown(m)) marker_sigma[m] = 1.0;  // effectively none: the data place it
    if (fixed != nullptr) marker_offset[m] = fixed->marker_offset[m];
  }

  // Poses: IK over the whole take, warm-started frame to frame from a cold start.
  IkOptions track;
  track.huber_delta_m = options.huber_m;
  track.max_iterations = 6;
  Model model = MakeModel(base, joint_offset, tmpl.markers, marker_offset);
  std::vector<Pose> poses(static_cast<size_t>(frames), RestPose(*model.skeleton));
  std::vector<double> weights(uM);
  std::vector<Vec3> targets(uM);
  std::vector<int> tracked;
  {
    IkState state(*model.skeleton, *model.markers);
    int previous = -2;
    for (int f : usable) {
      if (f != previous + 1) state.Reset();  // a gap in the usable frames: start cold
      for (size_t m = 0; m < uM; ++m) {
        targets[m] = at(f, static_cast<int>(m));
        weights[m] = targets[m].allFinite() && !unknown(m) ? 1.0 : 0.0;
      }
      const IkSummary s = SolveIk(*model.skeleton, *model.markers, track, targets, weights, &state);
      previous = f;
      if (s.status == IkStatus::kTooFewMarkers || s.status == IkStatus::kNumericalFailure) continue;
      poses[static_cast<size_t>(f)] = state.pose();
      tracked.push_back(f);
    }
  }
  if (tracked.size() < 10)
    throw std::invalid_argument("calibration: the template could not be solved on the take");
  // Markers of unknown offset: the mean of where the tracked poses put them on their joint.
  if (fixed == nullptr) {
    KinematicsWorkspace fk(*model.skeleton);
    std::vector<Vec3> sum(uM, Vec3::Zero());
    std::vector<int> count(uM, 0);
    for (int f : tracked) {
      ForwardKinematics(*model.skeleton, poses[static_cast<size_t>(f)], &fk);
      for (size_t m = 0; m < uM; ++m) {
        if (!unknown(m) || !at(f, static_cast<int>(m)).allFinite()) continue;
        const auto uj = static_cast<size_t>(tmpl.markers[m].attachments[0].joint);
        sum[m] += fk.R_WJ[uj].transpose() * (at(f, static_cast<int>(m)) - fk.p_WJ[uj]);
        ++count[m];
      }
    }
    for (size_t m = 0; m < uM; ++m)
      if (unknown(m) && count[m] > 0) marker_prior[m] = marker_offset[m] = sum[m] / count[m];
    model = MakeModel(base, joint_offset, tmpl.markers, marker_offset);
  }
  // Long takes: the candidates for the subset are thinned to at most 4000 frames.
  std::vector<int> candidates;
  const size_t stride = std::max<size_t>(1, tracked.size() / 4000);
  for (size_t i = 0; i < tracked.size(); i += stride) candidates.push_back(tracked[i]);
  const std::vector<int> selected =
      SelectVariedFrames(candidates, poses, valid_count, options.max_frames);

  // Landmarks: markers near a joint centre hold it. One on the joint's own segment
  // holds it through its offset (a tighter marker prior); one on the parent segment
  // through the difference of its offset and the joint's.
  struct Landmark {
    int joint, marker;
    Vec3 difference;  // a_k - o_j, template, parent frame
  };
  std::vector<Landmark> landmarks;
  for (int m = 0; m < M; ++m) {
    const auto um = static_cast<size_t>(m);
    if (unknown(um) || (um < tmpl.offset_guessed.size() && tmpl.offset_guessed[um] != 0)) continue;
    const int on = tmpl.markers[um].attachments[0].joint;
    if (marker_prior[um].norm() < options.landmark_radius_m * scale)
      marker_sigma[um] = std::min(marker_sigma[um], options.landmark_sigma_m);
    for (int j = 1; j < J; ++j) {
      if (base.joint(j).parent.value != on) continue;
      const Vec3 d = marker_prior[um] - joint_prior[static_cast<size_t>(j)];
      if (d.norm() < options.landmark_radius_m * scale) landmarks.push_back({j, m, d});
    }
  }

  // The markers whose template offsets fix each segment's frame (two or more known ones).
  std::map<int, std::vector<int>> frame_markers;
  for (int m = 0; m < M; ++m)
    if (!unknown(static_cast<size_t>(m)))
      frame_markers[tmpl.markers[static_cast<size_t>(m)].attachments[0].joint].push_back(m);
  for (auto it = frame_markers.begin(); it != frame_markers.end();)
    it = it->second.size() < 2 ? frame_markers.erase(it) : std::next(it);

  // Unknowns of the structure: the offsets of joints 1..J-1, then of the markers. Each
  // pose (root translation, then a body-frame rotation step per joint) is eliminated
  // frame by frame (Schur complement), so the normal equations are in the structure only.
  const int nj = 3 * (J - 1);
  const int n = nj + 3 * M;
  const int dofs = base.num_dofs();
  for (int j = 0; j < J; ++j)
    if (base.joint(j).type != (j == 0 ? JointType::kFree : JointType::kBall))
      throw std::invalid_argument(
          "calibration: the template must have a free root and ball joints");
  // Orderings that keep each frame's elimination sparse. A frame's pose block couples a
  // joint only with its ancestors and descendants, so with the pose's unknowns ordered
  // children before parents (post-order) its Cholesky factor L has no fill, and row block
  // k of W = L^-1 A is zero outside the structure of k's subtree and the offsets of k's
  // ancestors. With the structure ordered depth-first (pre-order: a joint's offset, then
  // its markers'), a subtree's unknowns are one contiguous range, and joint k's share of
  // the Schur complement is a dense update of that range plus a few offsets' columns.
  std::vector<std::vector<int>> children(static_cast<size_t>(J)),
      markers_on(static_cast<size_t>(J));
  for (int j = 1; j < J; ++j)
    children[static_cast<size_t>(base.joint(j).parent.value)].push_back(j);
  for (int m = 0; m < M; ++m)
    markers_on[static_cast<size_t>(tmpl.markers[static_cast<size_t>(m)].attachments[0].joint)]
        .push_back(m);
  std::vector<int> joint_var_at(static_cast<size_t>(J), -1), marker_var_at(uM);
  std::vector<int> subtree_begin(static_cast<size_t>(J)), subtree_end(static_cast<size_t>(J));
  std::vector<int> rotation_column(static_cast<size_t>(J)),
      subtree_first_column(static_cast<size_t>(J));
  std::vector<int> post_order;
  int translation_column = 0, next_var = 0, next_column = 0;
  auto order = [&](auto&& self, int j) -> void {
    const auto uj = static_cast<size_t>(j);
    subtree_begin[uj] = next_var;
    subtree_first_column[uj] = next_column;
    if (j > 0) joint_var_at[uj] = std::exchange(next_var, next_var + 3);
    for (int m : markers_on[uj])
      marker_var_at[static_cast<size_t>(m)] = std::exchange(next_var, next_var + 3);
    for (int c : children[uj]) self(self, c);
    subtree_end[uj] = next_var;
    if (j == 0) translation_column = std::exchange(next_column, next_column + 3);
    rotation_column[uj] = std::exchange(next_column, next_column + 3);
    post_order.push_back(j);
  };
  order(order, 0);
  if (next_var != n || next_column != dofs)
    throw std::logic_error("calibration: the unknowns' ordering does not cover them");
  // The offsets (structure unknowns) of each joint's strict ancestors.
  std::vector<std::vector<int>> ancestor_vars(static_cast<size_t>(J));
  for (int j = 1; j < J; ++j)
    for (int a = base.joint(j).parent.value; a > 0; a = base.joint(a).parent.value)
      ancestor_vars[static_cast<size_t>(j)].push_back(joint_var_at[static_cast<size_t>(a)]);
  auto joint_var = [&](int j) { return joint_var_at[static_cast<size_t>(j)]; };
  auto marker_var = [&](int m) { return marker_var_at[static_cast<size_t>(m)]; };
  const Mat3 mirror = Vec3(-1, 1, 1).asDiagonal();

  // The residuals of every frame for the current structure and poses.
  auto frame_residuals = [&](const Model& mdl, int f, const Pose& pose, KinematicsWorkspace* fk,
                             std::vector<double>* out) {
    ForwardKinematics(*mdl.skeleton, pose, fk);
    for (int m = 0; m < M; ++m) {
      if (!at(f, m).allFinite()) continue;
      out->push_back((at(f, m) - EvaluateMarker(mdl.markers->marker(m), *fk)).norm());
    }
  };
  auto robust = [&](double r) {
    const double d = options.huber_m;
    return r <= d ? r * r : 2.0 * d * r - d * d;
  };
  // The priors as weighted squares of the structure, scaled to the residuals' noise.
  auto prior_terms = [&](double s2, Matrix* H, Vector* g, double gauge) {
    auto add_pair = [&](int va, int vb, const Mat3& Mb, double weight) {  // weight |x_a + Mb x_b|^2
      H->block<3, 3>(va, va) += weight * Mat3::Identity();
      H->block<3, 3>(va, vb) += weight * Mb;
      H->block<3, 3>(vb, va) += weight * Mb.transpose();
      H->block<3, 3>(vb, vb) += weight * Mb.transpose() * Mb;
    };
    if (tmpl.gauge_left > 0 && tmpl.gauge_right > 0 && gauge > 0.0)
      add_pair(joint_var(tmpl.gauge_left), joint_var(tmpl.gauge_right), Mat3::Identity(), gauge);
    // Each segment's frame is the template's turned onto the markers: its markers' offsets
    // have no net rotation from the template's (sum of a0 x a = 0). The motion cannot fix
    // a frame's orientation (the poses turn the other way); without this the priors held
    // in it (a knee centre beside its epicondyle marker) would turn with it.
    if (gauge > 0.0) {
      for (const auto& [joint, members] : frame_markers) {
        Matrix C = Matrix::Zero(3, n);
        for (int m : members)
          C.block<3, 3>(0, marker_var(m)) = Skew(marker_prior[static_cast<size_t>(m)]);
        H->noalias() += gauge * C.transpose() * C;
      }
    }
    if (g == nullptr) return;
    for (int j = 1; j < J; ++j) {
      const auto uj = static_cast<size_t>(j);
      const double w = s2 / (joint_sigma[uj] * joint_sigma[uj]);
      H->block<3, 3>(joint_var(j), joint_var(j)) += w * Mat3::Identity();
      g->segment<3>(joint_var(j)) += w * joint_prior[uj];
      const int other = uj < tmpl.mirror.size() ? tmpl.mirror[uj] : -1;
      if (other > j)
        add_pair(joint_var(j), joint_var(other), -mirror,
                 s2 / (options.symmetry_sigma_m * options.symmetry_sigma_m));
    }
    for (int m = 0; m < M; ++m) {
      const auto um = static_cast<size_t>(m);
      const double w = s2 / (marker_sigma[um] * marker_sigma[um]);
      H->block<3, 3>(marker_var(m), marker_var(m)) += w * Mat3::Identity();
      g->segment<3>(marker_var(m)) += w * marker_prior[um];
    }
    // Landmarks on the parent segment: |(a_k - o_j) - d|^2.
    const double wl = s2 / (options.landmark_sigma_m * options.landmark_sigma_m);
    for (const Landmark& l : landmarks) {
      const int va = marker_var(l.marker), vo = joint_var(l.joint);
      H->block<3, 3>(va, va) += wl * Mat3::Identity();
      H->block<3, 3>(va, vo) -= wl * Mat3::Identity();
      H->block<3, 3>(vo, va) -= wl * Mat3::Identity();
      H->block<3, 3>(vo, vo) += wl * Mat3::Identity();
      g->segment<3>(va) += wl * l.difference;
      g->segment<3>(vo) -= wl * l.difference;
    }
  };
  auto structure_vector = [&]() {
    Vector x(n);
    for (int j = 1; j < J; ++j) x.segment<3>(joint_var(j)) = joint_offset[static_cast<size_t>(j)];
    for (int m = 0; m < M; ++m) x.segment<3>(marker_var(m)) = marker_offset[static_cast<size_t>(m)];
    return x;
  };
  // The whole cost: robust residuals plus priors (the priors as 0.5 x'Hx - g'x + c, so
  // compare differences only).
  auto total_cost = [&](const Model& mdl, const std::vector<Pose>& ps, double s2) {
    KinematicsWorkspace fk(*mdl.skeleton);
    std::vector<double> r;
    for (int f : selected) frame_residuals(mdl, f, ps[static_cast<size_t>(f)], &fk, &r);
    double cost = 0.0;
    for (double v : r) cost += robust(v);
    Matrix Hp = Matrix::Zero(n, n);
    Vector gp = Vector::Zero(n);
    prior_terms(s2, &Hp, &gp, 0.0);
    const Vector x = structure_vector();
    // |x - prior|^2 terms: x'Hx - 2 g'x (+ constant), the symmetry terms exactly.
    cost += x.dot(Hp * x) - 2.0 * gp.dot(x);
    if (tmpl.gauge_left > 0 && tmpl.gauge_right > 0) {
      const Vec3 gap = joint_offset[static_cast<size_t>(tmpl.gauge_left)] +
                       joint_offset[static_cast<size_t>(tmpl.gauge_right)];
      cost += 1e6 * gap.squaredNorm();
    }
    for (const auto& [joint, members] : frame_markers) {
      Vec3 turn = Vec3::Zero();
      for (int m : members)
        turn += marker_prior[static_cast<size_t>(m)].cross(marker_offset[static_cast<size_t>(m)]);
      cost += 1e6 * turn.squaredNorm();
    }
    return std::make_pair(cost, r);
  };

  SubjectCalibrationResult result;
  std::vector<double> residuals;
  {
    KinematicsWorkspace fk(*model.skeleton);
    for (int f : selected)
      frame_residuals(model, f, poses[static_cast<size_t>(f)], &fk, &residuals);
  }
  // The noise level the priors are weighed against (a 3-D Gaussian's median norm is
  // 1.54 sigma), never below 1 mm; re-estimated as the fit improves.
  double sigma_noise = std::max(0.001, Median(residuals) / 1.54);
  double lambda = 1e-3;
  KinematicsWorkspace ws(*model.skeleton);
  Matrix A_ps(dofs, n);
  Matrix A_pp(dofs, dofs);
  Vector b_p(dofs);
  std::vector<Matrix> frame_A_ps(selected.size());
  std::vector<Eigen::LLT<Matrix>> frame_solver(selected.size());
  std::vector<Vector> frame_b(selected.size());
  Matrix LinvA(dofs, n);
  Vector step(dofs);  // a frame's pose step in the skeleton's order
  std::vector<std::pair<int, Mat3>> pose_blocks, structure_blocks;
  const int iterations = fixed != nullptr ? 0 : options.iterations;
  for (int iteration = 0; iteration < iterations; ++iteration) {
    result.iterations = iteration + 1;
    const double s2 = sigma_noise * sigma_noise;
    Matrix S = Matrix::Zero(n, n);
    Vector rhs = Vector::Zero(n);
    for (size_t k = 0; k < selected.size(); ++k) {
      const int f = selected[k];
      ForwardKinematics(*model.skeleton, poses[static_cast<size_t>(f)], &ws);
      A_pp.setZero();
      A_ps.setZero();
      b_p.setZero();
      // The frame's structure-structure block goes straight into S (and its gradient into
      // rhs): an n x n matrix zeroed, filled and added per frame was most of the time.
      for (int m = 0; m < M; ++m) {
        const Vec3& y = at(f, m);
        if (!y.allFinite()) continue;
        const int joint = tmpl.markers[static_cast<size_t>(m)].attachments[0].joint;
        const auto uj = static_cast<size_t>(joint);
        const Vec3 p = ws.p_WJ[uj] + ws.R_WJ[uj] * marker_offset[static_cast<size_t>(m)];
        const Vec3 r = y - p;
        const double w = HuberWeight(r.norm(), options.huber_m);
        // Pose columns: the root's translation, and each joint on the chain's rotation.
        pose_blocks.assign(1, {translation_column, Mat3::Identity()});
        structure_blocks.assign(1, {marker_var(m), ws.R_WJ[uj]});
        for (int j = joint; j >= 0; j = base.joint(j).parent.value) {
          const auto u = static_cast<size_t>(j);
          pose_blocks.emplace_back(
              rotation_column[u],
              Mat3(-ws.R_WJ[u] * Skew(ws.R_WJ[u].transpose() * (p - ws.p_WJ[u]))));
          if (j > 0)
            structure_blocks.emplace_back(joint_var(j),
                                          ws.R_WJ[static_cast<size_t>(base.joint(j).parent.value)]);
        }
        // w Ja' formed once per block, then plain 3x3 products (a scalar times a transpose
        // times a block, per pair, was evaluated coefficient by coefficient).
        for (const auto& [ca, Ja] : pose_blocks) {
          const Mat3 wJaT = w * Ja.transpose();
          b_p.segment<3>(ca).noalias() += wJaT * r;
          for (const auto& [cb, Jb] : pose_blocks) A_pp.block<3, 3>(ca, cb).noalias() += wJaT * Jb;
          for (const auto& [cb, Jb] : structure_blocks)
            A_ps.block<3, 3>(ca, cb).noalias() += wJaT * Jb;
        }
        for (const auto& [ca, Ja] : structure_blocks) {
          const Mat3 wJaT = w * Ja.transpose();
          rhs.segment<3>(ca).noalias() += wJaT * r;
          for (const auto& [cb, Jb] : structure_blocks)
            S.block<3, 3>(ca, cb).noalias() += wJaT * Jb;
        }
      }
      // Damped (Marquardt); a joint no marker constrains still gets a tiny diagonal so
      // the frame's block can be inverted. P = L L' (a sum of J'J, plus the diagonal:
      // positive definite), so the frame's share of the Schur complement, A' P^-1 A, is
      // W'W with W = L^-1 A, a sum over W's row blocks, each nonzero only in its joint's
      // columns (see the orderings above); written to the lower triangle that S's LDLT
      // reads.
      Matrix P = A_pp;
      P.diagonal().array() += lambda * P.diagonal().array() + 1e-9;
      Eigen::LLT<Matrix> solver(P);
      if (solver.info() != Eigen::Success)
        throw std::invalid_argument("calibration: a frame's pose block is not positive definite");
      // W by forward substitution, children first, on each row block's own columns only:
      // row block k is A_k less the factor's coupling to k's descendants (the rows just
      // before k's own) times their rows of W, then solved by k's diagonal block.
      const Matrix& factor = solver.matrixLLT();  // L in the lower triangle
      LinvA.setZero();
      for (int j : post_order) {
        const auto uj = static_cast<size_t>(j);
        const int row = j == 0 ? translation_column : rotation_column[uj];
        const int rows = j == 0 ? 6 : 3;
        const int below = subtree_first_column[uj], below_rows = row - below;
        auto substitute = [&](int column, int columns) {
          auto W = LinvA.block(row, column, rows, columns);
          W = A_ps.block(row, column, rows, columns);
          if (below_rows > 0)
            W.noalias() -= factor.block(row, below, rows, below_rows) *
                           LinvA.block(below, column, below_rows, columns);
          factor.block(row, row, rows, rows).triangularView<Eigen::Lower>().solveInPlace(W);
        };
        const int first = subtree_begin[uj], count = subtree_end[uj] - first;
        substitute(first, count);
        for (int v : ancestor_vars[uj]) substitute(v, 3);
        const auto W_subtree = LinvA.block(row, first, rows, count);
        S.block(first, first, count, count)
            .selfadjointView<Eigen::Lower>()
            .rankUpdate(W_subtree.transpose(), -1.0);
        const std::vector<int>& above = ancestor_vars[uj];
        for (size_t a = 0; a < above.size(); ++a) {
          const auto W_a = LinvA.block(row, above[a], rows, 3);
          S.block(first, above[a], count, 3).noalias() -= W_subtree.transpose() * W_a;
          // Ancestors' offsets come before the subtree's, the parent's last.
          for (size_t b = a; b < above.size(); ++b)
            S.block<3, 3>(above[a], above[b]).noalias() -=
                W_a.transpose() * LinvA.block(row, above[b], rows, 3);
        }
      }
      rhs.noalias() -= LinvA.transpose() * solver.matrixL().solve(b_p);
      frame_A_ps[k] = A_ps;
      frame_solver[k] = std::move(solver);
      frame_b[k] = b_p;
    }
    // Priors on the structure, as a Gauss-Newton step from the current x.
    const Vector x0 = structure_vector();
    Matrix Hp = Matrix::Zero(n, n);
    Vector gp = Vector::Zero(n);
    prior_terms(s2, &Hp, &gp, 1e6);
    // Marquardt's damping scales with the data's own curvature: scaled with the gauge's
    // (1e6) it would freeze the hips' width along with their midpoint.
    const Vector damping = lambda * (S.diagonal().array() + 1e-9).matrix();
    S += Hp;
    rhs += gp - Hp * x0;
    S.diagonal() += damping;
    const Vector dx = S.ldlt().solve(rhs);  // reads S's lower triangle only
    if (!dx.allFinite()) throw std::invalid_argument("calibration: the bundle adjustment diverged");
    // The trial: structure and every pose stepped; kept if the cost went down.
    std::vector<Vec3> old_joints = joint_offset, old_markers = marker_offset;
    std::vector<Pose> trial = poses;
    for (int j = 1; j < J; ++j) joint_offset[static_cast<size_t>(j)] += dx.segment<3>(joint_var(j));
    for (int m = 0; m < M; ++m)
      marker_offset[static_cast<size_t>(m)] += dx.segment<3>(marker_var(m));
    for (size_t k = 0; k < selected.size(); ++k) {
      const Vector dp = frame_solver[k].solve(frame_b[k] - frame_A_ps[k] * dx);
      step.segment<3>(0) = dp.segment<3>(translation_column);
      for (int j = 0; j < J; ++j)
        step.segment<3>(base.dof_offset(j) + (j == 0 ? 3 : 0)) =
            dp.segment<3>(rotation_column[static_cast<size_t>(j)]);
      IntegratePose(base, step, &trial[static_cast<size_t>(selected[k])]);
    }
    const Model candidate = MakeModel(base, joint_offset, tmpl.markers, marker_offset);
    const double before = total_cost(model, poses, s2).first;
    const auto [after, trial_residuals] = total_cost(candidate, trial, s2);
    const double moved = dx.cwiseAbs().maxCoeff();
    if (after < before) {
      model = candidate;
      poses = std::move(trial);
      residuals = trial_residuals;
      lambda = std::max(1e-7, lambda / 3.0);
      sigma_noise = std::max(0.001, Median(residuals) / 1.54);
      if (moved < options.converged_m || before - after < 1e-9 * before) break;
    } else {
      joint_offset = std::move(old_joints);
      marker_offset = std::move(old_markers);
      lambda *= 10.0;
      if (lambda > 1e6) break;
    }
  }

  // Residuals on the final subject and poses.
  result.skeleton = *model.skeleton;
  result.markers = std::vector<MarkerDefinition>(model.markers->markers().begin(),
                                                 model.markers->markers().end());
  result.frames_used = selected;
  std::vector<double> sum_sq(uM, 0.0);
  result.marker_frames.assign(uM, 0);
  residuals.clear();
  double total_sq = 0.0;
  for (int f : selected) {
    ForwardKinematics(*model.skeleton, poses[static_cast<size_t>(f)], &ws);
    for (int m = 0; m < M; ++m) {
      if (!at(f, m).allFinite()) continue;
      const double r = (at(f, m) - EvaluateMarker(model.markers->marker(m), ws)).norm();
      sum_sq[static_cast<size_t>(m)] += r * r;
      ++result.marker_frames[static_cast<size_t>(m)];
      residuals.push_back(r);
      total_sq += r * r;
    }
  }
  result.marker_rms_m.resize(uM);
  for (size_t m = 0; m < uM; ++m)
    result.marker_rms_m[m] =
        result.marker_frames[m] > 0 ? std::sqrt(sum_sq[m] / result.marker_frames[m]) : kNaN;
  result.rms_m =
      residuals.empty() ? 0.0 : std::sqrt(total_sq / static_cast<double>(residuals.size()));
  result.median_residual_m = Median(residuals);

  // Coverage, per joint and direction: the SCoRE system of the joint alone (Ehrig et al.
  // 2006). Its centre c, fixed in the child's frame, sits at R_rel(t) c + d in the
  // parent's, so the information the poses carry about c is the spread of the relative
  // rotations R_rel(t) about their mean: sum_t (R_rel - mean)'(R_rel - mean). A direction
  // whose standard deviation (the noise over the root of that information) is under
  // covered_sigma_m is the motion's; the others are the priors'.
  std::vector<int> markers_below(static_cast<size_t>(J), 0);
  for (int m = 0; m < M; ++m)
    ++markers_below[static_cast<size_t>(tmpl.markers[static_cast<size_t>(m)].attachments[0].joint)];
  for (int j = J - 1; j > 0; --j)
    markers_below[static_cast<size_t>(base.joint(j).parent.value)] +=
        markers_below[static_cast<size_t>(j)];
  // A segment with joints below it that fewer than two known markers ride (an unmarked
  // spine or neck link, a one-marker clavicle) has no pose of its own in the solves: its
  // turn is whatever the chain's solve left it. The joints at either end of it are placed
  // by the motion only together, along the chain; their SCoRE sigmas measure that gauge,
  // not them (CMU's neck came out 34 cm long at 0.6 mm "functional").
  std::vector<int> known_markers(static_cast<size_t>(J), 0);
  for (int m = 0; m < M; ++m)
    if (!unknown(static_cast<size_t>(m)))
      ++known_markers[static_cast<size_t>(
          tmpl.markers[static_cast<size_t>(m)].attachments[0].joint)];
  std::vector<uint8_t> unmarked_link(static_cast<size_t>(J), 0);
  for (int j = 1; j < J; ++j) {
    const auto parent = static_cast<size_t>(base.joint(j).parent.value);
    if (parent != 0 && known_markers[parent] < 2) unmarked_link[parent] = 1;
  }
  std::vector<Mat3> relative;
  for (int j = 0; j < J; ++j) {
    JointCalibrationReport r;
    r.name = base.joint(j).name;
    if (j == 0) {
      r.method = "root";
      result.joints.push_back(r);
      continue;
    }
    const auto uj = static_cast<size_t>(j);
    const auto up = static_cast<size_t>(base.joint(j).parent.value);
    r.bone_length_m = joint_offset[uj].norm();
    Mat3 information = Mat3::Zero();
    if (markers_below[uj] > 0 && markers_below[0] > markers_below[uj]) {
      relative.clear();
      Mat3 mean = Mat3::Zero();
      for (int f : selected) {
        ForwardKinematics(*model.skeleton, poses[static_cast<size_t>(f)], &ws);
        relative.push_back(ws.R_WJ[up].transpose() * ws.R_WJ[uj]);
        mean += relative.back();
      }
      mean /= static_cast<double>(relative.size());
      for (const Mat3& R : relative) information += (R - mean).transpose() * (R - mean);
      // The range of the relative rotation about its principal axes (2nd to 98th
      // percentile, over the solved poses): a centre is determined along an axis by
      // the rotations about the two axes across it.
      std::vector<Vec3> turns;
      const Quat mean_q = Quat(poses[static_cast<size_t>(selected[0])].rotation[uj]);
      for (int f : selected)
        turns.push_back(
            LogRotation(mean_q.conjugate() * poses[static_cast<size_t>(f)].rotation[uj]));
      Vec3 centre = Vec3::Zero();
      for (const Vec3& v : turns) centre += v / static_cast<double>(turns.size());
      Mat3 spread = Mat3::Zero();
      for (const Vec3& v : turns) spread += (v - centre) * (v - centre).transpose();
      Eigen::SelfAdjointEigenSolver<Mat3> axes(spread);
      for (int k = 0; k < 3; ++k) {
        std::vector<double> along;
        for (const Vec3& v : turns) along.push_back(v.dot(axes.eigenvectors().col(2 - k)));
        std::sort(along.begin(), along.end());
        const size_t lo = along.size() / 50, hi = along.size() - 1 - along.size() / 50;
        r.rotation_spread_deg[k] = (along[hi] - along[lo]) * 180.0 / M_PI;
      }
    }
    Eigen::SelfAdjointEigenSolver<Mat3> eig(information);
    for (int k = 0; k < 3; ++k) {
      const double lambda_k = std::max(0.0, eig.eigenvalues()[2 - k]);  // largest information first
      r.data_sigma_m[k] = lambda_k > 1e-12 ? sigma_noise / std::sqrt(lambda_k) : 1e3;
    }
    // Along the most turned axis only the second-largest range helps; across it, the largest.
    const double t = options.covered_rotation_deg;
    r.directions_covered = 2 * (r.rotation_spread_deg[0] >= t) + (r.rotation_spread_deg[1] >= t);
    if (r.data_sigma_m[2] > options.covered_sigma_m)
      r.directions_covered = std::min(r.directions_covered, 2);
    if (r.data_sigma_m[0] > options.covered_sigma_m) r.directions_covered = 0;
    r.method = r.directions_covered == 3  ? "functional"
               : r.directions_covered > 0 ? "functional+prior"
                                          : "prior";
    if (r.directions_covered > 0 && (unmarked_link[up] || unmarked_link[uj])) r.method = "chain";
    // The result's own uncertainty: motion and prior combined, in its worst direction.
    const double prior_var = joint_sigma[uj] * joint_sigma[uj];
    const double worst_data_var = r.data_sigma_m[2] * r.data_sigma_m[2];
    r.uncertainty_m = std::sqrt(1.0 / (1.0 / worst_data_var + 1.0 / prior_var));
    result.joints.push_back(r);
  }
  // A segment with joints below it that fewer than two known markers ride (a spine or
  // neck link between two marked segments, a clavicle with one marker) has no frame of its
  // own: the fit is the same whichever way it is turned, the poses turning the other way,
  // and the adjustment leaves it wherever it wandered. A chest offset 20 deg off in the
  // spine's frame fitted as well as the template's, and the rest pose showed a bent spine
  // and a tilted head, which a BVH reader and a retargeted character copy. Each such
  // segment is turned, with everything it carries, to the template's way round; no joint
  // moves in any pose. An end segment (a hand with one finger marker, a toe) is left as it
  // is: what it points along is its end site, fixed in its frame and not turned with it.
  bool turned = false;
  for (int segment = 1; segment < J; ++segment) {
    if (known_markers[static_cast<size_t>(segment)] >= 2) continue;
    // Wahba's problem: the rotation that best turns what the segment carries onto the
    // template's (one vector: the least rotation).
    std::vector<std::pair<Vec3, Vec3>> carried;  // (fitted, template)
    for (int k = 1; k < J; ++k)
      if (base.joint(k).parent.value == segment)
        carried.emplace_back(joint_offset[static_cast<size_t>(k)],
                             joint_prior[static_cast<size_t>(k)]);
    if (carried.empty()) continue;  // an end segment
    for (int m = 0; m < M; ++m)
      if (!unknown(static_cast<size_t>(m)) &&
          tmpl.markers[static_cast<size_t>(m)].attachments[0].joint == segment)
        carried.emplace_back(marker_offset[static_cast<size_t>(m)],
                             marker_prior[static_cast<size_t>(m)]);
    Mat3 turn = Mat3::Identity();
    if (carried.size() == 1) {
      turn = Quat::FromTwoVectors(carried[0].first, carried[0].second).toRotationMatrix();
    } else {
      Mat3 correlation = Mat3::Zero();
      for (const auto& [fitted, templ] : carried) correlation += templ * fitted.transpose();
      const Eigen::JacobiSVD<Mat3> svd(correlation, Eigen::ComputeFullU | Eigen::ComputeFullV);
      Mat3 D = Mat3::Identity();
      if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0) D(2, 2) = -1.0;
      turn = svd.matrixU() * D * svd.matrixV().transpose();
    }
    for (int k = 1; k < J; ++k)
      if (base.joint(k).parent.value == segment)
        joint_offset[static_cast<size_t>(k)] = turn * joint_offset[static_cast<size_t>(k)];
    for (int m = 0; m < M; ++m)
      if (tmpl.markers[static_cast<size_t>(m)].attachments[0].joint == segment)
        marker_offset[static_cast<size_t>(m)] = turn * marker_offset[static_cast<size_t>(m)];
    turned = true;
  }
  if (turned) {
    const Model straightened = MakeModel(base, joint_offset, tmpl.markers, marker_offset);
    result.skeleton = *straightened.skeleton;
    result.markers = std::vector<MarkerDefinition>(straightened.markers->markers().begin(),
                                                   straightened.markers->markers().end());
  }
  return result;
}

}  // namespace

SubjectCalibrationResult CalibrateSubject(const CalibrationTemplate& tmpl,
                                          std::span<const Vec3> observed, int frames,
                                          const SubjectCalibrationOptions& options) {
  options.Validate();
  SubjectCalibrationResult whole = SolveOnce(tmpl, observed, frames, options, nullptr);
  // Only a take with more frames than a solve's poses has frames to spare for the others.
  const int subsets = std::min(options.interleaved_solves, frames / options.max_frames);
  if (subsets < 2) return whole;
  const int J = whole.skeleton.num_joints();
  const size_t M = tmpl.markers.size();
  std::vector<std::vector<Vec3>> joint_solves, marker_solves;
  auto keep = [&](const SubjectCalibrationResult& r) {
    std::vector<Vec3> joints(static_cast<size_t>(J)), markers(M);
    for (int j = 0; j < J; ++j) joints[static_cast<size_t>(j)] = r.skeleton.joint(j).offset;
    for (size_t m = 0; m < M; ++m) markers[m] = r.markers[m].attachments[0].offset;
    joint_solves.push_back(std::move(joints));
    marker_solves.push_back(std::move(markers));
  };
  keep(whole);
  std::vector<Vec3> subset;
  for (int first = 0; first < subsets; ++first) {
    subset.clear();
    int subset_frames = 0;
    for (int f = first; f < frames; f += subsets, ++subset_frames)
      subset.insert(subset.end(), observed.begin() + static_cast<std::ptrdiff_t>(f * M),
                    observed.begin() + static_cast<std::ptrdiff_t>((f + 1) * M));
    try {
      keep(SolveOnce(tmpl, subset, subset_frames, options, nullptr));
    } catch (const std::invalid_argument&) {
      // Too few usable frames in this subset: the others carry the mean.
    }
  }
  const auto n = static_cast<double>(joint_solves.size());
  FixedStructure mean{std::vector<Vec3>(static_cast<size_t>(J), Vec3::Zero()),
                      std::vector<Vec3>(M, Vec3::Zero())};
  for (size_t k = 0; k < joint_solves.size(); ++k) {
    for (size_t j = 0; j < static_cast<size_t>(J); ++j)
      mean.joint_offset[j] += joint_solves[k][j] / n;
    for (size_t m = 0; m < M; ++m) mean.marker_offset[m] += marker_solves[k][m] / n;
  }
  SubjectCalibrationResult result = SolveOnce(tmpl, observed, frames, options, &mean);
  result.iterations = whole.iterations;
  result.solves = static_cast<int>(joint_solves.size());
  for (int j = 1; j < J; ++j) {
    const auto uj = static_cast<size_t>(j);
    double sum_sq = 0.0;
    for (const std::vector<Vec3>& solve : joint_solves)
      sum_sq += (solve[uj] - mean.joint_offset[uj]).squaredNorm();
    JointCalibrationReport& r = result.joints[uj];
    r.solves_sigma_m = std::sqrt(sum_sq / std::max(1.0, n - 1.0));
    // Not divided by sqrt(n): the subsets interleave one motion, so their solves share what
    // it leaves undetermined (and its soft-tissue shifts, which follow the pose) and are not
    // independent. Divided, the uncertainty read 2-6 times smaller than the bones' error
    // against a synthetic truth (bench/README.md, "How far the uncertainty can be trusted").
    r.uncertainty_m = std::max(r.uncertainty_m, r.solves_sigma_m);
  }
  return result;
}

}  // namespace mocapd
