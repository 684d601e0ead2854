// Motion for benchmarks: a real BVH take from ../shared when present (never required),
// else the built-in humanoid's procedural motion, with the default marker layout.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "filters/marker_model.hpp"
#include "formats/bvh.hpp"
#include "formats/c3d.hpp"

namespace mocapd::bench {

struct BenchTake {
  std::string name;
  BvhTake bvh;                               ///< As read (or generated).
  std::vector<Pose> motion;                  ///< Resampled to the benchmark rate.
  std::shared_ptr<const MarkerSet> markers;  ///< Default layout on the take's skeleton.
};

/// The shared data folder's Bandai takes (sorted), or empty if ../shared is absent.
/// MOCAPD_SHARED_DATA overrides the location of shared/data.
std::vector<std::string> SharedBvhTakes();

/// Loads a BVH take (or, for an empty path, 20 s of the humanoid's mixed motion) and
/// prepares it at rate_hz.
BenchTake LoadBenchTake(const std::string& bvh_path, double rate_hz);

/// The baselines' gap fill, offline over the whole take: each gap of each point filled
/// linearly, or by a cubic Hermite with Catmull-Rom slopes (cubic), between its ends;
/// a gap open at either end holds the nearest sample.
C3dTake FillGaps(const C3dTake& in, bool cubic);

/// Runs a benchmark's body and turns what it throws (a take that cannot be read, a bad
/// option value) into "PROGRAM: message" and exit status 1, not std::terminate.
int RunReportingErrors(const char* program, int (*body)(int, char**), int argc, char** argv);

}  // namespace mocapd::bench
