// Index types and Eigen aliases shared by every stage of the pipeline.
// Distinct index types keep a marker index from being used as a joint index.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <limits>

namespace mocapd {

/// A strongly typed index; Tag makes JointIndex and MarkerIndex incompatible.
template <typename Tag>
struct TypedIndex {
  static constexpr int kInvalid = -1;
  int value = kInvalid;
  constexpr TypedIndex() = default;
  constexpr explicit TypedIndex(int v) : value(v) {}
  constexpr bool is_valid() const { return value >= 0; }
  constexpr operator int() const { return value; }  // NOLINT: indexing convenience
  friend constexpr bool operator==(TypedIndex a, TypedIndex b) { return a.value == b.value; }
};

struct JointTag {};
struct MarkerTag {};
using JointIndex = TypedIndex<JointTag>;
using MarkerIndex = TypedIndex<MarkerTag>;

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using Quat = Eigen::Quaterniond;
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// v scaled down to length max_norm if it is longer.
inline Vec3 ClampNorm(const Vec3& v, double max_norm) {
  const double n = v.norm();
  return n > max_norm ? Vec3(v * (max_norm / n)) : v;
}

}  // namespace mocapd
