// One actor's endless motion-graph stream, as `mocap-sim replay --graph` sends it: the
// actor's seeded walk through the graph, resampled to the stream's rate, with markers
// synthesized and (optionally) corrupted a chunk of a few seconds at a time. The replay
// streams it; the accuracy benchmark rebuilds the same actor offline (--graph-actor), so
// a soak's worst frame can be traced frame by frame.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "sim/corruption.hpp"
#include "sim/graph_walker.hpp"
#include "sim/replay_sources.hpp"

namespace mocapd {

struct GraphStreamChunk {
  uint64_t first_frame = 0;
  std::vector<Pose> truth;  ///< The walk's poses, one per frame.
  C3dTake clean;            ///< Their markers, synthesized.
  CorruptedTake corrupted;  ///< The markers as sent (clean when not corrupted).
};

class GraphActorStream {
 public:
  /// corrupt: "" (none), light, medium or heavy. The stream shares the source's library,
  /// graph and markers. Throws std::invalid_argument for a rate that is not positive and
  /// finite or an unknown severity.
  GraphActorStream(const GraphReplaySource& source, uint64_t walk_seed, double rate_hz,
                   const std::string& corrupt, uint64_t corrupt_seed);

  /// The next chunk, starting at frame `first` (where the last one ended), of at most
  /// total - first frames. Throws std::invalid_argument when first >= total.
  GraphStreamChunk Next(uint64_t first, uint64_t total);

  /// A chunk is corrupted on its own: an occlusion never spans two chunks.
  static constexpr double kChunkSeconds = 2.0;
  const std::shared_ptr<const MarkerSet>& markers() const { return source_.markers; }

 private:
  GraphReplaySource source_;  // shared pointers: the walker's references stay valid
  GraphWalker walker_;
  double rate_hz_;
  std::string corrupt_;
  uint64_t corrupt_seed_;
  uint64_t chunks_ = 0;
  std::vector<Pose> graph_frames_;  // the walk at the graph's rate, from graph_base_
  int64_t graph_base_ = 0;
};

/// Actor k (0-based: actor1 is 0) of a graph replay run with --seed replay_seed.
GraphActorStream ReplayGraphActor(const GraphReplaySource& source, uint64_t replay_seed, int k,
                                  double rate_hz, const std::string& corrupt);

/// A whole stream of `frames` frames (at least 1) as one take: the chunks joined.
GraphStreamChunk WholeGraphStream(GraphActorStream* stream, uint64_t frames);

}  // namespace mocapd
