// The cleanup's window and the order of its stages (see the header).
#include "filters/cleanup_pipeline.hpp"

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
      // The frame being published (t - K), the lookahead up to t, and two frames before
      // for slopes and trajectory continuity.
      window_(markers_->num_markers(), options_.lookahead + 3),
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
}

void CleanupPipeline::Reset() {
  window_.Clear();
  detector_.Reset();
  repair_.Reset();
  final_.Reset();
  next_in_ = next_out_ = 0;
}

bool CleanupPipeline::Push(std::span<const Vec3> p_WM) {
  const int64_t t = next_in_++;
  ++counters_.frames_in;
  WindowFrame& s = window_.at(t);
  s.frame = t;
  const auto m_count = static_cast<size_t>(markers_->num_markers());
  for (size_t m = 0; m < m_count; ++m) {
    const bool valid = m < p_WM.size() && p_WM[m].allFinite();
    s.raw[m] = valid ? p_WM[m] : Vec3::Constant(kNaN);
    s.valid[m] = valid;
    s.relabelled[m] = 0;
    s.mask[m] = valid ? MaskReason::kNone : MaskReason::kMissing;
  }
  detector_.Process(window_, t, next_out_, &counters_);
  if (t - options_.lookahead < next_out_) return false;
  Publish(next_out_, t);
  return true;
}

bool CleanupPipeline::Flush() {
  if (next_out_ >= next_in_) return false;
  Publish(next_out_, next_in_ - 1);
  return true;
}

void CleanupPipeline::Publish(int64_t tau, int64_t newest) {
  out_.frame = tau;
  repair_.Repair(window_, tau, newest, &out_, &counters_);
  final_.Solve(&out_, &counters_);
  ++counters_.frames_out;
  next_out_ = tau + 1;
}

}  // namespace mocapd
