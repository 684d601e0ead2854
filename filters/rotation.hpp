// Rotation helpers: the exponential and logarithm maps between rotation vectors
// and unit quaternions, used for every IK step (no Euler angles, no gimbal lock),
// and the slerp used when resampling motion.
// Reference: Grassia, "Practical parameterization of rotations using the
// exponential map", J. Graphics Tools 3(3), 1998.
#pragma once

#include <cmath>

#include "filters/types.hpp"

namespace mocapd {

/// Returns the unit quaternion rotating by |v| radians about v/|v|.
/// Uses the Taylor series near zero so small steps stay exact to double precision.
inline Quat ExpRotation(const Vec3& v) {
  const double theta_sq = v.squaredNorm();
  double w, k;
  if (theta_sq < 1e-2) {
    // Per-frame IK steps are small: the series (truncation error below theta^8 / 1e7,
    // i.e. 1e-15 at the 0.1 rad bound) is exact to double precision and avoids sin/cos.
    const double t2 = theta_sq, t4 = t2 * t2, t6 = t4 * t2;
    w = 1.0 - t2 / 8.0 + t4 / 384.0 - t6 / 46080.0;
    k = 0.5 - t2 / 48.0 + t4 / 3840.0 - t6 / 645120.0;
  } else {
    const double theta = std::sqrt(theta_sq);
    w = std::cos(0.5 * theta);
    k = std::sin(0.5 * theta) / theta;
  }
  return Quat(w, k * v.x(), k * v.y(), k * v.z());
}

/// Returns the rotation vector (axis * angle, angle in [0, pi]) of a unit quaternion.
inline Vec3 LogRotation(const Quat& q_in) {
  Quat q = q_in;
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();  // shortest arc
  const Vec3 xyz = q.vec();
  const double s = xyz.norm();
  if (s < 1e-9) return 2.0 * xyz / std::max(q.w(), 1e-300);
  const double theta = 2.0 * std::atan2(s, q.w());
  return xyz * (theta / s);
}

/// Returns the angle in radians of the rotation that takes a to b.
inline double AngleBetween(const Quat& a, const Quat& b) {
  return LogRotation(a.conjugate() * b).norm();
}

/// Returns the skew-symmetric matrix [v]x such that [v]x * u = v x u.
inline Mat3 Skew(const Vec3& v) {
  Mat3 m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

}  // namespace mocapd
