// libFuzzer entry point over the BVH reader: any input must parse or throw BvhError.
#include <cstddef>
#include <cstdint>
#include <string>

#include "formats/bvh.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    const mocapd::BvhTake take =
        mocapd::ParseBvh(std::string(reinterpret_cast<const char*>(data), size), "fuzz");
    (void)mocapd::FormatBvh(take);
  } catch (const mocapd::BvhError&) {
  }
  return 0;
}
