// One actor's motion-graph stream, chunk by chunk (see the header).
#include "sim/graph_stream.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "filters/resample.hpp"
#include "sim/synthesis.hpp"

namespace mocapd {

GraphActorStream::GraphActorStream(const GraphReplaySource& source, uint64_t walk_seed,
                                   double rate_hz, const std::string& corrupt,
                                   uint64_t corrupt_seed)
    : source_(source),
      walker_(*source.library, *source.graph, WalkOptions{.seed = walk_seed}),
      rate_hz_(rate_hz),
      corrupt_(corrupt),
      corrupt_seed_(corrupt_seed) {
  if (!(rate_hz > 0.0) || !std::isfinite(rate_hz))
    throw std::invalid_argument("graph stream: the rate must be positive and finite");
  if (!corrupt_.empty()) ParseCorruptionSeverity(corrupt_);  // throws naming the severity
}

GraphStreamChunk GraphActorStream::Next(uint64_t first, uint64_t total) {
  if (first >= total) throw std::invalid_argument("graph stream: no frames left to make");
  const MotionLibrary& lib = *source_.library;
  GraphStreamChunk chunk;
  chunk.first_frame = first;
  // At least one frame, however low the rate.
  const auto n = static_cast<size_t>(std::min<uint64_t>(
      total - first,
      std::max<uint64_t>(1, static_cast<uint64_t>(std::llround(kChunkSeconds * rate_hz_)))));
  chunk.truth.reserve(n);
  for (size_t k = 0; k < n; ++k) {
    const double x = static_cast<double>(first + k) * lib.rate_hz / rate_hz_;
    const auto i = static_cast<int64_t>(std::floor(x));
    while (graph_base_ + static_cast<int64_t>(graph_frames_.size()) <= i + 1)
      walker_.NextFrames(&graph_frames_);
    const Pose& a = graph_frames_[static_cast<size_t>(i - graph_base_)];
    const Pose& b = graph_frames_[static_cast<size_t>(i + 1 - graph_base_)];
    chunk.truth.emplace_back();
    InterpolatePose(a, b, x - static_cast<double>(i), &chunk.truth.back());
  }
  // Frames the stream has passed are dropped, keeping the buffer to about a chunk: the
  // next chunk starts at graph frame floor(x) of its first frame, and the last frame
  // made is always kept (the walk goes on from it).
  const auto next_first =
      static_cast<int64_t>(std::floor(static_cast<double>(first + n) * lib.rate_hz / rate_hz_));
  const int64_t keep_from =
      std::min(next_first, graph_base_ + static_cast<int64_t>(graph_frames_.size()) - 1);
  if (keep_from > graph_base_) {
    graph_frames_.erase(graph_frames_.begin(), graph_frames_.begin() + (keep_from - graph_base_));
    graph_base_ = keep_from;
  }
  chunk.clean =
      SynthesizeMarkers(*lib.skeleton, *source_.markers, chunk.truth, rate_hz_, SynthesisNoise{});
  ++chunks_;
  if (corrupt_.empty()) {
    chunk.corrupted.take = chunk.clean;
    chunk.corrupted.truth.assign(
        static_cast<size_t>(chunk.clean.num_frames) * static_cast<size_t>(chunk.clean.num_points()),
        CorruptionKind::kNone);
  } else {
    CorruptionOptions c;
    c.severity = ParseCorruptionSeverity(corrupt_);
    c.seed = corrupt_seed_ + chunks_ * 1000003ull;
    chunk.corrupted = CorruptTake(chunk.clean, source_.markers.get(), c);
  }
  return chunk;
}

GraphActorStream ReplayGraphActor(const GraphReplaySource& source, uint64_t replay_seed, int k,
                                  double rate_hz, const std::string& corrupt) {
  const auto uk = static_cast<uint64_t>(k);
  return GraphActorStream(source, replay_seed + uk, rate_hz, corrupt, replay_seed + 7919ull * uk);
}

namespace {
void Append(const C3dTake& from, C3dTake* to) {
  to->positions.insert(to->positions.end(), from.positions.begin(), from.positions.end());
  to->residuals.insert(to->residuals.end(), from.residuals.begin(), from.residuals.end());
  to->num_frames += from.num_frames;
}
}  // namespace

GraphStreamChunk WholeGraphStream(GraphActorStream* stream, uint64_t frames) {
  if (frames == 0) throw std::invalid_argument("graph stream: no frames asked for");
  GraphStreamChunk whole;
  for (uint64_t first = 0; first < frames;) {
    GraphStreamChunk chunk = stream->Next(first, frames);
    const auto n = static_cast<uint64_t>(chunk.truth.size());
    if (first == 0) {
      whole = std::move(chunk);
    } else {
      whole.truth.insert(whole.truth.end(), chunk.truth.begin(), chunk.truth.end());
      Append(chunk.clean, &whole.clean);
      Append(chunk.corrupted.take, &whole.corrupted.take);
      whole.corrupted.truth.insert(whole.corrupted.truth.end(), chunk.corrupted.truth.begin(),
                                   chunk.corrupted.truth.end());
      for (CorruptionEvent e : chunk.corrupted.events) {
        e.first_frame += static_cast<int>(first);
        e.last_frame += static_cast<int>(first);
        whole.corrupted.events.push_back(e);
      }
    }
    first += n;
  }
  // Each chunk's fraction was its own.
  const auto corrupted = std::count_if(whole.corrupted.truth.begin(), whole.corrupted.truth.end(),
                                       [](CorruptionKind k) { return k != CorruptionKind::kNone; });
  whole.corrupted.corrupted_fraction =
      whole.corrupted.truth.empty()
          ? 0.0
          : static_cast<double>(corrupted) / static_cast<double>(whole.corrupted.truth.size());
  return whole;
}

}  // namespace mocapd
