// The motion graph's library, dissimilarity, building, file and rendering.
#include "sim/motion_graph.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <numbers>
#include <sstream>
#include <stdexcept>

#include <nlohmann/json.hpp>

#include "filters/resample.hpp"
#include "formats/marker_layout.hpp"

namespace mocapd {
namespace {

uint64_t HashFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot be read");
  uint64_t h = 1469598103934665603ull;
  char buffer[65536];
  while (in.read(buffer, sizeof(buffer)) || in.gcount() > 0) {
    for (std::streamsize k = 0; k < in.gcount(); ++k) {
      h ^= static_cast<uint8_t>(buffer[k]);
      h *= 1099511628211ull;
    }
  }
  return h;
}

// The yaw of a rotation's twist about the vertical: additive under a rotation about Y
// applied on the left, which is all an alignment needs.
double HeadingYaw(const Mat3& R) {
  const Quat q(R);
  if (std::abs(q.w()) < 1e-9 && std::abs(q.y()) < 1e-9) return 0.0;
  return 2.0 * std::atan2(q.y(), q.w());
}

std::array<int, 2> FeetOf(const Skeleton& sk) {
  const HumanoidRoles roles = MatchHumanoidRoles(sk);
  return {roles.joint_of_role.at("foot_l"), roles.joint_of_role.at("foot_r")};
}

std::string Stem(const std::string& path) { return std::filesystem::path(path).stem().string(); }

// The joints the dissimilarity compares and their weights (summing to 1): every joint
// below the body root, weighted by the length of the bone leading to it, so long segments
// (thighs, spine) count more than short ones (fingers, toes); the body root itself gets
// the mean weight (its height is all that is left in the heading frame).
std::vector<std::pair<int, double>> FeatureWeights(const MotionLibrary& library) {
  const Skeleton& sk = *library.skeleton;
  const Pose& first = library.takes.front().front();
  std::vector<std::pair<int, double>> w;
  double sum = 0.0;
  for (int j = library.body_root + 1; j < sk.num_joints(); ++j) {
    if (!sk.IsAncestorOrSelf(library.body_root, j)) continue;
    const double length = LocalTranslation(sk, first, j).norm();
    if (length <= 1e-6) continue;
    w.emplace_back(j, length);
    sum += length;
  }
  if (w.empty()) return {{library.body_root, 1.0}};
  w.emplace_back(library.body_root, sum / static_cast<double>(w.size()));
  sum += w.back().second;
  for (auto& [j, weight] : w) weight /= sum;
  return w;
}

Vec3 RotateY(double yaw, const Vec3& v) {
  const double c = std::cos(yaw), s = std::sin(yaw);
  return {c * v.x() + s * v.z(), v.y(), -s * v.x() + c * v.z()};
}

// Sets the body root of pose so that its world transform is transform applied to what it was.
void ApplyPlanar(const MotionLibrary& library, const PlanarTransform& transform, Pose* pose) {
  const auto b = static_cast<size_t>(library.body_root);
  const Mat3 R_W = library.parent_rotation * pose->rotation[b].toRotationMatrix();
  const Vec3 p_W = library.parent_position + library.parent_rotation * pose->translation[b];
  const Mat3 R_new = transform.Rotation().toRotationMatrix() * R_W;
  const Vec3 p_new = transform.Apply(p_W);
  pose->rotation[b] = Quat(library.parent_rotation.transpose() * R_new).normalized();
  pose->translation[b] = library.parent_rotation.transpose() * (p_new - library.parent_position);
}

[[noreturn]] void FileError(const std::string& file, const std::string& field,
                            const std::string& what) {
  throw std::runtime_error(file + ": field '" + field + "': " + what);
}

const nlohmann::json& Field(const nlohmann::json& object, const std::string& key,
                            const std::string& file, const std::string& where) {
  if (!object.is_object()) FileError(file, where, "is not an object");
  const auto it = object.find(key);
  if (it == object.end()) FileError(file, where.empty() ? key : where + "." + key, "is missing");
  return *it;
}

double Number(const nlohmann::json& object, const std::string& key, const std::string& file,
              const std::string& where, double lo, double hi) {
  const nlohmann::json& v = Field(object, key, file, where);
  const std::string name = where.empty() ? key : where + "." + key;
  if (!v.is_number()) FileError(file, name, "is not a number");
  const double x = v.get<double>();
  if (!std::isfinite(x) || x < lo || x > hi)
    FileError(file, name,
              "is " + v.dump() + ", outside " + std::to_string(lo) + " .. " + std::to_string(hi));
  return x;
}

int Integer(const nlohmann::json& object, const std::string& key, const std::string& file,
            const std::string& where, int lo, int hi) {
  const nlohmann::json& v = Field(object, key, file, where);
  const std::string name = where.empty() ? key : where + "." + key;
  if (!v.is_number_integer()) FileError(file, name, "is not an integer");
  const int64_t x = v.get<int64_t>();
  if (x < lo || x > hi)
    FileError(file, name,
              "is " + v.dump() + ", outside " + std::to_string(lo) + " .. " + std::to_string(hi));
  return static_cast<int>(x);
}

std::string Text(const nlohmann::json& object, const std::string& key, const std::string& file,
                 const std::string& where) {
  const nlohmann::json& v = Field(object, key, file, where);
  if (!v.is_string()) FileError(file, where.empty() ? key : where + "." + key, "is not a string");
  return v.get<std::string>();
}

constexpr int kGraphFileVersion = 1;
// A foot this close to the ground (its lowest in the library) is taken to be down, and
// planted if it also moves slower than this.
constexpr double kContactHeightM = 0.05;
constexpr double kPlantedSpeed = 0.5;  // m/s

}  // namespace

double TakeRate(const BvhTake& take) {
  // A BVH's frame time is printed to a few digits (0.0333333): 30.00003 Hz is 30 Hz, and
  // taking it at its printed value would drop a take's last frame when resampled to 30.
  const double rate = take.rate_hz();
  return std::abs(rate - std::round(rate)) < 1e-5 * rate ? std::round(rate) : rate;
}

Vec3 PlanarTransform::Apply(const Vec3& p) const {
  return RotateY(yaw_rad, p) + Vec3(shift_x, 0.0, shift_z);
}

Quat PlanarTransform::Rotation() const { return Quat(Eigen::AngleAxisd(yaw_rad, Vec3::UnitY())); }

PlanarTransform PlanarTransform::Compose(const PlanarTransform& other) const {
  const Vec3 shift = Apply(Vec3(other.shift_x, 0.0, other.shift_z));
  return {yaw_rad + other.yaw_rad, shift.x(), shift.z()};
}

int MotionLibrary::TakeIndex(const std::string& name) const {
  for (size_t k = 0; k < names.size(); ++k)
    if (names[k] == name) return static_cast<int>(k);
  std::string known;
  for (const std::string& n : names) known += (known.empty() ? "" : ", ") + n;
  throw std::invalid_argument("no take named '" + name + "' in the graph (takes: " + known + ")");
}

double MotionLibrary::Step(int take, int f) const {
  if (f <= 0) return 0.0;
  const auto& p = path_m[static_cast<size_t>(take)];
  return p[static_cast<size_t>(f)] - p[static_cast<size_t>(f - 1)];
}

MotionLibrary LoadMotionLibrary(const std::vector<std::string>& paths, double rate_hz,
                                const std::string& units) {
  if (paths.empty()) throw std::runtime_error("motion graph: no takes given");
  std::vector<BvhTake> bvh;
  BvhReadOptions read;
  read.units = units;
  std::vector<uint64_t> hashes;
  for (const std::string& path : paths) {
    bvh.push_back(ReadBvh(path, read));
    hashes.push_back(HashFile(path));
  }
  return MakeMotionLibrary(bvh, paths, hashes, rate_hz);
}

MotionLibrary MakeMotionLibrary(const std::vector<BvhTake>& bvh,
                                const std::vector<std::string>& paths,
                                const std::vector<uint64_t>& file_hashes, double rate_hz) {
  if (bvh.empty() || bvh.size() != paths.size() || bvh.size() != file_hashes.size())
    throw std::invalid_argument("motion graph: one name and hash per take");
  // A single frame shows no motion, and its joints are typed by their channels alone (a
  // rig's static top joint with position channels reads as the one that translates):
  // merged below, one T-pose file among walks moved the graph's root onto a joint that
  // never moves, and every transition was lost.
  for (size_t t = 0; t < bvh.size(); ++t)
    if (bvh[t].frames.size() < 2)
      throw std::runtime_error(paths[t] + ": the take has " + std::to_string(bvh[t].frames.size()) +
                               " frame(s): a graph's takes need motion, two frames or more");
  // One skeleton for all: a joint that translates in any take translates in all (a take
  // standing in place reads its hips as a bone of fixed length).
  const Skeleton& first = bvh.front().skeleton;
  std::vector<Joint> joints(first.joints().begin(), first.joints().end());
  for (size_t t = 0; t < bvh.size(); ++t) {
    const Skeleton& sk = bvh[t].skeleton;
    auto differs = [&](const std::string& what) {
      return std::runtime_error(paths[t] + ": its skeleton differs from " + paths[0] + "'s (" +
                                what + "); a graph's takes must share one skeleton");
    };
    if (sk.num_joints() != first.num_joints())
      throw differs(std::to_string(sk.num_joints()) + " joints, not " +
                    std::to_string(first.num_joints()));
    for (int j = 0; j < sk.num_joints(); ++j) {
      const Joint& a = first.joint(j);
      const Joint& b = sk.joint(j);
      if (a.name != b.name || a.parent.value != b.parent.value)
        throw differs("joint " + std::to_string(j) + " is '" + b.name + "', not '" + a.name + "'");
      if (b.type == JointType::kFree) joints[static_cast<size_t>(j)].type = JointType::kFree;
      if (a.type != JointType::kFree && b.type != JointType::kFree && j > 0) {
        const double la = a.offset.norm(), lb = b.offset.norm();
        if (std::abs(la - lb) > 0.02 * std::max(la, lb) + 1e-3)
          throw differs("bone '" + b.name + "' is " + std::to_string(lb) + " m, not " +
                        std::to_string(la) + " m");
      }
    }
  }
  MotionLibrary lib;
  lib.skeleton = std::make_shared<const Skeleton>(joints);
  const Skeleton& sk = *lib.skeleton;
  lib.layout = bvh.front();
  lib.layout.frames.clear();
  lib.layout.skeleton = sk;
  lib.rate_hz = rate_hz > 0 ? rate_hz : TakeRate(bvh.front());
  lib.body_root = -1;
  for (int j = 0; j < sk.num_joints() && lib.body_root < 0; ++j)
    if (sk.joint(j).type == JointType::kFree) lib.body_root = j;
  if (lib.body_root < 0)
    throw std::runtime_error(paths[0] + ": no joint translates, so the takes cannot travel");
  for (int j = 0; j < lib.body_root; ++j)
    if (sk.IsAncestorOrSelf(j, lib.body_root) && sk.joint(j).type != JointType::kFixed)
      throw std::runtime_error(paths[0] + ": joint '" + sk.joint(j).name +
                               "' above the translating joint moves; the graph needs the "
                               "travel carried by one joint");
  for (size_t t = 0; t < bvh.size(); ++t) {
    std::string name = Stem(paths[t]);
    for (int n = 2; std::find(lib.names.begin(), lib.names.end(), name) != lib.names.end(); ++n)
      name = Stem(paths[t]) + "_" + std::to_string(n);
    lib.names.push_back(name);
    lib.paths.push_back(paths[t]);
    lib.file_hashes.push_back(file_hashes[t]);
    lib.takes.push_back(ResampleMotion(sk, bvh[t].frames, TakeRate(bvh[t]), lib.rate_hz));
  }
  KinematicsWorkspace ws(sk);
  ForwardKinematics(sk, lib.takes.front().front(), &ws);
  const int parent = sk.joint(lib.body_root).parent.value;
  if (parent >= 0) {
    lib.parent_rotation = ws.R_WJ[static_cast<size_t>(parent)];
    lib.parent_position = ws.p_WJ[static_cast<size_t>(parent)];
  }
  const auto b = static_cast<size_t>(lib.body_root);
  for (const std::vector<Pose>& take : lib.takes) {
    std::vector<Vec3> position;
    std::vector<double> yaw, path;
    for (const Pose& pose : take) {
      const Vec3 p = lib.parent_position + lib.parent_rotation * pose.translation[b];
      const Mat3 R = lib.parent_rotation * pose.rotation[b].toRotationMatrix();
      path.push_back(position.empty()
                         ? 0.0
                         : path.back() +
                               Vec3(p - position.back()).cwiseProduct(Vec3(1, 0, 1)).norm());
      position.push_back(p);
      yaw.push_back(HeadingYaw(R));
    }
    lib.root_position.push_back(std::move(position));
    lib.root_yaw.push_back(std::move(yaw));
    lib.path_m.push_back(std::move(path));
  }
  {
    double sum_sin = 0.0, sum_cos = 0.0;
    for (size_t t = 0; t < lib.takes.size(); ++t)
      for (size_t f = 1; f < lib.takes[t].size(); ++f) {
        const Vec3 v = lib.root_position[t][f] - lib.root_position[t][f - 1];
        if (std::hypot(v.x(), v.z()) * lib.rate_hz < 0.3) continue;
        const double offset = std::atan2(v.x(), v.z()) - lib.root_yaw[t][f];
        sum_sin += std::sin(offset);
        sum_cos += std::cos(offset);
      }
    if (sum_sin != 0.0 || sum_cos != 0.0) lib.forward_yaw_offset = std::atan2(sum_sin, sum_cos);
  }
  // The ground: where the feet get lowest (a low percentile, so one odd frame does not
  // set it). A rig without recognisable feet has no contacts to keep.
  try {
    const std::array<int, 2> feet = FeetOf(sk);
    std::vector<double> heights;
    for (const std::vector<Pose>& take : lib.takes) {
      std::vector<std::array<Vec3, 2>> positions;
      for (const Pose& pose : take) {
        ForwardKinematics(sk, pose, &ws);
        positions.push_back(
            {ws.p_WJ[static_cast<size_t>(feet[0])], ws.p_WJ[static_cast<size_t>(feet[1])]});
        for (const Vec3& p : positions.back()) heights.push_back(p.y());
      }
      lib.foot_position.push_back(std::move(positions));
    }
    std::sort(heights.begin(), heights.end());
    lib.ground_y = heights[heights.size() / 100];
    for (const auto& positions : lib.foot_position) {
      std::vector<std::array<bool, 2>> planted(positions.size());
      for (size_t f = 0; f < positions.size(); ++f)
        for (size_t side = 0; side < 2; ++side) {
          const size_t f0 = f > 0 ? f - 1 : f, f1 = std::min(positions.size() - 1, f + 1);
          Vec3 d = positions[f1][side] - positions[f0][side];
          d.y() = 0.0;
          const double speed =
              f1 > f0 ? d.norm() * lib.rate_hz / static_cast<double>(f1 - f0) : 0.0;
          planted[f][side] =
              positions[f][side].y() <= lib.ground_y + kContactHeightM && speed < kPlantedSpeed;
        }
      lib.foot_planted.push_back(std::move(planted));
    }
    const HumanoidRoles roles = MatchHumanoidRoles(sk);
    for (size_t side = 0; side < 2; ++side) {
      const std::string suffix = side == 0 ? "_l" : "_r";
      lib.legs[side] = {roles.joint_of_role.at("thigh" + suffix),
                        roles.joint_of_role.at("shin" + suffix),
                        roles.joint_of_role.at("foot" + suffix)};
    }
  } catch (const std::invalid_argument&) {
    lib.ground_y = -1e9;
    lib.foot_position.clear();
    lib.foot_planted.clear();
  }
  return lib;
}

Eigen::MatrixXd PoseFeatures(const MotionLibrary& library, int take, double velocity_weight_s) {
  const Skeleton& sk = *library.skeleton;
  const std::vector<std::pair<int, double>> weights = FeatureWeights(library);
  const std::vector<Pose>& frames = library.takes[static_cast<size_t>(take)];
  const int n = static_cast<int>(frames.size());
  std::vector<std::vector<Vec3>> world(static_cast<size_t>(n));
  KinematicsWorkspace ws(sk);
  for (int f = 0; f < n; ++f) {
    ForwardKinematics(sk, frames[static_cast<size_t>(f)], &ws);
    for (const auto& [j, w] : weights)
      world[static_cast<size_t>(f)].push_back(ws.p_WJ[static_cast<size_t>(j)]);
  }
  Eigen::MatrixXd F(n, static_cast<Eigen::Index>(6 * weights.size()));
  const double dt = 1.0 / library.rate_hz;
  for (int f = 0; f < n; ++f) {
    const double yaw = library.root_yaw[static_cast<size_t>(take)][static_cast<size_t>(f)];
    const Vec3 root = library.root_position[static_cast<size_t>(take)][static_cast<size_t>(f)];
    const Vec3 ground(root.x(), 0.0, root.z());
    const int f0 = std::max(0, f - 1), f1 = std::min(n - 1, f + 1);
    const double span = std::max(1, f1 - f0) * dt;
    for (size_t k = 0; k < weights.size(); ++k) {
      const double s = std::sqrt(weights[k].second);
      const Vec3 p = RotateY(-yaw, world[static_cast<size_t>(f)][k] - ground);
      const Vec3 v =
          RotateY(-yaw, world[static_cast<size_t>(f1)][k] - world[static_cast<size_t>(f0)][k]) /
          span;
      F.block<1, 3>(f, static_cast<Eigen::Index>(6 * k)) = s * p.transpose();
      F.block<1, 3>(f, static_cast<Eigen::Index>(6 * k + 3)) =
          s * velocity_weight_s * v.transpose();
    }
  }
  return F;
}

namespace {

// Heading from the roots; position from the feet that are down in both frames, so a
// planted foot stays where it is through the blend (aligning the roots would slide it by
// the poses' difference), else from the roots.
PlanarTransform AlignAt(const MotionLibrary& lib, int a, int i, int b, int j) {
  const auto ua = static_cast<size_t>(a), ub = static_cast<size_t>(b);
  const auto ui = static_cast<size_t>(i), uj = static_cast<size_t>(j);
  const double yaw = lib.root_yaw[ua][ui] - lib.root_yaw[ub][uj];
  Vec3 pa = lib.root_position[ua][ui];
  Vec3 pb = lib.root_position[ub][uj];
  if (!lib.foot_position.empty()) {
    Vec3 sum_a = Vec3::Zero(), sum_b = Vec3::Zero();
    int planted = 0;
    for (size_t foot = 0; foot < 2; ++foot) {
      const Vec3& fa = lib.foot_position[ua][ui][foot];
      const Vec3& fb = lib.foot_position[ub][uj][foot];
      if (fa.y() > lib.ground_y + kContactHeightM || fb.y() > lib.ground_y + kContactHeightM)
        continue;
      sum_a += fa;
      sum_b += fb;
      ++planted;
    }
    if (planted > 0) {
      pa = sum_a / planted;
      pb = sum_b / planted;
    }
  }
  pb = RotateY(yaw, pb);
  return {yaw, pa.x() - pb.x(), pa.z() - pb.z()};
}

// The weighted horizontal reach of the joints from the root: how far a heading error moves
// them, to weigh heading drift against joint distances.
double HeadingLever(const Eigen::MatrixXd& features) {
  double sum = 0.0;
  for (Eigen::Index k = 0; k + 2 < features.cols(); k += 6)
    sum += features(0, k) * features(0, k) + features(0, k + 2) * features(0, k + 2);
  return std::sqrt(sum);
}

}  // namespace

double BlendDistortion(const MotionLibrary& lib, const Eigen::MatrixXd& fa,
                       const Eigen::MatrixXd& fb, int a, int i, int b, int j, int L,
                       double velocity_weight_s) {
  const auto& ra = lib.root_position[static_cast<size_t>(a)];
  const auto& rb = lib.root_position[static_cast<size_t>(b)];
  const auto& ya = lib.root_yaw[static_cast<size_t>(a)];
  const auto& yb = lib.root_yaw[static_cast<size_t>(b)];
  const double lever = HeadingLever(fa);
  double sum = 0.0;
  for (int k = -L; k <= L; ++k) {
    const auto ia = static_cast<size_t>(i + k), jb = static_cast<size_t>(j + k);
    sum += (fa.row(static_cast<Eigen::Index>(ia)) - fb.row(static_cast<Eigen::Index>(jb)))
               .squaredNorm();
    Vec3 da = RotateY(-ya[static_cast<size_t>(i)], ra[ia] - ra[static_cast<size_t>(i)]);
    Vec3 db = RotateY(-yb[static_cast<size_t>(j)], rb[jb] - rb[static_cast<size_t>(j)]);
    da.y() = db.y() = 0.0;
    sum += (da - db).squaredNorm();
    const double turn = std::remainder(
        (ya[ia] - ya[static_cast<size_t>(i)]) - (yb[jb] - yb[static_cast<size_t>(j)]),
        2.0 * std::numbers::pi);
    sum += turn * turn * lever * lever;
  }
  const double rms = std::sqrt(sum / (2 * L + 1));
  // Spreading the mismatch over 2L frames adds velocity ~ rms / (2L dt) and acceleration
  // ~ rms / (2L dt)^2; each counted like the features' velocities (times tau, tau^2), so a
  // short window must buy its closer match with a smaller jerk.
  const double spread = velocity_weight_s * lib.rate_hz / (2.0 * L);
  return rms * (1.0 + spread + spread * spread);
}

MotionGraph BuildMotionGraph(const MotionLibrary& lib, const GraphBuildOptions& o,
                             GraphBuildReport* report) {
  const auto start = std::chrono::steady_clock::now();
  if (o.transitions_per_pair < 1)
    throw std::invalid_argument("graph build: transitions per pair must be >= 1");
  if (!(o.min_window_s > 0) || o.max_window_s < o.min_window_s || o.max_window_s >= 1.0)
    throw std::invalid_argument("graph build: windows must satisfy 0 < min <= max < 1 s");
  if (!(o.max_cost_m > 0)) throw std::invalid_argument("graph build: max cost must be > 0");
  MotionGraph graph;
  graph.rate_hz = lib.rate_hz;
  graph.options = o;
  for (int t = 0; t < lib.num_takes(); ++t)
    graph.takes.push_back({lib.names[static_cast<size_t>(t)], lib.paths[static_cast<size_t>(t)],
                           lib.num_frames(t), lib.file_hashes[static_cast<size_t>(t)]});
  std::vector<Eigen::MatrixXd> features;
  for (int t = 0; t < lib.num_takes(); ++t)
    features.push_back(PoseFeatures(lib, t, o.velocity_weight_s));
  const int l_min = std::max(1, static_cast<int>(std::lround(o.min_window_s * lib.rate_hz)));
  const int l_max = std::max(l_min, static_cast<int>(std::lround(o.max_window_s * lib.rate_hz)));
  const int radius = std::max(1, static_cast<int>(std::lround(0.1 * lib.rate_hz)));
  const int separation =
      std::max(1, static_cast<int>(std::lround(o.min_separation_s * lib.rate_hz)));
  const int min_loop = std::max(1, static_cast<int>(std::lround(o.min_loop_s * lib.rate_hz)));
  // A pose pair is worth a window only if the poses alone are this close (squared).
  const double prefilter = o.max_cost_m * o.max_cost_m;
  int candidates = 0;
  for (int a = 0; a < lib.num_takes(); ++a) {
    for (int b = 0; b < lib.num_takes(); ++b) {
      const Eigen::MatrixXd& fa = features[static_cast<size_t>(a)];
      const Eigen::MatrixXd& fb = features[static_cast<size_t>(b)];
      const Eigen::VectorXd na = fa.rowwise().squaredNorm(), nb = fb.rowwise().squaredNorm();
      Eigen::MatrixXd D = -2.0 * fa * fb.transpose();
      D.colwise() += na;
      D.rowwise() += nb.transpose();
      const int n_a = static_cast<int>(fa.rows()), n_b = static_cast<int>(fb.rows());
      std::vector<GraphTransition> found;
      for (int i = l_min; i + l_min < n_a; ++i) {
        for (int j = l_min; j + l_min < n_b; ++j) {
          const double d = D(i, j);
          if (d > prefilter) continue;
          if (a == b && std::abs(i - j) < min_loop) continue;
          bool minimum = true;
          for (int di = -radius; di <= radius && minimum; ++di)
            for (int dj = -radius; dj <= radius; ++dj) {
              const int ii = i + di, jj = j + dj;
              if ((di == 0 && dj == 0) || ii < 0 || jj < 0 || ii >= n_a || jj >= n_b) continue;
              const double other = D(ii, jj);
              // Ties go to the earlier cell so a flat valley yields one minimum.
              if (other < d || (other == d && (di < 0 || (di == 0 && dj < 0)))) {
                minimum = false;
                break;
              }
            }
          if (!minimum) continue;
          ++candidates;
          GraphTransition best;
          best.cost_m = 1e300;
          for (int L = l_min; L <= l_max; ++L) {
            if (i - L < 0 || i + L >= n_a || j - L < 0 || j + L >= n_b) break;
            const double c = BlendDistortion(lib, fa, fb, a, i, b, j, L, o.velocity_weight_s);
            if (c < best.cost_m) {
              best.cost_m = c;
              best.half_window = L;
            }
          }
          if (best.cost_m > o.max_cost_m) continue;
          best.from_take = a;
          best.from_frame = i;
          best.to_take = b;
          best.to_frame = j;
          found.push_back(best);
        }
      }
      std::sort(found.begin(), found.end(), [](const GraphTransition& x, const GraphTransition& y) {
        return x.cost_m != y.cost_m ? x.cost_m < y.cost_m : x.from_frame < y.from_frame;
      });
      int kept = 0;
      std::vector<int> taken;
      for (GraphTransition& t : found) {
        if (kept >= o.transitions_per_pair) break;
        if (std::any_of(taken.begin(), taken.end(),
                        [&](int f) { return std::abs(f - t.from_frame) < separation; }))
          continue;
        taken.push_back(t.from_frame);
        t.align = AlignAt(lib, a, t.from_frame, b, t.to_frame);
        graph.transitions.push_back(t);
        ++kept;
      }
    }
  }
  // The root path inside each blend, for planning.
  for (size_t k = 0; k < graph.transitions.size(); ++k) {
    std::vector<Pose> frames;
    PlanarTransform transform;
    PathStep step;
    step.transition = static_cast<int>(k);
    RenderStep(lib, graph, step, &transform, &frames);
    graph.transitions[k].blend_path_m = RootPathLength(lib, frames);
  }
  if (report) {
    report->candidates = candidates;
    report->kept = static_cast<int>(graph.transitions.size());
    report->seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return graph;
}

void WriteMotionGraph(const std::string& path, const MotionGraph& g) {
  namespace fs = std::filesystem;
  const fs::path folder = fs::absolute(fs::path(path)).parent_path();
  nlohmann::json j;
  j["format"] = "mocapd motion graph";
  j["version"] = kGraphFileVersion;
  j["rate_hz"] = g.rate_hz;
  j["units"] = g.units;
  j["options"] = {{"transitions_per_pair", g.options.transitions_per_pair},
                  {"max_cost_m", g.options.max_cost_m},
                  {"velocity_weight_s", g.options.velocity_weight_s},
                  {"min_window_s", g.options.min_window_s},
                  {"max_window_s", g.options.max_window_s},
                  {"min_separation_s", g.options.min_separation_s},
                  {"min_loop_s", g.options.min_loop_s}};
  j["takes"] = nlohmann::json::array();
  for (const GraphTakeRef& t : g.takes) {
    std::error_code ec;
    const fs::path absolute = fs::absolute(fs::path(t.path));
    fs::path relative = fs::relative(absolute, folder, ec);
    const std::string stored = ec || relative.empty() ? absolute.string() : relative.string();
    char hash[17];
    std::snprintf(hash, sizeof(hash), "%016llx", static_cast<unsigned long long>(t.file_hash));
    j["takes"].push_back(
        {{"name", t.name}, {"path", stored}, {"frames", t.frames}, {"fnv1a", hash}});
  }
  j["transitions"] = nlohmann::json::array();
  for (const GraphTransition& t : g.transitions)
    j["transitions"].push_back({{"from", g.takes[static_cast<size_t>(t.from_take)].name},
                                {"from_frame", t.from_frame},
                                {"to", g.takes[static_cast<size_t>(t.to_take)].name},
                                {"to_frame", t.to_frame},
                                {"half_window", t.half_window},
                                {"cost_m", t.cost_m},
                                {"align_yaw_deg", t.align.yaw_rad * 180.0 / std::numbers::pi},
                                {"align_shift_m", {t.align.shift_x, t.align.shift_z}},
                                {"blend_path_m", t.blend_path_m}});
  std::ofstream out(path);
  out << j.dump(1) << "\n";
  if (!out) throw std::runtime_error(path + ": cannot write the graph");
}

MotionGraph ReadMotionGraph(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot be read");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    throw std::runtime_error(path + ": not a JSON motion graph (" + e.what() + ")");
  }
  if (!j.is_object() || j.value("format", "") != "mocapd motion graph")
    throw std::runtime_error(path + ": not a mocapd motion graph (field 'format')");
  if (Integer(j, "version", path, "", 0, 1000) != kGraphFileVersion)
    FileError(path, "version", "is not " + std::to_string(kGraphFileVersion));
  MotionGraph g;
  g.rate_hz = Number(j, "rate_hz", path, "", 1.0, 10000.0);
  g.units = Text(j, "units", path, "");
  const nlohmann::json& o = Field(j, "options", path, "");
  g.options.transitions_per_pair = Integer(o, "transitions_per_pair", path, "options", 1, 1000);
  g.options.max_cost_m = Number(o, "max_cost_m", path, "options", 0.0, 100.0);
  g.options.velocity_weight_s = Number(o, "velocity_weight_s", path, "options", 0.0, 100.0);
  g.options.min_window_s = Number(o, "min_window_s", path, "options", 0.0, 1.0);
  g.options.max_window_s = Number(o, "max_window_s", path, "options", 0.0, 1.0);
  g.options.min_separation_s = Number(o, "min_separation_s", path, "options", 0.0, 1000.0);
  g.options.min_loop_s = Number(o, "min_loop_s", path, "options", 0.0, 1000.0);
  const nlohmann::json& takes = Field(j, "takes", path, "");
  if (!takes.is_array() || takes.empty()) FileError(path, "takes", "is not a non-empty array");
  for (size_t k = 0; k < takes.size(); ++k) {
    const std::string where = "takes[" + std::to_string(k) + "]";
    GraphTakeRef t;
    t.name = Text(takes[k], "name", path, where);
    t.path = Text(takes[k], "path", path, where);
    // Relative to the graph file's folder, wherever the reader runs.
    if (!std::filesystem::path(t.path).is_absolute())
      t.path = (std::filesystem::absolute(std::filesystem::path(path)).parent_path() / t.path)
                   .lexically_normal()
                   .string();
    t.frames = Integer(takes[k], "frames", path, where, 1, 100000000);
    const std::string hash = Text(takes[k], "fnv1a", path, where);
    char* end = nullptr;
    t.file_hash = std::strtoull(hash.c_str(), &end, 16);
    if (hash.size() != 16 || *end != '\0')
      FileError(path, where + ".fnv1a", "is not 16 hex digits");
    for (const GraphTakeRef& other : g.takes)
      if (other.name == t.name) FileError(path, where + ".name", "repeats '" + t.name + "'");
    g.takes.push_back(t);
  }
  const auto take_of = [&](const nlohmann::json& tr, const std::string& key,
                           const std::string& where) {
    const std::string name = Text(tr, key, path, where);
    for (size_t k = 0; k < g.takes.size(); ++k)
      if (g.takes[k].name == name) return static_cast<int>(k);
    FileError(path, where + "." + key, "names no take ('" + name + "')");
  };
  const nlohmann::json& trs = Field(j, "transitions", path, "");
  if (!trs.is_array()) FileError(path, "transitions", "is not an array");
  for (size_t k = 0; k < trs.size(); ++k) {
    const std::string where = "transitions[" + std::to_string(k) + "]";
    GraphTransition t;
    t.from_take = take_of(trs[k], "from", where);
    t.to_take = take_of(trs[k], "to", where);
    const int na = g.takes[static_cast<size_t>(t.from_take)].frames;
    const int nb = g.takes[static_cast<size_t>(t.to_take)].frames;
    // The window must fit both takes before its centres can be checked against it.
    t.half_window =
        Integer(trs[k], "half_window", path, where, 1, std::max(1, (std::min(na, nb) - 1) / 2));
    t.from_frame =
        Integer(trs[k], "from_frame", path, where, t.half_window, na - 1 - t.half_window);
    t.to_frame = Integer(trs[k], "to_frame", path, where, t.half_window, nb - 1 - t.half_window);
    t.cost_m = Number(trs[k], "cost_m", path, where, 0.0, 1e6);
    t.align.yaw_rad =
        Number(trs[k], "align_yaw_deg", path, where, -1e4, 1e4) * std::numbers::pi / 180.0;
    const nlohmann::json& shift = Field(trs[k], "align_shift_m", path, where);
    if (!shift.is_array() || shift.size() != 2 || !shift[0].is_number() || !shift[1].is_number())
      FileError(path, where + ".align_shift_m", "is not [x, z]");
    t.align.shift_x = shift[0].get<double>();
    t.align.shift_z = shift[1].get<double>();
    if (!std::isfinite(t.align.shift_x) || !std::isfinite(t.align.shift_z))
      FileError(path, where + ".align_shift_m", "is not finite");
    t.blend_path_m = Number(trs[k], "blend_path_m", path, where, 0.0, 1e6);
    g.transitions.push_back(t);
  }
  return g;
}

MotionLibrary LoadGraphLibrary(const MotionGraph& graph, const std::string& graph_path) {
  std::vector<std::string> paths;
  for (const GraphTakeRef& t : graph.takes) paths.push_back(t.path);
  MotionLibrary lib = LoadMotionLibrary(paths, graph.rate_hz, graph.units);
  for (size_t k = 0; k < graph.takes.size(); ++k) {
    if (lib.file_hashes[k] != graph.takes[k].file_hash)
      throw std::runtime_error(graph_path + ": take '" + graph.takes[k].name + "' (" + paths[k] +
                               ") changed since the graph was built; build it again");
    if (lib.num_frames(static_cast<int>(k)) != graph.takes[k].frames)
      throw std::runtime_error(graph_path + ": take '" + graph.takes[k].name + "' has " +
                               std::to_string(lib.num_frames(static_cast<int>(k))) + " frames at " +
                               std::to_string(graph.rate_hz) + " Hz, the graph says " +
                               std::to_string(graph.takes[k].frames) +
                               " (fields 'rate_hz' or 'takes[" + std::to_string(k) +
                               "].frames' were edited); build the graph again");
    lib.names[k] = graph.takes[k].name;
  }
  return lib;
}

void ValidatePath(const MotionLibrary& lib, const MotionGraph& g, const GraphPath& path) {
  int take = -1, next = -1;  // where the path continues
  for (size_t k = 0; k < path.size(); ++k) {
    const PathStep& s = path[k];
    const std::string at = "path step " + std::to_string(k) + ": ";
    if (s.transition >= 0) {
      if (s.transition >= static_cast<int>(g.transitions.size()))
        throw std::invalid_argument(at + "no transition " + std::to_string(s.transition));
      const GraphTransition& t = g.transitions[static_cast<size_t>(s.transition)];
      if (take >= 0 && (take != t.from_take || next != t.exit_frame()))
        throw std::invalid_argument(at + "the blend does not leave where the path is");
      take = t.to_take;
      next = t.entry_frame();
    } else {
      if (s.take < 0 || s.take >= lib.num_takes() || s.count < 1 || s.first < 0 ||
          s.first + s.count > lib.num_frames(s.take))
        throw std::invalid_argument(at + "frames outside the take");
      if (take >= 0 && (take != s.take || next != s.first))
        throw std::invalid_argument(at + "the play does not start where the path is");
      take = s.take;
      next = s.first + s.count;
    }
  }
}

namespace {

// Two-bone leg IK: turns the knee, then the hip, so the ankle reaches target; the foot
// keeps its world orientation.
void ReachAnkle(const Skeleton& sk, const std::array<int, 3>& leg, const Vec3& target, Pose* pose,
                KinematicsWorkspace* ws) {
  const auto hip = static_cast<size_t>(leg[0]), knee = static_cast<size_t>(leg[1]),
             ankle = static_cast<size_t>(leg[2]);
  ForwardKinematics(sk, *pose, ws);
  const Mat3 ankle_world = ws->R_WJ[ankle];
  const Vec3 H = ws->p_WJ[hip], K = ws->p_WJ[knee], A = ws->p_WJ[ankle];
  const Vec3 u = H - K, v = A - K;
  const double l1 = u.norm(), l2 = v.norm();
  if (l1 < 1e-6 || l2 < 1e-6) return;
  const double d = std::clamp((target - H).norm(), std::abs(l1 - l2) + 1e-4, l1 + l2 - 1e-4);
  const double current = std::acos(std::clamp(u.dot(v) / (l1 * l2), -1.0, 1.0));
  const double wanted =
      std::acos(std::clamp((l1 * l1 + l2 * l2 - d * d) / (2 * l1 * l2), -1.0, 1.0));
  Vec3 axis = u.cross(v);
  axis = axis.norm() > 1e-9 ? Vec3(axis.normalized()) : Vec3(ws->R_WJ[knee] * Vec3::UnitX());
  auto set_world = [&](size_t j, const Mat3& R_W) {
    const int parent = sk.joint(static_cast<int>(j)).parent.value;
    const Mat3 R_P = parent >= 0 ? ws->R_WJ[static_cast<size_t>(parent)] : Mat3::Identity();
    pose->rotation[j] = Quat(R_P.transpose() * R_W).normalized();
  };
  set_world(knee, Eigen::AngleAxisd(wanted - current, axis).toRotationMatrix() * ws->R_WJ[knee]);
  ForwardKinematics(sk, *pose, ws);
  const Quat swing = Quat::FromTwoVectors(ws->p_WJ[ankle] - H, target - H);
  set_world(hip, swing.toRotationMatrix() * ws->R_WJ[hip]);
  ForwardKinematics(sk, *pose, ws);
  set_world(ankle, ankle_world);
}

// Keeps a foot that is planted (in the take that dominates the blend at that frame)
// where it was when the blend found it down: blending two feet at slightly different
// places, or a planted one with a moving one, would slide it. The correction
// fades over a few frames where the foot lifts, or where the window ends with it down
// (the destination's own foot takes over there, which the alignment put in the same spot).
void KeepPlantedFeet(const MotionLibrary& lib, const GraphTransition& t, Pose* frames) {
  if (lib.foot_planted.empty()) return;
  const Skeleton& sk = *lib.skeleton;
  const int n = t.blend_frames();
  KinematicsWorkspace ws(sk);
  std::vector<std::array<Vec3, 2>> ankle(static_cast<size_t>(n));
  for (int k = 0; k < n; ++k) {
    ForwardKinematics(sk, frames[k], &ws);
    for (size_t side = 0; side < 2; ++side)
      ankle[static_cast<size_t>(k)][side] = ws.p_WJ[static_cast<size_t>(lib.legs[side][2])];
  }
  constexpr int kFade = 3;
  for (size_t side = 0; side < 2; ++side) {
    std::vector<Vec3> offset(static_cast<size_t>(n), Vec3::Zero());
    auto down = [&](int k) {
      const bool a = lib.foot_planted[static_cast<size_t>(t.from_take)]
                                     [static_cast<size_t>(t.exit_frame() + k)][side];
      const bool b = lib.foot_planted[static_cast<size_t>(t.to_take)]
                                     [static_cast<size_t>(t.to_frame - t.half_window + k)][side];
      return 2 * k < n ? a : b;  // the source that dominates the blend there
    };
    for (int k0 = 0; k0 < n;) {
      if (!down(k0)) {
        ++k0;
        continue;
      }
      int k1 = k0;
      while (k1 + 1 < n && down(k1 + 1)) ++k1;
      const Vec3 anchor = ankle[static_cast<size_t>(k0)][side];
      for (int k = k0; k <= k1; ++k) {
        Vec3 o = anchor - ankle[static_cast<size_t>(k)][side];
        o.y() = 0.0;
        // Down to the window's end: hand over to the destination's foot by the last frame.
        const double w =
            k1 == n - 1 ? std::clamp(static_cast<double>(k1 - k) / kFade, 0.0, 1.0) : 1.0;
        offset[static_cast<size_t>(k)] = w * o;
      }
      // Lifting inside the window: let the correction go over the next frames.
      for (int k = k1 + 1; k < n && k <= k1 + kFade; ++k)
        offset[static_cast<size_t>(k)] =
            offset[static_cast<size_t>(k1)] * (1.0 - static_cast<double>(k - k1) / (kFade + 1));
      k0 = k1 + 1;
    }
    for (int k = 0; k < n; ++k)
      if (offset[static_cast<size_t>(k)].squaredNorm() > 1e-10)
        ReachAnkle(sk, lib.legs[side],
                   ankle[static_cast<size_t>(k)][side] + offset[static_cast<size_t>(k)], &frames[k],
                   &ws);
  }
}

}  // namespace

void RenderStep(const MotionLibrary& lib, const MotionGraph& g, const PathStep& s,
                PlanarTransform* transform, std::vector<Pose>* out, std::vector<uint8_t>* blended) {
  RenderStep(lib, g, s, transform, out);
  if (blended) blended->resize(out->size(), s.transition >= 0 ? 1 : 0);
}

void RenderStep(const MotionLibrary& lib, const MotionGraph& g, const PathStep& s,
                PlanarTransform* transform, std::vector<Pose>* out) {
  if (s.transition < 0) {
    for (int f = s.first; f < s.first + s.count; ++f) {
      out->push_back(lib.takes[static_cast<size_t>(s.take)][static_cast<size_t>(f)]);
      ApplyPlanar(lib, *transform, &out->back());
    }
    return;
  }
  const GraphTransition& t = g.transitions[static_cast<size_t>(s.transition)];
  const PlanarTransform to = transform->Compose(t.align);
  const int L = t.half_window;
  for (int k = 0; k <= 2 * L; ++k) {
    Pose a = lib.takes[static_cast<size_t>(t.from_take)][static_cast<size_t>(t.from_frame - L + k)];
    Pose b = lib.takes[static_cast<size_t>(t.to_take)][static_cast<size_t>(t.to_frame - L + k)];
    ApplyPlanar(lib, *transform, &a);
    ApplyPlanar(lib, to, &b);
    out->emplace_back();
    {
      const double x = static_cast<double>(k) / (2.0 * L);
      InterpolatePose(a, b, x * x * (3.0 - 2.0 * x), &out->back());
    }
  }
  KeepPlantedFeet(lib, t, &(*out)[out->size() - static_cast<size_t>(t.blend_frames())]);
  *transform = to;
}

std::vector<Pose> RenderPath(const MotionLibrary& lib, const MotionGraph& g,
                             const GraphPath& path) {
  ValidatePath(lib, g, path);
  std::vector<Pose> out;
  out.reserve(static_cast<size_t>(PathFrames(g, path)));
  PlanarTransform transform;
  for (const PathStep& s : path) RenderStep(lib, g, s, &transform, &out);
  return out;
}

int PathFrames(const MotionGraph& g, const GraphPath& path) {
  int n = 0;
  for (const PathStep& s : path)
    n += s.transition >= 0 ? g.transitions[static_cast<size_t>(s.transition)].blend_frames()
                           : s.count;
  return n;
}

double PathDistance(const MotionLibrary& lib, const MotionGraph& g, const GraphPath& path) {
  return RootPathLength(lib, RenderPath(lib, g, path));
}

MotionSmoothness MeasureSmoothness(const MotionLibrary& lib, const std::vector<Pose>& frames,
                                   double contact_height_m) {
  const Skeleton& sk = *lib.skeleton;
  const std::array<int, 2> feet = FeetOf(sk);
  const size_t n = frames.size();
  std::vector<std::vector<Vec3>> world(n);
  KinematicsWorkspace ws(sk);
  for (size_t f = 0; f < n; ++f) {
    ForwardKinematics(sk, frames[f], &ws);
    world[f] = ws.p_WJ;
  }
  MotionSmoothness m;
  m.acceleration.assign(n, 0.0);
  m.foot_slide.assign(n, 0.0);
  const double rate2 = lib.rate_hz * lib.rate_hz;
  for (size_t f = 1; f + 1 < n; ++f) {
    double sum = 0.0;
    for (size_t j = 0; j < world[f].size(); ++j)
      sum += (world[f + 1][j] - 2.0 * world[f][j] + world[f - 1][j]).norm();
    m.acceleration[f] = sum / static_cast<double>(world[f].size()) * rate2;
    double slide = 0.0;
    for (int foot : feet) {
      const auto uf = static_cast<size_t>(foot);
      if (world[f][uf].y() > lib.ground_y + contact_height_m) continue;
      Vec3 d = world[f + 1][uf] - world[f - 1][uf];
      d.y() = 0.0;
      slide = std::max(slide, d.norm() * 0.5 * lib.rate_hz);
    }
    m.foot_slide[f] = slide;
  }
  return m;
}

double RootPathLength(const MotionLibrary& lib, const std::vector<Pose>& frames) {
  const auto b = static_cast<size_t>(lib.body_root);
  double sum = 0.0;
  for (size_t f = 1; f < frames.size(); ++f) {
    Vec3 d = lib.parent_rotation * (frames[f].translation[b] - frames[f - 1].translation[b]);
    d.y() = 0.0;
    sum += d.norm();
  }
  return sum;
}

}  // namespace mocapd
