// Seeded corruption of clean marker takes, the way real optical captures go wrong:
// cluster-correlated occlusion gaps (1/120 s to 2 s, some open at the start or end),
// label swaps between markers that pass within ~10 cm, pops (1-3 frames at 120 Hz, as
// long in time at other rates, at least one frame; 5-50 cm); every duration in seconds,
// so a take corrupts alike at any capture rate,
// frozen markers that pop back, markers falling off, and Gaussian jitter. Records what
// it did as a ground-truth mask, so cleanup can be scored. Shared by `mocap-sim synth
// --corrupt` and the replay simulator.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "filters/marker_model.hpp"
#include "formats/c3d.hpp"

namespace mocapd {

enum class CorruptionKind : uint8_t { kNone, kGap, kSwap, kPop, kFrozen, kFallenOff };
const char* to_string(CorruptionKind kind);

enum class CorruptionSeverity { kLight, kMedium, kHeavy };
/// Parses light|medium|heavy; throws std::invalid_argument otherwise.
CorruptionSeverity ParseCorruptionSeverity(const std::string& name);
/// Target fraction of marker-samples corrupted: 5 %, 15 %, 30 %.
double TargetCorruptedFraction(CorruptionSeverity severity);

struct CorruptionOptions {
  CorruptionSeverity severity = CorruptionSeverity::kMedium;
  uint64_t seed = 1;
  double jitter_min_m = 0.0005;  ///< Each marker gets a jitter sigma in [min, max].
  double jitter_max_m = 0.002;
  int up_axis = 1;  ///< 0 x, 1 y, 2 z: where "down" is for markers that fall off.
};

struct CorruptionEvent {
  CorruptionKind kind = CorruptionKind::kNone;
  int marker = -1;
  int other = -1;  ///< The swap partner.
  int first_frame = 0;
  int last_frame = 0;  ///< Inclusive.
};

struct CorruptedTake {
  C3dTake take;
  std::vector<CorruptionEvent> events;
  /// truth[frame * points + point]: what was done to the sample (jitter not counted).
  std::vector<CorruptionKind> truth;
  double corrupted_fraction = 0.0;
  CorruptionKind at(int frame, int point) const {
    return truth[static_cast<size_t>(frame) * static_cast<size_t>(take.num_points()) +
                 static_cast<size_t>(point)];
  }
};

/// Corrupts a clean take. markers (may be null) groups points into clusters by the joint
/// they ride on, for correlated occlusion; points are matched to markers by label.
/// Deterministic for a given seed. Throws std::invalid_argument for an empty take.
CorruptedTake CorruptTake(const C3dTake& clean, const MarkerSet* markers,
                          const CorruptionOptions& options);

/// The ground-truth mask as JSON: options, fraction, and the event list.
nlohmann::json CorruptionTruthJson(const CorruptedTake& corrupted,
                                   const CorruptionOptions& options);

}  // namespace mocapd
