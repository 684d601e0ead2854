// The mocapd wire format (documented byte by byte in protocol/README.md): a 16-byte
// versioned header and little-endian payloads for marker frames in and skeleton frames
// out. Encoding writes into a caller-owned buffer; decoding is bounds-checked, never
// throws and never allocates beyond the caller's message storage (sized once), and
// reports a status for every way a message can be malformed.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "filters/marker_model.hpp"

namespace mocapd::protocol {

inline constexpr uint32_t kMagic = 0x4450434d;  // "MCPD" in little-endian byte order
inline constexpr uint16_t kVersion = 1;
inline constexpr size_t kHeaderBytes = 16;
inline constexpr size_t kMaxSubjectName = 63;
inline constexpr size_t kMaxMarkers = 1024;
inline constexpr size_t kMaxJoints = 512;

enum class MessageType : uint16_t { kMarkerFrame = 2, kSkeletonFrame = 3 };

enum class DecodeStatus {
  kOk,
  kTooShort,         ///< Fewer bytes than the header or the payload needs.
  kBadMagic,
  kUnsupportedVersion,
  kWrongType,        ///< A valid message, but not the type asked for.
  kSizeMismatch,     ///< The header's payload size disagrees with the bytes or the counts.
  kBadSubjectName,   ///< Empty or longer than kMaxSubjectName.
  kTooManyItems,     ///< More markers or joints than the limits.
  kNonFinite,        ///< NaN or Inf where a number must be finite.
};
const char* to_string(DecodeStatus status);

/// Returns the 64-bit FNV-1a hash of the names in order (each followed by a zero byte):
/// the model hash that ties a frame to the marker set or skeleton it was made for.
uint64_t NamesHash(std::span<const std::string> names);
uint64_t MarkerSetHash(const MarkerSet& markers);
uint64_t SkeletonHash(const Skeleton& skeleton);

struct MarkerFrameMessage {
  std::string subject;
  uint64_t model_hash = 0;
  uint64_t frame_number = 0;
  uint64_t capture_time_ns = 0;
  float rate_hz = 0.0f;
  std::vector<Vec3> positions;  ///< Metres; NaN where invalid.
  std::vector<uint8_t> valid;
};

struct SkeletonFrameMessage {
  std::string subject;
  uint64_t model_hash = 0;
  uint64_t frame_number = 0;
  uint64_t capture_time_ns = 0;
  uint64_t publish_time_ns = 0;
  uint8_t status = 0;  ///< IkStatus of the final solve.
  float residual_m = 0.0f;
  Vec3 root_translation = Vec3::Zero();
  std::vector<Quat> rotations;  ///< Local joint rotations (R_PJ).
};

/// Appends the encoded message to out (cleared first). Never fails for messages within
/// the limits; throws std::invalid_argument otherwise (a programming error upstream).
void EncodeMarkerFrame(const MarkerFrameMessage& message, std::vector<uint8_t>* out);
void EncodeSkeletonFrame(const SkeletonFrameMessage& message, std::vector<uint8_t>* out);

/// Reads the message type after validating the header. Returns kOk and sets type.
DecodeStatus PeekType(std::span<const uint8_t> bytes, MessageType* type);
/// Decodes into message, reusing its storage (no allocation once it has held a message
/// of this size). On any status but kOk, message is unspecified.
DecodeStatus DecodeMarkerFrame(std::span<const uint8_t> bytes, MarkerFrameMessage* message);
DecodeStatus DecodeSkeletonFrame(std::span<const uint8_t> bytes, SkeletonFrameMessage* message);

}  // namespace mocapd::protocol
