// libFuzzer entry point over every wire decoder: any input must decode or get a status.
#include <cstddef>
#include <cstdint>
#include <span>

#include "protocol/messages.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static mocapd::protocol::MarkerFrameMessage markers;
  static mocapd::protocol::SkeletonFrameMessage skeleton;
  const std::span<const uint8_t> bytes(data, size);
  mocapd::protocol::MessageType type;
  (void)mocapd::protocol::PeekType(bytes, &type);
  (void)mocapd::protocol::DecodeMarkerFrame(bytes, &markers);
  (void)mocapd::protocol::DecodeSkeletonFrame(bytes, &skeleton);
  return 0;
}
