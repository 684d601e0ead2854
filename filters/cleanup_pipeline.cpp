// The cleanup's window and the order of its stages (see the header).
#include "filters/cleanup_pipeline.hpp"

#include <algorithm>
#include <optional>

namespace mocapd {
namespace {

const CleanupOptions& Validated(const CleanupOptions& options) {
  options.Validate();
  return options;
}

}  // namespace

CleanupPipeline::CleanupPipeline(std::shared_ptr<const Skeleton> skeleton,
                                 std::shared_ptr<const MarkerSet> markers,
                                 const CleanupOptions& options)
    : skeleton_(std::move(skeleton)),
      markers_(std::move(markers)),
      options_(Validated(options)),
      smoothing_frames_(std::min(FrameRules(options_).solve_smoothing_frames, options_.lookahead)),
      // The frame being published (t - K), the lookahead up to t, and two frames before
      // for slopes and trajectory continuity, or as many as the smoothing reaches back.
      window_(markers_->num_markers(), options_.lookahead + 1 + std::max(2, smoothing_frames_)),
      detector_(*skeleton_, *markers_, options_),
      repair_(markers_->num_markers(), options_),
      final_(*skeleton_, *markers_, options_) {
  const auto m = static_cast<size_t>(markers_->num_markers());
  out_.markers.assign(m, Vec3::Constant(kNaN));
  out_.status.assign(m, MarkerStatus::kUnrecoverable);
  out_.reason.assign(m, MaskReason::kNone);
  out_.source.assign(m, SampleSource::kNone);
  out_.weight.assign(m, 0.0);
  out_.pose = RestPose(*skeleton_);
  last_taken_.assign(m, Vec3::Zero());
  has_last_taken_.assign(m, 0);
  last_taken_at_.assign(m, 0);
  glitch_last_.assign(m, Vec3::Constant(kNaN));
  displacement_.assign(m, 0.0);
  solve_samples_.assign(m, Vec3::Zero());
  return_motion_.assign(m, Vec3::Constant(kNaN));
  // Centre weights of a least-squares cubic (equally, quadratic) through 2n + 1
  // equally spaced samples: 3 (3n^2 + 3n - 1 - 5j^2) / ((2n - 1)(2n + 1)(2n + 3)).
  const int n_max = smoothing_frames_;
  smoothing_weights_.assign(static_cast<size_t>((n_max + 1) * (n_max + 1)), 0.0);
  for (int n = 0; n <= n_max; ++n)
    for (int j = 0; j <= n; ++j) {
      const double nn = n;
      smoothing_weights_[static_cast<size_t>(n * (n_max + 1) + j)] =
          n == 0 ? 1.0
                 : 3.0 * (3.0 * nn * nn + 3.0 * nn - 1.0 - 5.0 * j * j) /
                       ((2.0 * nn - 1.0) * (2.0 * nn + 1.0) * (2.0 * nn + 3.0));
    }
}

void CleanupPipeline::Reset() {
  window_.Clear();
  detector_.Reset();
  repair_.Reset();
  final_.Reset();
  std::fill(has_last_taken_.begin(), has_last_taken_.end(), 0);
  last_taken_frame_ = -1;
  glitch_since_ = -1;
  next_in_ = next_out_ = 0;
}

bool CleanupPipeline::Push(std::span<const Vec3> p_WM) {
  const int64_t t = next_in_++;
  ++counters_.frames_in;
  WindowFrame& s = window_.at(t);
  s.frame = t;
  s.resync = false;
  const auto m_count = static_cast<size_t>(markers_->num_markers());
  for (size_t m = 0; m < m_count; ++m) {
    bool valid = m < p_WM.size() && p_WM[m].allFinite();
    if (valid && p_WM[m].cwiseAbs().maxCoeff() > options_.capture_volume_m) {
      valid = false;
      ++counters_.samples_out_of_volume;
    }
    s.raw[m] = valid ? p_WM[m] : Vec3::Constant(kNaN);
    s.valid[m] = valid;
    s.relabelled[m] = 0;
    s.mask[m] = valid ? MaskReason::kNone : MaskReason::kMissing;
  }
  GateGlitch(s);
  s.blind = std::none_of(s.valid.begin(), s.valid.end(), [](uint8_t v) { return v != 0; });
  detector_.Process(window_, t, next_out_, &counters_);
  if (t - options_.lookahead < next_out_) return false;
  Publish(next_out_, t);
  return true;
}

// A frame whose markers all jumped further than a body can move since the last frame
// taken is the capture's glitch (a broken frame, a world-frame hiccup): published as
// missing, it harms no solver's history. A jump that persists is a re-synchronisation.
void CleanupPipeline::GateGlitch(WindowFrame& s) {
  const size_t m_count = s.raw.size();
  // The median over the markers seen in this frame and in `from` of how far they moved.
  auto median_move = [&](const std::vector<Vec3>& from, auto&& seen) -> std::optional<double> {
    int count = 0;
    for (size_t m = 0; m < m_count; ++m)
      if (s.valid[m] && seen(m))
        displacement_[static_cast<size_t>(count++)] = (s.raw[m] - from[m]).norm();
    if (count < 3) return std::nullopt;
    const auto mid = displacement_.begin() + count / 2;
    std::nth_element(displacement_.begin(), mid, displacement_.begin() + count);
    return *mid;
  };
  bool glitch = false;
  if (last_taken_frame_ >= 0) {
    // How far each marker moved beyond what a body can since it was last taken, by its own
    // time: a frame with fewer than three markers seen is taken without them, and judged
    // by the frame's time, markers back from a dropout had one frame's allowance for the
    // whole of it (their first frame back gated, and the glitch carried on from there).
    int count = 0;
    for (size_t m = 0; m < m_count; ++m) {
      if (!s.valid[m] || !has_last_taken_[m]) continue;
      const double seconds = static_cast<double>(s.frame - last_taken_at_[m]) / options_.rate_hz;
      displacement_[static_cast<size_t>(count++)] =
          (s.raw[m] - last_taken_[m]).norm() - (options_.glitch_speed_mps * seconds + 0.05);
    }
    if (count >= 3) {
      const auto mid = displacement_.begin() + count / 2;
      std::nth_element(displacement_.begin(), mid, displacement_.begin() + count);
      glitch = *mid > 0.0;
    }
    const auto from_taken = median_move(last_taken_, [&](size_t m) { return has_last_taken_[m]; });
    // Within a glitch, the allowance above grows with every frame gated, until a jump that
    // persists passes for motion (2 m at 120 Hz after 6 frames) and the skeleton chased it
    // at the catch-up speed, every sample "observed". A frame nearer the glitch's frames
    // than the last one taken carries the glitch on.
    if (!glitch && from_taken && glitch_since_ >= 0) {
      const auto from_glitch =
          median_move(glitch_last_, [&](size_t m) { return glitch_last_[m].allFinite(); });
      glitch = from_glitch && *from_glitch < *from_taken;
    }
  }
  if (glitch) {
    glitch_since_ = glitch_since_ < 0 ? s.frame : glitch_since_;
    if (static_cast<double>(s.frame - glitch_since_ + 1) / options_.rate_hz <=
        options_.glitch_resync_s) {
      ++counters_.glitch_frames;
      for (size_t m = 0; m < m_count; ++m) {
        glitch_last_[m] = s.valid[m] ? s.raw[m] : Vec3::Constant(kNaN);
        s.raw[m] = Vec3::Constant(kNaN);
        s.valid[m] = 0;
        s.mask[m] = MaskReason::kMissing;
      }
      return;
    }
    // It persisted: the world moved. Take it, the solves starting from it afresh (the
    // repair and the final solve when this frame is published).
    ++counters_.resyncs;
    detector_.Reset();
    s.resync = true;
  }
  glitch_since_ = -1;
  for (size_t m = 0; m < m_count; ++m) {
    if (!s.valid[m]) continue;
    last_taken_[m] = s.raw[m];
    last_taken_at_[m] = s.frame;
    has_last_taken_[m] = 1;
  }
  last_taken_frame_ = s.frame;
}

// A captured sample's smoothed position: the centre of a cubic fitted through it and the
// same number of clean captured samples either side (centred, so a steady motion leaves
// it where it is), reaching as far as the window and the take hold clean samples on both
// sides. Anything else is fitted as published.
void CleanupPipeline::SmoothCapturedSamples(int64_t tau, int64_t newest) {
  const size_t m_count = solve_samples_.size();
  const int reach = static_cast<int>(std::min<int64_t>(smoothing_frames_, newest - tau));
  const size_t row = static_cast<size_t>(smoothing_frames_ + 1);
  for (size_t m = 0; m < m_count; ++m) {
    solve_samples_[m] = out_.markers[m];
    return_motion_[m] = Vec3::Constant(kNaN);
    if (out_.source[m] != SampleSource::kCaptured) continue;
    auto clean = [&](int64_t f) {
      if (!window_.Holds(f)) return false;
      const WindowFrame& w = window_.at(f);
      return w.valid[m] && w.mask[m] == MaskReason::kNone;
    };
    // Back from a gap: its motion over the next two frames, for the final solve's
    // catch-up to start from, if the lookahead shows both and they differ by no more than
    // a spike (spike_m: a swap or pop the detectors missed is no motion; capture jitter
    // alone moves a 240 Hz step by more than the catch-up's acceleration limit).
    if (!clean(tau - 1) && clean(tau + 1) && clean(tau + 2)) {
      const Vec3 first = window_.at(tau + 1).raw[m] - out_.markers[m];
      const Vec3 second = window_.at(tau + 2).raw[m] - window_.at(tau + 1).raw[m];
      if ((second - first).norm() <= options_.spike_m) return_motion_[m] = 0.5 * (first + second);
    }
    if (reach <= 0) continue;
    int n = 0;
    // The window's older frame may be a resync's start: nothing before it belongs.
    while (n < reach && clean(tau - n - 1) && clean(tau + n + 1) && !window_.at(tau - n).resync &&
           !window_.at(tau + n + 1).resync)
      ++n;
    if (n < 2) continue;  // a cubic through 3 samples is the samples
    const double* weight = &smoothing_weights_[static_cast<size_t>(n) * row];
    Vec3 sum = weight[0] * out_.markers[m];
    for (int j = 1; j <= n; ++j)
      sum += weight[j] * (window_.at(tau - j).raw[m] + window_.at(tau + j).raw[m]);
    solve_samples_[m] = sum;
  }
}

bool CleanupPipeline::Flush() {
  if (next_out_ >= next_in_) return false;
  Publish(next_out_, next_in_ - 1);
  return true;
}

void CleanupPipeline::Publish(int64_t tau, int64_t newest) {
  out_.frame = tau;
  if (window_.at(tau).resync) {
    repair_.Reset();
    final_.Reset();
  }
  repair_.Repair(window_, tau, newest, &out_, &counters_);
  SmoothCapturedSamples(tau, newest);
  final_.Solve(&out_, &counters_, solve_samples_, return_motion_);
  ++counters_.frames_out;
  next_out_ = tau + 1;
}

}  // namespace mocapd
