// Retrieval on a motion graph: role features on both rigs and a Viterbi trellis.
#include "sim/graph_match.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "filters/resample.hpp"
#include "formats/marker_layout.hpp"

namespace mocapd {
namespace {

const char* const kRoles[] = {"pelvis",      "thigh_l",   "shin_l",      "foot_l",    "thigh_r",
                              "shin_r",      "foot_r",    "upper_arm_l", "forearm_l", "hand_l",
                              "upper_arm_r", "forearm_r", "hand_r",      "head"};
constexpr int kNumRoles = static_cast<int>(sizeof(kRoles) / sizeof(kRoles[0]));

struct RoleTrack {
  /// Per frame, per role: the joint in the body's heading frame (origin under the pelvis),
  /// divided by the leg length.
  std::vector<std::array<Vec3, kNumRoles>> position;
  /// Per frame: the pelvis's horizontal travel since the frame before, in this frame's
  /// heading frame, divided by the leg length (the pelvis's own position is fixed there).
  std::vector<Vec3> travel;
  double scale = 1.0;  ///< Leg length, m.
};

RoleTrack TrackRoles(const Skeleton& sk, const std::vector<Pose>& frames) {
  const HumanoidRoles roles = MatchHumanoidRoles(sk);
  std::array<int, kNumRoles> joint{};
  for (int r = 0; r < kNumRoles; ++r)
    joint[static_cast<size_t>(r)] = roles.joint_of_role.at(kRoles[r]);
  RoleTrack track;
  KinematicsWorkspace ws(sk);
  ForwardKinematics(sk, RestPose(sk), &ws);
  auto at = [&](const char* role) {
    return ws.p_WJ[static_cast<size_t>(roles.joint_of_role.at(role))];
  };
  track.scale =
      0.5 * ((at("thigh_l") - at("shin_l")).norm() + (at("shin_l") - at("foot_l")).norm() +
             (at("thigh_r") - at("shin_r")).norm() + (at("shin_r") - at("foot_r")).norm());
  if (!(track.scale > 1e-3))
    throw std::invalid_argument("match: the skeleton's legs have no length");
  Vec3 last_pelvis = Vec3::Zero();
  for (const Pose& pose : frames) {
    ForwardKinematics(sk, pose, &ws);
    // The heading from the body, not from a rig's rest orientation: forward is
    // perpendicular to the hips' line, horizontally.
    const Vec3 across = at("thigh_l") - at("thigh_r");
    Vec3 forward = Vec3::UnitY().cross(across);
    forward.y() = 0.0;
    const double yaw = forward.norm() > 1e-9 ? std::atan2(forward.x(), forward.z()) : 0.0;
    const double c = std::cos(-yaw), s = std::sin(-yaw);
    const Vec3 pelvis = at("pelvis");
    Vec3 travel = Vec3::Zero();
    if (!track.position.empty()) {
      const Vec3 d(pelvis.x() - last_pelvis.x(), 0.0, pelvis.z() - last_pelvis.z());
      travel = Vec3(c * d.x() + s * d.z(), 0.0, -s * d.x() + c * d.z()) / track.scale;
    }
    last_pelvis = pelvis;
    track.travel.push_back(travel);
    std::array<Vec3, kNumRoles> p;
    for (int r = 0; r < kNumRoles; ++r) {
      Vec3 d = ws.p_WJ[static_cast<size_t>(joint[static_cast<size_t>(r)])] -
               Vec3(pelvis.x(), 0.0, pelvis.z());
      p[static_cast<size_t>(r)] =
          Vec3(c * d.x() + s * d.z(), d.y(), -s * d.x() + c * d.z()) / track.scale;
    }
    track.position.push_back(p);
  }
  return track;
}

// A role's motion from frame f-1 to f in the body's heading frame (the pelvis: its travel).
Vec3 RoleVelocity(const RoleTrack& t, int f, int r) {
  if (r == 0) return t.travel[static_cast<size_t>(f)];
  return t.position[static_cast<size_t>(f)][static_cast<size_t>(r)] -
         t.position[static_cast<size_t>(f - 1)][static_cast<size_t>(r)];
}

Eigen::MatrixXd Features(const RoleTrack& t, double velocity_weight_frames) {
  const auto n = static_cast<Eigen::Index>(t.position.size());
  Eigen::MatrixXd F(n, 6 * kNumRoles);
  for (Eigen::Index f = 0; f < n; ++f) {
    const Eigen::Index f0 = std::max<Eigen::Index>(0, f - 1),
                       f1 = std::min<Eigen::Index>(n - 1, f + 1);
    const double span = static_cast<double>(std::max<Eigen::Index>(1, f1 - f0));
    for (int r = 0; r < kNumRoles; ++r) {
      const Vec3& p = t.position[static_cast<size_t>(f)][static_cast<size_t>(r)];
      const Vec3 v =
          r == 0 ? RoleVelocity(t, static_cast<int>(f1), 0) * 0.5 +
                       RoleVelocity(t, static_cast<int>(std::max<Eigen::Index>(1, f)), 0) * 0.5
                 : Vec3((t.position[static_cast<size_t>(f1)][static_cast<size_t>(r)] -
                         t.position[static_cast<size_t>(f0)][static_cast<size_t>(r)]) /
                        span);
      F.block<1, 3>(f, 6 * r) = p.transpose();
      F.block<1, 3>(f, 6 * r + 3) = velocity_weight_frames * v.transpose();
    }
  }
  return F / std::sqrt(static_cast<double>(kNumRoles));
}

}  // namespace

MatchResult MatchQuery(const MotionLibrary& lib, const MotionGraph& graph, const BvhTake& query,
                       const MatchOptions& o) {
  const std::vector<Pose> q_frames =
      ResampleMotion(query.skeleton, query.frames, TakeRate(query), lib.rate_hz);
  if (q_frames.size() < 2) throw std::invalid_argument("match: the query needs at least 2 frames");
  const double vw = o.velocity_weight_s * lib.rate_hz;
  const RoleTrack q_track = TrackRoles(query.skeleton, q_frames);
  const Eigen::MatrixXd fq = Features(q_track, vw);
  // Every library frame as one row, takes one after another.
  std::vector<int> take_start;
  std::vector<RoleTrack> tracks;
  int total = 0;
  for (int t = 0; t < lib.num_takes(); ++t) {
    take_start.push_back(total);
    tracks.push_back(TrackRoles(*lib.skeleton, lib.takes[static_cast<size_t>(t)]));
    total += lib.num_frames(t);
  }
  Eigen::MatrixXd fl(total, 6 * kNumRoles);
  for (int t = 0; t < lib.num_takes(); ++t) {
    const Eigen::MatrixXd f = Features(tracks[static_cast<size_t>(t)], vw);
    fl.middleRows(take_start[static_cast<size_t>(t)], f.rows()) = f;
  }
  // The trellis holds a cost and a way in per query frame and library frame (and the
  // retrieval costs as many doubles): refuse what would not fit rather than swap.
  constexpr double kMaxTrellisBytes = 1024.0 * 1024.0 * 1024.0;
  const double trellis_bytes =
      static_cast<double>(q_frames.size()) * total * (2 * sizeof(double) + sizeof(int));
  if (trellis_bytes > kMaxTrellisBytes)
    throw std::invalid_argument(
        "match: a " + std::to_string(q_frames.size()) + "-frame query against " +
        std::to_string(total) + " library frames needs " +
        std::to_string(static_cast<long>(trellis_bytes / (1 << 20))) + " MB; split the query");
  // Retrieval cost: feature distance, query frames x library frames.
  Eigen::MatrixXd cost = -2.0 * fq * fl.transpose();
  cost.colwise() += fq.rowwise().squaredNorm();
  cost.rowwise() += fl.rowwise().squaredNorm().transpose();
  cost = cost.cwiseMax(0.0).cwiseSqrt();

  const int Q = static_cast<int>(q_frames.size());
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double> best(static_cast<size_t>(Q) * static_cast<size_t>(total), inf);
  // How each state was reached: -1 from the frame before in its take, -2 started there,
  // >= 0 through that transition.
  std::vector<int> via(best.size(), -2);
  auto cell = [&](int q, int row) {
    return static_cast<size_t>(q) * static_cast<size_t>(total) + static_cast<size_t>(row);
  };
  for (int row = 0; row < total; ++row) best[cell(0, row)] = cost(0, row);
  // Transitions by the source frame they leave after (their blend's first frame - 1).
  std::vector<std::vector<int>> leaving(static_cast<size_t>(total));
  for (size_t k = 0; k < graph.transitions.size(); ++k) {
    const GraphTransition& t = graph.transitions[k];
    if (t.exit_frame() >= 1)
      leaving[static_cast<size_t>(take_start[static_cast<size_t>(t.from_take)] + t.exit_frame() -
                                  1)]
          .push_back(static_cast<int>(k));
  }
  for (int q = 1; q < Q; ++q) {
    for (int t = 0; t < lib.num_takes(); ++t) {
      const int s0 = take_start[static_cast<size_t>(t)];
      for (int f = 1; f < lib.num_frames(t); ++f) {
        const double c = best[cell(q - 1, s0 + f - 1)] + cost(q, s0 + f);
        if (c < best[cell(q, s0 + f)]) {
          best[cell(q, s0 + f)] = c;
          via[cell(q, s0 + f)] = -1;
        }
      }
    }
    // Blends leaving from states at q - 1 land at q - 1 + (2L + 1).
    for (int row = 0; row < total; ++row) {
      if (leaving[static_cast<size_t>(row)].empty() || !std::isfinite(best[cell(q - 1, row)]))
        continue;
      for (int k : leaving[static_cast<size_t>(row)]) {
        const GraphTransition& t = graph.transitions[static_cast<size_t>(k)];
        const int n = t.blend_frames();
        if (q - 1 + n >= Q) continue;
        const int a0 = take_start[static_cast<size_t>(t.from_take)] + t.exit_frame();
        const int b0 = take_start[static_cast<size_t>(t.to_take)] + t.to_frame - t.half_window;
        double c =
            best[cell(q - 1, row)] + o.transition_weight * t.cost_m / tracks.front().scale * n;
        for (int k2 = 0; k2 < n; ++k2) {
          const double alpha = static_cast<double>(k2) / (n - 1);
          c += (1.0 - alpha) * cost(q + k2, a0 + k2) + alpha * cost(q + k2, b0 + k2);
        }
        const size_t land = cell(q - 1 + n, b0 + n - 1);
        if (c < best[land]) {
          best[land] = c;
          via[land] = k;
        }
      }
    }
  }
  // Back from the cheapest last state.
  int row = 0;
  for (int r = 1; r < total; ++r)
    if (best[cell(Q - 1, r)] < best[cell(Q - 1, row)]) row = r;
  if (!std::isfinite(best[cell(Q - 1, row)]))
    throw std::runtime_error(
        "match: no path through the graph lasts the query's " + std::to_string(Q) +
        " frames (its takes are shorter and too few transitions join them; "
        "build the graph with more or looser transitions, or split the query)");
  auto take_of = [&](int r) {
    int t = 0;
    while (t + 1 < lib.num_takes() && take_start[static_cast<size_t>(t + 1)] <= r) ++t;
    return t;
  };
  GraphPath reversed;
  MatchResult result;
  int q = Q - 1;
  int play_end = row;  // the last row of the current play (inclusive)
  while (true) {
    const int v = via[cell(q, row)];
    if (v == -1) {
      --q;
      --row;
      continue;
    }
    const int t = take_of(row);
    reversed.push_back({t, row - take_start[static_cast<size_t>(t)], play_end - row + 1, -1});
    if (v == -2) break;
    const GraphTransition& tr = graph.transitions[static_cast<size_t>(v)];
    // This play began at the blend's landing frame (entry - 1), which the blend renders.
    reversed.back().first += 1;
    reversed.back().count -= 1;
    if (reversed.back().count == 0) reversed.pop_back();
    reversed.push_back({-1, 0, 0, v});
    ++result.jumps;
    q -= tr.blend_frames();
    row = take_start[static_cast<size_t>(tr.from_take)] + tr.exit_frame() - 1;
    play_end = row;
  }
  result.path.assign(reversed.rbegin(), reversed.rend());
  result.query_frames = Q;

  // The velocity difference, per frame, in the query's scale.
  const std::vector<Pose> got = RenderPath(lib, graph, result.path);
  const RoleTrack g_track = TrackRoles(*lib.skeleton, got);
  const int n = std::min(Q, static_cast<int>(got.size()));
  double sum = 0.0;
  for (int f = 1; f < n; ++f) {
    double frame_sum = 0.0;
    for (int r = 0; r < kNumRoles; ++r) {
      const Vec3 vq = RoleVelocity(q_track, f, r);
      const Vec3 vg = RoleVelocity(g_track, f, r);
      frame_sum += (vq - vg).norm() * q_track.scale * 100.0;
    }
    frame_sum /= kNumRoles;
    sum += frame_sum;
    result.worst_velocity_difference_cm = std::max(result.worst_velocity_difference_cm, frame_sum);
  }
  result.velocity_difference_cm = n > 1 ? sum / (n - 1) : 0.0;
  return result;
}

}  // namespace mocapd
