// `mocapd demo`: the README's main job until the daemon lands. Synthesizes a take
// from the project's own humanoid and procedural motion, solves it frame by frame with
// the warm-started IK exactly as the live path will, and prints accuracy and speed.
#pragma once

#include <cstdint>
#include <ostream>
#include <string>

namespace mocapd {

struct DemoOptions {
  double seconds = 20.0;
  double rate_hz = 120.0;
  double noise_mm = 1.0;
  std::string motion = "mixed";
  uint64_t seed = 1;
};

/// Runs the demo, printing progress and a final table to out. Returns 0 on success.
int RunDemoCommand(const DemoOptions& options, std::ostream& out);

}  // namespace mocapd
