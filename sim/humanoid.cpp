// Procedural humanoid skeleton and motion. Proportions follow Winter's anthropometric
// segment lengths as fractions of height (Winter, "Biomechanics and Motor Control of
// Human Movement", 4th ed., table 4.1); the gait is a sum of sinusoids per joint.
#include "sim/humanoid.hpp"

#include <algorithm>
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
  if (name == "rom") return HumanoidMotion::kRom;
  throw std::invalid_argument("unknown motion '" + name +
                              "' (expected walk, reach, turn, mixed or rom)");
}

namespace {

// The humanoid's joints a motion drives, by index (left first).
struct HumanoidJoints {
  explicit HumanoidJoints(const Skeleton& skeleton) : skeleton_(skeleton) {
    hips = Index("Hips");
    spine = Index("Spine");
    chest = Index("Chest");
    neck = Index("Neck");
    head = Index("Head");
    for (int s = 0; s < 2; ++s) {
      const std::string side = s == 0 ? "Left" : "Right";
      shoulder[s] = Index(side + "Shoulder");
      arm[s] = Index(side + "Arm");
      forearm[s] = Index(side + "ForeArm");
      hand[s] = Index(side + "Hand");
      upleg[s] = Index(side + "UpLeg");
      leg[s] = Index(side + "Leg");
      foot[s] = Index(side + "Foot");
      toe[s] = Index(side + "ToeBase");
    }
  }
  size_t hips, spine, chest, neck, head;
  size_t shoulder[2], arm[2], forearm[2], hand[2], upleg[2], leg[2], foot[2], toe[2];

 private:
  size_t Index(const std::string& name) const {
    const auto j = skeleton_.FindJoint(name);
    if (!j) throw std::invalid_argument("humanoid motion needs joint '" + name + "'");
    return static_cast<size_t>(j->value);
  }
  const Skeleton& skeleton_;
};

// A calibration's range-of-motion take, standing in place, 20 s per cycle: star arcs of
// each hip, knee bends, shoulder circles, elbow bends with forearm twists and wrist
// circles, then trunk twists and bends, nods and head turns with ankle circles. Each
// phase fades in and out over half a second, so the motion stays smooth.
std::vector<Pose> MakeRangeOfMotion(const Skeleton& skeleton, double seconds, double rate_hz) {
  const HumanoidJoints J(skeleton);
  const size_t hips = J.hips, spine = J.spine, chest = J.chest, neck = J.neck, head = J.head;
  const size_t* arm = J.arm;
  const size_t* forearm = J.forearm;
  const size_t* hand = J.hand;
  const size_t* upleg = J.upleg;
  const size_t* leg = J.leg;
  const size_t* foot = J.foot;
  const Vec3 X = Vec3::UnitX(), Y = Vec3::UnitY(), Z = Vec3::UnitZ();
  const auto frames = static_cast<size_t>(std::max(1.0, std::round(seconds * rate_hz)));
  const Pose rest = RestPose(skeleton);
  std::vector<Pose> out;
  out.reserve(frames);
  auto phase = [](double t, double from, double to) {
    return SmoothStep(from, from + 0.5, t) * (1.0 - SmoothStep(to - 0.5, to, t));
  };
  for (size_t f = 0; f < frames; ++f) {
    const double time = static_cast<double>(f) / rate_hz;
    const double t = std::fmod(time, 20.0);
    const double w = M_PI;  // one circle per 2 s
    Pose pose = rest;
    pose.translation[hips] = rest.translation[hips] + Vec3(0.01 * std::sin(0.5 * time), 0, 0);
    const double trunk = phase(t, 16.0, 20.0);
    pose.rotation[hips] = AxisAngle(Y, 0.15 * trunk * std::sin(0.8 * w * t));
    pose.rotation[spine] = AxisAngle(Y, 0.35 * trunk * std::sin(0.5 * w * t)) *
                           AxisAngle(X, 0.25 * trunk * std::sin(0.7 * w * t)) *
                           AxisAngle(Z, 0.2 * trunk * std::cos(0.6 * w * t));
    pose.rotation[chest] = AxisAngle(Y, 0.3 * trunk * std::sin(0.5 * w * t + 0.4)) *
                           AxisAngle(Z, 0.15 * trunk * std::sin(0.6 * w * t));
    pose.rotation[neck] = AxisAngle(X, 0.3 * trunk * std::sin(0.9 * w * t));
    pose.rotation[head] = AxisAngle(Y, 0.6 * trunk * std::sin(0.4 * w * t)) *
                          AxisAngle(Z, 0.2 * trunk * std::cos(0.5 * w * t));
    for (int side = 0; side < 2; ++side) {
      const double s = side == 0 ? 1.0 : -1.0;
      // Hip star arcs: the thigh circles around a cone, the knee a little bent.
      const double star = phase(t, side == 0 ? 0.0 : 4.0, side == 0 ? 4.0 : 8.0);
      const double bend = phase(t, 8.0, 10.0) * (0.5 - 0.5 * std::cos(w * t + side * M_PI));
      pose.rotation[upleg[side]] =
          AxisAngle(X, -0.65 * star * (0.6 + std::sin(w * t)) - 0.6 * bend) *
          AxisAngle(Z, s * 0.45 * star * (0.5 + std::cos(w * t))) *
          AxisAngle(Y, s * 0.3 * star * std::sin(0.5 * w * t));
      pose.rotation[leg[side]] = AxisAngle(X, 0.3 * star + 1.4 * bend);
      const double ankle = trunk;
      pose.rotation[foot[side]] = AxisAngle(X, 0.35 * ankle * std::sin(w * t + side)) *
                                  AxisAngle(Z, s * 0.25 * ankle * std::cos(w * t + side));
      // Arms hang; shoulder circles, then elbow bends with forearm twists and wrist circles.
      const double circle = phase(t, 10.0, 14.0);
      const double elbow = phase(t, 14.0, 16.0);
      pose.rotation[arm[side]] = AxisAngle(Y, -s * 0.8 * circle * std::sin(w * t)) *
                                 AxisAngle(Z, -s * (1.3 - circle * (0.6 + 0.5 * std::cos(w * t)))) *
                                 AxisAngle(X, 0.5 * circle * std::sin(0.5 * w * t));
      pose.rotation[forearm[side]] =
          AxisAngle(Y, -s * (0.15 + 1.1 * elbow * (0.5 - 0.5 * std::cos(w * t)))) *
          AxisAngle(X, 0.9 * elbow * std::sin(0.5 * w * t));
      pose.rotation[hand[side]] = AxisAngle(Z, s * 0.5 * elbow * std::sin(w * t)) *
                                  AxisAngle(Y, 0.4 * elbow * std::cos(w * t));
    }
    out.push_back(std::move(pose));
  }
  return out;
}

}  // namespace

std::vector<Pose> MakeHumanoidMotion(const Skeleton& skeleton, HumanoidMotion motion,
                                     double seconds, double rate_hz) {
  if (motion == HumanoidMotion::kRom) return MakeRangeOfMotion(skeleton, seconds, rate_hz);
  const HumanoidJoints J(skeleton);
  const size_t hips = J.hips, spine = J.spine, chest = J.chest, neck = J.neck, head = J.head;
  const size_t* shoulder = J.shoulder;
  const size_t* arm = J.arm;
  const size_t* forearm = J.forearm;
  const size_t* hand = J.hand;
  const size_t* upleg = J.upleg;
  const size_t* leg = J.leg;
  const size_t* foot = J.foot;
  const size_t* toe = J.toe;
  const Vec3 X = Vec3::UnitX(), Y = Vec3::UnitY(), Z = Vec3::UnitZ();
  const double leg_length = -(skeleton.joint(static_cast<int>(leg[0])).offset.y() +
                              skeleton.joint(static_cast<int>(foot[0])).offset.y());

  const auto frames = static_cast<size_t>(std::max(1.0, std::round(seconds * rate_hz)));
  std::vector<Pose> out;
  out.reserve(frames);
  const Pose rest = RestPose(skeleton);
  double yaw = 0.0;
  Vec3 position = rest.translation[hips];
  const Vec3 start = position;
  const double dt = 1.0 / rate_hz;
  // A stage is finite: a walker past kStageRadiusM from where it started, heading away,
  // turns back (at up to kTurnBackRadPerS, eased in and out). A 120 s walk went straight on
  // to 156 m, past the default capture volume (100 m), and the replay scored every marker
  // gated as missing (982 cm mean error). Takes of up to about 23 s never reach it.
  constexpr double kStageRadiusM = 30.0, kTurnBackRadPerS = 1.2, kTurnEaseRadPerS2 = 2.4;
  double turn_back = 0.0;
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
      case HumanoidMotion::kRom: break;  // MakeRangeOfMotion
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
    {
      Vec3 away = position - start;
      away.y() = 0.0;
      const Vec3 heading = AxisAngle(Y, yaw) * Vec3::UnitZ();
      const bool turning_back = away.norm() > kStageRadiusM && heading.dot(away) > 0.0;
      const double wanted = turning_back ? kTurnBackRadPerS : 0.0;
      turn_back += std::clamp(wanted - turn_back, -kTurnEaseRadPerS2 * dt, kTurnEaseRadPerS2 * dt);
      turn_rate += turn_back;
    }
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
