// Slerp/lerp resampling of skeletal motion.
#include "filters/resample.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace mocapd {

void InterpolatePose(const Pose& a, const Pose& b, double alpha, Pose* out) {
  *out = a;
  for (size_t j = 0; j < a.rotation.size(); ++j) {
    out->rotation[j] = a.rotation[j].slerp(alpha, b.rotation[j]).normalized();
    out->translation[j] = (1.0 - alpha) * a.translation[j] + alpha * b.translation[j];
  }
}

std::vector<Pose> ResampleMotion(
    const Skeleton& /*skeleton: the poses are interpolated joint by joint*/,
    const std::vector<Pose>& frames, double src_rate_hz, double dst_rate_hz) {
  if (!(src_rate_hz > 0.0) || !(dst_rate_hz > 0.0))
    throw std::invalid_argument("resample: rates must be > 0");
  if (frames.empty()) throw std::invalid_argument("resample: no frames");
  const double duration = static_cast<double>(frames.size() - 1) / src_rate_hz;
  const auto count = static_cast<size_t>(std::floor(duration * dst_rate_hz + 1e-9)) + 1;
  std::vector<Pose> out;
  out.reserve(count);
  for (size_t k = 0; k < count; ++k) {
    const double x = static_cast<double>(k) / dst_rate_hz * src_rate_hz;
    const auto i = std::min(static_cast<size_t>(std::floor(x)), frames.size() - 1);
    const size_t i1 = std::min(i + 1, frames.size() - 1);
    const double a = std::clamp(x - static_cast<double>(i), 0.0, 1.0);
    out.emplace_back();
    InterpolatePose(frames[i], frames[i1], a, &out.back());
  }
  return out;
}

}  // namespace mocapd
