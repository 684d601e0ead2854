// libFuzzer entry point over every wire decoder: any input must decode or get a status.
#include <cstddef>
#include <cstdint>
#include <span>

#include "protocol/messages.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static mocapd::protocol::MarkerFrameMessage markers;
  static mocapd::protocol::SkeletonFrameMessage skeleton;
  static mocapd::protocol::SubjectDescriptionMessage description;
  static mocapd::protocol::CleanedMarkersMessage cleaned;
  static mocapd::protocol::SubjectStatusMessage status;
  static mocapd::protocol::EndOfStreamMessage end;
  static mocapd::protocol::CalibrationStatusMessage calibration;
  const std::span<const uint8_t> bytes(data, size);
  mocapd::protocol::MessageType type;
  (void)mocapd::protocol::PeekType(bytes, &type);
  (void)mocapd::protocol::DecodeMarkerFrame(bytes, &markers);
  (void)mocapd::protocol::DecodeSkeletonFrame(bytes, &skeleton);
  (void)mocapd::protocol::DecodeSubjectDescription(bytes, &description);
  (void)mocapd::protocol::DecodeCleanedMarkers(bytes, &cleaned);
  (void)mocapd::protocol::DecodeSubjectStatus(bytes, &status);
  (void)mocapd::protocol::DecodeEndOfStream(bytes, &end);
  (void)mocapd::protocol::DecodeCalibrationStatus(bytes, &calibration);
  return 0;
}
