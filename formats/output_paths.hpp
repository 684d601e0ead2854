// The commands that read takes and write results (mocapd process / calibrate, mocap-sim
// synth / replay / record, the graph commands) refuse, before any work, an output that
// names one of their inputs or another output: a mistyped --out-c3d once replaced a raw
// capture with its cleaned copy, with exit status 0.
#pragma once

#include <span>
#include <string>

namespace mocapd {

/// A command-line path and the option that gave it, for messages.
struct NamedPath {
  std::string option;
  std::string path;
};

/// Throws std::runtime_error naming both options when an output is the same file as an
/// input or as an earlier output (".", "..", symbolic and hard links resolved). Empty paths
/// (an option not given) are skipped.
void RefuseOutputsOverInputs(std::span<const NamedPath> inputs, std::span<const NamedPath> outputs);

}  // namespace mocapd
