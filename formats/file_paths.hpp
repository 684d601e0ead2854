// Paths the readers and commands share: a whole file read with errors that name it, and
// the refusal, before any work, of an output that cannot be written or that names one of
// the command's inputs or another output (mocapd process / calibrate, mocap-sim synth / replay, the
// graph commands): a mistyped --out-c3d once replaced a raw capture with its cleaned copy, with
// exit status 0.
#pragma once

#include <span>
#include <string>

namespace mocapd {

/// The whole file's bytes. Throws std::runtime_error naming the path when it cannot be
/// opened or is a folder (which opens, and reads as nothing or as an error far from it:
/// `model = "/tmp"` was reported as a missing format_version).
std::string ReadWholeFile(const std::string& path);

/// A command-line path and the option that gave it, for messages.
struct NamedPath {
  std::string option;
  std::string path;
};

/// Throws std::runtime_error naming both options when an output is the same file as an
/// input or as an earlier output (".", "..", symbolic and hard links resolved), and naming
/// the option when an output cannot be written: its folder missing or read-only, or the
/// path itself a folder. Called before any work, so a long replay or calibration is not
/// run to fail at its end. Empty paths (an option not given) are skipped.
void CheckOutputPaths(std::span<const NamedPath> inputs, std::span<const NamedPath> outputs);

}  // namespace mocapd
