// libFuzzer entry point over the TOML files an operator writes: the daemon config (its
// subject models resolved against config/, so the demo subject loads) and marker sets.
// Any input must parse or throw std::runtime_error naming where it went wrong.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "formats/marker_set.hpp"
#include "runtime/daemon_config.hpp"

#ifndef MOCAPD_CONFIG_DIR
#error "MOCAPD_CONFIG_DIR must name the source tree's config/ directory"
#endif

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  // A subject path from the input could name a device that never ends (/dev/zero): the
  // config is the operator's, so only files under config/ are worth loading here.
  if (text.find("/dev") != std::string::npos || text.find("/proc") != std::string::npos) return 0;
  try {
    const mocapd::DaemonConfig config = mocapd::ParseDaemonConfig(text, "fuzz", MOCAPD_CONFIG_DIR);
    for (const auto& subject : config.subjects) (void)mocapd::SubjectFingerprint(subject, config);
  } catch (const std::runtime_error&) {
  }
  try {
    const mocapd::MarkerSetDefinition set = mocapd::ParseMarkerSet(text, "fuzz");
    for (const auto& marker : set.markers) (void)set.Find(marker.name);
  } catch (const std::runtime_error&) {
  }
  return 0;
}
