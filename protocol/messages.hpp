// The mocapd wire format (documented byte by byte in protocol/README.md): a 16-byte
// versioned header and little-endian payloads for marker frames in; skeleton frames,
// cleaned markers, subject descriptions and subject status out. Version 2 gives the
// frames a stream block (capture session, exact rate, SMPTE timecode); version 1 stays
// readable and writable for senders and consumers that predate it. Encoding writes into a
// caller-owned buffer; decoding is bounds-checked, never throws and never allocates beyond the
// caller's message storage (sized once), and reports a status for every way a message can be
// malformed.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "filters/marker_model.hpp"

namespace mocapd::protocol {

inline constexpr uint32_t kMagic = 0x4450434d;  // "MCPD" in little-endian byte order
inline constexpr uint16_t kVersion1 = 1;
inline constexpr uint16_t kVersion2 = 2;
inline constexpr uint16_t kVersion = kVersion2;  ///< The newest: what encoders write by default.
inline constexpr size_t kStreamBlockBytes = 24;
inline constexpr size_t kHeaderBytes = 16;
inline constexpr size_t kMaxSubjectName = 63;
inline constexpr size_t kMaxMarkers = 1024;
inline constexpr size_t kMaxJoints = 512;

enum class MessageType : uint16_t {
  kSubjectDescription = 1,
  kMarkerFrame = 2,
  kSkeletonFrame = 3,
  kCleanedMarkers = 4,
  kSubjectStatus = 5,
  kEndOfStream = 6,
  kCalibrationStatus = 7,
};

/// How a subject is doing, carried by skeleton frames and status messages.
enum class SubjectState : uint8_t {
  kTracking = 0,   ///< Solved from markers as captured.
  kRepairing = 1,  ///< Some of this frame's markers were repaired.
  kLost = 2,       ///< Too few markers to solve; the pose is held.
  kStalled = 3,    ///< No input for longer than the watchdog timeout.
  kWaiting = 4,    ///< No frame received yet.
};
const char* to_string(SubjectState state);

enum class DecodeStatus {
  kOk,
  kTooShort,  ///< Fewer bytes than the header or the payload needs.
  kBadMagic,
  kUnsupportedVersion,
  kWrongType,       ///< A valid message, but not the type asked for.
  kSizeMismatch,    ///< The header's payload size disagrees with the bytes or the counts.
  kBadSubjectName,  ///< Empty or longer than kMaxSubjectName.
  kTooManyItems,    ///< More markers or joints than the limits.
  kNonFinite,       ///< NaN or Inf where a number must be finite.
  kBadField,        ///< A field outside its allowed values (flags, names, parent indices, enums).
};
const char* to_string(DecodeStatus status);

/// Returns the 64-bit FNV-1a hash of the names in order (each followed by a zero byte):
/// the model hash that ties a frame to the marker set or skeleton it was made for.
uint64_t NamesHash(std::span<const std::string> names);
uint64_t MarkerSetHash(const MarkerSet& markers);
uint64_t SkeletonHash(const Skeleton& skeleton);

/// SMPTE timecode of a frame as the capture system stamped it.
struct Timecode {
  uint8_t hours = 0, minutes = 0, seconds = 0, frames = 0;
  uint8_t subframe = 0;  ///< Capture frames within one timecode frame (240 Hz on 30 fps: 0..7).
  bool drop_frame = false;
  uint16_t rate = 0;  ///< Nominal timecode frames per second (24, 25, 30, 60): frames < rate.
  bool operator==(const Timecode&) const = default;
};

/// "HH:MM:SS:FF" (";" before the frames when drop-frame, as SMPTE writes it), then
/// ".S" with the subframe when it is not 0.
std::string FormatTimecode(const Timecode& timecode);

/// Version 2's stream block: which capture a frame belongs to and when it was taken. A v1
/// frame decodes with everything zero / absent.
struct StreamInfo {
  /// Chosen by the sender, changed whenever the capture restarts (new take, system restart):
  /// frame numbers are only comparable within one session. 0: not given.
  uint64_t session_id = 0;
  /// The exact capture rate as a fraction (119.88 Hz is 120000/1001); 0/0: not given.
  uint32_t rate_numerator = 0;
  uint32_t rate_denominator = 0;
  bool has_timecode = false;
  Timecode timecode;
  bool operator==(const StreamInfo&) const = default;
};

struct MarkerFrameMessage {
  uint16_t version = kVersion;  ///< Set by decoding; encoding writes this version.
  StreamInfo stream;            ///< Version 2 only.
  std::string subject;
  uint64_t model_hash = 0;
  uint64_t frame_number = 0;
  uint64_t capture_time_ns = 0;
  float rate_hz = 0.0f;
  std::vector<Vec3> positions;  ///< Metres; NaN where invalid.
  std::vector<uint8_t> valid;
};

struct SkeletonFrameMessage {
  uint16_t version = kVersion;
  StreamInfo stream;  ///< The marker frame's, carried through (version 2 only).
  std::string subject;
  uint64_t model_hash = 0;
  uint64_t frame_number = 0;
  uint64_t capture_time_ns = 0;
  uint64_t publish_time_ns = 0;
  uint8_t status = 0;  ///< IkStatus of the final solve.
  SubjectState subject_state = SubjectState::kTracking;
  float residual_m = 0.0f;
  Vec3 root_translation = Vec3::Zero();
  std::vector<Quat> rotations;  ///< Local joint rotations (R_PJ).
  /// Optional (empty, or one per joint): global joint transforms in the world frame.
  std::vector<Quat> global_rotations;
  std::vector<Vec3> global_positions;
};

/// The model a subject's frames are made for: published so a consumer can interpret
/// skeleton frames (names, hierarchy, rest pose) and check their model hashes.
struct SubjectDescriptionMessage {
  uint16_t version = kVersion;  ///< Same payload in versions 1 and 2.
  std::string subject;
  uint64_t marker_set_hash = 0;
  uint64_t skeleton_hash = 0;
  float rate_hz = 0.0f;
  uint16_t lookahead_frames = 0;
  std::vector<std::string> marker_names;
  std::vector<std::string> joint_names;
  std::vector<int16_t> joint_parents;  ///< -1 for the root; otherwise an earlier joint.
  std::vector<Vec3> rest_offsets;      ///< Metres, in the parent's frame.
  std::vector<Quat> rest_rotations;
};

/// Per-marker status on the wire (MarkerStatus in filters/cleanup_pipeline.hpp).
struct CleanedMarkersMessage {
  uint16_t version = kVersion;
  StreamInfo stream;  ///< The marker frame's, carried through (version 2 only).
  std::string subject;
  uint64_t model_hash = 0;  ///< Marker-set hash.
  uint64_t frame_number = 0;
  uint64_t capture_time_ns = 0;
  uint64_t publish_time_ns = 0;
  std::vector<Vec3> positions;  ///< Metres; NaN where unrecoverable.
  std::vector<uint8_t> status;  ///< 0 observed, 1 repaired, 2 unrecoverable.
  std::vector<uint8_t> reason;  ///< MaskReason of a repaired sample, else 0.
};

/// Published by the daemon for each subject on every stats tick and when the watchdog
/// sees its input stall, so a consumer learns a subject is stalled even with no frames.
/// Bits of SubjectStatusMessage::problems. Readers ignore bits they do not know, so a
/// newer daemon may add some.
inline constexpr uint8_t kProblemModelSuspect = 1;    ///< Observed samples far from the model.
inline constexpr uint8_t kProblemRejectingInput = 2;  ///< Every recent frame dropped.
inline constexpr uint8_t kProblemUnstableInput = 4;   ///< Re-synchronised 5 times in 2 s.

struct SubjectStatusMessage {
  uint16_t version = kVersion;  ///< Same payload in versions 1 and 2.
  std::string subject;
  SubjectState state = SubjectState::kWaiting;
  uint8_t problems = 0;            ///< kProblem* bits.
  uint64_t last_frame_number = 0;  ///< Last frame received (0 before any).
  uint64_t since_last_input_ns = 0;
  uint64_t frames_in = 0;
  uint64_t frames_out = 0;
  uint64_t frames_dropped = 0;
};

/// A live-calibrated subject's progress (published with its status while it calibrates
/// from its own stream): the calibration's state and, per joint of the subject's
/// description (same order), how ready its centre is.
enum class CalibrationState : uint8_t {
  kWaiting = 0,
  kCollecting = 1,
  kCalibrated = 2,
  kFailed = 3
};
const char* to_string(CalibrationState state);

/// Bits of JointCalibrationReadiness::flags.
inline constexpr uint8_t kJointCalibrated = 1;  ///< A refinement has placed the centre.
inline constexpr uint8_t kJointReady = 2;       ///< The motion determines it in >= 2 directions.

struct JointCalibrationReadiness {
  uint8_t directions_covered = 0;  ///< 0..3: of the centre's directions, those the motion fixes.
  uint8_t flags = 0;               ///< kJoint* bits.
  float uncertainty_mm = -1.0f;    ///< The centre's; -1 before the first refinement.
  float moved_mm = -1.0f;          ///< Since the previous refinement; -1 before a second.
  bool operator==(const JointCalibrationReadiness&) const = default;
};

struct CalibrationStatusMessage {
  uint16_t version = kVersion;  ///< Same payload in versions 1 and 2.
  std::string subject;
  uint64_t skeleton_hash =
      0;  ///< The skeleton published now (the template's, then the calibrated one's).
  CalibrationState state = CalibrationState::kWaiting;
  uint16_t refinements = 0;
  float height_m = 0.0f;     ///< The template's scale (0 before the first usable frame).
  float collected_s = 0.0f;  ///< Motion kept for the calibration.
  std::vector<JointCalibrationReadiness> joints;
};

/// Capture to daemon: the subject's stream ends here (a recorded take is over, or the
/// capture stops). The daemon publishes everything its lookahead holds for the subject
/// at once and starts the next frame afresh, instead of waiting for K more frames.
struct EndOfStreamMessage {
  std::string subject;
  uint64_t last_frame_number = 0;  ///< The last frame sent (informational).
  uint16_t version = kVersion;     ///< Same payload in versions 1 and 2.
};

/// Appends the encoded message to out (cleared first), in the message's version. Never
/// fails for messages within the limits; throws std::invalid_argument otherwise (a
/// programming error upstream).
void EncodeMarkerFrame(const MarkerFrameMessage& message, std::vector<uint8_t>* out);
void EncodeSkeletonFrame(const SkeletonFrameMessage& message, std::vector<uint8_t>* out);
void EncodeSubjectDescription(const SubjectDescriptionMessage& message, std::vector<uint8_t>* out);
void EncodeCleanedMarkers(const CleanedMarkersMessage& message, std::vector<uint8_t>* out);
void EncodeSubjectStatus(const SubjectStatusMessage& message, std::vector<uint8_t>* out);
void EncodeEndOfStream(const EndOfStreamMessage& message, std::vector<uint8_t>* out);
void EncodeCalibrationStatus(const CalibrationStatusMessage& message, std::vector<uint8_t>* out);

/// The description of a solved subject, from its model.
SubjectDescriptionMessage DescribeSubject(const std::string& subject, const Skeleton& skeleton,
                                          const MarkerSet& markers, float rate_hz,
                                          int lookahead_frames);

/// A name a sender or a file chose (a subject, a marker label), fit for a log line or a
/// terminal: control characters escaped as in JSON and bytes that are no UTF-8 replaced.
std::string PrintableName(std::string_view name);

/// Whether a subject configured at subject_hz takes frames that say frame_hz: its rate, or
/// its NTSC rate (1000/1001 of it: 119.88 for 120), each within 0.1 %; and, for a subject
/// configured at an NTSC rate (not whole, and 1001/1000 of it is), its nominal rate too
/// (119.88 takes 120; 120 does not take 120.12). The daemon's rule, which the replay checks
/// at its handshake.
bool CaptureRateAccepted(double frame_hz, double subject_hz);

/// Reads the message type after validating the header. Returns kOk and sets type.
DecodeStatus PeekType(std::span<const uint8_t> bytes, MessageType* type);
/// Decodes into message, reusing its storage (no allocation once it has held a message
/// of this size). On any status but kOk, message.subject holds the subject's name if it
/// was read (empty otherwise), so the failure can be charged to that subject, and
/// message.frame_number and message.stream hold their values if they were read (0 and
/// an empty stream otherwise); the rest is unspecified.
DecodeStatus DecodeMarkerFrame(std::span<const uint8_t> bytes, MarkerFrameMessage* message);
DecodeStatus DecodeSkeletonFrame(std::span<const uint8_t> bytes, SkeletonFrameMessage* message);
DecodeStatus DecodeSubjectDescription(std::span<const uint8_t> bytes,
                                      SubjectDescriptionMessage* message);
DecodeStatus DecodeCleanedMarkers(std::span<const uint8_t> bytes, CleanedMarkersMessage* message);
DecodeStatus DecodeSubjectStatus(std::span<const uint8_t> bytes, SubjectStatusMessage* message);
DecodeStatus DecodeEndOfStream(std::span<const uint8_t> bytes, EndOfStreamMessage* message);
DecodeStatus DecodeCalibrationStatus(std::span<const uint8_t> bytes,
                                     CalibrationStatusMessage* message);

}  // namespace mocapd::protocol
