// Encoding and bounds-checked decoding of the wire messages.
#include "protocol/messages.hpp"

#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include "protocol/byte_io.hpp"

namespace mocapd::protocol {
namespace {

constexpr size_t kMarkerBytes = 13;         // x, y, z (f32) + flags (u8)
constexpr size_t kJointBytes = 16;          // quaternion w, x, y, z (f32)
constexpr size_t kGlobalJointBytes = 28;    // quaternion (4 x f32) + position (3 x f32)
constexpr uint8_t kMaxSolveStatus = 3;      // IkStatus::kNumericalFailure
constexpr size_t kCleanedMarkerBytes = 14;  // x, y, z (f32) + status (u8) + reason (u8)
constexpr uint16_t kFlagGlobalTransforms = 1;
constexpr uint8_t kMaxMaskReason = 10;  // MaskReason::kTrimmed
constexpr uint8_t kTimecodePresent = 1;
constexpr uint8_t kTimecodeDropFrame = 2;

bool KnownVersion(uint16_t version) { return version == kVersion1 || version == kVersion2; }

// The payload size is patched in by FinishMessage once the payload is written, so it
// can never disagree with what was written.
void WriteHeader(ByteWriter& w, MessageType type, uint16_t version) {
  if (!KnownVersion(version))
    throw std::invalid_argument("protocol: cannot encode version " + std::to_string(version));
  w.WriteU32(kMagic);
  w.WriteU16(version);
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
    throw std::invalid_argument("protocol: subject name must be 1.." +
                                std::to_string(kMaxSubjectName) + " bytes");
  w.WriteU8(static_cast<uint8_t>(subject.size()));
  w.WriteString(subject);
}

// Validates the header; on success the reader is positioned at the payload.
DecodeStatus ReadHeader(ByteReader& r, MessageType expected, uint16_t* version_out) {
  uint32_t magic = 0, payload = 0, reserved = 0;
  uint16_t version = 0, type = 0;
  if (!r.ReadU32(&magic) || !r.ReadU16(&version) || !r.ReadU16(&type) || !r.ReadU32(&payload) ||
      !r.ReadU32(&reserved))
    return DecodeStatus::kTooShort;
  if (magic != kMagic) return DecodeStatus::kBadMagic;
  if (!KnownVersion(version)) return DecodeStatus::kUnsupportedVersion;
  if (type != static_cast<uint16_t>(expected)) return DecodeStatus::kWrongType;
  *version_out = version;
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

// Every message starts with the header and the subject name.
DecodeStatus ReadPrelude(ByteReader& r, MessageType type, uint16_t* version, std::string* subject) {
  if (const DecodeStatus s = ReadHeader(r, type, version); s != DecodeStatus::kOk) return s;
  return ReadSubject(r, subject);
}

// Version 2's stream block; a field outside its range is a bad field, so a consumer can
// trust a timecode it is handed.
void WriteStream(ByteWriter& w, const StreamInfo& stream) {
  w.WriteU64(stream.session_id);
  w.WriteU32(stream.rate_numerator);
  w.WriteU32(stream.rate_denominator);
  const Timecode tc = stream.has_timecode ? stream.timecode : Timecode{};
  w.WriteU8(tc.hours);
  w.WriteU8(tc.minutes);
  w.WriteU8(tc.seconds);
  w.WriteU8(tc.frames);
  w.WriteU8(tc.subframe);
  w.WriteU8(stream.has_timecode
                ? static_cast<uint8_t>(kTimecodePresent | (tc.drop_frame ? kTimecodeDropFrame : 0))
                : 0);
  w.WriteU16(tc.rate);
}

bool ValidTimecode(const Timecode& tc) {
  // Drop-frame counting exists only for the NTSC rates (29.97 and its multiples).
  return tc.rate > 0 && tc.hours < 24 && tc.minutes < 60 && tc.seconds < 60 &&
         tc.frames < tc.rate && (!tc.drop_frame || tc.rate % 30 == 0);
}

DecodeStatus ReadStream(ByteReader& r, float rate_hz, StreamInfo* stream) {
  uint8_t flags = 0;
  Timecode& tc = stream->timecode;
  if (!r.ReadU64(&stream->session_id) || !r.ReadU32(&stream->rate_numerator) ||
      !r.ReadU32(&stream->rate_denominator) || !r.ReadU8(&tc.hours) || !r.ReadU8(&tc.minutes) ||
      !r.ReadU8(&tc.seconds) || !r.ReadU8(&tc.frames) || !r.ReadU8(&tc.subframe) ||
      !r.ReadU8(&flags) || !r.ReadU16(&tc.rate))
    return DecodeStatus::kTooShort;
  if ((flags & ~(kTimecodePresent | kTimecodeDropFrame)) != 0) return DecodeStatus::kBadField;
  stream->has_timecode = (flags & kTimecodePresent) != 0;
  tc.drop_frame = (flags & kTimecodeDropFrame) != 0;
  if (stream->has_timecode ? !ValidTimecode(tc) : flags != 0) return DecodeStatus::kBadField;
  if (!stream->has_timecode) tc = Timecode{};
  if ((stream->rate_numerator == 0) != (stream->rate_denominator == 0))
    return DecodeStatus::kBadField;
  // The fraction is the exact rate, the float its rounding: they must agree.
  if (stream->rate_numerator != 0 && rate_hz > 0.0f) {
    const double exact = static_cast<double>(stream->rate_numerator) / stream->rate_denominator;
    if (std::abs(exact - rate_hz) > 1e-4 * exact) return DecodeStatus::kBadField;
  }
  return DecodeStatus::kOk;
}

// What follows the fixed fields of a frame: the stream block in version 2, then
// item_bytes of per-item arrays, exactly. rate_hz: the frame's own rate (0 if it has none).
// A version 2 frame that fails before its stream block is read (its size, its item count)
// still names its session, the block's first field, when the bytes are there: dropped, it
// is then known as this session's frame (not one of another stream), and the gap it leaves
// is not counted again as frames lost before the daemon.
void PeekSessionId(ByteReader r, uint16_t version, StreamInfo* stream) {
  uint64_t session_id = 0;
  if (version >= kVersion2 && r.ReadU64(&session_id)) stream->session_id = session_id;
}

DecodeStatus ReadStreamAndSize(ByteReader& r, uint16_t version, size_t item_bytes, float rate_hz,
                               StreamInfo* stream) {
  const size_t stream_bytes = version >= kVersion2 ? kStreamBlockBytes : 0;
  *stream = StreamInfo{};
  if (r.remaining() != stream_bytes + item_bytes) {
    PeekSessionId(r, version, stream);
    return DecodeStatus::kSizeMismatch;
  }
  return stream_bytes != 0 ? ReadStream(r, rate_hz, stream) : DecodeStatus::kOk;
}

bool Finite(float v) { return std::isfinite(v); }

void WriteQuat(ByteWriter& w, const Quat& q) {
  w.WriteF32(static_cast<float>(q.w()));
  w.WriteF32(static_cast<float>(q.x()));
  w.WriteF32(static_cast<float>(q.y()));
  w.WriteF32(static_cast<float>(q.z()));
}

void WriteVec3(ByteWriter& w, const Vec3& v) {
  for (int k = 0; k < 3; ++k) w.WriteF32(static_cast<float>(v[k]));
}

// Reads n finite floats; kTooShort or kNonFinite otherwise.
DecodeStatus ReadFinite(ByteReader& r, float* values, int n) {
  for (int i = 0; i < n; ++i) {
    if (!r.ReadF32(&values[i])) return DecodeStatus::kTooShort;
    if (!Finite(values[i])) return DecodeStatus::kNonFinite;
  }
  return DecodeStatus::kOk;
}

DecodeStatus ReadQuat(ByteReader& r, Quat* q) {
  float c[4];
  if (const DecodeStatus s = ReadFinite(r, c, 4); s != DecodeStatus::kOk) return s;
  *q = Quat(c[0], c[1], c[2], c[3]);
  return DecodeStatus::kOk;
}

DecodeStatus ReadVec3(ByteReader& r, Vec3* v) {
  float c[3];
  if (const DecodeStatus s = ReadFinite(r, c, 3); s != DecodeStatus::kOk) return s;
  *v = Vec3(c[0], c[1], c[2]);
  return DecodeStatus::kOk;
}

// Marker and joint names follow the subject-name rule: 1..63 bytes after a u8 length.
DecodeStatus ReadName(ByteReader& r, std::string* name) {
  const DecodeStatus s = ReadSubject(r, name);
  return s == DecodeStatus::kBadSubjectName ? DecodeStatus::kBadField : s;
}

void WriteName(ByteWriter& w, const std::string& name) {
  if (name.empty() || name.size() > kMaxSubjectName)
    throw std::invalid_argument("protocol: marker and joint names must be 1.." +
                                std::to_string(kMaxSubjectName) + " bytes: '" + name + "'");
  w.WriteU8(static_cast<uint8_t>(name.size()));
  w.WriteString(name);
}

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
    case DecodeStatus::kBadField: return "bad_field";
  }
  return "?";
}

const char* to_string(SubjectState state) {
  switch (state) {
    case SubjectState::kTracking: return "tracking";
    case SubjectState::kRepairing: return "repairing";
    case SubjectState::kLost: return "lost";
    case SubjectState::kStalled: return "stalled";
    case SubjectState::kWaiting: return "waiting";
  }
  return "?";
}

std::string FormatTimecode(const Timecode& tc) {
  char text[32];
  std::snprintf(text, sizeof text, "%02u:%02u:%02u%c%02u", unsigned{tc.hours}, unsigned{tc.minutes},
                unsigned{tc.seconds}, tc.drop_frame ? ';' : ':', unsigned{tc.frames});
  std::string out = text;
  if (tc.subframe != 0) out += "." + std::to_string(tc.subframe);
  return out;
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
  for (const Joint& j : skeleton.joints())
    names.push_back(j.name + "/" + std::to_string(j.parent.value));
  return NamesHash(names);
}

void EncodeMarkerFrame(const MarkerFrameMessage& m, std::vector<uint8_t>* out) {
  if (m.positions.size() > kMaxMarkers || m.valid.size() != m.positions.size())
    throw std::invalid_argument("protocol: marker frame with inconsistent or too many markers");
  out->clear();
  ByteWriter w(out);
  WriteHeader(w, MessageType::kMarkerFrame, m.version);
  WriteSubject(w, m.subject);
  w.WriteU64(m.model_hash);
  w.WriteU64(m.frame_number);
  w.WriteU64(m.capture_time_ns);
  w.WriteF32(m.rate_hz);
  w.WriteU16(static_cast<uint16_t>(m.positions.size()));
  w.WriteU16(0);
  if (m.version >= kVersion2) WriteStream(w, m.stream);
  for (size_t i = 0; i < m.positions.size(); ++i) {
    const bool valid = m.valid[i] && m.positions[i].allFinite();
    for (int k = 0; k < 3; ++k) w.WriteF32(valid ? static_cast<float>(m.positions[i][k]) : 0.0f);
    w.WriteU8(valid ? 1 : 0);
  }
  FinishMessage(out);
}

DecodeStatus DecodeMarkerFrame(std::span<const uint8_t> bytes, MarkerFrameMessage* m) {
  ByteReader r(bytes);
  m->frame_number = 0;
  m->stream = StreamInfo{};
  if (const DecodeStatus s = ReadPrelude(r, MessageType::kMarkerFrame, &m->version, &m->subject);
      s != DecodeStatus::kOk) {
    m->subject.clear();
    return s;
  }
  uint16_t count = 0, reserved = 0;
  if (!r.ReadU64(&m->model_hash) || !r.ReadU64(&m->frame_number) ||
      !r.ReadU64(&m->capture_time_ns) || !r.ReadF32(&m->rate_hz) || !r.ReadU16(&count) ||
      !r.ReadU16(&reserved))
    return DecodeStatus::kTooShort;
  if (count > kMaxMarkers) {
    PeekSessionId(r, m->version, &m->stream);
    return DecodeStatus::kTooManyItems;
  }
  // The stream block is read before the rate is judged, so a frame dropped for its rate is
  // known by its session too (and not counted again as a skipped number).
  const bool rate_ok = Finite(m->rate_hz) && m->rate_hz > 0.0f;
  if (const DecodeStatus s = ReadStreamAndSize(r, m->version, kMarkerBytes * count,
                                               rate_ok ? m->rate_hz : 0.0f, &m->stream);
      s != DecodeStatus::kOk)
    return s;
  if (!rate_ok) return DecodeStatus::kNonFinite;
  m->positions.resize(count);
  m->valid.resize(count);
  for (size_t i = 0; i < count; ++i) {
    float xyz[3];
    uint8_t flags = 0;
    if (!r.ReadF32(&xyz[0]) || !r.ReadF32(&xyz[1]) || !r.ReadF32(&xyz[2]) || !r.ReadU8(&flags))
      return DecodeStatus::kTooShort;
    const bool valid = (flags & 1u) != 0;
    if (valid && !(Finite(xyz[0]) && Finite(xyz[1]) && Finite(xyz[2])))
      return DecodeStatus::kNonFinite;
    m->valid[i] = valid;
    m->positions[i] = valid ? Vec3(xyz[0], xyz[1], xyz[2]) : Vec3::Constant(kNaN);
  }
  return DecodeStatus::kOk;
}

void EncodeSkeletonFrame(const SkeletonFrameMessage& m, std::vector<uint8_t>* out) {
  const bool globals = !m.global_rotations.empty();
  if (m.rotations.size() > kMaxJoints)
    throw std::invalid_argument("protocol: skeleton frame with too many joints");
  if (globals && (m.global_rotations.size() != m.rotations.size() ||
                  m.global_positions.size() != m.rotations.size()))
    throw std::invalid_argument(
        "protocol: skeleton frame with global transforms for some joints only");
  out->clear();
  ByteWriter w(out);
  WriteHeader(w, MessageType::kSkeletonFrame, m.version);
  WriteSubject(w, m.subject);
  w.WriteU64(m.model_hash);
  w.WriteU64(m.frame_number);
  w.WriteU64(m.capture_time_ns);
  w.WriteU64(m.publish_time_ns);
  w.WriteU8(m.status);
  w.WriteU8(static_cast<uint8_t>(m.subject_state));
  w.WriteU16(globals ? kFlagGlobalTransforms : 0);
  w.WriteU16(static_cast<uint16_t>(m.rotations.size()));
  w.WriteU16(0);  // reserved
  if (m.version >= kVersion2) WriteStream(w, m.stream);
  w.WriteF32(m.residual_m);
  WriteVec3(w, m.root_translation);
  for (const Quat& q : m.rotations) WriteQuat(w, q);
  if (globals) {
    for (size_t j = 0; j < m.rotations.size(); ++j) {
      WriteQuat(w, m.global_rotations[j]);
      WriteVec3(w, m.global_positions[j]);
    }
  }
  FinishMessage(out);
}

DecodeStatus DecodeSkeletonFrame(std::span<const uint8_t> bytes, SkeletonFrameMessage* m) {
  ByteReader r(bytes);
  if (const DecodeStatus s = ReadPrelude(r, MessageType::kSkeletonFrame, &m->version, &m->subject);
      s != DecodeStatus::kOk)
    return s;
  uint8_t state = 0;
  uint16_t flags = 0, count = 0, reserved = 0;
  if (!r.ReadU64(&m->model_hash) || !r.ReadU64(&m->frame_number) ||
      !r.ReadU64(&m->capture_time_ns) || !r.ReadU64(&m->publish_time_ns) || !r.ReadU8(&m->status) ||
      !r.ReadU8(&state) || !r.ReadU16(&flags) || !r.ReadU16(&count) || !r.ReadU16(&reserved))
    return DecodeStatus::kTooShort;
  if (m->status > kMaxSolveStatus || state > static_cast<uint8_t>(SubjectState::kWaiting) ||
      (flags & ~kFlagGlobalTransforms) != 0)
    return DecodeStatus::kBadField;
  m->subject_state = static_cast<SubjectState>(state);
  if (count > kMaxJoints) return DecodeStatus::kTooManyItems;
  const bool globals = (flags & kFlagGlobalTransforms) != 0;
  const size_t item_bytes = 16 + (kJointBytes + (globals ? kGlobalJointBytes : 0)) * count;
  if (const DecodeStatus s = ReadStreamAndSize(r, m->version, item_bytes, 0.0f, &m->stream);
      s != DecodeStatus::kOk)
    return s;
  if (!r.ReadF32(&m->residual_m)) return DecodeStatus::kTooShort;
  if (!Finite(m->residual_m)) return DecodeStatus::kNonFinite;
  if (const DecodeStatus s = ReadVec3(r, &m->root_translation); s != DecodeStatus::kOk) return s;
  m->rotations.resize(count);
  for (Quat& q : m->rotations)
    if (const DecodeStatus s = ReadQuat(r, &q); s != DecodeStatus::kOk) return s;
  m->global_rotations.resize(globals ? count : 0);
  m->global_positions.resize(globals ? count : 0);
  for (size_t j = 0; j < m->global_rotations.size(); ++j) {
    if (const DecodeStatus s = ReadQuat(r, &m->global_rotations[j]); s != DecodeStatus::kOk)
      return s;
    if (const DecodeStatus s = ReadVec3(r, &m->global_positions[j]); s != DecodeStatus::kOk)
      return s;
  }
  return DecodeStatus::kOk;
}

std::string PrintableName(std::string_view name) {
  // JSON's escapes for control characters and U+FFFD for bytes that are no UTF-8: a
  // sender's name must neither end a log line early (a forged line after it), nor move a
  // terminal's cursor, nor be invalid text.
  const std::string quoted = nlohmann::json(std::string(name))
                                 .dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  return quoted.substr(1, quoted.size() - 2);
}

bool CaptureRateAccepted(double frame_hz, double subject_hz) {
  const auto near = [frame_hz](double hz) { return std::abs(frame_hz - hz) <= 1e-3 * hz; };
  const double ntsc_hz = subject_hz * 1000.0 / 1001.0, nominal_hz = subject_hz * 1001.0 / 1000.0;
  const bool configured_ntsc = std::abs(subject_hz - std::round(subject_hz)) > 1e-4 * subject_hz &&
                               std::abs(nominal_hz - std::round(nominal_hz)) <= 1e-4 * nominal_hz;
  return near(subject_hz) || near(ntsc_hz) || (configured_ntsc && near(nominal_hz));
}

SubjectDescriptionMessage DescribeSubject(const std::string& subject, const Skeleton& skeleton,
                                          const MarkerSet& markers, float rate_hz,
                                          int lookahead_frames) {
  SubjectDescriptionMessage d;
  d.subject = subject;
  d.marker_set_hash = MarkerSetHash(markers);
  d.skeleton_hash = SkeletonHash(skeleton);
  d.rate_hz = rate_hz;
  d.lookahead_frames = static_cast<uint16_t>(lookahead_frames);
  for (const MarkerDefinition& m : markers.markers()) d.marker_names.push_back(m.name);
  for (const Joint& j : skeleton.joints()) {
    d.joint_names.push_back(j.name);
    d.joint_parents.push_back(static_cast<int16_t>(j.parent.is_valid() ? j.parent.value : -1));
    d.rest_offsets.push_back(j.offset);
    d.rest_rotations.push_back(j.rest_rotation);
  }
  return d;
}

void EncodeSubjectDescription(const SubjectDescriptionMessage& m, std::vector<uint8_t>* out) {
  const size_t joints = m.joint_names.size();
  if (m.marker_names.size() > kMaxMarkers || joints > kMaxJoints ||
      m.joint_parents.size() != joints || m.rest_offsets.size() != joints ||
      m.rest_rotations.size() != joints)
    throw std::invalid_argument(
        "protocol: subject description with inconsistent or too many markers/joints");
  out->clear();
  ByteWriter w(out);
  WriteHeader(w, MessageType::kSubjectDescription, m.version);
  WriteSubject(w, m.subject);
  w.WriteU64(m.marker_set_hash);
  w.WriteU64(m.skeleton_hash);
  w.WriteF32(m.rate_hz);
  w.WriteU16(m.lookahead_frames);
  w.WriteU16(static_cast<uint16_t>(m.marker_names.size()));
  w.WriteU16(static_cast<uint16_t>(joints));
  w.WriteU16(0);  // reserved
  for (const std::string& name : m.marker_names) WriteName(w, name);
  for (size_t j = 0; j < joints; ++j) {
    WriteName(w, m.joint_names[j]);
    w.WriteI16(m.joint_parents[j]);
    WriteVec3(w, m.rest_offsets[j]);
    WriteQuat(w, m.rest_rotations[j]);
  }
  FinishMessage(out);
}

DecodeStatus DecodeSubjectDescription(std::span<const uint8_t> bytes,
                                      SubjectDescriptionMessage* m) {
  ByteReader r(bytes);
  if (const DecodeStatus s =
          ReadPrelude(r, MessageType::kSubjectDescription, &m->version, &m->subject);
      s != DecodeStatus::kOk)
    return s;
  uint16_t markers = 0, joints = 0, reserved = 0;
  if (!r.ReadU64(&m->marker_set_hash) || !r.ReadU64(&m->skeleton_hash) || !r.ReadF32(&m->rate_hz) ||
      !r.ReadU16(&m->lookahead_frames) || !r.ReadU16(&markers) || !r.ReadU16(&joints) ||
      !r.ReadU16(&reserved))
    return DecodeStatus::kTooShort;
  if (!Finite(m->rate_hz) || !(m->rate_hz > 0.0f)) return DecodeStatus::kNonFinite;
  if (markers > kMaxMarkers || joints > kMaxJoints) return DecodeStatus::kTooManyItems;
  // Each name takes at least 2 bytes and each joint 30 more: refuse counts the bytes cannot
  // hold before sizing anything by them.
  if (r.remaining() < 2u * markers + 32u * joints) return DecodeStatus::kSizeMismatch;
  m->marker_names.resize(markers);
  for (std::string& name : m->marker_names)
    if (const DecodeStatus s = ReadName(r, &name); s != DecodeStatus::kOk) return s;
  m->joint_names.resize(joints);
  m->joint_parents.resize(joints);
  m->rest_offsets.resize(joints);
  m->rest_rotations.resize(joints);
  for (size_t j = 0; j < joints; ++j) {
    if (const DecodeStatus s = ReadName(r, &m->joint_names[j]); s != DecodeStatus::kOk) return s;
    if (!r.ReadI16(&m->joint_parents[j])) return DecodeStatus::kTooShort;
    const int parent = m->joint_parents[j];
    // Parents first, exactly one root (joint 0).
    if ((j == 0) != (parent == -1) || parent >= static_cast<int>(j) || parent < -1)
      return DecodeStatus::kBadField;
    if (const DecodeStatus s = ReadVec3(r, &m->rest_offsets[j]); s != DecodeStatus::kOk) return s;
    if (const DecodeStatus s = ReadQuat(r, &m->rest_rotations[j]); s != DecodeStatus::kOk) return s;
  }
  if (r.remaining() != 0) return DecodeStatus::kSizeMismatch;
  return DecodeStatus::kOk;
}

void EncodeCleanedMarkers(const CleanedMarkersMessage& m, std::vector<uint8_t>* out) {
  if (m.positions.size() > kMaxMarkers || m.status.size() != m.positions.size() ||
      m.reason.size() != m.positions.size())
    throw std::invalid_argument("protocol: cleaned markers with inconsistent or too many markers");
  out->clear();
  ByteWriter w(out);
  WriteHeader(w, MessageType::kCleanedMarkers, m.version);
  WriteSubject(w, m.subject);
  w.WriteU64(m.model_hash);
  w.WriteU64(m.frame_number);
  w.WriteU64(m.capture_time_ns);
  w.WriteU64(m.publish_time_ns);
  w.WriteU16(static_cast<uint16_t>(m.positions.size()));
  w.WriteU16(0);  // reserved
  if (m.version >= kVersion2) WriteStream(w, m.stream);
  for (size_t i = 0; i < m.positions.size(); ++i) {
    // An unrecoverable sample has no position: zeros on the wire, NaN once decoded.
    const bool known = m.status[i] != 2 && m.positions[i].allFinite();
    WriteVec3(w, known ? m.positions[i] : Vec3::Zero());
    w.WriteU8(known ? m.status[i] : 2);
    w.WriteU8(known ? m.reason[i] : 0);
  }
  FinishMessage(out);
}

DecodeStatus DecodeCleanedMarkers(std::span<const uint8_t> bytes, CleanedMarkersMessage* m) {
  ByteReader r(bytes);
  if (const DecodeStatus s = ReadPrelude(r, MessageType::kCleanedMarkers, &m->version, &m->subject);
      s != DecodeStatus::kOk)
    return s;
  uint16_t count = 0, reserved = 0;
  if (!r.ReadU64(&m->model_hash) || !r.ReadU64(&m->frame_number) ||
      !r.ReadU64(&m->capture_time_ns) || !r.ReadU64(&m->publish_time_ns) || !r.ReadU16(&count) ||
      !r.ReadU16(&reserved))
    return DecodeStatus::kTooShort;
  if (count > kMaxMarkers) return DecodeStatus::kTooManyItems;
  if (const DecodeStatus s =
          ReadStreamAndSize(r, m->version, kCleanedMarkerBytes * count, 0.0f, &m->stream);
      s != DecodeStatus::kOk)
    return s;
  m->positions.resize(count);
  m->status.resize(count);
  m->reason.resize(count);
  for (size_t i = 0; i < count; ++i) {
    Vec3 p;
    if (const DecodeStatus s = ReadVec3(r, &p); s != DecodeStatus::kOk) return s;
    if (!r.ReadU8(&m->status[i]) || !r.ReadU8(&m->reason[i])) return DecodeStatus::kTooShort;
    if (m->status[i] > 2 || m->reason[i] > kMaxMaskReason) return DecodeStatus::kBadField;
    m->positions[i] = m->status[i] == 2 ? Vec3::Constant(kNaN) : p;
  }
  return DecodeStatus::kOk;
}

void EncodeSubjectStatus(const SubjectStatusMessage& m, std::vector<uint8_t>* out) {
  out->clear();
  ByteWriter w(out);
  WriteHeader(w, MessageType::kSubjectStatus, m.version);
  WriteSubject(w, m.subject);
  w.WriteU8(static_cast<uint8_t>(m.state));
  w.WriteU8(m.problems);
  w.WriteU16(0);  // reserved
  w.WriteU64(m.last_frame_number);
  w.WriteU64(m.since_last_input_ns);
  w.WriteU64(m.frames_in);
  w.WriteU64(m.frames_out);
  w.WriteU64(m.frames_dropped);
  FinishMessage(out);
}

DecodeStatus DecodeSubjectStatus(std::span<const uint8_t> bytes, SubjectStatusMessage* m) {
  ByteReader r(bytes);
  if (const DecodeStatus s = ReadPrelude(r, MessageType::kSubjectStatus, &m->version, &m->subject);
      s != DecodeStatus::kOk)
    return s;
  uint8_t state = 0;
  uint16_t reserved16 = 0;
  if (!r.ReadU8(&state) || !r.ReadU8(&m->problems) || !r.ReadU16(&reserved16) ||
      !r.ReadU64(&m->last_frame_number) || !r.ReadU64(&m->since_last_input_ns) ||
      !r.ReadU64(&m->frames_in) || !r.ReadU64(&m->frames_out) || !r.ReadU64(&m->frames_dropped))
    return DecodeStatus::kTooShort;
  if (r.remaining() != 0) return DecodeStatus::kSizeMismatch;
  if (state > static_cast<uint8_t>(SubjectState::kWaiting)) return DecodeStatus::kBadField;
  m->state = static_cast<SubjectState>(state);
  return DecodeStatus::kOk;
}

void EncodeEndOfStream(const EndOfStreamMessage& m, std::vector<uint8_t>* out) {
  out->clear();
  ByteWriter w(out);
  WriteHeader(w, MessageType::kEndOfStream, m.version);
  WriteSubject(w, m.subject);
  w.WriteU64(m.last_frame_number);
  FinishMessage(out);
}

DecodeStatus DecodeEndOfStream(std::span<const uint8_t> bytes, EndOfStreamMessage* m) {
  ByteReader r(bytes);
  if (const DecodeStatus s = ReadPrelude(r, MessageType::kEndOfStream, &m->version, &m->subject);
      s != DecodeStatus::kOk)
    return s;
  if (!r.ReadU64(&m->last_frame_number)) return DecodeStatus::kTooShort;
  if (r.remaining() != 0) return DecodeStatus::kSizeMismatch;
  return DecodeStatus::kOk;
}

const char* to_string(CalibrationState state) {
  switch (state) {
    case CalibrationState::kWaiting: return "waiting";
    case CalibrationState::kCollecting: return "collecting";
    case CalibrationState::kCalibrated: return "calibrated";
    case CalibrationState::kFailed: return "failed";
  }
  return "?";
}

void EncodeCalibrationStatus(const CalibrationStatusMessage& m, std::vector<uint8_t>* out) {
  if (m.joints.size() > kMaxJoints)
    throw std::invalid_argument("calibration status: more joints than the wire carries");
  out->clear();
  ByteWriter w(out);
  WriteHeader(w, MessageType::kCalibrationStatus, m.version);
  WriteSubject(w, m.subject);
  w.WriteU64(m.skeleton_hash);
  w.WriteU8(static_cast<uint8_t>(m.state));
  w.WriteU8(0);  // reserved
  w.WriteU16(m.refinements);
  w.WriteF32(m.height_m);
  w.WriteF32(m.collected_s);
  w.WriteU16(static_cast<uint16_t>(m.joints.size()));
  for (const JointCalibrationReadiness& j : m.joints) {
    w.WriteU8(j.directions_covered);
    w.WriteU8(j.flags);
    w.WriteF32(j.uncertainty_mm);
    w.WriteF32(j.moved_mm);
  }
  FinishMessage(out);
}

DecodeStatus DecodeCalibrationStatus(std::span<const uint8_t> bytes, CalibrationStatusMessage* m) {
  ByteReader r(bytes);
  if (const DecodeStatus s =
          ReadPrelude(r, MessageType::kCalibrationStatus, &m->version, &m->subject);
      s != DecodeStatus::kOk)
    return s;
  uint8_t state = 0, reserved = 0;
  uint16_t count = 0;
  if (!r.ReadU64(&m->skeleton_hash) || !r.ReadU8(&state) || !r.ReadU8(&reserved) ||
      !r.ReadU16(&m->refinements) || !r.ReadF32(&m->height_m) || !r.ReadF32(&m->collected_s) ||
      !r.ReadU16(&count))
    return DecodeStatus::kTooShort;
  if (count > kMaxJoints) return DecodeStatus::kTooManyItems;
  if (r.remaining() != static_cast<size_t>(count) * 10) return DecodeStatus::kSizeMismatch;
  m->joints.resize(count);
  for (JointCalibrationReadiness& j : m->joints)
    if (!r.ReadU8(&j.directions_covered) || !r.ReadU8(&j.flags) || !r.ReadF32(&j.uncertainty_mm) ||
        !r.ReadF32(&j.moved_mm))
      return DecodeStatus::kTooShort;
  if (state > static_cast<uint8_t>(CalibrationState::kFailed)) return DecodeStatus::kBadField;
  if (!std::isfinite(m->height_m) || !std::isfinite(m->collected_s))
    return DecodeStatus::kNonFinite;
  for (const JointCalibrationReadiness& j : m->joints) {
    if (j.directions_covered > 3) return DecodeStatus::kBadField;
    if (!std::isfinite(j.uncertainty_mm) || !std::isfinite(j.moved_mm))
      return DecodeStatus::kNonFinite;
  }
  m->state = static_cast<CalibrationState>(state);
  return DecodeStatus::kOk;
}

DecodeStatus PeekType(std::span<const uint8_t> bytes, MessageType* type) {
  ByteReader r(bytes);
  uint32_t magic = 0;
  uint16_t version = 0, raw = 0;
  if (!r.ReadU32(&magic) || !r.ReadU16(&version) || !r.ReadU16(&raw))
    return DecodeStatus::kTooShort;
  if (magic != kMagic) return DecodeStatus::kBadMagic;
  if (!KnownVersion(version)) return DecodeStatus::kUnsupportedVersion;
  if (raw < static_cast<uint16_t>(MessageType::kSubjectDescription) ||
      raw > static_cast<uint16_t>(MessageType::kCalibrationStatus))
    return DecodeStatus::kWrongType;
  *type = static_cast<MessageType>(raw);
  return DecodeStatus::kOk;
}

}  // namespace mocapd::protocol
