// Tests for the refusal of an output that names an input or another output, or that
// cannot be written.
#include "formats/file_paths.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include <unistd.h>

#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

// The error CheckOutputPaths throws, or "" when it accepts.
std::string Refusal(std::initializer_list<NamedPath> inputs,
                    std::initializer_list<NamedPath> outputs) {
  try {
    CheckOutputPaths(std::span(inputs.begin(), inputs.size()),
                     std::span(outputs.begin(), outputs.size()));
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

class OutputPathsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = testing::TempDir("file_paths");
    std::ofstream(dir_ + "/take.c3d") << "raw";
  }
  std::string dir_;
};

TEST_F(OutputPathsTest, AWholeFileIsReadAndAFolderOrAMissingFileNamed) {
  EXPECT_EQ(ReadWholeFile(dir_ + "/take.c3d"), "raw");
  // A folder opens on Linux and reads as nothing: `model = "/tmp"` in a config was
  // reported as a subject file missing its format_version.
  try {
    ReadWholeFile(dir_);
    ADD_FAILURE() << "a folder was read";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()), dir_ + ": is a folder, not a file");
  }
  EXPECT_THROW(ReadWholeFile(dir_ + "/missing.c3d"), std::runtime_error);
}

TEST_F(OutputPathsTest, AnOutputNamingAnInputIsRefusedNamingBothOptions) {
  const std::string take = dir_ + "/take.c3d";
  EXPECT_EQ(Refusal({{"--in", take}}, {{"--out-c3d", take}}),
            "--out-c3d " + take + ": is the same file as --in " + take +
                "; an input is never overwritten: write elsewhere");
  // The same file by another spelling: "." and "..", a relative path, a symbolic link.
  EXPECT_NE(Refusal({{"--in", take}}, {{"--out", dir_ + "/./sub/../take.c3d"}}), "");
  const std::string relative =
      std::filesystem::relative(take, std::filesystem::current_path()).string();
  EXPECT_NE(Refusal({{"--in", relative}}, {{"--out", take}}), "");
  std::filesystem::remove(dir_ + "/link.c3d");
  std::filesystem::create_symlink(take, dir_ + "/link.c3d");
  EXPECT_NE(Refusal({{"--in", take}}, {{"--out", dir_ + "/link.c3d"}}), "");
  // A hard link is the same file under another name.
  std::filesystem::remove(dir_ + "/hard.c3d");
  std::filesystem::create_hard_link(take, dir_ + "/hard.c3d");
  EXPECT_NE(Refusal({{"--in", take}}, {{"--out", dir_ + "/hard.c3d"}}), "");
}

TEST_F(OutputPathsTest, TwoOutputsNamingOneFileAreRefused) {
  const std::string out = dir_ + "/solved.bvh";  // need not exist yet
  EXPECT_EQ(Refusal({}, {{"--out-bvh", out}, {"--out-c3d", out}}),
            "--out-c3d " + out + ": is the same file as --out-bvh " + out +
                "; each output needs a file of its own");
}

TEST_F(OutputPathsTest, DistinctFilesAndOptionsNotGivenAreAccepted) {
  EXPECT_EQ(Refusal({{"--in", dir_ + "/take.c3d"}, {"--retarget", ""}},
                    {{"--out-bvh", dir_ + "/solved.bvh"},
                     {"--out-c3d", dir_ + "/cleaned.c3d"},
                     {"--report", ""},
                     {"--plot", ""}}),
            "");
}

// Found before the work, not after it: `replay --report /missing/r.json` ran the whole
// replay and then failed, and `calibrate --out` in a missing folder solved the subject first.
TEST_F(OutputPathsTest, AnOutputThatCannotBeWrittenIsRefusedNamingItsOption) {
  EXPECT_EQ(Refusal({}, {{"--report", dir_ + "/missing/r.json"}}),
            "--report " + dir_ + "/missing/r.json: the folder " + dir_ + "/missing does not exist");
  EXPECT_EQ(Refusal({}, {{"--out", dir_}}), "--out " + dir_ + ": is a folder, not a file");
  // A device is written, not replaced: two outputs discarded to /dev/null are fine.
  EXPECT_EQ(Refusal({}, {{"--out-bvh", "/dev/null"}, {"--report", "/dev/null"}}), "");
  // Read-only is only read-only to a user who is not root (CI runs as root).
  if (geteuid() != 0) {
    const std::string locked = dir_ + "/locked.json";
    std::ofstream(locked) << "{}";
    std::filesystem::permissions(locked, std::filesystem::perms::owner_read);
    EXPECT_EQ(Refusal({}, {{"--report", locked}}),
              "--report " + locked + ": cannot be written (read-only)");
    std::filesystem::remove(locked);
  }
}

}  // namespace
}  // namespace mocapd
