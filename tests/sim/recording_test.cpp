// Tests for recorded capture streams: exact round trips, and crash safety -- a recording
// cut anywhere, or damaged, reads back up to its last intact record and says so.
#include "sim/recording.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

std::vector<uint8_t> Bytes(std::initializer_list<int> values) {
  std::vector<uint8_t> b;
  for (int v : values) b.push_back(static_cast<uint8_t>(v));
  return b;
}

std::string WriteThree(const std::string& dir) {
  const std::string path = dir + "/three.mcr";
  RecordingWriter w(path);
  w.Append(1000, "markers/actor1/", Bytes({1, 2, 3}));
  w.Append(2000, "markers/actor1/", Bytes({4, 5}));
  w.Append(8'333'333, "markers/actor2/", std::vector<uint8_t>(300, 7));
  EXPECT_EQ(w.records(), 3u);
  return path;
}

TEST(RecordingTest, EveryRecordReadsBackWithItsTopicTimeAndBytes) {
  const std::string path = WriteThree(testing::TempDir("recording_roundtrip"));
  EXPECT_TRUE(IsRecordingFile(path));
  const Recording r = ReadRecording(path);
  ASSERT_EQ(r.messages.size(), 3u);
  EXPECT_EQ(r.ignored_tail_bytes, 0u);
  EXPECT_GT(r.start_wall_ns, 0u);
  EXPECT_EQ(r.messages[1].offset_ns, 2000);
  EXPECT_EQ(r.messages[1].topic, "markers/actor1/");
  EXPECT_EQ(r.messages[1].message, Bytes({4, 5}));
  EXPECT_EQ(r.messages[2].topic, "markers/actor2/");
  EXPECT_EQ(r.messages[2].message.size(), 300u);
}

TEST(RecordingTest, ARecordingCutAnywhereKeepsEveryCompleteRecord) {
  const std::string dir = testing::TempDir("recording_cut");
  const std::string path = WriteThree(dir);
  const auto full = std::filesystem::file_size(path);
  const size_t third_record = 20 + 15 + 300 + 4;
  for (size_t cut = full - third_record; cut < full; ++cut) {
    const std::string copy = dir + "/cut.mcr";
    std::filesystem::copy_file(path, copy, std::filesystem::copy_options::overwrite_existing);
    std::filesystem::resize_file(copy, cut);
    const Recording r = ReadRecording(copy);
    ASSERT_EQ(r.messages.size(), 2u) << "cut at " << cut;
    EXPECT_EQ(r.ignored_tail_bytes, cut - (full - third_record));
  }
}

TEST(RecordingTest, ADamagedRecordEndsTheReadThereAndIsReported) {
  const std::string path = WriteThree(testing::TempDir("recording_damaged"));
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  f.seekp(16 + 20 + 15 + 3 + 4 + 20 + 15);  // the second record's first message byte
  f.put(static_cast<char>(99));
  f.close();
  const Recording r = ReadRecording(path);
  EXPECT_EQ(r.messages.size(), 1u);
  EXPECT_GT(r.ignored_tail_bytes, 0u);
}

TEST(RecordingTest, OtherFilesAreRefusedWithTheirName) {
  const std::string dir = testing::TempDir("recording_other");
  std::ofstream(dir + "/x.mcr") << "not a recording at all";
  EXPECT_FALSE(IsRecordingFile(dir + "/x.mcr"));
  try {
    ReadRecording(dir + "/x.mcr");
    FAIL() << "expected an error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("x.mcr: not a mocap-sim recording"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW(ReadRecording(dir + "/missing.mcr"), std::runtime_error);
}

}  // namespace
}  // namespace mocapd
