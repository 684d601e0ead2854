// libFuzzer entry point over the C3D reader: any input must parse or throw C3dError.
#include <cstddef>
#include <cstdint>
#include <span>

#include "formats/c3d.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    const mocapd::C3dTake take = mocapd::ParseC3d(std::span<const uint8_t>(data, size), "fuzz");
    // Touch what was read so the sanitizers see every sample.
    double sum = 0.0;
    for (const auto& p : take.positions)
      if (p.allFinite()) sum += p.sum();
    (void)sum;
  } catch (const mocapd::C3dError&) {
  }
  return 0;
}
