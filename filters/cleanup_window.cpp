// Names of the cleanup's shared enums.
#include "filters/cleanup_window.hpp"

namespace mocapd {

const char* to_string(MaskReason reason) {
  switch (reason) {
    case MaskReason::kNone: return "none";
    case MaskReason::kMissing: return "missing";
    case MaskReason::kDisagreement: return "disagreement";
    case MaskReason::kResidual: return "residual";
    case MaskReason::kSpike: return "spike";
    case MaskReason::kRigidDistance: return "rigid_distance";
    case MaskReason::kSwap: return "swap";
    case MaskReason::kFrozen: return "frozen";
    case MaskReason::kFallenOff: return "fallen_off";
    case MaskReason::kSmallTrack: return "small_track";
    case MaskReason::kTrimmed: return "trimmed";
  }
  return "?";
}

const char* to_string(MarkerStatus status) {
  switch (status) {
    case MarkerStatus::kObserved: return "observed";
    case MarkerStatus::kRepaired: return "repaired";
    case MarkerStatus::kUnrecoverable: return "unrecoverable";
  }
  return "?";
}

}  // namespace mocapd
