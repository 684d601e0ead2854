// Tests for the C3D reader and writer: exact round trips in every processor format and
// storage, labels beyond 255 points, model outputs, missing samples, and clear errors
// (never a crash) for truncated or corrupt files.
#include "formats/c3d.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <random>

namespace mocapd {
namespace {

C3dTake MakeTake(int points, int frames) {
  C3dTake take;
  for (int p = 0; p < points; ++p) take.labels.push_back("M" + std::to_string(p));
  take.rate_hz = 120.0;
  take.Allocate(frames);
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(-1500.0, 1500.0);
  for (int f = 0; f < frames; ++f) {
    for (int p = 0; p < points; ++p) {
      const size_t i =
          static_cast<size_t>(f) * static_cast<size_t>(points) + static_cast<size_t>(p);
      if ((f + p) % 7 == 3) continue;  // missing
      // Values on a 0.1 mm grid so integer storage is exact too.
      take.positions[i] = Vec3(std::round(u(rng)), std::round(u(rng)), std::round(u(rng))) * 1e-4;
      take.residuals[i] = 0.5f;
    }
  }
  return take;
}

void ExpectSameTake(const C3dTake& a, const C3dTake& b) {
  EXPECT_EQ(a.labels, b.labels);
  EXPECT_EQ(a.num_frames, b.num_frames);
  EXPECT_EQ(a.rate_hz, b.rate_hz);
  EXPECT_EQ(a.units, b.units);
  for (int f = 0; f < a.num_frames; ++f) {
    for (int p = 0; p < a.num_points(); ++p) {
      ASSERT_EQ(a.valid(f, p), b.valid(f, p)) << f << " " << p;
      if (a.valid(f, p)) {
        // Equal to float precision in file units (mm).
        ASSERT_LT((a.at(f, p) - b.at(f, p)).norm(), 1e-7) << f << " " << p;
      } else {
        ASSERT_FALSE(b.at(f, p).allFinite());
      }
    }
  }
}

TEST(C3dTest, FloatIntelWriteThenReadIsExact) {
  const C3dTake take = MakeTake(7, 40);
  const C3dTake dut = ParseC3d(EncodeC3d(take), "mem");
  ExpectSameTake(take, dut);
  EXPECT_EQ(dut.processor, "Intel");
  EXPECT_TRUE(dut.float_storage);
  // Bit-exact: what was read re-encodes to the same bytes.
  EXPECT_EQ(EncodeC3d(dut), EncodeC3d(take));
}

// The take written in every processor's layout and both storages, then read back.
std::vector<C3dTake> ReadInEveryEncoding(const C3dTake& take) {
  std::vector<C3dTake> reads;
  for (auto processor : {C3dEncoding::Processor::kIntel, C3dEncoding::Processor::kDec,
                         C3dEncoding::Processor::kMips}) {
    for (bool integer : {false, true}) {
      C3dEncoding encoding;
      encoding.processor = processor;
      encoding.integer_storage = integer;
      reads.push_back(ParseC3d(EncodeC3d(take, encoding), "mem"));
    }
  }
  return reads;
}

TEST(C3dTest, ReadsDecMipsAndIntegerFiles) {
  const C3dTake take = MakeTake(5, 12);
  const std::vector<C3dTake> reads = ReadInEveryEncoding(take);
  for (size_t i = 0; i < reads.size(); ++i) {
    SCOPED_TRACE(reads[i].processor + (reads[i].float_storage ? " float" : " int"));
    EXPECT_EQ(reads[i].float_storage, i % 2 == 0);  // float, then integer, per processor
    ExpectSameTake(take, reads[i]);
  }
}

TEST(C3dTest, LabelsBeyond255PointsUseLabels2) {
  const C3dTake take = MakeTake(300, 2);
  const C3dTake dut = ParseC3d(EncodeC3d(take), "mem");
  ASSERT_EQ(dut.num_points(), 300);
  EXPECT_EQ(dut.labels[299], "M299");
}

TEST(C3dTest, TellsModelOutputsFromMarkers) {
  C3dTake take = MakeTake(4, 3);
  take.model_output_kind[2] = "ANGLES";
  take.model_output_kind[3] = "POWERS";
  const C3dTake dut = ParseC3d(EncodeC3d(take), "mem");
  EXPECT_TRUE(dut.is_marker(0));
  EXPECT_TRUE(dut.is_marker(1));
  EXPECT_EQ(dut.model_output_kind[2], "ANGLES");
  EXPECT_EQ(dut.model_output_kind[3], "POWERS");
}

TEST(C3dTest, ConvertsUnitsToMetres) {
  C3dTake take = MakeTake(2, 2);
  take.units = "cm";
  take.metres_per_unit = 0.01;
  const C3dTake dut = ParseC3d(EncodeC3d(take), "mem");
  EXPECT_EQ(dut.units, "cm");
  EXPECT_LT((dut.at(0, 0) - take.at(0, 0)).norm(), 1e-7);  // float precision of 15 cm in cm
  EXPECT_NEAR(dut.at(0, 0).x(), take.at(0, 0).x(), 1e-7);
}

TEST(C3dTest, EveryTruncationIsAClearError) {
  const std::vector<uint8_t> bytes = EncodeC3d(MakeTake(3, 6));
  for (size_t n = 0; n < bytes.size(); n += (n < 1200 ? 1 : 13)) {
    const std::span<const uint8_t> prefix(bytes.data(), n);
    try {
      ParseC3d(prefix, "cut.c3d");
      // A cut inside the final padding leaves a complete file; anything else must throw.
      EXPECT_GE(n, bytes.size() - 512) << n;
    } catch (const C3dError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find("cut.c3d: "), std::string::npos);
      EXPECT_NE(what.find(" section, byte "), std::string::npos) << what;
    }
  }
}

TEST(C3dTest, TruncatedDataNamesTheFrame) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeTake(3, 60));
  bytes.resize(bytes.size() - 700);
  try {
    ParseC3d(bytes, "short.c3d");
    FAIL();
  } catch (const C3dError& e) {
    EXPECT_NE(std::string(e.what()).find("data section"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("file ends inside frame"), std::string::npos) << e.what();
  }
}

TEST(C3dTest, CorruptBytesNeverCrash) {
  const std::vector<uint8_t> original = EncodeC3d(MakeTake(4, 10));
  std::mt19937_64 rng(11);
  std::uniform_int_distribution<size_t> pos(0, original.size() - 1);
  std::uniform_int_distribution<int> byte(0, 255);
  int errors = 0;
  for (int trial = 0; trial < 2000; ++trial) {
    std::vector<uint8_t> bytes = original;
    for (int k = 0; k < 1 + trial % 8; ++k) bytes[pos(rng)] = static_cast<uint8_t>(byte(rng));
    try {
      ParseC3d(bytes, "fuzz.c3d");
    } catch (const C3dError&) {
      ++errors;
    }
  }
  EXPECT_GT(errors, 0);
}

TEST(C3dTest, FramesWithNothingToStoreAreRejectedNotWalked) {
  // Found by fuzzing: a huge frame count with zero bytes per frame used to loop for
  // minutes. Such a file carries no samples at all and is now refused at once.
  C3dTake empty;
  empty.rate_hz = 100.0;
  empty.Allocate(40000);
  try {
    ParseC3d(EncodeC3d(empty), "empty.c3d");
    FAIL();
  } catch (const C3dError& e) {
    EXPECT_NE(std::string(e.what()).find("40000 frames declared but no points or analog channels"),
              std::string::npos)
        << e.what();
  }
}

TEST(C3dTest, BadHeaderKeyIsReported) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeTake(2, 2));
  bytes[1] = 0x51;
  try {
    ParseC3d(bytes, "x.c3d");
    FAIL();
  } catch (const C3dError& e) {
    EXPECT_NE(std::string(e.what()).find("header section, byte 1: not a C3D file: its second "
                                         "byte is 81 where a C3D has 0x50"),
              std::string::npos)
        << e.what();
  }
  // A text file (a BVH given where a take goes) says what it starts with.
  const std::string bvh = "HIERARCHY\nROOT Hips\n";
  try {
    ParseC3d(std::span(reinterpret_cast<const uint8_t*>(bvh.data()), bvh.size()), "take.bvh");
    FAIL();
  } catch (const C3dError& e) {
    EXPECT_NE(std::string(e.what()).find("it is text starting \"HIERARCHY\" (a BVH file)"),
              std::string::npos)
        << e.what();
  }
}

TEST(C3dTest, UnknownProcessorIsReported) {
  std::vector<uint8_t> bytes = EncodeC3d(MakeTake(2, 2));
  bytes[512 + 3] = 99;
  EXPECT_THROW(ParseC3d(bytes, "x.c3d"), C3dError);
}

TEST(C3dTest, WriterRejectsInconsistentTakes) {
  C3dTake take = MakeTake(2, 2);
  take.positions.pop_back();
  EXPECT_THROW(EncodeC3d(take), std::invalid_argument);
  take = MakeTake(2, 2);
  take.rate_hz = 0;
  EXPECT_THROW(EncodeC3d(take), std::invalid_argument);
}

// A Vicon file labels "Dan:LBWT"; the subject written from it by `mocapd calibrate` says
// "LBWT", and `mocapd process` and `mocap-sim replay` found none of its markers.
TEST(C3dTest, FindsALabelUnderASubjectPrefixPaddingOrAnotherCase) {
  C3dTake take;
  take.labels = {"Dan:LBWT", "Dan:RBWT  ", "lfhd", "LBWT2"};
  EXPECT_EQ(take.FindLabel("LBWT"), 0);
  EXPECT_EQ(take.FindLabel("RBWT"), 1);
  EXPECT_EQ(take.FindLabel("LFHD"), 2);
  EXPECT_EQ(take.FindLabel("LBWT2"), 3);
  EXPECT_EQ(take.FindLabel("Dan:LBWT"), 0);  // exact first
  EXPECT_EQ(take.FindLabel("RFHD"), -1);
  take.labels = {"Dan:LBWT", "Eve:LBWT"};  // two subjects: no unique answer
  EXPECT_EQ(take.FindLabel("LBWT"), -1);
  EXPECT_EQ(take.FindLabel("Eve:LBWT"), 1);
  EXPECT_EQ(take.MatchingLabels("LBWT"), (std::vector<int>{0, 1}));
  take.labels = {"Eve:LBWT"};
  EXPECT_EQ(take.FindLabel("Dan:LBWT"), -1);  // a prefix names its subject
  EXPECT_EQ(take.FindLabel("eve:lbwt"), 0);
  take.labels = {"LBWT", "lbwt", "LBWT"};  // repeated exactly: the file's first
  EXPECT_EQ(take.FindLabel("LBWT"), 0);
  EXPECT_EQ(take.MatchingLabels("LBWT"), (std::vector<int>{0, 2}));
}

// Exporters write a gap as (0, 0, 0) with residual 0: a marker exactly at the origin is
// missing, not a sample there (a calibration then rejected the whole limb around it). A
// model output (an angle) of zero stays a value.
TEST(C3dTest, AMarkerExactlyAtTheOriginIsMissing) {
  for (const bool float_storage : {true, false}) {
    C3dTake take = MakeTake(3, 10);
    take.labels.push_back("LKneeAngles");
    take.Allocate(10);
    for (int f = 0; f < 10; ++f)
      for (int p = 0; p < 4; ++p) {
        take.at(f, p) = p == 0 ? Vec3::Zero() : Vec3(0.1 * (p + 1), 0.2, 0.3);
        take.residuals[static_cast<size_t>(f * 4 + p)] = 0.0f;
      }
    take.at(4, 1) = Vec3::Zero();
    take.model_output_kind[3] = "ANGLES";
    for (int f = 0; f < 10; ++f) take.at(f, 3) = Vec3::Zero();
    C3dEncoding encoding;
    encoding.integer_storage = !float_storage;
    const C3dTake read = ParseC3d(EncodeC3d(take, encoding), "zeros.c3d");
    EXPECT_EQ(read.origin_samples_missing, 11) << float_storage;
    for (int f = 0; f < 10; ++f) {
      EXPECT_FALSE(read.valid(f, 0));
      EXPECT_EQ(read.valid(f, 1), f != 4);
      EXPECT_TRUE(read.valid(f, 2));
      EXPECT_TRUE(read.valid(f, 3));  // an angle of zero
    }
  }
}

// An exporter that rewrote POINT:RATE and not the header (or the other way round): the
// parameter is used, and the reader says so rather than leaving a take that plays fast
// or slow unexplained.
TEST(C3dTest, AHeaderRateThatDisagreesWithPointRateIsNoted) {
  C3dTake take = MakeTake(3, 10);
  take.rate_hz = 120.0;
  std::vector<uint8_t> bytes = EncodeC3d(take);
  EXPECT_TRUE(ParseC3d(bytes, "same.c3d").notes.empty());
  const float header_rate = 100.0f;  // Intel: a little-endian float at byte 20
  std::memcpy(&bytes[20], &header_rate, sizeof(header_rate));
  const C3dTake read = ParseC3d(bytes, "rates.c3d");
  EXPECT_EQ(read.rate_hz, 120.0);
  ASSERT_EQ(read.notes.size(), 1u);
  EXPECT_NE(read.notes[0].find("100 Hz"), std::string::npos) << read.notes[0];
  EXPECT_NE(read.notes[0].find("POINT:RATE 120 Hz"), std::string::npos) << read.notes[0];
}

// TRIAL:ACTUAL_END_FIELD counts frames past the header's 65535; a cropping tool can leave
// a stale one behind, longer than the header and the data. The header's count then
// stands (the file was refused: "file ends inside frame 601 of 5000").
TEST(C3dTest, AStaleTrialRangeLongerThanTheDataLeavesTheHeadersCount) {
  const C3dTake take = MakeTake(3, 20);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  EXPECT_EQ(ParseC3d(bytes, "t.c3d").num_frames, 20);
  // ACTUAL_END_FIELD's value follows its name, link (2), type (1), dimension count (1)
  // and dimension (1): low word, high word, little-endian.
  const std::string name = "ACTUAL_END_FIELD";
  const auto at = std::search(bytes.begin(), bytes.end(), name.begin(), name.end());
  ASSERT_NE(at, bytes.end());
  const auto value = static_cast<size_t>(at - bytes.begin()) + name.size() + 2 + 1 + 1 + 1;
  EXPECT_EQ(bytes[value] + 256 * bytes[value + 1], take.first_frame + 19);
  bytes[value] = 5000 & 0xff;
  bytes[value + 1] = 5000 >> 8;
  const C3dTake read = ParseC3d(bytes, "t.c3d");
  EXPECT_EQ(read.num_frames, 20);
  EXPECT_LT((read.at(19, 2) - take.at(19, 2)).norm(), 1e-6);
}

// The byte offset of a parameter's first value: after its name, link (2), type (1) and
// dimension count (1), and the dimensions themselves.
size_t ValueOffset(const std::vector<uint8_t>& bytes, const std::string& name, int dimensions) {
  const auto at = std::search(bytes.begin(), bytes.end(), name.begin(), name.end());
  EXPECT_NE(at, bytes.end()) << name;
  return static_cast<size_t>(at - bytes.begin()) + name.size() + 2 + 1 + 1 +
         static_cast<size_t>(dimensions);
}

// An encoded 20-frame take cropped to nothing as a cropping tool leaves it: the header
// and POINT:FRAMES count no frame, the TRIAL range of the take it came from says 5000.
void CropToNothingLeavingTheTrialRange(std::vector<uint8_t>* bytes, int first_frame) {
  std::vector<uint8_t>& b = *bytes;
  const size_t trial_end = ValueOffset(b, "ACTUAL_END_FIELD", 1);
  b[trial_end] = 5000 & 0xff;
  b[trial_end + 1] = 5000 >> 8;
  const size_t point_frames = ValueOffset(b, "FRAMES", 0);
  ASSERT_EQ(b[point_frames] + 256 * b[point_frames + 1], 20);
  b[point_frames] = b[point_frames + 1] = 0;
  const int last = first_frame - 1;  // header word 5, one before the first (word 4)
  b[8] = static_cast<uint8_t>(last & 0xff);
  b[9] = static_cast<uint8_t>(last >> 8);
}

// POINT:USED rewritten from the 3 points the take holds (and the header says) to `used`.
void RewritePointUsed(std::vector<uint8_t>* bytes, uint8_t used) {
  const size_t at = ValueOffset(*bytes, "USED", 0);
  ASSERT_EQ((*bytes)[at] + 256 * (*bytes)[at + 1], 3);
  (*bytes)[at] = used;
}

// Reads bytes expecting `take` back, with one note, which says `note`.
C3dTake ReadWithOneNote(const std::vector<uint8_t>& bytes, const C3dTake& take,
                        const std::string& note) {
  const C3dTake read = ParseC3d(bytes, "noted.c3d");
  ExpectSameTake(take, read);
  EXPECT_EQ(read.notes.size(), 1u);
  for (const std::string& n : read.notes) EXPECT_NE(n.find(note), std::string::npos) << n;
  return read;
}

// A take cropped to nothing: the header and POINT:FRAMES say zero frames, but the TRIAL
// range of the take it came from stayed behind. Trusted because the header counted
// nothing, it made an empty take a truncated one ("file ends inside frame 21 of 5000").
TEST(C3dTest, AnEmptyTakeWithAStaleTrialRangeReadsAsEmpty) {
  const C3dTake take = MakeTake(3, 20);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  ASSERT_NO_FATAL_FAILURE(CropToNothingLeavingTheTrialRange(&bytes, take.first_frame));
  EXPECT_EQ(ParseC3d(bytes, "empty.c3d").num_frames, 0);
}

// An exporter that rewrote POINT:USED and not the header: the data holds frames of the
// header's count, which is used, with a note (it was refused as a truncated file). Where
// the data holds frames of neither, the error names both counts.
TEST(C3dTest, APointCountTheDataDoesNotHoldGivesWayToTheHeadersWithANote) {
  const C3dTake take = MakeTake(3, 20);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  ASSERT_NO_FATAL_FAILURE(RewritePointUsed(&bytes, 5));
  ReadWithOneNote(bytes, take, "POINT:USED says 5 points, the header 3");
  // Neither count fits: the last frame cut short (header word 9: the data's first block).
  const size_t data_start = (bytes[16] + 256u * bytes[17] - 1) * 512;
  bytes.resize(data_start + 19 * 3 * 16 + 8);
  try {
    ParseC3d(bytes, "cut.c3d");
    FAIL();
  } catch (const C3dError& e) {
    EXPECT_NE(std::string(e.what()).find("POINT:USED says 5 points, the header 3, and the data "
                                         "holds frames of neither"),
              std::string::npos)
        << e.what();
  }
}

// Fewer points in POINT:USED than the header and the data hold: the smaller count's
// frames leave most of the data section unread, the header's fill it. Every frame was
// read at the wrong stride, silently.
TEST(C3dTest, APointCountThatLeavesTheDataHalfReadGivesWayToTheHeadersWithANote) {
  const C3dTake take = MakeTake(3, 100);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  ASSERT_NO_FATAL_FAILURE(RewritePointUsed(&bytes, 1));
  ReadWithOneNote(bytes, take, "POINT:USED says 1 points, the header 3");
}

// No points and no frames, with a stale TRIAL range from the take it was cut from: nothing
// per frame confirms the range, so the header's count (none) stands. It was refused ("5000
// frames declared but no points or analog channels to store").
TEST(C3dTest, ATakeWithNoPointsAndAStaleTrialRangeReadsAsEmpty) {
  C3dTake take;
  take.rate_hz = 100.0;
  take.Allocate(20);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  ASSERT_NO_FATAL_FAILURE(CropToNothingLeavingTheTrialRange(&bytes, take.first_frame));
  const C3dTake read = ParseC3d(bytes, "nothing.c3d");
  EXPECT_EQ(read.num_frames, 0);
  EXPECT_EQ(read.num_points(), 0);
}

// POINT:SCALE's sign says float or integer samples, and so does the header's scale. An
// exporter that rewrote one: float data read as integers (or the reverse) was garbage in
// every frame, without a word. Only one storage's frames fill the data: that one is read.
TEST(C3dTest, AScaleWhoseSignTheDataContradictsGivesWayToTheHeadersWithANote) {
  const C3dTake take = MakeTake(3, 100);
  for (const bool integer : {false, true}) {
    C3dEncoding encoding;
    encoding.integer_storage = integer;
    std::vector<uint8_t> bytes = EncodeC3d(take, encoding);
    const float wrong = integer ? -0.1f : 0.1f;  // Intel: little-endian IEEE
    std::memcpy(&bytes[ValueOffset(bytes, "SCALE", 0)], &wrong, sizeof(wrong));
    const C3dTake read = ReadWithOneNote(
        bytes, take,
        integer ? "POINT:SCALE is -0.1 (float samples), the header's scale 0.1: the data holds "
                  "frames of integer samples"
                : "POINT:SCALE is 0.1 (integer samples), the header's scale -0.1: the data "
                  "holds frames of float samples");
    EXPECT_EQ(read.float_storage, !integer);
  }
}

// The same take with 8 analog channels sampled once a frame stored after each frame's
// points (zeros), ANALOG:USED saying `channels` and the header `header_values`.
// ANALOG:USED (the second USED: POINT's comes first) rewritten to `channels`.
void RewriteAnalogUsed(std::vector<uint8_t>* bytes, uint8_t channels) {
  std::vector<uint8_t>& b = *bytes;
  const std::string used = "USED";
  const auto point_used = std::search(b.begin(), b.end(), used.begin(), used.end());
  const auto analog_used = std::search(point_used + 1, b.end(), used.begin(), used.end());
  ASSERT_NE(analog_used, b.end());
  b[static_cast<size_t>(analog_used - b.begin()) + used.size() + 4] = channels;
}

std::vector<uint8_t> WithAnalogChannels(const C3dTake& take, uint8_t channels,
                                        uint8_t header_values) {
  std::vector<uint8_t> b = EncodeC3d(take);
  RewriteAnalogUsed(&b, channels);
  b[4] = header_values;  // header word 3: analog values a frame
  b[5] = 0;
  const size_t data_start = (b[16] + 256u * b[17] - 1) * 512;
  const size_t point_bytes = static_cast<size_t>(take.num_points()) * 16;
  std::vector<uint8_t> out(b.begin(), b.begin() + static_cast<std::ptrdiff_t>(data_start));
  for (int f = 0; f < take.num_frames; ++f) {
    const auto frame = b.begin() + static_cast<std::ptrdiff_t>(data_start + f * point_bytes);
    out.insert(out.end(), frame, frame + static_cast<std::ptrdiff_t>(point_bytes));
    out.insert(out.end(), 8 * 4, 0);
  }
  out.resize((out.size() + 511) / 512 * 512, 0);
  return out;
}

// The header's count of analog values a frame against ANALOG:USED times the analog samples
// a frame: where only the parameters' fills the data, the points were read at the wrong
// stride, silently (73 % of a take's samples then repaired as missing).
TEST(C3dTest, AnAnalogCountTheDataContradictsGivesWayToTheParametersWithANote) {
  const C3dTake take = MakeTake(3, 100);
  ReadWithOneNote(WithAnalogChannels(take, 8, 4), take,
                  "the header stores 4 analog values a frame, ANALOG:USED x ANALOG:RATE / "
                  "POINT:RATE 8: the data holds frames of 8");
  // The header right and the parameter wrong: the header's stands. The only note is the
  // analog rate the data then holds (2 samples a frame of 4 channels) against ANALOG:RATE.
  const C3dTake header_right = ParseC3d(WithAnalogChannels(take, 4, 8), "analog.c3d");
  ExpectSameTake(take, header_right);
  ASSERT_EQ(header_right.notes.size(), 1u);
  EXPECT_EQ(header_right.notes[0].rfind("ANALOG:RATE is ", 0), 0u) << header_right.notes[0];
  // Two fields at odds: POINT:USED 2 points fewer than the header and ANALOG:USED 8 values
  // more make the same frame. Sizes cannot say which; the points' fallback stands alone,
  // as before (the analog check took the header's last two points for analog values).
  std::vector<uint8_t> both = EncodeC3d(take);
  ASSERT_NO_FATAL_FAILURE(RewritePointUsed(&both, 1));
  ASSERT_NO_FATAL_FAILURE(RewriteAnalogUsed(&both, 8));
  ReadWithOneNote(both, take, "POINT:USED says 1 points, the header 3");
}

// Little-endian bytes of floats or int16s, as C3dParameter holds them.
template <typename T>
std::vector<uint8_t> LittleEndian(std::initializer_list<T> values) {
  std::vector<uint8_t> out(values.size() * sizeof(T));
  size_t at = 0;
  for (T v : values) {
    std::memcpy(out.data() + at, &v, sizeof(T));
    at += sizeof(T);
  }
  return out;
}

// The groups a cleanup does not touch (force plates' geometry, gait events, the subjects)
// were dropped from every C3D written, and POINT:SCALE was rewritten as -0.1, so a residual
// word of 2 at scale 1 (2.00 mm) read back as 0.20 mm. Both now come through in every
// encoding, and the force plates go only with analog channels to describe.
TEST(C3dTest, OtherParametersAndResidualWordsComeThroughAWriteAndARead) {
  C3dTake take = MakeTake(3, 10);
  take.point_scale = 1.0;
  for (float& r : take.residuals)
    if (r >= 0.0f) r = static_cast<float>(0x7f02);  // cameras 0x7f, residual 2 units
  const std::string events = "Foot Strike" + std::string("Foot Off   ");
  take.other_parameters = {
      {"EVENT", "USED", 2, {}, LittleEndian<int16_t>({2})},
      {"EVENT", "LABELS", -1, {11, 2}, std::vector<uint8_t>(events.begin(), events.end())},
      {"EVENT", "TIMES", 4, {2, 2}, LittleEndian<float>({0.0f, 1.5f, 0.0f, 2.25f})},
      {"FORCE_PLATFORM", "CORNERS", 4, {3, 2}, LittleEndian<float>({300, 250, 0, -300, 250, 0})},
      {"POINT", "X_SCREEN", -1, {2}, {'+', 'X'}},
      {"SUBJECTS", "IS_STATIC", 1, {}, {0}},
  };
  const auto kept = [](const C3dTake& t, const std::string& key) -> const C3dParameter* {
    for (const C3dParameter& p : t.other_parameters)
      if (p.group + ":" + p.name == key) return &p;
    return nullptr;
  };
  for (const C3dTake& dut : ReadInEveryEncoding(take)) {
    SCOPED_TRACE(dut.processor + (dut.float_storage ? " float" : " int"));
    for (const char* key :
         {"EVENT:USED", "EVENT:LABELS", "EVENT:TIMES", "POINT:X_SCREEN", "SUBJECTS:IS_STATIC"}) {
      const C3dParameter* p = kept(dut, key);
      const C3dParameter* q = kept(take, key);
      ASSERT_NE(p, nullptr) << key;
      EXPECT_EQ(p->type, q->type) << key;
      EXPECT_EQ(p->dims, q->dims) << key;
      EXPECT_EQ(p->data, q->data) << key;
    }
    EXPECT_EQ(kept(dut, "FORCE_PLATFORM:CORNERS"), nullptr);  // no analog channels written
    if (dut.float_storage) {
      EXPECT_EQ(dut.point_scale, 1.0);
    }
    // In every encoding, each sample's cameras and its residual in millimetres.
    for (size_t i = 0; i < take.residuals.size(); ++i) {
      ASSERT_EQ(dut.residuals[i] < 0.0f, take.residuals[i] < 0.0f) << i;
      if (take.residuals[i] < 0.0f) continue;
      const auto word = static_cast<int>(dut.residuals[i]);
      ASSERT_EQ(word >> 8, 0x7f) << i;
      ASSERT_NEAR((word & 0xff) * dut.point_scale, 2.0, 1e-6) << i;
    }
  }
  // With analog channels, the force plates' parameters come too; read, then written again,
  // the same bytes.
  take.analog.labels = {"Fz1"};
  take.analog.descriptions = {""};
  take.analog.units = {"N"};
  take.analog.scale = {1.0};
  take.analog.offset = {0};
  take.analog.samples_per_frame = 1;
  take.analog.values.assign(10, 1.0f);
  const C3dTake once = ParseC3d(EncodeC3d(take), "plates.c3d");
  ASSERT_NE(kept(once, "FORCE_PLATFORM:CORNERS"), nullptr);
  EXPECT_EQ(kept(once, "FORCE_PLATFORM:CORNERS")->data, kept(take, "FORCE_PLATFORM:CORNERS")->data);
  EXPECT_EQ(EncodeC3d(ParseC3d(EncodeC3d(once), "again.c3d")), EncodeC3d(once));
}

// A take's analog channels (force plates, EMG) come through a read and a write as the
// file stored them, with what turns them into units: the cleaned C3D of `mocapd process`
// lost them all (160 values a frame read, 0 written).
TEST(C3dTest, AnalogChannelsSurviveAWriteAndARead) {
  C3dTake take = MakeTake(3, 20);
  C3dTake::Analog& analog = take.analog;
  analog.labels = {"Fx1", "Fy1", "EMG1"};
  analog.descriptions = {"force x", "force y", ""};
  analog.units = {"N", "N", "V"};
  analog.scale = {0.5, -0.25, 0.0009765625};  // the file holds float32: exact ones
  analog.offset = {2048, 0, 7};
  analog.gen_scale = 2.0;
  analog.samples_per_frame = 4;
  for (size_t i = 0; i < 20u * analog.values_per_frame(); ++i)
    analog.values.push_back(static_cast<float>(static_cast<int>(i * 37 % 4001) - 2000));
  for (const C3dTake& dut : ReadInEveryEncoding(take)) {
    SCOPED_TRACE(dut.processor + (dut.float_storage ? " float" : " int"));
    ExpectSameTake(take, dut);
    EXPECT_TRUE(dut.notes.empty());
    EXPECT_EQ(dut.analog.labels, analog.labels);
    EXPECT_EQ(dut.analog.descriptions, analog.descriptions);
    EXPECT_EQ(dut.analog.units, analog.units);
    EXPECT_EQ(dut.analog.scale, analog.scale);
    EXPECT_EQ(dut.analog.offset, analog.offset);
    EXPECT_EQ(dut.analog.gen_scale, analog.gen_scale);
    EXPECT_EQ(dut.analog.samples_per_frame, 4);
    EXPECT_EQ(dut.analog.values, analog.values);
  }
  // Read back and written again: the same bytes.
  const C3dTake once = ParseC3d(EncodeC3d(take), "analog.c3d");
  EXPECT_EQ(EncodeC3d(once), EncodeC3d(take));
  // One actor's points chosen from a take of two: the stage's analog channels stay (they
  // were dropped with the other actor's points).
  C3dTake two_actors = take;
  two_actors.labels = {"Ann:M0", "Ann:M1", "Bob:M0"};
  SelectActor(&two_actors, "Ann", "two.c3d");
  ASSERT_EQ(two_actors.num_points(), 2);
  EXPECT_EQ(two_actors.analog.values, analog.values);
  EXPECT_NO_THROW((void)EncodeC3d(two_actors));
  // Integer storage of an unsigned format holds 0..65535, and its offsets read unsigned.
  take.analog.format = "UNSIGNED";
  take.analog.offset = {40000, 0, 7};
  for (float& v : take.analog.values) v += 30000.0f;  // 28000..32000: inside either range
  take.analog.values[5] = 65535.0f;
  C3dEncoding integer;
  integer.integer_storage = true;
  const C3dTake unsigned_read = ParseC3d(EncodeC3d(take, integer), "unsigned.c3d");
  EXPECT_EQ(unsigned_read.analog.format, "UNSIGNED");
  EXPECT_EQ(unsigned_read.analog.offset, take.analog.offset);
  EXPECT_EQ(unsigned_read.analog.values, take.analog.values);
  take.analog.values[5] = 70000.0f;
  EXPECT_THROW((void)EncodeC3d(take, integer), std::invalid_argument);
  // Values that do not match frames x channels x samples are refused, not written short.
  take.analog.values.pop_back();
  EXPECT_THROW((void)EncodeC3d(take), std::invalid_argument);
}

// A C writer ends a label with a NUL and may leave its buffer's bytes after it: the label
// ends at the NUL ("M0\0XYZ" was read as "M0\0XYZ", matched no subject marker and was
// written by calibrate as "M0XYZ").
TEST(C3dTest, ALabelEndsAtItsFirstNul) {
  C3dTake take = MakeTake(3, 10);
  take.labels[1] = "LONGNAME";
  std::vector<uint8_t> bytes = EncodeC3d(take);
  const std::string padded = "M0      ";
  const auto at = std::search(bytes.begin(), bytes.end(), padded.begin(), padded.end());
  ASSERT_NE(at, bytes.end());
  const char garbage[] = {'M', '0', '\0', 'X', 'Y', 'Z', ' ', ' '};
  std::copy(std::begin(garbage), std::end(garbage), at);
  EXPECT_EQ(ParseC3d(bytes, "nul.c3d").labels[0], "M0");
}

// A take cropped by rewriting its frame counts alone: the counted frames are read, and
// the frames past them said (they were left out without a word).
TEST(C3dTest, FramesPastTheCountAreNotedNotDroppedInSilence) {
  const C3dTake take = MakeTake(3, 100);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  const int last = take.first_frame + 49;
  bytes[8] = static_cast<uint8_t>(last & 0xff);  // header word 5: the last frame
  bytes[9] = static_cast<uint8_t>(last >> 8);
  const size_t point_frames = ValueOffset(bytes, "FRAMES", 0);
  bytes[point_frames] = 50;
  bytes[point_frames + 1] = 0;
  const size_t trial_end = ValueOffset(bytes, "ACTUAL_END_FIELD", 1);
  bytes[trial_end] = static_cast<uint8_t>(last & 0xff);
  bytes[trial_end + 1] = static_cast<uint8_t>(last >> 8);
  const C3dTake read = ParseC3d(bytes, "cropped.c3d");
  EXPECT_EQ(read.num_frames, 50);
  ASSERT_EQ(read.notes.size(), 1u);
  EXPECT_EQ(read.notes[0],
            "the data section is larger than the 50 frames the header and parameters count (room "
            "for 106): the 50 counted are read");
  EXPECT_TRUE(ParseC3d(EncodeC3d(take), "whole.c3d").notes.empty());
  // An empty take's padded data block is no frame past the count.
  EXPECT_TRUE(ParseC3d(EncodeC3d(MakeTake(3, 0)), "empty.c3d").notes.empty());
}

// A take cropped by rewriting the header's range, POINT:FRAMES left at the original's
// 2751: the data holds the header's 20 frames, which are read, with a note. The file was
// refused ("file ends inside frame 21 of 2751").
TEST(C3dTest, AStalePointFramesLongerThanTheDataGivesWayToTheHeadersWithANote) {
  const C3dTake take = MakeTake(3, 20);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  const size_t point_frames = ValueOffset(bytes, "FRAMES", 0);
  bytes[point_frames] = 2751 & 0xff;
  bytes[point_frames + 1] = 2751 >> 8;
  ReadWithOneNote(bytes, take, "POINT:FRAMES says 2751 frames, the header 20");
}

// The mirror: a crop that rewrote POINT:FRAMES (and TRIAL) but left the header's longer
// count was refused as truncated ("file ends inside frame 21 of 2751").
TEST(C3dTest, AStaleHeaderCountLongerThanTheDataGivesWayToPointFramesWithANote) {
  const C3dTake take = MakeTake(3, 20);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  const int last = take.first_frame + 2750;
  bytes[8] = static_cast<uint8_t>(last & 0xff);
  bytes[9] = static_cast<uint8_t>(last >> 8);
  ReadWithOneNote(bytes, take,
                  "the header counts 2751 frames, POINT:FRAMES 20: the data holds 20, so "
                  "POINT:FRAMES is read");
}

// A tool that grew the parameter section by a block moved the data on and updated the
// header's data start, not POINT:DATA_START, which then pointed inside the parameters:
// read there, every frame was garbage and nothing said so. One pointing a block past the
// data's start was refused as truncated.
TEST(C3dTest, ADataStartThatCannotBeTheDataGivesWayToTheHeadersWithANote) {
  const C3dTake take = MakeTake(3, 20);
  const std::vector<uint8_t> encoded = EncodeC3d(take);
  const size_t param_start = (static_cast<size_t>(encoded[0]) - 1) * 512;
  const size_t data_block =
      static_cast<size_t>(encoded[16]) | (static_cast<size_t>(encoded[17]) << 8);
  const auto block = [](size_t b) { return std::to_string(b); };
  {
    std::vector<uint8_t> grown = encoded;
    grown.insert(grown.begin() + static_cast<std::ptrdiff_t>((data_block - 1) * 512), 512, 0);
    grown[param_start + 2] = static_cast<uint8_t>(grown[param_start + 2] + 1);
    grown[16] = static_cast<uint8_t>((data_block + 1) & 0xff);
    grown[17] = static_cast<uint8_t>((data_block + 1) >> 8);
    ReadWithOneNote(grown, take,
                    "POINT:DATA_START says block " + block(data_block) + ", the header block " +
                        block(data_block + 1) +
                        ": POINT:DATA_START lies inside the parameter section, so the header's "
                        "is read");
  }
  {
    std::vector<uint8_t> late = encoded;
    const size_t value = ValueOffset(late, "DATA_START", 0);
    late[value] = static_cast<uint8_t>((data_block + 1) & 0xff);
    late[value + 1] = static_cast<uint8_t>((data_block + 1) >> 8);
    ReadWithOneNote(late, take,
                    "POINT:DATA_START says block " + block(data_block + 1) + ", the header block " +
                        block(data_block) +
                        ": POINT:DATA_START leaves too little data for the 20 frames counted, "
                        "so the header's is read");
  }
}

// Data at neither start (both fields a block past it) reads as a file too short: the
// error says which block the data was read from and what each field said, where it said
// only where the file ended.
TEST(C3dTest, AFileTooShortForItsDataStartSaysWhereTheDataWasRead) {
  const C3dTake take = MakeTake(3, 20);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  const size_t data_block = static_cast<size_t>(bytes[16]) | (static_cast<size_t>(bytes[17]) << 8);
  const size_t value = ValueOffset(bytes, "DATA_START", 0);
  for (const size_t at : {size_t{16}, value}) {
    bytes[at] = static_cast<uint8_t>((data_block + 1) & 0xff);
    bytes[at + 1] = static_cast<uint8_t>((data_block + 1) >> 8);
  }
  try {
    ParseC3d(bytes, "moved.c3d");
    FAIL() << "a file too short for its data start was read";
  } catch (const C3dError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("file ends inside frame"), std::string::npos) << what;
    EXPECT_NE(what.find("data read from block " + std::to_string(data_block + 1) +
                        " (the header's and POINT:DATA_START's)"),
              std::string::npos)
        << what;
  }
  // The fields disagreeing, and neither holding the frames: both are named.
  bytes[16] = static_cast<uint8_t>((data_block + 2) & 0xff);
  bytes[17] = static_cast<uint8_t>((data_block + 2) >> 8);
  try {
    ParseC3d(bytes, "moved.c3d");
    FAIL() << "a file too short for its data start was read";
  } catch (const C3dError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("POINT:DATA_START says " + std::to_string(data_block + 1) +
                        ", the header " + std::to_string(data_block + 2)),
              std::string::npos)
        << what;
  }
}

// Two quirks in one file: POINT:FRAMES left at a longer take's count and POINT:USED
// rewritten. The point counts were weighed against the stale frame count, which no layout
// fits, so the header's points were never tried and the file was refused as truncated.
TEST(C3dTest, AStalePointFramesAndARewrittenPointUsedAreBothReconciled) {
  const C3dTake take = MakeTake(3, 20);
  for (const int used : {5, 1}) {
    std::vector<uint8_t> bytes = EncodeC3d(take);
    const size_t point_frames = ValueOffset(bytes, "FRAMES", 0);
    bytes[point_frames] = 2751 & 0xff;
    bytes[point_frames + 1] = 2751 >> 8;
    ASSERT_NO_FATAL_FAILURE(RewritePointUsed(&bytes, used));
    const C3dTake read = ParseC3d(bytes, "two_quirks.c3d");
    ExpectSameTake(take, read);
    ASSERT_EQ(read.notes.size(), 2u) << "POINT:USED " << used;
    EXPECT_NE(
        read.notes[0].find("POINT:USED says " + std::to_string(used) + " points, the header 3"),
        std::string::npos)
        << read.notes[0];
    EXPECT_NE(read.notes[1].find("POINT:FRAMES says 2751 frames, the header 20"), std::string::npos)
        << read.notes[1];
  }
}

// Past 65535 frames the header is capped; the count is in the TRIAL range or a POINT:FRAMES
// wide enough. With neither (no TRIAL group, POINT:FRAMES a 16-bit count wrapped or 0),
// the smaller count won: 65536 frames dropped, or an empty take, in silence. The data's
// whole frames are read, its padding block not among them, with a note.
TEST(C3dTest, ACappedHeaderReadsEveryFrameTheDataHoldsWhenNoCountIsWider) {
  const C3dTake take = MakeTake(1, 70000);
  const std::vector<uint8_t> encoded = EncodeC3d(take);
  // 65535: capped like the header (the frames past it were dropped).
  for (const float point_frames : {4464.0f, 0.0f, 65535.0f}) {
    SCOPED_TRACE(point_frames);
    std::vector<uint8_t> bytes = encoded;
    const std::string trial = "ACTUAL_END_FIELD";
    auto at = std::search(bytes.begin(), bytes.end(), trial.begin(), trial.end());
    ASSERT_NE(at, bytes.end());
    *at = 'X';  // an unknown parameter now: no TRIAL range
    const size_t frames_at = ValueOffset(bytes, "FRAMES", 0);
    std::memcpy(&bytes[frames_at], &point_frames, sizeof point_frames);
    const C3dTake read = ParseC3d(bytes, "long.c3d");
    ExpectSameTake(take, read);
    ASSERT_EQ(read.notes.size(), 1u);
    EXPECT_NE(read.notes[0].find("capped at 65535"), std::string::npos) << read.notes[0];
    EXPECT_NE(read.notes[0].find("the 70000 whole frames the data holds are read"),
              std::string::npos)
        << read.notes[0];
  }
}

// An analog rate that is no whole number of samples a point frame (1000 Hz at 120 Hz:
// 8.33) is read as the data stores it, 8 a frame, and a write states 960 Hz: noted, where
// it had changed without a word.
TEST(C3dTest, AnAnalogRateThatIsNoWholeNumberOfSamplesAFrameIsNoted) {
  C3dTake take = MakeTake(2, 10);
  take.analog.labels = {"Fz1", "EMG1"};
  take.analog.descriptions = {"", ""};
  take.analog.units = {"N", "V"};
  take.analog.scale = {1.0, 1.0};
  take.analog.offset = {0.0, 0.0};
  take.analog.samples_per_frame = 8;
  take.analog.values.assign(10u * take.analog.values_per_frame(), 3.0f);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  const float written = 960.0f, claimed = 1000.0f;
  const auto* w = reinterpret_cast<const uint8_t*>(&written);
  const auto at = std::search(bytes.begin(), bytes.end(), w, w + 4);
  ASSERT_NE(at, bytes.end());
  std::memcpy(&*at, &claimed, 4);
  const C3dTake read = ParseC3d(bytes, "analog_rate.c3d");
  EXPECT_EQ(read.analog.samples_per_frame, 8);
  ASSERT_EQ(read.notes.size(), 1u);
  EXPECT_EQ(read.notes[0],
            "ANALOG:RATE is 1000 Hz, but the data holds 8 analog samples a 120 Hz frame for "
            "each of its 2 channels (960 Hz): read, and written, as 960 Hz");
  // Where the two agree, nothing is said; nor where they differ by NTSC's 1000/1001 (119.88
  // Hz points, 1200 Hz analog: one rate labelled two ways).
  EXPECT_TRUE(ParseC3d(EncodeC3d(take), "agree.c3d").notes.empty());
  take.rate_hz = 120000.0 / 1001.0;
  take.analog.samples_per_frame = 10;
  take.analog.values.assign(10u * take.analog.values_per_frame(), 3.0f);
  std::vector<uint8_t> ntsc = EncodeC3d(take);
  const float ntsc_written = static_cast<float>(take.rate_hz * 10), ntsc_claimed = 1200.0f;
  const auto* n = reinterpret_cast<const uint8_t*>(&ntsc_written);
  const auto ntsc_at = std::search(ntsc.begin(), ntsc.end(), n, n + 4);
  ASSERT_NE(ntsc_at, ntsc.end());
  std::memcpy(&*ntsc_at, &ntsc_claimed, 4);
  EXPECT_TRUE(ParseC3d(ntsc, "ntsc.c3d").notes.empty());
}

// A header counting 1000 frames against POINT:FRAMES's 1200, the data holding 1200: the
// 1200 are read, as before, and the disagreement is said (it was settled in silence).
TEST(C3dTest, AHeaderCountShorterThanPointFramesIsNoted) {
  const C3dTake take = MakeTake(2, 1200);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  const uint16_t last = 1000;
  std::memcpy(&bytes[8], &last, 2);  // the header's last frame (first is 1)
  const C3dTake read = ParseC3d(bytes, "counts.c3d");
  EXPECT_EQ(read.num_frames, 1200);
  ASSERT_EQ(read.notes.size(), 1u);
  EXPECT_EQ(read.notes[0],
            "the header counts 1000 frames, POINT:FRAMES 1200: the data holds 1200, so "
            "POINT:FRAMES is read");
}

// " mm" was refused as an unknown unit while "mm " was read; a take numbered from 0
// kept its numbering nowhere (the writer made it 1..n).
TEST(C3dTest, UnitsAreTrimmedBothSidesAndATakeFromFrameZeroKeepsItsNumbering) {
  C3dTake take = MakeTake(2, 5);
  take.units = " mm";
  take.first_frame = 0;
  const C3dTake read = ParseC3d(EncodeC3d(take), "zero.c3d");
  EXPECT_EQ(read.units, "mm");
  EXPECT_EQ(read.first_frame, 0);
  EXPECT_EQ(read.num_frames, 5);
  EXPECT_TRUE(read.notes.empty());
}

// An unknown POINT:UNITS is named as such, not only by its byte offset.
TEST(C3dTest, AnUnknownUnitNamesPointUnits) {
  C3dTake take = MakeTake(2, 5);
  take.units = "metres";  // the writer knows it; the bytes are then changed to "parsec"
  std::vector<uint8_t> bytes = EncodeC3d(take);
  const std::string metres = "metres";
  const auto at = std::search(bytes.begin(), bytes.end(), metres.begin(), metres.end());
  ASSERT_NE(at, bytes.end());
  std::copy_n(std::string("parsec").begin(), 6, at);
  try {
    (void)ParseC3d(bytes, "odd.c3d");
    ADD_FAILURE() << "read";
  } catch (const C3dError& e) {
    EXPECT_NE(std::string(e.what()).find("POINT:UNITS: unknown length unit 'parsec'"),
              std::string::npos)
        << e.what();
  }
}

// A writer that counted its parameter blocks wrong (one, for a section of several): the
// entries linked on past it were cut off in silence, labels and units among them. They
// are read to the last, up to the data section, with a note; what follows the last entry
// in its block is no entry.
TEST(C3dTest, ParametersLinkedPastTheDeclaredBlocksAreReadWithANote) {
  const C3dTake take = MakeTake(200, 3);
  std::vector<uint8_t> bytes = EncodeC3d(take);
  const size_t param_start = (bytes[0] - 1u) * 512;
  ASSERT_GE(bytes[param_start + 2], 3);  // labels alone take 800 bytes
  bytes[param_start + 2] = 1;
  ReadWithOneNote(bytes, take, "the parameter section's header says 1 blocks, its entries run on");
}

// Two actors in one take: neither chosen is an error naming both; one chosen keeps its
// points (and their samples) alone; one that is not there names those that are.
TEST(C3dTest, SelectActorKeepsOneActorsPointsOrNamesTheActors) {
  C3dTake take = MakeTake(6, 6);
  take.labels = {"Justin:LASI", "Copy:LASI", "Justin:RASI", "Copy:RASI", "Justin:C7", "Copy:C7"};
  const auto error_of = [&](const std::string& actor) {
    C3dTake copy = take;
    try {
      SelectActor(&copy, actor, "two.c3d");
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(error_of(""),
            "two.c3d: the take holds the markers of 2 actors (Justin, Copy): choose one with "
            "--actor");
  EXPECT_EQ(error_of("Dan"),
            "two.c3d: no point is labelled for actor 'Dan' (the take's actors: "
            "Justin, Copy)");
  C3dTake copy = take;
  SelectActor(&copy, "Copy:", "two.c3d");
  ASSERT_EQ(copy.labels, (std::vector<std::string>{"Copy:LASI", "Copy:RASI", "Copy:C7"}));
  for (int f = 0; f < take.num_frames; ++f) {
    for (const auto& [kept, original] : {std::pair{0, 1}, std::pair{1, 3}, std::pair{2, 5}}) {
      ASSERT_EQ(copy.valid(f, kept), take.valid(f, original));
      if (take.valid(f, original)) {
        EXPECT_EQ(copy.at(f, kept), take.at(f, original));
      }
    }
  }
  C3dTake one = MakeTake(2, 3);  // no prefixes: nothing to choose
  EXPECT_NO_THROW(SelectActor(&one, "", "one.c3d"));
  EXPECT_EQ(one.num_points(), 2);
  // A prefix on a point or two is a stray label copy, not an actor to choose.
  C3dTake strays = take;
  strays.labels = {"LASI", "Dan:RASI", "Eve:RASI", "C7", "LPSI", "RPSI"};
  EXPECT_NO_THROW(SelectActor(&strays, "", "strays.c3d"));
  EXPECT_EQ(strays.num_points(), 6);
}

TEST(C3dTest, MetresPerUnitKnowsTheUsualUnits) {
  EXPECT_DOUBLE_EQ(MetresPerUnit("mm"), 1e-3);
  EXPECT_DOUBLE_EQ(MetresPerUnit("M "), 1.0);
  EXPECT_DOUBLE_EQ(MetresPerUnit(" mm"), 1e-3);
  EXPECT_DOUBLE_EQ(MetresPerUnit("in"), 0.0254);
  EXPECT_THROW(MetresPerUnit("parsec"), std::invalid_argument);
  // Spelled out, as some exporters write POINT:UNITS (they were refused).
  EXPECT_DOUBLE_EQ(MetresPerUnit("millimeters"), 1e-3);
  EXPECT_DOUBLE_EQ(MetresPerUnit("Meter"), 1.0);
  EXPECT_DOUBLE_EQ(MetresPerUnit("centimetres"), 1e-2);
}

}  // namespace
}  // namespace mocapd
