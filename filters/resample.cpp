// Slerp/lerp resampling of skeletal motion.
#include "filters/resample.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace mocapd {

std::vector<Pose> ResampleMotion(const Skeleton& skeleton, const std::vector<Pose>& frames,
                                 double src_rate_hz, double dst_rate_hz) {
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
    Pose p = frames[i];
    for (int j = 0; j < skeleton.num_joints(); ++j) {
      const auto uj = static_cast<size_t>(j);
      p.rotation[uj] = frames[i].rotation[uj].slerp(a, frames[i1].rotation[uj]).normalized();
      p.translation[uj] = (1.0 - a) * frames[i].translation[uj] + a * frames[i1].translation[uj];
    }
    out.push_back(std::move(p));
  }
  return out;
}

}  // namespace mocapd
