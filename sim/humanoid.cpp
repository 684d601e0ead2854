// Procedural humanoid skeleton and motion. Proportions follow Winter's anthropometric
// segment lengths as fractions of height (Winter, "Biomechanics and Motor Control of
// Human Movement", 4th ed., table 4.1); the gait is a sum of sinusoids per joint.
#include "sim/humanoid.hpp"

#include <cmath>
#include <stdexcept>

#include "filters/rotation.hpp"

namespace mocapd {
namespace {

Quat AxisAngle(const Vec3& axis, double angle) {
  return Quat(Eigen::AngleAxisd(angle, axis.normalized()));
}

// Smooth 0->1 step over [a, b].
double SmoothStep(double a, double b, double t) {
  const double x = std::clamp((t - a) / (b - a), 0.0, 1.0);
  return x * x * (3.0 - 2.0 * x);
}

}  // namespace

Skeleton MakeHumanoidSkeleton(double height_m) {
  const double h = height_m;
  std::vector<Joint> j;
  auto add = [&](const std::string& name, int parent, Vec3 offset,
                 JointType type = JointType::kBall) {
    Joint joint;
    joint.name = name;
    joint.parent = JointIndex(parent);
    joint.offset = offset;
    joint.type = type;
    j.push_back(joint);
    return static_cast<int>(j.size()) - 1;
  };
  const int hips = add("Hips", -1, Vec3(0, 0.53 * h, 0), JointType::kFree);
  const int spine = add("Spine", hips, Vec3(0, 0.06 * h, 0.005 * h));
  const int chest = add("Chest", spine, Vec3(0, 0.13 * h, -0.01 * h));
  const int neck = add("Neck", chest, Vec3(0, 0.12 * h, 0.0));
  add("Head", neck, Vec3(0, 0.06 * h, 0.01 * h));
  for (int side = 0; side < 2; ++side) {
    const double s = side == 0 ? 1.0 : -1.0;
    const std::string p = side == 0 ? "Left" : "Right";
    const int shoulder = add(p + "Shoulder", chest, Vec3(s * 0.02 * h, 0.10 * h, 0.0));
    const int arm = add(p + "Arm", shoulder, Vec3(s * 0.09 * h, 0.0, 0.0));
    const int forearm = add(p + "ForeArm", arm, Vec3(s * 0.186 * h, 0.0, 0.0));
    add(p + "Hand", forearm, Vec3(s * 0.146 * h, 0.0, 0.0));
  }
  for (int side = 0; side < 2; ++side) {
    const double s = side == 0 ? 1.0 : -1.0;
    const std::string p = side == 0 ? "Left" : "Right";
    const int upleg = add(p + "UpLeg", hips, Vec3(s * 0.055 * h, -0.03 * h, 0.0));
    const int leg = add(p + "Leg", upleg, Vec3(0.0, -0.245 * h, 0.0));
    const int foot = add(p + "Foot", leg, Vec3(0.0, -0.246 * h, 0.0));
    add(p + "ToeBase", foot, Vec3(0.0, -0.035 * h, 0.10 * h));
  }
  return Skeleton(std::move(j));
}

HumanoidMotion ParseHumanoidMotion(const std::string& name) {
  if (name == "walk") return HumanoidMotion::kWalk;
  if (name == "reach") return HumanoidMotion::kReach;
  if (name == "turn") return HumanoidMotion::kTurn;
  if (name == "mixed") return HumanoidMotion::kMixed;
  throw std::invalid_argument("unknown motion '" + name +
                              "' (expected walk, reach, turn or mixed)");
}

std::vector<Pose> MakeHumanoidMotion(const Skeleton& skeleton, HumanoidMotion motion,
                                     double seconds, double rate_hz) {
  auto idx = [&](const char* name) {
    const auto j = skeleton.FindJoint(name);
    if (!j) throw std::invalid_argument(std::string("humanoid motion needs joint '") + name + "'");
    return static_cast<size_t>(j->value);
  };
  const size_t hips = idx("Hips"), spine = idx("Spine"), chest = idx("Chest"), neck = idx("Neck"),
               head = idx("Head");
  const size_t shoulder[2] = {idx("LeftShoulder"), idx("RightShoulder")};
  const size_t arm[2] = {idx("LeftArm"), idx("RightArm")};
  const size_t forearm[2] = {idx("LeftForeArm"), idx("RightForeArm")};
  const size_t hand[2] = {idx("LeftHand"), idx("RightHand")};
  const size_t upleg[2] = {idx("LeftUpLeg"), idx("RightUpLeg")};
  const size_t leg[2] = {idx("LeftLeg"), idx("RightLeg")};
  const size_t foot[2] = {idx("LeftFoot"), idx("RightFoot")};
  const size_t toe[2] = {idx("LeftToeBase"), idx("RightToeBase")};
  const Vec3 X = Vec3::UnitX(), Y = Vec3::UnitY(), Z = Vec3::UnitZ();
  const double leg_length = -(skeleton.joint(static_cast<int>(leg[0])).offset.y() +
                              skeleton.joint(static_cast<int>(foot[0])).offset.y());

  const auto frames = static_cast<size_t>(std::max(1.0, std::round(seconds * rate_hz)));
  std::vector<Pose> out;
  out.reserve(frames);
  const Pose rest = RestPose(skeleton);
  double yaw = 0.0;
  Vec3 position = rest.translation[hips];
  const double dt = 1.0 / rate_hz;
  for (size_t f = 0; f < frames; ++f) {
    const double t = static_cast<double>(f) * dt;
    // How much of each behaviour is active at time t.
    double walk = 0.0, turn_rate = 0.0, reach = 0.0;
    switch (motion) {
      case HumanoidMotion::kWalk: walk = SmoothStep(0.0, 0.5, t); break;
      case HumanoidMotion::kReach: reach = 0.5 - 0.5 * std::cos(2.0 * M_PI * t / 3.0); break;
      case HumanoidMotion::kTurn:
        turn_rate = 1.2 * SmoothStep(0.0, 0.5, t);
        walk = 0.4 * SmoothStep(0.0, 0.5, t);
        break;
      case HumanoidMotion::kMixed: {
        const double cycle = std::fmod(t, 9.0);
        walk = SmoothStep(0.0, 0.6, cycle) * (1.0 - SmoothStep(5.0, 5.6, cycle));
        turn_rate = 1.4 * (SmoothStep(2.5, 3.0, cycle) - SmoothStep(4.0, 4.5, cycle));
        reach = SmoothStep(5.6, 6.6, cycle) * (1.0 - SmoothStep(7.8, 8.8, cycle));
        break;
      }
    }
    const double phase = 2.0 * M_PI * 0.95 * t;  // ~1.9 steps per second
    Pose pose = rest;
    yaw += turn_rate * dt;
    const double speed = 1.3 * walk * (leg_length / 0.86);
    position += AxisAngle(Y, yaw) * Vec3(0, 0, speed * dt);
    Vec3 root = position;
    root.y() =
        rest.translation[hips].y() - 0.02 * walk * (1.0 - std::cos(2.0 * phase)) - 0.08 * reach;
    root.x() += 0.02 * walk * std::sin(phase);
    pose.translation[hips] = root;
    pose.rotation[hips] = AxisAngle(Y, yaw + 0.12 * walk * std::sin(phase)) *
                          AxisAngle(Z, 0.05 * walk * std::sin(phase)) *
                          AxisAngle(X, 0.05 * walk + 0.25 * reach);
    pose.rotation[spine] =
        AxisAngle(Y, -0.08 * walk * std::sin(phase)) * AxisAngle(X, 0.03 + 0.15 * reach);
    pose.rotation[chest] = AxisAngle(Y, -0.10 * walk * std::sin(phase) + 0.3 * reach) *
                           AxisAngle(Z, 0.03 * std::sin(0.7 * t));
    pose.rotation[neck] = AxisAngle(X, -0.05 - 0.1 * reach) * AxisAngle(Y, 0.1 * std::sin(0.5 * t));
    pose.rotation[head] = AxisAngle(Y, 0.25 * std::sin(0.35 * t)) *
                          AxisAngle(X, 0.1 * std::sin(0.8 * t) + 0.2 * reach);
    for (int side = 0; side < 2; ++side) {
      const double s = side == 0 ? 1.0 : -1.0;
      const double ph = phase + (side == 0 ? 0.0 : M_PI);
      // Legs: hip flexion about X, knee flexion (positive bends the shin back), ankle.
      const double hip_flex = walk * (0.45 * std::sin(ph)) + 0.6 * reach * (side == 0 ? 0.3 : 0.9);
      const double knee = walk * (0.55 * std::max(0.0, std::sin(ph - 1.2)) + 0.1) + 1.0 * reach;
      pose.rotation[upleg[side]] =
          AxisAngle(X, -hip_flex) * AxisAngle(Z, s * (0.05 + 0.04 * walk * std::cos(ph)));
      pose.rotation[leg[side]] = AxisAngle(X, knee);
      pose.rotation[foot[side]] =
          AxisAngle(X, -0.2 * walk * std::sin(ph + 0.8) - 0.4 * reach) * AxisAngle(Y, s * 0.05);
      pose.rotation[toe[side]] = AxisAngle(X, 0.25 * walk * std::max(0.0, std::sin(ph + 2.2)));
      // Arms hang from the T-pose, swing against the legs; the right arm reaches forward.
      const double reach_side = side == 1 ? reach : 0.3 * reach;
      pose.rotation[shoulder[side]] = AxisAngle(Z, s * (-0.1 + 0.15 * reach_side)) *
                                      AxisAngle(Y, s * 0.05 * walk * std::sin(ph));
      const double down = (1.25 - 0.9 * reach_side);
      pose.rotation[arm[side]] =
          AxisAngle(Y, -s * (0.35 * walk * std::sin(ph + M_PI) + 1.3 * reach_side)) *
          AxisAngle(Z, -s * down) * AxisAngle(X, 0.4 * std::sin(0.4 * t + side));
      pose.rotation[forearm[side]] =
          AxisAngle(Y, -s * (0.3 + 0.25 * walk * (1.0 + std::sin(ph + M_PI)) - 0.2 * reach_side)) *
          AxisAngle(X, 0.6 * std::sin(0.3 * t + 1.0 + side));
      pose.rotation[hand[side]] =
          AxisAngle(Z, s * 0.2 * std::sin(0.9 * t + side)) * AxisAngle(Y, 0.15 * std::sin(1.3 * t));
    }
    out.push_back(std::move(pose));
  }
  return out;
}

}  // namespace mocapd
