// Defaults, bounds and validation of the cleanup's options.
#include "filters/cleanup_options.hpp"

#include <algorithm>
#include <array>
#include <sstream>
#include <stdexcept>
#include <string>

#include "filters/motion_memory.hpp"

namespace mocapd {
namespace {

constexpr double kMm = 1e-3;
constexpr double kDeg = M_PI / 180.0;
constexpr double kMs = 1e-3;
constexpr double kNone = 1.0;  // the key's unit is SI already

using O = CleanupOptions;
using F = CleanupOptionField;
constexpr const char* kPipeline = "pipeline";
constexpr const char* kDetectors = "pipeline.detectors";
const std::array kFields = {
    F{"rate_hz", nullptr, "rate_hz", kNone, kMinCaptureRateHz, kMaxCaptureRateHz, &O::rate_hz},
    F{"lookahead", kPipeline, "lookahead", kNone, 0, 1000, &O::lookahead},
    F{"window_s", kPipeline, "window_ms", kMs, 1, 1e7, &O::window_s},
    F{"capture_volume_m", kPipeline, "capture_volume_m", kNone, 1, 1e6, &O::capture_volume_m},
    F{"glitch_speed_mps", kPipeline, "glitch_speed_mps", kNone, 1, 1e6, &O::glitch_speed_mps},
    F{"glitch_resync_s", kPipeline, "glitch_resync_ms", kMs, 0, 1e7, &O::glitch_resync_s},
    F{"disagreement_position_m", kDetectors, "disagreement_position_mm", kMm, 1, 1e5,
      &O::disagreement_position_m},
    F{"disagreement_rotation_rad", kDetectors, "disagreement_rotation_deg", kDeg, 1, 1000,
      &O::disagreement_rotation_rad},
    F{"disagreement_residual_m", nullptr, "disagreement_residual_mm", kMm, 0, 1000,
      &O::disagreement_residual_m},
    F{"residual_floor_m", kDetectors, "residual_floor_mm", kMm, 0.1, 1e5, &O::residual_floor_m},
    F{"residual_scale_factor", kDetectors, "residual_scale_factor", kNone, 1, 100,
      &O::residual_scale_factor},
    F{"spike_m", kDetectors, "spike_mm", kMm, 1, 1e5, &O::spike_m},
    F{"rigid_tolerance_m", kDetectors, "rigid_tolerance_mm", kMm, 1, 1e5, &O::rigid_tolerance_m},
    F{"swap_margin_m", kDetectors, "swap_margin_mm", kMm, 0, 1e5, &O::swap_margin_m},
    F{"swap_search_m", kDetectors, "swap_search_mm", kMm, 1, 1e5, &O::swap_search_m},
    F{"relabel_swaps", kDetectors, "relabel_swaps", kNone, 0, 1, &O::relabel_swaps},
    F{"frozen_radius_m", nullptr, "frozen_radius_mm", kMm, 0.1, 1e5, &O::frozen_radius_m},
    F{"frozen_reference_motion_m", nullptr, "frozen_reference_motion_mm", kMm, 0.1, 1e5,
      &O::frozen_reference_motion_m},
    F{"frozen_s", kDetectors, "frozen_ms", kMs, 1, 1e7, &O::frozen_s},
    F{"frozen_backdate_s", nullptr, "frozen_backdate_ms", kMs, 0, 1e7, &O::frozen_backdate_s},
    F{"reference_cold_start_wait_s", nullptr, "reference_cold_start_wait_ms", kMs, 0, 1e7,
      &O::reference_cold_start_wait_s},
    F{"stray_residual_m", kDetectors, "stray_residual_mm", kMm, 1, 1e5, &O::stray_residual_m},
    F{"stray_s", kDetectors, "stray_ms", kMs, 1, 1e7, &O::stray_s},
    F{"fallen_s", kDetectors, "fallen_ms", kMs, 1, 1e7, &O::fallen_s},
    F{"fallen_residual_m", kDetectors, "fallen_residual_mm", kMm, 1, 1e5, &O::fallen_residual_m},
    F{"off_joint_m", kDetectors, "off_joint_mm", kMm, 0, 1e5, &O::off_joint_m},
    F{"small_gap_s", kDetectors, "small_gap_ms", kMs, 0, 1e5, &O::small_gap_s},
    F{"small_track_s", kDetectors, "small_track_ms", kMs, 0, 1e5, &O::small_track_s},
    F{"trim_slope_mps", nullptr, "trim_slope_mps", kNone, 1e-3, 1e3, &O::trim_slope_mps},
    F{"max_trim_s", kDetectors, "max_trim_ms", kMs, 0, 1e5, &O::max_trim_s},
    F{"max_offset_velocity_mps", nullptr, "max_offset_velocity_mps", kNone, 1e-3, 1e3,
      &O::max_offset_velocity_mps},
    F{"fill_reference_acceleration_mps2", nullptr, "fill_reference_acceleration_mps2", kNone, 0,
      1e6, &O::fill_reference_acceleration_mps2},
    F{"fill_snap_release_s", nullptr, "fill_snap_release_ms", kMs, 0, 1e6, &O::fill_snap_release_s},
    F{"fill_start_velocity_s", nullptr, "fill_start_velocity_ms", kMs, 0, 1e6,
      &O::fill_start_velocity_s},
    F{"fill_end_velocity_s", nullptr, "fill_end_velocity_ms", kMs, 0, 1e6, &O::fill_end_velocity_s},
    F{"fill_ease_s", nullptr, "fill_ease_ms", kMs, 0, 1e6, &O::fill_ease_s},
    F{"fill_interpolation_horizon_s", nullptr, "fill_interpolation_horizon_ms", kMs, 0, 1e6,
      &O::fill_interpolation_horizon_s},
    F{"repaired_weight", nullptr, "repaired_weight", kNone, 0, 1, &O::repaired_weight},
    F{"interpolated_weight", nullptr, "interpolated_weight", kNone, 0, 1, &O::interpolated_weight},
    F{"fill_weight_growth_per_s", nullptr, "fill_weight_growth_per_s", kNone, 0, 1e6,
      &O::fill_weight_growth_per_s},
    F{"data_catchup_mps", nullptr, "data_catchup_mps", kNone, 0, 1e3, &O::data_catchup_mps},
    F{"data_catchup_time_s", nullptr, "data_catchup_time_ms", kMs, 0, 1e6, &O::data_catchup_time_s},
    F{"data_catchup_max_mps", nullptr, "data_catchup_max_mps", kNone, 0, 1e3,
      &O::data_catchup_max_mps},
    F{"data_motion_acceleration_mps2", nullptr, "data_motion_acceleration_mps2", kNone, 1e-3, 1e7,
      &O::data_motion_acceleration_mps2},
    F{"fill_anchor_speed_mps", nullptr, "fill_anchor_speed_mps", kNone, 0, 1e3,
      &O::fill_anchor_speed_mps},
    F{"anchor_holds_unseen_limbs", nullptr, "anchor_holds_unseen_limbs", kNone, 0, 1,
      &O::anchor_holds_unseen_limbs},
    F{"unseen_limb_turn_radps", nullptr, "unseen_limb_turn_dps", kDeg, 0, 1e9,
      &O::unseen_limb_turn_radps},
    F{"unseen_limb_memory_s", nullptr, "unseen_limb_memory_s", kNone, 0, 600,
      &O::unseen_limb_memory_s},
    F{"unseen_limb_recall_turn_radps", nullptr, "unseen_limb_recall_turn_dps", kDeg, 1, 1e9,
      &O::unseen_limb_recall_turn_radps},
    F{"unseen_limb_interpolation_speed_mps", nullptr, "unseen_limb_interpolation_speed_mps", kNone,
      0, 1e3, &O::unseen_limb_interpolation_speed_mps},
    F{"unseen_knee_tolerance_rad", kDetectors, "unseen_knee_tolerance_deg", kDeg, 0, 180,
      &O::unseen_knee_tolerance_rad},
    F{"unseen_knee_turn_radps", nullptr, "unseen_knee_turn_dps", kDeg, 0, 1e6,
      &O::unseen_knee_turn_radps},
    F{"solve_smoothing_s", kPipeline, "solve_smoothing_ms", kMs, 0, 1000, &O::solve_smoothing_s},
};

std::string Str(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

}  // namespace

CleanupOptions::CleanupOptions() {
  robust_ik.huber_delta_m = 0.004;
  robust_ik.cold_start_least_squares_first = true;
  // A segment moves up to 7 cm in a 60 Hz frame, and from a warm start that far off the
  // Huber loss converges slowly: with 3 iterations the reference lagged a lifting foot,
  // rejected its clean markers and the final solve chased them (Bandai medium 60 Hz
  // rotation error 2.34 -> 2.28 degrees, heavy 4.95 -> 4.77, with 6). Most frames still
  // converge in one or two.
  robust_ik.max_iterations = 6;
  // The reference starts only on half the marker set: a take that opened with three
  // markers seen had its reference solved on them, the hands 68 cm off, and the fills
  // riding it took the skeleton there (CMU 01_01 with its first frame cut to 3 markers).
  robust_ik.cold_start_min_fraction = 0.5;
  // The reference carries little of its own velocity into the next frame: an unobserved
  // segment then stays near its last pose instead of swinging on.
  robust_ik.prediction_velocity_gain = 0.2;
  final_ik.prediction_velocity_gain = 0.5;
  // A stronger pull toward the warm start than plain IK: the final solve sees repaired
  // samples, and smoothness is what a published skeleton needs.
  final_ik.temporal_weight = 3e-3;
  // Two LM iterations suffice for the final solve and one for the naive solve (it only
  // has to show which joints the outliers drag), both warm-started from a nearby pose;
  // the worst frame's iterations are what the per-frame p99 is made of.
  final_ik.max_iterations = 2;
  naive_ik.max_iterations = 1;
  // The anchor starts from last frame's final pose, so one iteration reaches it.
  anchor_ik = final_ik;
  anchor_ik.max_iterations = 1;
}

std::span<const CleanupOptionField> CleanupOptionFields() { return kFields; }

void CleanupOptions::Validate() const {
  for (const CleanupOptionField& f : kFields) {
    const double value =
        std::visit([this](auto member) { return static_cast<double>(this->*member); }, f.member);
    const double min = f.min * f.to_si, max = f.max * f.to_si;
    if (!(value >= min && value <= max))  // NaN fails too
      throw std::invalid_argument(std::string("CleanupOptions.") + f.name + ": must be in [" +
                                  Str(min) + ", " + Str(max) + "], got " + Str(value));
  }
  if (!(frozen_reference_motion_m > frozen_radius_m))
    throw std::invalid_argument(
        "CleanupOptions.frozen_reference_motion_m: must exceed frozen_radius_m (" +
        Str(frozen_radius_m) + "), got " + Str(frozen_reference_motion_m));
  if (unseen_limb_memory_s > 0.0 && unseen_limb_memory_s < MotionMemory::kMinUsefulSpanS)
    throw std::invalid_argument(
        "CleanupOptions.unseen_limb_memory_s: must be 0 (off) or at least " +
        Str(MotionMemory::kMinUsefulSpanS) + " (time to recall and to test a recall), got " +
        Str(unseen_limb_memory_s));
  naive_ik.Validate();
  robust_ik.Validate();
  final_ik.Validate();
  anchor_ik.Validate();
}

CleanupFrameRules FrameRules(const CleanupOptions& o) {
  const double rate = o.rate_hz, dt = 1.0 / rate;
  auto frames = [&](double seconds, int at_least) {
    return std::max(at_least, static_cast<int>(std::lround(seconds * rate)));
  };
  CleanupFrameRules r;
  r.statistics_weight = 2.0 / (std::max(1.0, o.window_s * rate) + 1.0);
  r.frozen_frames = frames(o.frozen_s, 1);
  r.frozen_backdate_frames = frames(o.frozen_backdate_s, 0);
  r.reference_cold_start_wait_frames = frames(o.reference_cold_start_wait_s, 0);
  r.stray_frames = frames(o.stray_s, 1);
  r.fallen_frames = frames(o.fallen_s, 1);
  r.small_gap_frames = frames(o.small_gap_s, 0);
  r.small_track_frames = frames(o.small_track_s, 0);
  r.max_trim_frames = frames(o.max_trim_s, 0);
  r.trim_slope_m = o.trim_slope_mps / rate;
  r.max_offset_velocity_m = o.max_offset_velocity_mps / rate;
  r.fill_snap_release =
      o.fill_snap_release_s > 0.0 ? 1.0 - std::exp(-dt / o.fill_snap_release_s) : 1.0;
  r.fill_start_velocity_weight =
      o.fill_start_velocity_s > 0.0 ? 1.0 - std::exp(-dt / o.fill_start_velocity_s) : 1.0;
  r.fill_end_velocity_frames = frames(o.fill_end_velocity_s, 1);
  r.fill_ease_frames = frames(o.fill_ease_s, 0);
  // Never short of the small gaps: a plain Hermite must see its gap's end.
  r.fill_interpolation_horizon_frames =
      std::max(frames(o.fill_interpolation_horizon_s, 1), r.small_gap_frames);
  r.fill_weight_ramp =
      o.fill_weight_growth_per_s > 0.0 ? std::exp(o.fill_weight_growth_per_s * dt) : 1.0;
  r.marker_jump_m = o.glitch_speed_mps / rate;
  r.data_catchup_m = o.data_catchup_mps / rate;
  r.data_catchup_share =
      o.data_catchup_time_s > 0.0 ? 1.0 - std::exp(-dt / o.data_catchup_time_s) : 0.0;
  r.data_catchup_max_m = o.data_catchup_max_mps / rate;
  r.data_motion_acceleration_m = o.data_motion_acceleration_mps2 / (rate * rate);
  r.fill_anchor_radius_m = o.fill_anchor_speed_mps / rate;
  r.unseen_limb_turn_rad = o.unseen_limb_turn_radps / rate;
  r.unseen_limb_recall_turn_rad = o.unseen_limb_recall_turn_radps / rate;
  r.unseen_limb_interpolation_radius_m = o.unseen_limb_interpolation_speed_mps / rate;
  r.solve_smoothing_frames = frames(o.solve_smoothing_s, 0);
  return r;
}

IkOptions WithUnseenKneeRule(IkOptions ik, const CleanupOptions& options) {
  ik.unseen_knee_tolerance_rad = options.unseen_knee_tolerance_rad;
  ik.unseen_knee_max_turn_rad = options.unseen_knee_turn_radps / options.rate_hz;
  return ik;
}

}  // namespace mocapd
