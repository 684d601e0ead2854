// Cubic Hermite segments, the interpolant of the gap repair: a cubic on [0, L] frames
// with given values and per-frame derivatives at both ends (C0 and C1 continuity with
// what surrounds the gap).
// Basis: h00 = 2u^3 - 3u^2 + 1, h10 = u^3 - 2u^2 + u, h01 = -2u^3 + 3u^2, h11 = u^3 - u^2,
// u = x / L, P(x) = h00 p0 + h10 L m0 + h01 p1 + h11 L m1 (Catmull & Rom's form; see
// e.g. de Boor, "A Practical Guide to Splines", ch. IV).
#pragma once

#include "filters/types.hpp"

namespace mocapd {

struct HermiteSegment {
  Vec3 p0 = Vec3::Zero(), m0 = Vec3::Zero();  ///< Value and per-frame derivative at x = 0.
  Vec3 p1 = Vec3::Zero(), m1 = Vec3::Zero();  ///< Value and per-frame derivative at x = L.
  double length = 1.0;                        ///< L, frames (> 0).

  /// Value at x frames from the start.
  Vec3 Value(double x) const {
    const double u = x / length, u2 = u * u, u3 = u2 * u;
    return (2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * length * m0 + (-2 * u3 + 3 * u2) * p1 +
           (u3 - u2) * length * m1;
  }
  /// Per-frame derivative at x frames from the start.
  Vec3 Derivative(double x) const {
    const double u = x / length, u2 = u * u;
    return ((6 * u2 - 6 * u) * p0 + (-6 * u2 + 6 * u) * p1) / length + (3 * u2 - 4 * u + 1) * m0 +
           (3 * u2 - 2 * u) * m1;
  }
};

}  // namespace mocapd
