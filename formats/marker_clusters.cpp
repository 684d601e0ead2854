// Markers of an unknown set: a template fitted by multi-start and articulated ICP against
// anatomical and surface landmarks, segments by nearest landmark, then by rigidity.
#include "formats/marker_clusters.hpp"

#include "filters/ik_solver.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "formats/marker_set.hpp"

namespace mocapd {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// The template in a pose, as world landmark positions (1.75 m, y up, facing +z).
struct PosedLandmarks {
  Pose pose;
  std::vector<Vec3> position;
  std::vector<int> joint;
};

void PlaceLandmarks(const Skeleton& templ, std::span<const MarkerDefinition> landmarks,
                    PosedLandmarks* out) {
  KinematicsWorkspace fk(templ);
  ForwardKinematics(templ, out->pose, &fk);
  out->position.clear();
  out->joint.clear();
  for (const MarkerDefinition& d : landmarks) {
    out->position.push_back(EvaluateMarker(d, fk));
    out->joint.push_back(d.attachments[0].joint);
  }
}

// People stand for a capture's first frames with the arms down, in an A or in a T: the
// upper arms turned about the forward axis by `abduction`.
PosedLandmarks PoseTemplate(const Skeleton& templ, const HumanoidRoles& roles,
                            std::span<const MarkerDefinition> landmarks, double abduction) {
  Pose pose = RestPose(templ);
  KinematicsWorkspace rest(templ);
  ForwardKinematics(templ, pose, &rest);
  for (const auto& [role, sign] : {std::pair<const char*, double>{"upper_arm_l", 1.0},
                                   std::pair<const char*, double>{"upper_arm_r", -1.0}}) {
    const auto j = static_cast<size_t>(roles.joint_of_role.at(role));
    const int parent = templ.joint(static_cast<int>(j)).parent.value;
    const Mat3 R_parent = rest.R_WJ[static_cast<size_t>(parent)];
    const Mat3 turn = Eigen::AngleAxisd(sign * abduction, Vec3::UnitZ()).toRotationMatrix();
    pose.rotation[j] = Quat(R_parent.transpose() * turn * R_parent) * pose.rotation[j];
  }
  PosedLandmarks out;
  out.pose = std::move(pose);
  PlaceLandmarks(templ, landmarks, &out);
  return out;
}

// Generic points on each segment's surface (an elliptic cylinder about its bone, the
// axes left-right and front-back for the trunk), so that a marker where no built-in set
// puts one still finds its segment: a finger marker is nearer the hand's surface than
// any set's wrist marker.
std::vector<MarkerDefinition> SurfaceLandmarks(const Skeleton& templ) {
  struct Section {
    const char* base;
    double across, deep;  // semi-axes, m, 1.75 m adult
  };
  static constexpr Section kSections[] = {
      {"pelvis", 0.15, 0.10},      {"spine", 0.14, 0.10},     {"chest", 0.15, 0.11},
      {"neck", 0.05, 0.05},        {"head", 0.08, 0.10},      {"clavicle", 0.05, 0.05},
      {"upper_arm", 0.045, 0.045}, {"forearm", 0.035, 0.035}, {"hand", 0.035, 0.015},
      {"thigh", 0.075, 0.075},     {"shin", 0.05, 0.05},      {"foot", 0.04, 0.04},
      {"toe", 0.03, 0.02}};
  KinematicsWorkspace rest(templ);
  ForwardKinematics(templ, RestPose(templ), &rest);
  std::vector<MarkerDefinition> out;
  for (int j = 0; j < templ.num_joints(); ++j) {
    const std::string& role = templ.joint(j).name;
    const std::string mirror_free =
        role.ends_with("_l") || role.ends_with("_r") ? role.substr(0, role.size() - 2) : role;
    const Section* section = nullptr;
    for (const Section& c : kSections)
      if (mirror_free == c.base) section = &c;
    if (section == nullptr) continue;
    const Vec3 bone = TemplateBone(role, 1.75);
    const Vec3 along_bone = bone.normalized();
    Vec3 u1 = std::abs(along_bone.y()) > 0.7 ? Vec3::UnitX() : Vec3::UnitY();
    u1 = (u1 - u1.dot(along_bone) * along_bone).normalized();
    const Vec3 u2 = along_bone.cross(u1);
    const auto uj = static_cast<size_t>(j);
    // Away from the joints: a marker on a joint (a wrist bar, an epicondyle) rides the
    // proximal segment by every set's convention, and the sets' landmarks say so.
    const bool end_segment = mirror_free == "hand" || mirror_free == "toe" || mirror_free == "head";
    const std::array<double, 3> alongs =
        end_segment ? std::array<double, 3>{0.45, 0.7, 0.95} : std::array<double, 3>{0.3, 0.5, 0.7};
    for (double along : alongs)
      for (int k = 0; k < 8; ++k) {
        const double angle = k * M_PI / 4.0;
        const Vec3 p = rest.p_WJ[uj] + along * bone + section->across * std::cos(angle) * u1 +
                       section->deep * std::sin(angle) * u2;
        MarkerDefinition d;
        d.name = role + "@" + std::to_string(out.size());
        d.attachments[0] = {j, 1.0, rest.R_WJ[uj].transpose() * (p - rest.p_WJ[uj])};
        out.push_back(d);
      }
  }
  return out;
}

struct Fit {
  Mat3 R = Mat3::Identity();  // template -> world: x = s R y + t
  double s = 1.0;
  Vec3 t = Vec3::Zero();
  double cost = kInf;
};

int Nearest(const PosedLandmarks& lm, const Vec3& y, double* distance) {
  int best = -1;
  double d2 = kInf;
  for (size_t k = 0; k < lm.position.size(); ++k) {
    const double e = (lm.position[k] - y).squaredNorm();
    if (e < d2) {
      d2 = e;
      best = static_cast<int>(k);
    }
  }
  *distance = std::sqrt(d2);
  return best;
}

// Trimmed similarity ICP from one start; its cost is the mean of the squared distances
// (capped at 10 cm, so a studio's odd marker cannot steer it) over the frame's markers.
Fit RunIcp(const PosedLandmarks& lm, const std::vector<Vec3>& points, Fit fit) {
  constexpr double kCap = 0.10;
  Eigen::Matrix3Xd src(3, points.size()), dst(3, points.size());
  for (int iteration = 0; iteration < 15; ++iteration) {
    int n = 0;
    double cost = 0.0;
    for (const Vec3& x : points) {
      const Vec3 y = fit.R.transpose() * (x - fit.t) / fit.s;
      double d = 0.0;
      const int k = Nearest(lm, y, &d);
      if (k < 0) continue;
      const double world = d * fit.s;
      cost += std::min(world, kCap) * std::min(world, kCap);
      if (world > kCap) continue;
      src.col(n) = lm.position[static_cast<size_t>(k)];
      dst.col(n) = x;
      ++n;
    }
    fit.cost = cost / static_cast<double>(points.size());
    if (n < 4) break;
    const Eigen::Matrix3Xd from = src.leftCols(n), to = dst.leftCols(n);
    const Eigen::Matrix4d T = Eigen::umeyama(from, to, true);
    const Mat3 sR = T.topLeftCorner<3, 3>();
    const double s = std::cbrt(sR.determinant());
    // Heights outside 1.0-2.5 m are no adult's: the fit has slid off the body.
    if (!(s > 1.0 / 1.75 && s < 2.5 / 1.75)) break;
    fit.s = s;
    fit.R = sR / s;
    fit.t = T.topRightCorner<3, 1>();
  }
  return fit;
}

}  // namespace

double DistanceSpread(std::span<const Vec3> positions, int num_markers, int frames, int a, int b,
                      int stride) {
  // Robust: 1.4826 x the median absolute deviation (a Gaussian's standard deviation), so
  // the frames a swap or a pop corrupts do not make a rigid pair look loose.
  std::vector<double> d;
  stride = std::max(1, stride);
  const auto M = static_cast<size_t>(num_markers);
  for (int f = 0; f < frames; f += stride) {
    const Vec3& pa = positions[static_cast<size_t>(f) * M + static_cast<size_t>(a)];
    const Vec3& pb = positions[static_cast<size_t>(f) * M + static_cast<size_t>(b)];
    if (pa.allFinite() && pb.allFinite()) d.push_back((pa - pb).norm());
  }
  if (d.size() < 10) return kNaN;
  auto median = [](std::vector<double>& v) {
    const auto mid = v.begin() + static_cast<long>(v.size() / 2);
    std::nth_element(v.begin(), mid, v.end());
    return *mid;
  };
  const double centre = median(d);
  for (double& x : d) x = std::abs(x - centre);
  return 1.4826 * median(d);
}

ClusterPlacement PlaceByClustering(const Skeleton& templ, const HumanoidRoles& roles,
                                   std::span<const MarkerDefinition> landmarks,
                                   std::span<const Vec3> positions, int num_markers, int frames,
                                   const ClusterPlacementOptions& options) {
  const int M = num_markers;
  const auto uM = static_cast<size_t>(M);
  if (M < options.min_markers)
    throw std::runtime_error("calibrate: the labels match no known marker set, and " +
                             std::to_string(M) +
                             " markers are too few to place by clustering (at least " +
                             std::to_string(options.min_markers) +
                             " needed); name a set with --marker-set NAME or FILE.toml");
  if (landmarks.empty()) throw std::invalid_argument("PlaceByClustering: no landmarks");
  if (frames < 1 || positions.size() != static_cast<size_t>(frames) * uM)
    throw std::invalid_argument("PlaceByClustering: positions do not match frames x markers");
  auto at = [&](int f, int m) -> const Vec3& {
    return positions[static_cast<size_t>(f) * uM + static_cast<size_t>(m)];
  };
  ClusterPlacement out;

  // How rigidly every pair of markers moves together (step 3).
  const int stride = std::max(1, frames / 600);
  std::vector<double> spread(uM * uM, 0.0);
  for (int a = 0; a < M; ++a)
    for (int b = a + 1; b < M; ++b)
      spread[static_cast<size_t>(a) * uM + static_cast<size_t>(b)] =
          spread[static_cast<size_t>(b) * uM + static_cast<size_t>(a)] =
              DistanceSpread(positions, M, frames, a, b, stride);

  // 1. The template fitted to well-seen frames: up to six, spread over the take, each
  // seeing the most markers any frame sees (or nearly).
  std::vector<int> seen(static_cast<size_t>(frames), 0);
  int most = 0;
  for (int f = 0; f < frames; ++f) {
    for (int m = 0; m < M; ++m) seen[static_cast<size_t>(f)] += at(f, m).allFinite();
    most = std::max(most, seen[static_cast<size_t>(f)]);
  }
  if (2 * most < M) throw std::runtime_error("calibrate: no frame sees half of the markers");
  // Takes are joined with an all-missing frame between them: two frames are of one take
  // when no such frame lies between them.
  std::vector<int> take_of(static_cast<size_t>(frames), 0);
  for (int f = 1; f < frames; ++f)
    take_of[static_cast<size_t>(f)] =
        take_of[static_cast<size_t>(f - 1)] + (seen[static_cast<size_t>(f)] == 0 ? 1 : 0);
  auto same_take = [&](int a, int b) {
    return take_of[static_cast<size_t>(a)] == take_of[static_cast<size_t>(b)] &&
           seen[static_cast<size_t>(a)] > 0 && seen[static_cast<size_t>(b)] > 0;
  };
  std::vector<int> well_seen;
  for (int f = 0; f < frames; ++f)
    if (seen[static_cast<size_t>(f)] * 10 >= most * 9) well_seen.push_back(f);
  std::vector<int> starts;
  const size_t tries = std::min<size_t>(6, well_seen.size());
  for (size_t i = 0; i < tries; ++i) starts.push_back(well_seen[i * well_seen.size() / tries]);

  std::vector<PosedLandmarks> poses;
  for (double abduction_deg : {8.0, 45.0, 85.0})
    poses.push_back(PoseTemplate(templ, roles, landmarks, abduction_deg * M_PI / 180.0));
  double template_extent = 0.0;
  {
    double lo = kInf, hi = -kInf;
    for (const Vec3& p : poses[0].position) {
      lo = std::min(lo, p.y());
      hi = std::max(hi, p.y());
    }
    template_extent = hi - lo;
  }
  // Which way is up is the exporter's choice: each axis, each sign, 8 headings about it...
  // ...and, since a capture's floor may be tilted or the actor leaning, the frame's own
  // long axis (its markers' first principal direction: a body is tall and narrow).
  std::vector<Vec3> ups;
  for (int axis = 0; axis < 3; ++axis)
    for (double sign : {1.0, -1.0}) ups.push_back(sign * Vec3::Unit(axis));
  auto orientations_about = [](const std::vector<Vec3>& up_candidates) {
    std::vector<Mat3> out_orientations;
    for (const Vec3& up : up_candidates) {
      const Mat3 tilt = Quat::FromTwoVectors(Vec3::UnitY(), up).toRotationMatrix();
      for (int h = 0; h < 8; ++h)
        out_orientations.push_back(tilt * Eigen::AngleAxisd(h * M_PI / 4.0, Vec3::UnitY()));
    }
    return out_orientations;
  };
  auto seen_in = [&](int f) {
    std::vector<Vec3> points;
    for (int m = 0; m < M; ++m)
      if (at(f, m).allFinite()) points.push_back(at(f, m));
    return points;
  };
  std::vector<Vec3> template_centres;
  for (const PosedLandmarks& posed : poses) {
    Vec3 centre = Vec3::Zero();
    for (const Vec3& q : posed.position) centre += q;
    template_centres.push_back(centre / static_cast<double>(posed.position.size()));
  }
  Fit best;
  int best_pose = 0;
  for (int f : starts) {
    const std::vector<Vec3> points = seen_in(f);
    std::vector<Vec3> frame_ups = ups;
    {
      Vec3 mean = Vec3::Zero();
      for (const Vec3& x : points) mean += x;
      mean /= static_cast<double>(points.size());
      Mat3 scatter = Mat3::Zero();
      for (const Vec3& x : points) scatter += (x - mean) * (x - mean).transpose();
      const Eigen::SelfAdjointEigenSolver<Mat3> eigen(scatter);
      const Vec3 long_axis = eigen.eigenvectors().col(2);
      frame_ups.push_back(long_axis);
      frame_ups.push_back(-long_axis);
    }
    const std::vector<Mat3> orientations = orientations_about(frame_ups);
    for (size_t p = 0; p < poses.size(); ++p) {
      const Vec3& template_centre = template_centres[p];
      for (const Mat3& R : orientations) {
        const Vec3 up = R * Vec3::UnitY();
        double lo = kInf, hi = -kInf;
        Vec3 centre = Vec3::Zero();
        for (const Vec3& x : points) {
          lo = std::min(lo, x.dot(up));
          hi = std::max(hi, x.dot(up));
          centre += x;
        }
        centre /= static_cast<double>(points.size());
        Fit start;
        start.R = R;
        start.s = std::clamp((hi - lo) / template_extent, 0.6, 1.4);
        start.t = centre - start.s * R * template_centre;
        const Fit fit = RunIcp(poses[p], points, start);
        if (fit.cost < best.cost) {
          best = fit;
          best_pose = static_cast<int>(p);
          out.reference_frame = f;
        }
      }
    }
  }
  // Which way the body faces. The template looks much the same from behind, so a fit
  // can face backwards, its left and right swapped. People walk forwards: where the take
  // travels, the direction its legs' sides give ((left - right) x up) must be the way it
  // goes. A take that stays in place (a range of motion) says nothing, and the fit stands.
  {
    const PosedLandmarks& fitted = poses[static_cast<size_t>(best_pose)];
    std::vector<int> leg_side(uM, 0);  // +1 left, -1 right
    for (int m = 0; m < M; ++m) {
      const Vec3& x = at(out.reference_frame, m);
      if (!x.allFinite()) continue;
      double d = 0.0;
      const int k = Nearest(fitted, best.R.transpose() * (x - best.t) / best.s, &d);
      if (k < 0) continue;
      const std::string& role = templ.joint(fitted.joint[static_cast<size_t>(k)]).name;
      if (role.starts_with("thigh") || role.starts_with("shin") || role.starts_with("foot") ||
          role.starts_with("toe"))
        leg_side[static_cast<size_t>(m)] = role.ends_with("_l") ? 1 : -1;
    }
    const Vec3 up = best.R * Vec3::UnitY();
    auto sides = [&](int f, Vec3* left, Vec3* middle) {
      Vec3 sum[2] = {Vec3::Zero(), Vec3::Zero()};
      int count[2] = {0, 0};
      for (int m = 0; m < M; ++m) {
        const int side = leg_side[static_cast<size_t>(m)];
        if (side == 0 || !at(f, m).allFinite()) continue;
        sum[side > 0 ? 0 : 1] += at(f, m);
        ++count[side > 0 ? 0 : 1];
      }
      if (count[0] == 0 || count[1] == 0) return false;
      *left = sum[0] / count[0] - sum[1] / count[1];
      *left -= left->dot(up) * up;
      *middle = 0.5 * (sum[0] / count[0] + sum[1] / count[1]);
      return left->norm() > 0.05;
    };
    const int step = std::max(1, frames / 400);
    double forward_travel = 0.0, travel = 0.0;
    for (int f = 0; f + step < frames; f += step) {
      Vec3 left_a, middle_a, left_b, middle_b;
      if (!same_take(f, f + step) || !sides(f, &left_a, &middle_a) ||
          !sides(f + step, &left_b, &middle_b))
        continue;
      Vec3 moved = middle_b - middle_a;
      moved -= moved.dot(up) * up;
      const Vec3 facing = (left_a + left_b).cross(up).normalized();
      forward_travel += moved.dot(facing);
      travel += moved.norm();
    }
    // Swaying in place adds up to metres of path but little along the facing; a walk
    // adds most of its path one way.
    constexpr double kWalkedM = 2.0, kMostlyOneWay = 0.5;
    if (forward_travel < -kWalkedM && forward_travel < -kMostlyOneWay * travel) {
      Fit turned = best;
      turned.R = best.R * Eigen::AngleAxisd(M_PI, Vec3::UnitY()).toRotationMatrix();
      best = RunIcp(fitted, seen_in(out.reference_frame), turned);
      out.turned_round = true;
    }
  }

  // The limbs turned to the frame's own pose (articulated ICP: the template's IK onto
  // the markers, each tied to its nearest landmark), so that elbows, knees and a head
  // that are not as the template stands do not hand their markers to a neighbour.
  std::vector<MarkerDefinition> everywhere(landmarks.begin(), landmarks.end());
  for (MarkerDefinition& d : SurfaceLandmarks(templ)) everywhere.push_back(std::move(d));
  PosedLandmarks lm;
  lm.pose = poses[static_cast<size_t>(best_pose)].pose;
  PlaceLandmarks(templ, everywhere, &lm);
  {
    std::vector<Vec3> targets;
    for (int m = 0; m < M; ++m)
      if (at(out.reference_frame, m).allFinite())
        targets.push_back(best.R.transpose() * (at(out.reference_frame, m) - best.t) / best.s);
    IkOptions ik;
    ik.max_iterations = 20;
    ik.cold_start_max_iterations = 20;
    ik.huber_delta_m = 0.02;
    ik.predict_constant_velocity = false;
    ik.temporal_weight = 1e-3;
    std::vector<double> weights(targets.size());
    for (int iteration = 0; iteration < 6; ++iteration) {
      std::vector<MarkerDefinition> tied;
      for (size_t i = 0; i < targets.size(); ++i) {
        double d = 0.0;
        const int k = std::max(0, Nearest(lm, targets[i], &d));
        tied.push_back(everywhere[static_cast<size_t>(k)]);
        tied.back().name = std::to_string(i);  // two markers may tie to one landmark
        weights[i] = d < 0.12 ? 1.0 : 0.0;
      }
      const MarkerSet set(templ, std::move(tied));
      IkState state(templ, set);
      state.Reset(lm.pose);
      const IkSummary summary = SolveIk(templ, set, ik, targets, weights, &state);
      if (summary.status == IkStatus::kTooFewMarkers ||
          summary.status == IkStatus::kNumericalFailure)
        break;
      lm.pose = state.pose();
      PlaceLandmarks(templ, everywhere, &lm);
    }
  }
  out.height_m = 1.75 * best.s;
  out.landmark_rms_m = std::sqrt(best.cost);
  {
    const Vec3 up = best.R * Vec3::UnitY();
    int axis = 0;
    up.cwiseAbs().maxCoeff(&axis);
    out.up_axis = std::string(up[axis] >= 0 ? "+" : "-") + "xyz"[axis];
    out.tilt_deg = std::acos(std::clamp(std::abs(up[axis]), 0.0, 1.0)) * 180.0 / M_PI;
  }

  // 2. Segments by nearest landmark (set or surface); the offset is the nearest set
  // landmark's on that segment where one is near, else the surface point's.
  const int J = templ.num_joints();
  // cost[m][j]: distance from marker m to segment j's nearest landmark (world metres),
  // and that landmark; markers not seen in the reference frame use the nearest frame
  // that sees them (the template stays where the fit put it).
  std::vector<double> cost(uM * static_cast<size_t>(J), kInf);
  std::vector<int> nearest(uM * static_cast<size_t>(J), -1);
  // ...and to its nearest set landmark alone.
  std::vector<double> set_cost(uM * static_cast<size_t>(J), kInf);
  std::vector<int> set_nearest(uM * static_cast<size_t>(J), -1);
  for (int m = 0; m < M; ++m) {
    // A marker the reference frame does not see is taken from the nearest frame of the
    // same take that does, carried into the reference frame by the rigid motion of the
    // markers both frames see (the body moved in between).
    const int ref = out.reference_frame;
    int f = -1;
    for (int step = 0; step < frames && f < 0; ++step)
      for (int g : {ref + step, ref - step})
        if (f < 0 && g >= 0 && g < frames && same_take(g, ref) && at(g, m).allFinite()) f = g;
    if (f < 0) continue;
    Vec3 x = at(f, m);
    if (f != ref) {
      std::vector<Vec3> from, to;
      for (int k = 0; k < M; ++k)
        if (at(f, k).allFinite() && at(ref, k).allFinite()) {
          from.push_back(at(f, k));
          to.push_back(at(ref, k));
        }
      if (from.size() < 3) continue;
      const Eigen::Matrix3Xd a =
          Eigen::Map<const Eigen::Matrix3Xd>(from[0].data(), 3, static_cast<long>(from.size()));
      const Eigen::Matrix3Xd b =
          Eigen::Map<const Eigen::Matrix3Xd>(to[0].data(), 3, static_cast<long>(to.size()));
      const Eigen::Matrix4d T = Eigen::umeyama(a, b, false);
      x = T.topLeftCorner<3, 3>() * x + T.topRightCorner<3, 1>();
    }
    const Vec3 y = best.R.transpose() * (x - best.t) / best.s;
    for (size_t k = 0; k < lm.position.size(); ++k) {
      const size_t cell =
          static_cast<size_t>(m) * static_cast<size_t>(J) + static_cast<size_t>(lm.joint[k]);
      const double d = (lm.position[k] - y).norm() * best.s;
      if (d < cost[cell]) {
        cost[cell] = d;
        nearest[cell] = static_cast<int>(k);
      }
      if (k < landmarks.size() && d < set_cost[cell]) {
        set_cost[cell] = d;
        set_nearest[cell] = static_cast<int>(k);
      }
    }
  }
  auto own_best = [&](int m) {
    int j_best = 0;
    for (int j = 1; j < J; ++j)
      if (cost[static_cast<size_t>(m * J + j)] < cost[static_cast<size_t>(m * J + j_best)])
        j_best = j;
    return j_best;
  };
  out.joint.assign(uM, 0);
  for (int m = 0; m < M; ++m) out.joint[static_cast<size_t>(m)] = own_best(m);

  // 3. The motion's word: a marker that does not keep its distances to its own segment's
  // markers, but does to a neighbouring segment's, moves there. Only a contradiction
  // moves it: where a joint hardly turned, both segments look rigid with it and the
  // shape's choice stands.
  // Every marker is judged against the shape's placement, then the moves are made, so
  // the result does not depend on the order of the labels.
  std::vector<int> placed_by_shape = out.joint;
  for (int m = 0; m < M; ++m) {
    auto score = [&](int j) {
      double first = kInf, second = kInf;
      for (int k = 0; k < M; ++k) {
        if (k == m || placed_by_shape[static_cast<size_t>(k)] != j) continue;
        const double s = spread[static_cast<size_t>(m) * uM + static_cast<size_t>(k)];
        if (!std::isfinite(s)) continue;
        if (s < first) {
          second = first;
          first = s;
        } else if (s < second) {
          second = s;
        }
      }
      // A segment may hold only one other marker: its nearest two when it has them.
      return std::isfinite(second) ? 0.5 * (first + second) : first;
    };
    const int current = placed_by_shape[static_cast<size_t>(m)];
    const double here = score(current);
    int target = current;
    double there = here;
    // Only to a neighbouring segment: the body's shape put the marker near this one,
    // and markers across the chest or pelvis keep their distances too.
    for (int j = 0; j < J; ++j) {
      if (templ.joint(j).parent.value != current && templ.joint(current).parent.value != j)
        continue;
      const double s = score(j);
      if (s < there) {
        there = s;
        target = j;
      }
    }
    // A marker alone on its segment has nothing to be rigid with: the shape stands.
    if (target == current || !std::isfinite(here) || !(here > options.rigid_std_m) ||
        !(there <= options.rigid_std_m))
      continue;
    out.joint[static_cast<size_t>(m)] = target;
    ++out.moved_by_rigidity;
  }
  out.offset.assign(uM, Vec3::Zero());
  out.anatomical.assign(uM, 0);
  constexpr double kOnLandmarkM = 0.10;
  for (int m = 0; m < M; ++m) {
    const auto um = static_cast<size_t>(m);
    const int j = out.joint[um];
    const auto cell = static_cast<size_t>(m * J + j);
    out.anatomical[um] = set_cost[cell] < kOnLandmarkM;
    const int k = out.anatomical[um] ? set_nearest[cell] : nearest[cell];
    if (k >= 0) out.offset[um] = everywhere[static_cast<size_t>(k)].attachments[0].offset;
  }
  return out;
}

}  // namespace mocapd
