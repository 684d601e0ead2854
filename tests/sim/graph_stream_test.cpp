// A graph actor's stream as the replay sends it and as the accuracy benchmark rebuilds it
// offline: the whole stream is its chunks joined, an actor's seeds repeat it, and each
// chunk is corrupted on its own.
#include "sim/graph_stream.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <vector>

namespace mocapd {
namespace {

constexpr double kRate = 60.0;  // 120 frames a chunk

const GraphReplaySource& Humanoid() {
  static const GraphReplaySource source = GraphSource("humanoid");
  return source;
}

bool SameSample(const Vec3& a, const Vec3& b) {
  return (a.hasNaN() && b.hasNaN()) || (!a.hasNaN() && !b.hasNaN() && a == b);
}

TEST(GraphStreamTest, TheWholeStreamIsItsChunksJoined) {
  GraphActorStream for_whole = ReplayGraphActor(Humanoid(), 1, 2, kRate, "medium");
  GraphActorStream by_chunk = ReplayGraphActor(Humanoid(), 1, 2, kRate, "medium");
  const uint64_t frames = 300;  // two whole chunks and a short one
  const GraphStreamChunk whole = WholeGraphStream(&for_whole, frames);
  ASSERT_EQ(whole.truth.size(), frames);
  ASSERT_EQ(whole.corrupted.take.num_frames, static_cast<int>(frames));
  ASSERT_EQ(whole.clean.num_frames, static_cast<int>(frames));
  const int points = whole.corrupted.take.num_points();
  ASSERT_EQ(whole.corrupted.truth.size(), frames * static_cast<size_t>(points));
  size_t events = 0;
  for (uint64_t first = 0; first < frames;) {
    const GraphStreamChunk chunk = by_chunk.Next(first, frames);
    ASSERT_EQ(chunk.first_frame, first);
    for (int f = 0; f < chunk.corrupted.take.num_frames; ++f) {
      const int g = static_cast<int>(first) + f;
      EXPECT_EQ(chunk.truth[static_cast<size_t>(f)].rotation,
                whole.truth[static_cast<size_t>(g)].rotation);
      for (int p = 0; p < points; ++p) {
        EXPECT_TRUE(SameSample(chunk.corrupted.take.at(f, p), whole.corrupted.take.at(g, p)))
            << "frame " << g << " point " << p;
        EXPECT_EQ(chunk.corrupted.at(f, p), whole.corrupted.at(g, p));
        EXPECT_EQ(chunk.clean.at(f, p), whole.clean.at(g, p));
      }
    }
    for (const CorruptionEvent& e : chunk.corrupted.events) {
      ASSERT_LT(events, whole.corrupted.events.size());
      const CorruptionEvent& joined = whole.corrupted.events[events++];
      EXPECT_EQ(joined.marker, e.marker);
      EXPECT_EQ(joined.first_frame, e.first_frame + static_cast<int>(first));
      EXPECT_EQ(joined.last_frame, e.last_frame + static_cast<int>(first));
    }
    first += chunk.truth.size();
  }
  EXPECT_EQ(events, whole.corrupted.events.size());
}

TEST(GraphStreamTest, AnActorsSeedsRepeatItsStreamAndOtherActorsDiffer) {
  GraphActorStream a = ReplayGraphActor(Humanoid(), 1, 0, kRate, "medium");
  GraphActorStream again = ReplayGraphActor(Humanoid(), 1, 0, kRate, "medium");
  GraphActorStream other = ReplayGraphActor(Humanoid(), 1, 1, kRate, "medium");
  const GraphStreamChunk x = WholeGraphStream(&a, 200), y = WholeGraphStream(&again, 200),
                         z = WholeGraphStream(&other, 200);
  EXPECT_EQ(x.corrupted.truth, y.corrupted.truth);
  EXPECT_EQ(x.truth.back().rotation, y.truth.back().rotation);
  EXPECT_NE(x.corrupted.truth, z.corrupted.truth);
  EXPECT_NE(x.truth.back().rotation, z.truth.back().rotation);
}

TEST(GraphStreamTest, EachChunkIsCorruptedOnItsOwnWithItsOwnSeed) {
  GraphActorStream stream = ReplayGraphActor(Humanoid(), 3, 0, kRate, "heavy");
  const auto chunk_frames =
      static_cast<uint64_t>(std::llround(GraphActorStream::kChunkSeconds * kRate));
  const uint64_t total = 3 * chunk_frames;
  std::vector<std::vector<CorruptionKind>> masks;
  for (uint64_t first = 0; first < total; first += chunk_frames) {
    const GraphStreamChunk chunk = stream.Next(first, total);
    ASSERT_EQ(chunk.truth.size(), chunk_frames);
    ASSERT_FALSE(chunk.corrupted.events.empty());
    // An event of a chunk is inside it: an occlusion never spans two chunks.
    for (const CorruptionEvent& e : chunk.corrupted.events) {
      EXPECT_GE(e.first_frame, 0);
      EXPECT_LT(e.last_frame, static_cast<int>(chunk_frames)) << to_string(e.kind);
    }
    masks.push_back(chunk.corrupted.truth);
  }
  // Each chunk's corruption has its own seed: no two chunks corrupt the same samples.
  EXPECT_NE(masks[0], masks[1]);
  EXPECT_NE(masks[1], masks[2]);
}

TEST(GraphStreamTest, TheWholeStreamsCorruptedFractionIsOverAllItsSamples) {
  GraphActorStream stream = ReplayGraphActor(Humanoid(), 1, 0, kRate, "medium");
  const GraphStreamChunk whole = WholeGraphStream(&stream, 400);
  size_t corrupted = 0, missing = 0;
  for (size_t i = 0; i < whole.corrupted.truth.size(); ++i) {
    corrupted += whole.corrupted.truth[i] != CorruptionKind::kNone;
    missing += whole.corrupted.take.residuals[i] < 0.0f;
  }
  ASSERT_EQ(whole.corrupted.take.residuals.size(), whole.corrupted.truth.size());
  EXPECT_GT(missing, 0u);
  EXPECT_DOUBLE_EQ(
      whole.corrupted.corrupted_fraction,
      static_cast<double>(corrupted) / static_cast<double>(whole.corrupted.truth.size()));
}

TEST(GraphStreamTest, ABadRateSeverityOrFrameCountIsRefused) {
  EXPECT_THROW(ReplayGraphActor(Humanoid(), 1, 0, 0.0, ""), std::invalid_argument);
  EXPECT_THROW(ReplayGraphActor(Humanoid(), 1, 0, -60.0, ""), std::invalid_argument);
  EXPECT_THROW(ReplayGraphActor(Humanoid(), 1, 0, std::nan(""), ""), std::invalid_argument);
  EXPECT_THROW(ReplayGraphActor(Humanoid(), 1, 0, kRate, "extreme"), std::invalid_argument);
  GraphActorStream stream = ReplayGraphActor(Humanoid(), 1, 0, kRate, "");
  EXPECT_THROW(WholeGraphStream(&stream, 0), std::invalid_argument);
  EXPECT_THROW(stream.Next(10, 10), std::invalid_argument);
  // A rate too low for a whole frame per chunk still makes one a chunk.
  GraphActorStream slow = ReplayGraphActor(Humanoid(), 1, 0, 0.1, "");
  EXPECT_EQ(WholeGraphStream(&slow, 3).truth.size(), 3u);
}

TEST(GraphStreamTest, AnUncorruptedStreamSendsItsCleanMarkers) {
  GraphActorStream stream = ReplayGraphActor(Humanoid(), 1, 0, kRate, "");
  const GraphStreamChunk whole = WholeGraphStream(&stream, 150);
  EXPECT_TRUE(whole.corrupted.events.empty());
  for (CorruptionKind k : whole.corrupted.truth) EXPECT_EQ(k, CorruptionKind::kNone);
  for (int f = 0; f < whole.clean.num_frames; ++f)
    for (int p = 0; p < whole.clean.num_points(); ++p)
      EXPECT_TRUE(SameSample(whole.clean.at(f, p), whole.corrupted.take.at(f, p)));
}

}  // namespace
}  // namespace mocapd
