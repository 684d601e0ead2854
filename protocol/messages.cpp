// Encoding and bounds-checked decoding of the wire messages.
#include "protocol/messages.hpp"

#include <cmath>
#include <stdexcept>

#include "protocol/byte_io.hpp"

namespace mocapd::protocol {
namespace {

constexpr size_t kMarkerBytes = 13;  // x, y, z (f32) + flags (u8)
constexpr size_t kJointBytes = 16;   // quaternion w, x, y, z (f32)

// The payload size is patched in by FinishMessage once the payload is written, so it
// can never disagree with what was written.
void WriteHeader(ByteWriter& w, MessageType type) {
  w.WriteU32(kMagic);
  w.WriteU16(kVersion);
  w.WriteU16(static_cast<uint16_t>(type));
  w.WriteU32(0);  // payload size, patched
  w.WriteU32(0);  // reserved
}

void FinishMessage(std::vector<uint8_t>* out) {
  const auto payload = static_cast<uint32_t>(out->size() - kHeaderBytes);
  for (size_t i = 0; i < 4; ++i) (*out)[8 + i] = static_cast<uint8_t>(payload >> (8 * i));
}

void WriteSubject(ByteWriter& w, const std::string& subject) {
  if (subject.empty() || subject.size() > kMaxSubjectName)
    throw std::invalid_argument("protocol: subject name must be 1.." + std::to_string(kMaxSubjectName) + " bytes");
  w.WriteU8(static_cast<uint8_t>(subject.size()));
  w.WriteString(subject);
}

// Validates the header; on success the reader is positioned at the payload.
DecodeStatus ReadHeader(ByteReader& r, MessageType expected) {
  uint32_t magic = 0, payload = 0, reserved = 0;
  uint16_t version = 0, type = 0;
  if (!r.ReadU32(&magic) || !r.ReadU16(&version) || !r.ReadU16(&type) || !r.ReadU32(&payload) || !r.ReadU32(&reserved))
    return DecodeStatus::kTooShort;
  if (magic != kMagic) return DecodeStatus::kBadMagic;
  if (version != kVersion) return DecodeStatus::kUnsupportedVersion;
  if (type != static_cast<uint16_t>(expected)) return DecodeStatus::kWrongType;
  if (r.remaining() < payload) return DecodeStatus::kTooShort;
  if (r.remaining() != payload) return DecodeStatus::kSizeMismatch;
  return DecodeStatus::kOk;
}

DecodeStatus ReadSubject(ByteReader& r, std::string* subject) {
  uint8_t length = 0;
  if (!r.ReadU8(&length)) return DecodeStatus::kTooShort;
  if (length == 0 || length > kMaxSubjectName) return DecodeStatus::kBadSubjectName;
  if (!r.ReadString(length, subject)) return DecodeStatus::kTooShort;
  return DecodeStatus::kOk;
}

bool Finite(float v) { return std::isfinite(v); }

}  // namespace

const char* to_string(DecodeStatus status) {
  switch (status) {
    case DecodeStatus::kOk: return "ok";
    case DecodeStatus::kTooShort: return "too_short";
    case DecodeStatus::kBadMagic: return "bad_magic";
    case DecodeStatus::kUnsupportedVersion: return "unsupported_version";
    case DecodeStatus::kWrongType: return "wrong_type";
    case DecodeStatus::kSizeMismatch: return "size_mismatch";
    case DecodeStatus::kBadSubjectName: return "bad_subject_name";
    case DecodeStatus::kTooManyItems: return "too_many_items";
    case DecodeStatus::kNonFinite: return "non_finite";
  }
  return "?";
}

uint64_t NamesHash(std::span<const std::string> names) {
  uint64_t h = 1469598103934665603ull;  // FNV-1a offset basis
  for (const std::string& name : names) {
    for (char c : name) {
      h ^= static_cast<uint8_t>(c);
      h *= 1099511628211ull;
    }
    h *= 1099511628211ull;  // the zero separator
  }
  return h;
}

uint64_t MarkerSetHash(const MarkerSet& markers) {
  std::vector<std::string> names;
  for (const MarkerDefinition& m : markers.markers()) names.push_back(m.name);
  return NamesHash(names);
}

uint64_t SkeletonHash(const Skeleton& skeleton) {
  std::vector<std::string> names;
  for (const Joint& j : skeleton.joints()) names.push_back(j.name + "/" + std::to_string(j.parent.value));
  return NamesHash(names);
}

void EncodeMarkerFrame(const MarkerFrameMessage& m, std::vector<uint8_t>* out) {
  if (m.positions.size() > kMaxMarkers || m.valid.size() != m.positions.size())
    throw std::invalid_argument("protocol: marker frame with inconsistent or too many markers");
  out->clear();
  ByteWriter w(out);
  WriteHeader(w, MessageType::kMarkerFrame);
  WriteSubject(w, m.subject);
  w.WriteU64(m.model_hash);
  w.WriteU64(m.frame_number);
  w.WriteU64(m.capture_time_ns);
  w.WriteF32(m.rate_hz);
  w.WriteU16(static_cast<uint16_t>(m.positions.size()));
  w.WriteU16(0);
  for (size_t i = 0; i < m.positions.size(); ++i) {
    const bool valid = m.valid[i] && m.positions[i].allFinite();
    for (int k = 0; k < 3; ++k) w.WriteF32(valid ? static_cast<float>(m.positions[i][k]) : 0.0f);
    w.WriteU8(valid ? 1 : 0);
  }
  FinishMessage(out);
}

DecodeStatus DecodeMarkerFrame(std::span<const uint8_t> bytes, MarkerFrameMessage* m) {
  ByteReader r(bytes);
  if (const DecodeStatus s = ReadHeader(r, MessageType::kMarkerFrame); s != DecodeStatus::kOk) return s;
  if (const DecodeStatus s = ReadSubject(r, &m->subject); s != DecodeStatus::kOk) return s;
  uint16_t count = 0, reserved = 0;
  if (!r.ReadU64(&m->model_hash) || !r.ReadU64(&m->frame_number) || !r.ReadU64(&m->capture_time_ns) || !r.ReadF32(&m->rate_hz) ||
      !r.ReadU16(&count) || !r.ReadU16(&reserved))
    return DecodeStatus::kTooShort;
  if (!Finite(m->rate_hz) || !(m->rate_hz > 0.0f)) return DecodeStatus::kNonFinite;
  if (count > kMaxMarkers) return DecodeStatus::kTooManyItems;
  if (r.remaining() != kMarkerBytes * count) return DecodeStatus::kSizeMismatch;
  m->positions.resize(count);
  m->valid.resize(count);
  for (size_t i = 0; i < count; ++i) {
    float xyz[3];
    uint8_t flags = 0;
    if (!r.ReadF32(&xyz[0]) || !r.ReadF32(&xyz[1]) || !r.ReadF32(&xyz[2]) || !r.ReadU8(&flags)) return DecodeStatus::kTooShort;
    const bool valid = (flags & 1u) != 0;
    if (valid && !(Finite(xyz[0]) && Finite(xyz[1]) && Finite(xyz[2]))) return DecodeStatus::kNonFinite;
    m->valid[i] = valid;
    m->positions[i] = valid ? Vec3(xyz[0], xyz[1], xyz[2]) : Vec3::Constant(kNaN);
  }
  return DecodeStatus::kOk;
}

void EncodeSkeletonFrame(const SkeletonFrameMessage& m, std::vector<uint8_t>* out) {
  if (m.rotations.size() > kMaxJoints) throw std::invalid_argument("protocol: skeleton frame with too many joints");
  out->clear();
  ByteWriter w(out);
  WriteHeader(w, MessageType::kSkeletonFrame);
  WriteSubject(w, m.subject);
  w.WriteU64(m.model_hash);
  w.WriteU64(m.frame_number);
  w.WriteU64(m.capture_time_ns);
  w.WriteU64(m.publish_time_ns);
  w.WriteU8(m.status);
  w.WriteU8(0);  // flags, reserved
  w.WriteU16(static_cast<uint16_t>(m.rotations.size()));
  w.WriteF32(m.residual_m);
  for (int k = 0; k < 3; ++k) w.WriteF32(static_cast<float>(m.root_translation[k]));
  for (const Quat& q : m.rotations) {
    w.WriteF32(static_cast<float>(q.w()));
    w.WriteF32(static_cast<float>(q.x()));
    w.WriteF32(static_cast<float>(q.y()));
    w.WriteF32(static_cast<float>(q.z()));
  }
  FinishMessage(out);
}

DecodeStatus DecodeSkeletonFrame(std::span<const uint8_t> bytes, SkeletonFrameMessage* m) {
  ByteReader r(bytes);
  if (const DecodeStatus s = ReadHeader(r, MessageType::kSkeletonFrame); s != DecodeStatus::kOk) return s;
  if (const DecodeStatus s = ReadSubject(r, &m->subject); s != DecodeStatus::kOk) return s;
  uint8_t flags = 0;
  uint16_t count = 0;
  float root[3];
  if (!r.ReadU64(&m->model_hash) || !r.ReadU64(&m->frame_number) || !r.ReadU64(&m->capture_time_ns) || !r.ReadU64(&m->publish_time_ns) ||
      !r.ReadU8(&m->status) || !r.ReadU8(&flags) || !r.ReadU16(&count) || !r.ReadF32(&m->residual_m) || !r.ReadF32(&root[0]) ||
      !r.ReadF32(&root[1]) || !r.ReadF32(&root[2]))
    return DecodeStatus::kTooShort;
  if (count > kMaxJoints) return DecodeStatus::kTooManyItems;
  if (r.remaining() != kJointBytes * count) return DecodeStatus::kSizeMismatch;
  if (!(Finite(root[0]) && Finite(root[1]) && Finite(root[2]) && Finite(m->residual_m))) return DecodeStatus::kNonFinite;
  m->root_translation = Vec3(root[0], root[1], root[2]);
  m->rotations.resize(count);
  for (size_t i = 0; i < count; ++i) {
    float q[4];
    for (float& c : q)
      if (!r.ReadF32(&c)) return DecodeStatus::kTooShort;
    if (!(Finite(q[0]) && Finite(q[1]) && Finite(q[2]) && Finite(q[3]))) return DecodeStatus::kNonFinite;
    m->rotations[i] = Quat(q[0], q[1], q[2], q[3]);
  }
  return DecodeStatus::kOk;
}

DecodeStatus PeekType(std::span<const uint8_t> bytes, MessageType* type) {
  ByteReader r(bytes);
  uint32_t magic = 0;
  uint16_t version = 0, raw = 0;
  if (!r.ReadU32(&magic) || !r.ReadU16(&version) || !r.ReadU16(&raw)) return DecodeStatus::kTooShort;
  if (magic != kMagic) return DecodeStatus::kBadMagic;
  if (version != kVersion) return DecodeStatus::kUnsupportedVersion;
  if (raw != static_cast<uint16_t>(MessageType::kMarkerFrame) && raw != static_cast<uint16_t>(MessageType::kSkeletonFrame))
    return DecodeStatus::kWrongType;
  *type = static_cast<MessageType>(raw);
  return DecodeStatus::kOk;
}

}  // namespace mocapd::protocol
