// Tests for the wire messages: exact round trips, model hashes, and a status (never a
// crash) for every way a message can be malformed.
#include "protocol/messages.hpp"

#include <gtest/gtest.h>

#include <cstring>
#include <limits>

#include "protocol/byte_io.hpp"
#include "tests/support/allocation_counter.hpp"

namespace mocapd::protocol {
namespace {

MarkerFrameMessage SampleMarkers() {
  MarkerFrameMessage m;
  m.subject = "actor1";
  m.model_hash = 0x1234567890abcdefull;
  m.frame_number = 42;
  m.capture_time_ns = 1'700'000'000'123'456'789ull;
  m.rate_hz = 120.0f;
  m.positions = {Vec3(0.5, 1.25, -0.75), Vec3::Constant(kNaN), Vec3(-1.5, 0.0, 2.0)};
  m.valid = {1, 0, 1};
  return m;
}

SkeletonFrameMessage SampleSkeleton() {
  SkeletonFrameMessage m;
  m.subject = "actor1";
  m.model_hash = 77;
  m.frame_number = 9;
  m.capture_time_ns = 1000;
  m.publish_time_ns = 2500;
  m.status = 1;
  m.residual_m = 0.0015f;
  m.root_translation = Vec3(0.25, 0.875, -3.5);
  m.rotations = {Quat::Identity(), Quat(0.5, 0.5, 0.5, 0.5)};
  return m;
}

SubjectDescriptionMessage SampleDescription() {
  SubjectDescriptionMessage d;
  d.subject = "actor1";
  d.marker_set_hash = 11;
  d.skeleton_hash = 22;
  d.rate_hz = 240.0f;
  d.lookahead_frames = 12;
  d.marker_names = {"LASI", "RASI", "LKNE"};
  d.joint_names = {"Hips", "LeftUpLeg", "LeftLeg"};
  d.joint_parents = {-1, 0, 1};
  d.rest_offsets = {Vec3(0, 0.9, 0), Vec3(0.1, -0.05, 0), Vec3(0, -0.42, 0)};
  d.rest_rotations = {Quat::Identity(), Quat(0.5, 0.5, 0.5, 0.5), Quat::Identity()};
  return d;
}

CleanedMarkersMessage SampleCleaned() {
  CleanedMarkersMessage c;
  c.subject = "actor1";
  c.model_hash = 11;
  c.frame_number = 7;
  c.capture_time_ns = 100;
  c.publish_time_ns = 200;
  c.positions = {Vec3(0.5, 1.0, 1.5), Vec3(0.25, 0.5, 0.75), Vec3::Constant(kNaN)};
  c.status = {0, 1, 2};
  c.reason = {0, 3, 0};
  return c;
}

// Every prefix of a valid message is rejected as short or inconsistent, and so is one
// extra byte: no decoder reads past what it was given or accepts trailing bytes.
template <typename Message, typename Decode>
void ExpectEveryTruncationRejected(std::vector<uint8_t> bytes, Decode decode) {
  Message dut;
  for (size_t n = 0; n < bytes.size(); ++n) {
    const DecodeStatus s = decode(std::span<const uint8_t>(bytes.data(), n), &dut);
    EXPECT_TRUE(s == DecodeStatus::kTooShort || s == DecodeStatus::kSizeMismatch)
        << n << " " << to_string(s);
  }
  bytes.push_back(0);
  EXPECT_EQ(decode(bytes, &dut), DecodeStatus::kSizeMismatch);
}

TEST(MessagesTest, MarkerFrameRoundTripsExactlyForFloatValues) {
  std::vector<uint8_t> bytes;
  EncodeMarkerFrame(SampleMarkers(), &bytes);
  MarkerFrameMessage dut;
  ASSERT_EQ(DecodeMarkerFrame(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(dut.subject, "actor1");
  EXPECT_EQ(dut.model_hash, 0x1234567890abcdefull);
  EXPECT_EQ(dut.frame_number, 42u);
  EXPECT_EQ(dut.capture_time_ns, 1'700'000'000'123'456'789ull);
  EXPECT_EQ(dut.rate_hz, 120.0f);
  ASSERT_EQ(dut.positions.size(), 3u);
  EXPECT_EQ(dut.positions[0], Vec3(0.5, 1.25, -0.75));
  EXPECT_FALSE(dut.valid[1]);
  EXPECT_FALSE(dut.positions[1].allFinite());
  MessageType type;
  ASSERT_EQ(PeekType(bytes, &type), DecodeStatus::kOk);
  EXPECT_EQ(type, MessageType::kMarkerFrame);
}

TEST(MessagesTest, HeaderIsLittleEndianWithMagicVersionTypeAndSize) {
  std::vector<uint8_t> bytes;
  EncodeMarkerFrame(SampleMarkers(), &bytes);
  EXPECT_EQ(std::string(bytes.begin(), bytes.begin() + 4), "MCPD");
  EXPECT_EQ(bytes[4], 2);  // version
  EXPECT_EQ(bytes[6], 2);  // marker frame
  const uint32_t payload =
      bytes[8] | (bytes[9] << 8) | (bytes[10] << 16) | (static_cast<uint32_t>(bytes[11]) << 24);
  EXPECT_EQ(payload, bytes.size() - kHeaderBytes);
}

TEST(MessagesTest, SkeletonFrameRoundTrips) {
  std::vector<uint8_t> bytes;
  EncodeSkeletonFrame(SampleSkeleton(), &bytes);
  SkeletonFrameMessage dut;
  ASSERT_EQ(DecodeSkeletonFrame(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(dut.publish_time_ns, 2500u);
  EXPECT_EQ(dut.status, 1);
  EXPECT_EQ(dut.root_translation, Vec3(0.25, 0.875, -3.5));
  ASSERT_EQ(dut.rotations.size(), 2u);
  EXPECT_TRUE(dut.rotations[1].isApprox(Quat(0.5, 0.5, 0.5, 0.5)));
  EXPECT_EQ(dut.subject_state, SubjectState::kTracking);
  EXPECT_TRUE(dut.global_rotations.empty());
  MarkerFrameMessage wrong;
  EXPECT_EQ(DecodeMarkerFrame(bytes, &wrong), DecodeStatus::kWrongType);
}

TEST(MessagesTest, SkeletonFrameCarriesOptionalGlobalTransformsAndSubjectState) {
  SkeletonFrameMessage m = SampleSkeleton();
  m.subject_state = SubjectState::kRepairing;
  m.global_rotations = {Quat(0.5, -0.5, 0.5, -0.5), Quat::Identity()};
  m.global_positions = {Vec3(1, 2, 3), Vec3(-1, -2, -3)};
  std::vector<uint8_t> bytes;
  EncodeSkeletonFrame(m, &bytes);
  SkeletonFrameMessage dut;
  ASSERT_EQ(DecodeSkeletonFrame(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(dut.subject_state, SubjectState::kRepairing);
  ASSERT_EQ(dut.global_positions.size(), 2u);
  EXPECT_EQ(dut.global_positions[1], Vec3(-1, -2, -3));
  EXPECT_TRUE(dut.global_rotations[0].isApprox(Quat(0.5, -0.5, 0.5, -0.5)));
  ExpectEveryTruncationRejected<SkeletonFrameMessage>(bytes, DecodeSkeletonFrame);
  // Globals for only some joints is a programming error upstream.
  m.global_positions.pop_back();
  EXPECT_THROW(EncodeSkeletonFrame(m, &bytes), std::invalid_argument);
}

TEST(MessagesTest, SkeletonFrameRejectsUnknownFlagsStatesAndSolveStatuses) {
  std::vector<uint8_t> good;
  EncodeSkeletonFrame(SampleSkeleton(), &good);
  const size_t state_offset = kHeaderBytes + 1 + 6 + 32 + 1;
  SkeletonFrameMessage dut;
  std::vector<uint8_t> b = good;
  b[state_offset] = 9;
  EXPECT_EQ(DecodeSkeletonFrame(b, &dut), DecodeStatus::kBadField);
  b = good;
  b[state_offset - 1] = 4;  // a final solve status IkStatus does not have
  EXPECT_EQ(DecodeSkeletonFrame(b, &dut), DecodeStatus::kBadField);
  b = good;
  b[state_offset + 1] = 0x02;  // an undefined flag bit
  EXPECT_EQ(DecodeSkeletonFrame(b, &dut), DecodeStatus::kBadField);
  b = good;
  b[state_offset + 1] = 0x01;  // globals claimed but not sent
  EXPECT_EQ(DecodeSkeletonFrame(b, &dut), DecodeStatus::kSizeMismatch);
}

TEST(MessagesTest, SubjectDescriptionRoundTripsNamesHierarchyAndRestPose) {
  std::vector<uint8_t> bytes;
  EncodeSubjectDescription(SampleDescription(), &bytes);
  SubjectDescriptionMessage dut;
  ASSERT_EQ(DecodeSubjectDescription(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(dut.subject, "actor1");
  EXPECT_EQ(dut.marker_set_hash, 11u);
  EXPECT_EQ(dut.skeleton_hash, 22u);
  EXPECT_EQ(dut.rate_hz, 240.0f);
  EXPECT_EQ(dut.lookahead_frames, 12);
  EXPECT_EQ(dut.marker_names, (std::vector<std::string>{"LASI", "RASI", "LKNE"}));
  EXPECT_EQ(dut.joint_names, (std::vector<std::string>{"Hips", "LeftUpLeg", "LeftLeg"}));
  EXPECT_EQ(dut.joint_parents, (std::vector<int16_t>{-1, 0, 1}));
  EXPECT_LT((dut.rest_offsets[2] - Vec3(0, -0.42, 0)).norm(), 1e-7);
  EXPECT_TRUE(dut.rest_rotations[1].isApprox(Quat(0.5, 0.5, 0.5, 0.5)));
  ExpectEveryTruncationRejected<SubjectDescriptionMessage>(bytes, DecodeSubjectDescription);
}

TEST(MessagesTest, SubjectDescriptionRejectsBrokenHierarchiesAndNames) {
  SubjectDescriptionMessage d = SampleDescription();
  std::vector<uint8_t> bytes;
  SubjectDescriptionMessage dut;
  d.joint_parents = {-1, 2, 1};  // a parent after its child
  EncodeSubjectDescription(d, &bytes);
  EXPECT_EQ(DecodeSubjectDescription(bytes, &dut), DecodeStatus::kBadField);
  d.joint_parents = {-1, -1, 1};  // two roots
  EncodeSubjectDescription(d, &bytes);
  EXPECT_EQ(DecodeSubjectDescription(bytes, &dut), DecodeStatus::kBadField);
  d = SampleDescription();
  EncodeSubjectDescription(d, &bytes);
  const size_t first_name = kHeaderBytes + 1 + 6 + 8 + 8 + 4 + 2 + 2 + 2 + 2;
  bytes[first_name] = 0;  // an empty marker name
  EXPECT_EQ(DecodeSubjectDescription(bytes, &dut), DecodeStatus::kBadField);
  d.marker_names[0] = "";
  EXPECT_THROW(EncodeSubjectDescription(d, &bytes), std::invalid_argument);
  // A count far beyond the bytes is refused before anything is sized by it.
  d = SampleDescription();
  EncodeSubjectDescription(d, &bytes);
  bytes[first_name - 4] = 0xff;
  bytes[first_name - 3] = 0x01;  // joints = 511
  EXPECT_EQ(DecodeSubjectDescription(bytes, &dut), DecodeStatus::kSizeMismatch);
}

TEST(MessagesTest, CleanedMarkersRoundTripWithStatusAndReason) {
  std::vector<uint8_t> bytes;
  EncodeCleanedMarkers(SampleCleaned(), &bytes);
  CleanedMarkersMessage dut;
  ASSERT_EQ(DecodeCleanedMarkers(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(dut.frame_number, 7u);
  EXPECT_EQ(dut.publish_time_ns, 200u);
  EXPECT_EQ(dut.positions[1], Vec3(0.25, 0.5, 0.75));
  EXPECT_EQ(dut.status, (std::vector<uint8_t>{0, 1, 2}));
  EXPECT_EQ(dut.reason, (std::vector<uint8_t>{0, 3, 0}));
  EXPECT_FALSE(dut.positions[2].allFinite());
  ExpectEveryTruncationRejected<CleanedMarkersMessage>(bytes, DecodeCleanedMarkers);
  const size_t first_status = kHeaderBytes + 1 + 6 + 32 + 4 + 12;
  bytes[first_status] = 3;
  EXPECT_EQ(DecodeCleanedMarkers(bytes, &dut), DecodeStatus::kBadField);
  bytes[first_status] = 1;
  bytes[first_status + 1] = 40;
  EXPECT_EQ(DecodeCleanedMarkers(bytes, &dut), DecodeStatus::kBadField);
}

TEST(MessagesTest, EndOfStreamRoundTrips) {
  EndOfStreamMessage m;
  m.subject = "actor3";
  m.last_frame_number = 4321;
  std::vector<uint8_t> bytes;
  EncodeEndOfStream(m, &bytes);
  EXPECT_EQ(bytes.size(), kHeaderBytes + 1 + 6 + 8);
  EndOfStreamMessage dut;
  ASSERT_EQ(DecodeEndOfStream(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(dut.subject, "actor3");
  EXPECT_EQ(dut.last_frame_number, 4321u);
  ExpectEveryTruncationRejected<EndOfStreamMessage>(bytes, DecodeEndOfStream);
  MarkerFrameMessage other;
  EXPECT_EQ(DecodeMarkerFrame(bytes, &other), DecodeStatus::kWrongType);
}

TEST(MessagesTest, SubjectStatusRoundTrips) {
  SubjectStatusMessage m;
  m.subject = "actor2";
  m.state = SubjectState::kStalled;
  m.last_frame_number = 1000;
  m.since_last_input_ns = 2'000'000'000;
  m.frames_in = 1001;
  m.frames_out = 990;
  m.frames_dropped = 3;
  m.problems = kProblemModelSuspect;
  std::vector<uint8_t> bytes;
  EncodeSubjectStatus(m, &bytes);
  SubjectStatusMessage dut;
  ASSERT_EQ(DecodeSubjectStatus(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(dut.subject, "actor2");
  EXPECT_EQ(dut.state, SubjectState::kStalled);
  EXPECT_EQ(dut.since_last_input_ns, 2'000'000'000u);
  EXPECT_EQ(dut.frames_out, 990u);
  EXPECT_EQ(dut.problems, kProblemModelSuspect);
  ExpectEveryTruncationRejected<SubjectStatusMessage>(bytes, DecodeSubjectStatus);
  bytes[kHeaderBytes + 1 + 6] = 7;
  EXPECT_EQ(DecodeSubjectStatus(bytes, &dut), DecodeStatus::kBadField);
  MessageType type;
  EXPECT_EQ(PeekType(bytes, &type), DecodeStatus::kOk);
  EXPECT_EQ(type, MessageType::kSubjectStatus);
}

TEST(MessagesTest, CalibrationStatusRoundTripsWithEveryJointsReadiness) {
  CalibrationStatusMessage m;
  m.subject = "actor3";
  m.skeleton_hash = 0x1234567890abcdefULL;
  m.state = CalibrationState::kCalibrated;
  m.refinements = 4;
  m.height_m = 1.62f;
  m.collected_s = 17.5f;
  m.joints = {{0, kJointCalibrated | kJointReady, 0.0f, 0.0f},
              {3, kJointCalibrated | kJointReady, 1.5f, 2.25f},
              {1, kJointCalibrated, 30.0f, -1.0f}};
  std::vector<uint8_t> bytes;
  EncodeCalibrationStatus(m, &bytes);
  EXPECT_EQ(bytes.size(), kHeaderBytes + 1 + 6 + 22 + 10 * 3);
  CalibrationStatusMessage dut;
  ASSERT_EQ(DecodeCalibrationStatus(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(dut.subject, "actor3");
  EXPECT_EQ(dut.skeleton_hash, m.skeleton_hash);
  EXPECT_EQ(dut.state, CalibrationState::kCalibrated);
  EXPECT_EQ(dut.refinements, 4);
  EXPECT_EQ(dut.height_m, 1.62f);
  EXPECT_EQ(dut.joints, m.joints);
  ExpectEveryTruncationRejected<CalibrationStatusMessage>(bytes, DecodeCalibrationStatus);
  MessageType type;
  EXPECT_EQ(PeekType(bytes, &type), DecodeStatus::kOk);
  EXPECT_EQ(type, MessageType::kCalibrationStatus);
  const size_t state_at = kHeaderBytes + 1 + 6 + 8;
  std::vector<uint8_t> bad = bytes;
  bad[state_at] = 4;
  EXPECT_EQ(DecodeCalibrationStatus(bad, &dut), DecodeStatus::kBadField);
  bad = bytes;
  bad[state_at + 14] = 4;  // the first joint's directions
  EXPECT_EQ(DecodeCalibrationStatus(bad, &dut), DecodeStatus::kBadField);
  bad = bytes;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::memcpy(&bad[state_at + 16], &nan, 4);
  EXPECT_EQ(DecodeCalibrationStatus(bad, &dut), DecodeStatus::kNonFinite);
  bad = bytes;
  bad[state_at + 12] = 0xff;  // joint count far beyond the bytes
  bad[state_at + 13] = 0x7f;
  EXPECT_EQ(DecodeCalibrationStatus(bad, &dut), DecodeStatus::kTooManyItems);
  SubjectStatusMessage other;
  EXPECT_EQ(DecodeSubjectStatus(bytes, &other), DecodeStatus::kWrongType);
}

TEST(MessagesTest, EveryTruncationAndExtensionIsRejected) {
  std::vector<uint8_t> bytes;
  EncodeMarkerFrame(SampleMarkers(), &bytes);
  MarkerFrameMessage dut;
  for (size_t n = 0; n < bytes.size(); ++n) {
    const DecodeStatus s = DecodeMarkerFrame(std::span<const uint8_t>(bytes.data(), n), &dut);
    EXPECT_TRUE(s == DecodeStatus::kTooShort || s == DecodeStatus::kSizeMismatch)
        << n << " " << to_string(s);
  }
  bytes.push_back(0);
  EXPECT_EQ(DecodeMarkerFrame(bytes, &dut), DecodeStatus::kSizeMismatch);
}

TEST(MessagesTest, MalformedFieldsGetTheirOwnStatus) {
  std::vector<uint8_t> good;
  MarkerFrameMessage v1 = SampleMarkers();  // version 1: the markers follow the count
  v1.version = kVersion1;
  EncodeMarkerFrame(v1, &good);
  MarkerFrameMessage dut;
  auto with = [&](size_t offset, uint8_t value) {
    std::vector<uint8_t> b = good;
    b[offset] = value;
    return DecodeMarkerFrame(b, &dut);
  };
  EXPECT_EQ(with(0, 'X'), DecodeStatus::kBadMagic);
  EXPECT_EQ(with(4, 9), DecodeStatus::kUnsupportedVersion);
  EXPECT_EQ(with(6, 7), DecodeStatus::kWrongType);
  EXPECT_EQ(with(16, 0), DecodeStatus::kBadSubjectName);
  EXPECT_EQ(with(16, 200), DecodeStatus::kBadSubjectName);
  // The marker count (after subject, hash, frame, time, rate) claiming more than sent.
  const size_t count_offset = kHeaderBytes + 1 + 6 + 8 + 8 + 8 + 4;
  EXPECT_EQ(with(count_offset, 4), DecodeStatus::kSizeMismatch);
  EXPECT_EQ(with(count_offset + 1, 0x10), DecodeStatus::kTooManyItems);
  // A NaN in a valid marker's x.
  std::vector<uint8_t> nan = good;
  const float q = std::numeric_limits<float>::quiet_NaN();
  std::memcpy(&nan[count_offset + 4], &q, 4);
  EXPECT_EQ(DecodeMarkerFrame(nan, &dut), DecodeStatus::kNonFinite);
  // A zero rate.
  std::vector<uint8_t> zero_rate = good;
  const float zero = 0.0f;
  std::memcpy(&zero_rate[count_offset - 4], &zero, 4);
  EXPECT_EQ(DecodeMarkerFrame(zero_rate, &dut), DecodeStatus::kNonFinite);
}

StreamInfo SampleStream() {
  StreamInfo s;
  s.session_id = 0xfeedfacecafebeefull;
  s.rate_numerator = 120000;
  s.rate_denominator = 1001;  // 119.88 Hz
  s.has_timecode = true;
  s.timecode = {10, 59, 58, 29, 3, true, 30};
  return s;
}

// A marker frame at 119.88 Hz with the sample stream block.
MarkerFrameMessage SampleMarkersWithStream() {
  MarkerFrameMessage m = SampleMarkers();
  m.rate_hz = 119.88f;
  m.stream = SampleStream();
  return m;
}

TEST(MessagesTest, AFailedMarkerFrameKeepsOnlyWhatWasReadOfItsSubjectAndNumber) {
  std::vector<uint8_t> bytes;
  EncodeMarkerFrame(SampleMarkersWithStream(), &bytes);
  MarkerFrameMessage m;
  m.subject = "stale";
  m.frame_number = 7;
  m.stream.session_id = 9;
  // Cut inside the subject's name: nothing of the frame is known.
  std::vector<uint8_t> cut(bytes.begin(), bytes.begin() + kHeaderBytes + 3);
  ASSERT_EQ(DecodeMarkerFrame(cut, &m), DecodeStatus::kTooShort);
  EXPECT_TRUE(m.subject.empty());
  EXPECT_EQ(m.frame_number, 0u);
  EXPECT_EQ(m.stream.session_id, 0u);
  // An exact rate that contradicts the float rate: the subject, number and session were
  // read (a daemon charges the drop to that subject and knows which number it was).
  MarkerFrameMessage contradicting = SampleMarkersWithStream();
  contradicting.rate_hz = 120.0f;
  contradicting.stream.rate_numerator = 120000;
  contradicting.stream.rate_denominator = 1001;
  EncodeMarkerFrame(contradicting, &bytes);
  ASSERT_EQ(DecodeMarkerFrame(bytes, &m), DecodeStatus::kBadField);
  EXPECT_EQ(m.subject, contradicting.subject);
  EXPECT_EQ(m.frame_number, contradicting.frame_number);
  EXPECT_EQ(m.stream.session_id, contradicting.stream.session_id);
}

TEST(MessagesTest, VersionTwoFramesCarryTheStreamBlockThrough) {
  MarkerFrameMessage m = SampleMarkersWithStream();
  std::vector<uint8_t> bytes;
  EncodeMarkerFrame(m, &bytes);
  MarkerFrameMessage v1_form = m;
  v1_form.version = kVersion1;
  std::vector<uint8_t> v1_bytes;
  EncodeMarkerFrame(v1_form, &v1_bytes);
  EXPECT_EQ(bytes.size(), v1_bytes.size() + kStreamBlockBytes);
  MarkerFrameMessage dut;
  ASSERT_EQ(DecodeMarkerFrame(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(dut.version, kVersion2);
  EXPECT_EQ(dut.stream, SampleStream());
  EXPECT_EQ(dut.positions[2], m.positions[2]);

  SkeletonFrameMessage skeleton = SampleSkeleton();
  skeleton.stream = SampleStream();
  EncodeSkeletonFrame(skeleton, &bytes);
  SkeletonFrameMessage skeleton_dut;
  ASSERT_EQ(DecodeSkeletonFrame(bytes, &skeleton_dut), DecodeStatus::kOk);
  EXPECT_EQ(skeleton_dut.stream, SampleStream());
  EXPECT_EQ(skeleton_dut.rotations[1].coeffs(), skeleton.rotations[1].coeffs());
  ExpectEveryTruncationRejected<SkeletonFrameMessage>(bytes, DecodeSkeletonFrame);

  CleanedMarkersMessage cleaned = SampleCleaned();
  cleaned.stream = SampleStream();
  EncodeCleanedMarkers(cleaned, &bytes);
  CleanedMarkersMessage cleaned_dut;
  ASSERT_EQ(DecodeCleanedMarkers(bytes, &cleaned_dut), DecodeStatus::kOk);
  EXPECT_EQ(cleaned_dut.stream, SampleStream());
  EXPECT_EQ(cleaned_dut.status, cleaned.status);
  ExpectEveryTruncationRejected<CleanedMarkersMessage>(bytes, DecodeCleanedMarkers);
}

TEST(MessagesTest, VersionOneMessagesStillDecodeWithNoStream) {
  MarkerFrameMessage m = SampleMarkers();
  m.version = kVersion1;
  m.stream = SampleStream();  // not on the wire in version 1
  std::vector<uint8_t> bytes;
  EncodeMarkerFrame(m, &bytes);
  EXPECT_EQ(bytes[4], 1);
  MarkerFrameMessage dut;
  dut.stream = SampleStream();  // left over from an earlier frame: must be cleared
  ASSERT_EQ(DecodeMarkerFrame(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(dut.version, kVersion1);
  EXPECT_EQ(dut.stream, StreamInfo{});
  EXPECT_EQ(dut.frame_number, 42u);
  SubjectStatusMessage status;
  status.subject = "actor1";
  status.version = kVersion1;
  EncodeSubjectStatus(status, &bytes);
  SubjectStatusMessage status_dut;
  ASSERT_EQ(DecodeSubjectStatus(bytes, &status_dut), DecodeStatus::kOk);
  EXPECT_EQ(status_dut.version, kVersion1);
  bytes[4] = 3;  // a version from the future
  EXPECT_EQ(DecodeSubjectStatus(bytes, &status_dut), DecodeStatus::kUnsupportedVersion);
  MessageType type;
  EXPECT_EQ(PeekType(bytes, &type), DecodeStatus::kUnsupportedVersion);
  m.version = 3;
  EXPECT_THROW(EncodeMarkerFrame(m, &bytes), std::invalid_argument);
}

TEST(MessagesTest, StreamBlockFieldsOutOfRangeAreBadFields) {
  std::vector<uint8_t> good;
  EncodeMarkerFrame(SampleMarkersWithStream(), &good);
  // After subject "actor1", hash, frame, time, rate, count and reserved.
  const size_t stream = kHeaderBytes + 1 + 6 + 8 + 8 + 8 + 4 + 2 + 2;
  const size_t timecode = stream + 16;
  MarkerFrameMessage dut;
  auto with = [&](size_t offset, uint8_t value) {
    std::vector<uint8_t> b = good;
    b[offset] = value;
    return DecodeMarkerFrame(b, &dut);
  };
  ASSERT_EQ(with(timecode, 10), DecodeStatus::kOk);              // the unchanged hour
  EXPECT_EQ(with(timecode + 0, 24), DecodeStatus::kBadField);    // hours
  EXPECT_EQ(with(timecode + 1, 60), DecodeStatus::kBadField);    // minutes
  EXPECT_EQ(with(timecode + 2, 60), DecodeStatus::kBadField);    // seconds
  EXPECT_EQ(with(timecode + 3, 30), DecodeStatus::kBadField);    // frames at 30 fps
  EXPECT_EQ(with(timecode + 5, 0x07), DecodeStatus::kBadField);  // an undefined flag bit
  EXPECT_EQ(with(timecode + 6, 25), DecodeStatus::kBadField);    // drop-frame at 25 fps
  EXPECT_EQ(with(timecode + 6, 0), DecodeStatus::kBadField);     // timecode rate 0
  EXPECT_EQ(with(timecode + 5, 0x00), DecodeStatus::kOk);        // no timecode: fields ignored
  EXPECT_FALSE(dut.stream.has_timecode);
  // A rate fraction with no denominator, or one the float rate disagrees with.
  std::vector<uint8_t> b = good;
  std::memset(&b[stream + 12], 0, 4);
  EXPECT_EQ(DecodeMarkerFrame(b, &dut), DecodeStatus::kBadField);
  b = good;
  b[stream + 12] = 1;  // 120000 / 1 (low byte of 1001 is 0xe9)
  b[stream + 13] = 0;
  EXPECT_EQ(DecodeMarkerFrame(b, &dut), DecodeStatus::kBadField);
  std::memset(&b[stream + 8], 0, 8);  // 0/0: not given
  EXPECT_EQ(DecodeMarkerFrame(b, &dut), DecodeStatus::kOk);
}

TEST(MessagesTest, TimecodeFormatsAsSmpteWritesIt) {
  EXPECT_EQ(FormatTimecode({1, 2, 3, 4, 0, false, 30}), "01:02:03:04");
  EXPECT_EQ(FormatTimecode({10, 59, 58, 29, 3, true, 30}), "10:59:58;29.3");
}

TEST(MessagesTest, EncoderRefusesMessagesOutsideTheLimits) {
  MarkerFrameMessage m = SampleMarkers();
  std::vector<uint8_t> out;
  m.subject = std::string(64, 'a');
  EXPECT_THROW(EncodeMarkerFrame(m, &out), std::invalid_argument);
  m = SampleMarkers();
  m.valid.pop_back();
  EXPECT_THROW(EncodeMarkerFrame(m, &out), std::invalid_argument);
}

TEST(MessagesTest, ModelHashesDependOnNamesAndOrder) {
  const std::vector<std::string> a = {"LASI", "RASI"}, b = {"RASI", "LASI"}, c = {"LASIR", "ASI"};
  EXPECT_NE(NamesHash(a), NamesHash(b));
  EXPECT_NE(NamesHash(a), NamesHash(c));
  EXPECT_EQ(NamesHash(a), NamesHash(std::vector<std::string>{"LASI", "RASI"}));
}

TEST(MessagesTest, DecodingReusesStorageWithoutAllocating) {
  std::vector<uint8_t> bytes;
  EncodeMarkerFrame(SampleMarkers(), &bytes);
  MarkerFrameMessage dut;
  ASSERT_EQ(DecodeMarkerFrame(bytes, &dut), DecodeStatus::kOk);
  testing::ScopedAllocationCounter counter;
  for (int i = 0; i < 100; ++i) ASSERT_EQ(DecodeMarkerFrame(bytes, &dut), DecodeStatus::kOk);
  EXPECT_EQ(counter.count(), 0u);
}

}  // namespace
}  // namespace mocapd::protocol
