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
  EXPECT_EQ(bytes[4], 1);  // version
  EXPECT_EQ(bytes[6], 2);  // marker frame
  const uint32_t payload = bytes[8] | (bytes[9] << 8) | (bytes[10] << 16) | (static_cast<uint32_t>(bytes[11]) << 24);
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
  MarkerFrameMessage wrong;
  EXPECT_EQ(DecodeMarkerFrame(bytes, &wrong), DecodeStatus::kWrongType);
}

TEST(MessagesTest, EveryTruncationAndExtensionIsRejected) {
  std::vector<uint8_t> bytes;
  EncodeMarkerFrame(SampleMarkers(), &bytes);
  MarkerFrameMessage dut;
  for (size_t n = 0; n < bytes.size(); ++n) {
    const DecodeStatus s = DecodeMarkerFrame(std::span<const uint8_t>(bytes.data(), n), &dut);
    EXPECT_TRUE(s == DecodeStatus::kTooShort || s == DecodeStatus::kSizeMismatch) << n << " " << to_string(s);
  }
  bytes.push_back(0);
  EXPECT_EQ(DecodeMarkerFrame(bytes, &dut), DecodeStatus::kSizeMismatch);
}

TEST(MessagesTest, MalformedFieldsGetTheirOwnStatus) {
  std::vector<uint8_t> good;
  EncodeMarkerFrame(SampleMarkers(), &good);
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
