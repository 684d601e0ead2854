// libFuzzer entry point over the TOML files an operator writes: the daemon config (its
// subject models resolved against config/, so the demo subject loads) and marker sets.
// Any input must parse or throw std::runtime_error naming where it went wrong.
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "formats/marker_set.hpp"
#include "formats/toml_reader.hpp"
#include "runtime/daemon_config.hpp"

#ifndef MOCAPD_CONFIG_DIR
#error "MOCAPD_CONFIG_DIR must name the source tree's config/ directory"
#endif

namespace {
// Whether a string anywhere in the document (as TOML decodes it, escapes and all) could
// name a file outside config/ (an absolute path, or one climbing out with ".."): a device
// that never ends (/dev/zero) would hang the load. The config is the operator's, so only
// files under config/ are worth reading.
bool NamesAFileElsewhere(const toml::node& node) {
  if (const auto* text = node.as_string()) {
    const std::string& s = text->get();
    return (!s.empty() && s.front() == '/') || s.find("..") != std::string::npos;
  }
  bool elsewhere = false;
  if (const auto* table = node.as_table())
    for (const auto& [key, child] : *table) elsewhere = elsewhere || NamesAFileElsewhere(child);
  if (const auto* array = node.as_array())
    for (const toml::node& child : *array) elsewhere = elsewhere || NamesAFileElsewhere(child);
  return elsewhere;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    if (!NamesAFileElsewhere(mocapd::ParseToml(text, "fuzz"))) {
      const mocapd::DaemonConfig config =
          mocapd::ParseDaemonConfig(text, "fuzz", MOCAPD_CONFIG_DIR);
      for (const auto& subject : config.subjects) (void)mocapd::SubjectFingerprint(subject, config);
    }
  } catch (const std::runtime_error&) {
  }
  try {
    const mocapd::MarkerSetDefinition set = mocapd::ParseMarkerSet(text, "fuzz");
    for (const auto& marker : set.markers) (void)set.Find(marker.name);
  } catch (const std::runtime_error&) {
  }
  return 0;
}
