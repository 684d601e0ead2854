// Tests for take summaries (mocap-sim info).
#include "sim/take_info.hpp"

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "formats/c3d.hpp"
#include "protocol/messages.hpp"
#include "sim/recording.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

TEST(TakeInfoTest, CountsMissingSamplesAndGapsPerMarker) {
  C3dTake take;
  take.labels = {"A", "B"};
  take.rate_hz = 100.0;
  take.Allocate(10);
  take.model_output_kind[1] = "ANGLES";
  for (int f = 0; f < 10; ++f) {
    // A is missing at frames 2-3 and 7: two gaps, longest 2.
    if (f != 2 && f != 3 && f != 7) {
      take.at(f, 0) = Vec3(1, 2, 3);
      take.residuals[static_cast<size_t>(f) * 2] = 0.0f;
    }
    take.at(f, 1) = Vec3(0, 0, 0);
    take.residuals[static_cast<size_t>(f) * 2 + 1] = 0.0f;
  }
  const std::string path = testing::TempDir("info") + "/take.C3D";
  WriteC3d(path, take);
  const TakeInfo info = InspectTake(path);
  EXPECT_EQ(info.format, "c3d");
  EXPECT_EQ(info.frames, 10);
  ASSERT_EQ(info.points.size(), 2u);
  EXPECT_EQ(info.points[0].gaps, 2);
  EXPECT_EQ(info.points[0].longest_gap, 2);
  EXPECT_DOUBLE_EQ(info.points[0].missing_fraction, 0.3);
  EXPECT_EQ(info.points[1].kind, "ANGLES");
  const nlohmann::json j = TakeInfoJson(info);
  EXPECT_EQ(j["points"][0]["label"], "A");
  EXPECT_EQ(j["points"][0]["gaps"], 2);
  EXPECT_EQ(j["rate_hz"], 100.0);
  EXPECT_NE(FormatTakeInfo(info).find("30.00%"), std::string::npos);
}

// A C3D's analog channels are named with their rate (a take's force plates were invisible
// to `info`, and lost without a word by `process --out-c3d`).
TEST(TakeInfoTest, NamesAC3dsAnalogChannels) {
  C3dTake take;
  take.labels = {"A"};
  take.rate_hz = 100.0;
  take.Allocate(3);
  take.analog.labels = {"Fz1", "EMG1"};
  take.analog.descriptions = take.analog.units = {"", ""};
  take.analog.scale = {1.0, 1.0};
  take.analog.offset = {0.0, 0.0};
  take.analog.samples_per_frame = 10;
  take.analog.values.assign(3 * 2 * 10, 1.0f);
  const std::string path = testing::TempDir("info_analog") + "/analog.c3d";
  WriteC3d(path, take);
  const TakeInfo info = InspectTake(path);
  EXPECT_NE(
      FormatTakeInfo(info).find("analog  2 channels x 10 samples a frame (1000 Hz): Fz1 EMG1"),
      std::string::npos)
      << FormatTakeInfo(info);
  EXPECT_EQ(TakeInfoJson(info)["analog"]["samples_per_frame"], 10);
}

TEST(TakeInfoTest, DescribesBvhJoints) {
  const TakeInfo info = InspectTake(std::string(MOCAPD_TEST_DATA_DIR) + "/tiny_static_root.bvh");
  EXPECT_EQ(info.format, "bvh");
  EXPECT_EQ(info.frames, 3);
  ASSERT_EQ(info.joints.size(), 5u);
  EXPECT_EQ(info.joints[1], "Hips (free)");
  EXPECT_EQ(info.end_sites, 1);
  EXPECT_EQ(TakeInfoJson(info)["joints"][0], "joint_Root (fixed)");
  // No unit in a BVH: the guess (which cannot tell in from cm) is said to be one.
  EXPECT_TRUE(info.units_guessed);
  EXPECT_NE(FormatTakeInfo(info).find("units   cm (guessed from its bones)"), std::string::npos)
      << FormatTakeInfo(info);
}

// A recording's summary is what a user checks before replaying it: which subjects, how
// many frames, and which frames the capture lost before they reached the recorder.
TEST(TakeInfoTest, SummarisesARecordingsStreamsWithTheirSkippedFramesAndSessions) {
  const std::string path = testing::TempDir("take_info_recording") + "/capture.rec";
  {
    RecordingWriter w(path);
    std::vector<uint8_t> bytes;
    int64_t t = 0;
    auto frame = [&](const std::string& subject, uint16_t version, uint64_t session,
                     uint64_t number, int markers, size_t cut = 0) {
      protocol::MarkerFrameMessage m;
      m.version = version;
      m.stream.session_id = session;
      m.subject = subject;
      m.frame_number = number;
      m.rate_hz = 120.0f;
      m.positions.assign(static_cast<size_t>(markers), Vec3::Zero());
      m.valid.assign(static_cast<size_t>(markers), 1);
      protocol::EncodeMarkerFrame(m, &bytes);
      bytes.resize(bytes.size() - cut);
      w.Append(t += 8'333'333, "markers/" + subject + "/", bytes);
    };
    // actor1 (v2): 10, 11, 14 (two skipped), 14 again, then a new session from 1.
    for (uint64_t n : {10, 11, 14, 14}) frame("actor1", 2, 7, n, 3);
    for (uint64_t n : {1, 2}) frame("actor1", 2, 8, n, 3);
    // actor2 (v1 has no session id): 100, 101, 103, then the numbers start again at 5.
    for (uint64_t n : {100, 101, 103, 5, 6}) frame("actor2", 1, 0, n, 4);
    // actor3 (v2): a counter that wraps past 2^64 - 1 goes on; a v1 frame between is a
    // new session, as the daemon takes it.
    for (uint64_t n : {UINT64_MAX - 1, UINT64_MAX, uint64_t{0}, uint64_t{1}})
      frame("actor3", 2, 9, n, 2);
    frame("actor3", 1, 0, 2, 2);
    protocol::EncodeEndOfStream({"actor1", 2}, &bytes);
    w.Append(t += 1000, "markers/actor1/", bytes);
    w.Append(t += 1000, "markers/actor1/", std::vector<uint8_t>{1, 2, 3});
    // A marker frame cut short: counted as a marker frame that does not decode.
    frame("actor1", 2, 8, 3, 3, /*cut=*/5);
  }
  const TakeInfo info = InspectTake(path);
  EXPECT_EQ(info.format, "recording");
  EXPECT_EQ(info.frames, 16);
  EXPECT_EQ(info.messages, 19);
  EXPECT_EQ(info.undecodable_messages, 1);
  EXPECT_EQ(info.undecodable_marker_frames, 1);
  EXPECT_DOUBLE_EQ(info.rate_hz, 120.0);
  ASSERT_EQ(info.streams.size(), 3u);
  const RecordedStreamInfo& a1 = info.streams[0];
  EXPECT_EQ(a1.subject, "actor1");
  EXPECT_EQ(a1.frames, 6);
  EXPECT_EQ(a1.frames_skipped, 2);
  EXPECT_EQ(a1.frames_out_of_order, 1);
  EXPECT_EQ(a1.sessions, 2);
  EXPECT_EQ(a1.end_of_stream, 1);
  EXPECT_EQ(a1.markers, 3);
  EXPECT_EQ(a1.protocol_version, 2);
  const RecordedStreamInfo& a2 = info.streams[1];
  EXPECT_EQ(a2.frames_skipped, 1);
  EXPECT_EQ(a2.sessions, 2);
  EXPECT_EQ(a2.first_frame, 100u);
  EXPECT_EQ(a2.last_frame, 6u);
  EXPECT_EQ(a2.protocol_version, 1);
  const RecordedStreamInfo& a3 = info.streams[2];
  EXPECT_EQ(a3.frames_skipped, 0);
  EXPECT_EQ(a3.frames_out_of_order, 0);
  EXPECT_EQ(a3.sessions, 2);
  EXPECT_EQ(a3.last_frame, 2u);
  EXPECT_EQ(a3.min_protocol_version, 1);
  EXPECT_EQ(a3.protocol_version, 2);
  const std::string table = FormatTakeInfo(info);
  EXPECT_NE(table.find("actor2"), std::string::npos) << table;
  EXPECT_EQ(TakeInfoJson(info)["streams"][0]["frames_skipped"], 2);
}

// A subject name is whatever a sender put on the wire: an escape sequence, a newline or
// bytes that are no UTF-8 are printed escaped, so the summary neither moves the
// terminal's cursor nor forges a line, and the JSON is still written.
TEST(TakeInfoTest, ARecordedNameWithControlCharactersIsPrintedEscaped) {
  const std::string path = testing::TempDir("take_info_names") + "/capture.rec";
  const std::string forged = "a\x1b[2Jb\nc\xff";
  {
    RecordingWriter w(path);
    std::vector<uint8_t> bytes;
    protocol::MarkerFrameMessage m;
    m.subject = forged;
    m.frame_number = 1;
    m.rate_hz = 120.0f;
    m.positions.assign(2, Vec3::Zero());
    m.valid.assign(2, 1);
    protocol::EncodeMarkerFrame(m, &bytes);
    w.Append(1, "markers/x/", bytes);
  }
  const TakeInfo info = InspectTake(path);
  ASSERT_EQ(info.streams.size(), 1u);
  EXPECT_EQ(info.streams[0].subject, forged);  // kept as sent; only its printing escapes
  const std::string table = FormatTakeInfo(info);
  EXPECT_EQ(table.find('\x1b'), std::string::npos) << table;
  EXPECT_EQ(table.find("b\nc"), std::string::npos) << table;
  EXPECT_NE(table.find("a\\u001b[2Jb\\nc\xef\xbf\xbd"), std::string::npos) << table;
  EXPECT_NO_THROW(
      (void)TakeInfoJson(info).dump(2, ' ', false, nlohmann::json::error_handler_t::replace));
}

TEST(TakeInfoTest, UnknownExtensionIsRejected) {
  EXPECT_THROW(InspectTake("take.fbx"), std::invalid_argument);
  EXPECT_EQ(FileExtension("/a.b/take"), "");
  EXPECT_EQ(FileExtension("x.BVH"), "bvh");
}

}  // namespace
}  // namespace mocapd
