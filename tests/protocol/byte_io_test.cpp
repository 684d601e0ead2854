// Tests for bounds-checked byte reading and writing in every byte order and float format.
#include "protocol/byte_io.hpp"

#include <gtest/gtest.h>

namespace mocapd {
namespace {

TEST(ByteIoTest, RoundTripsEveryTypeInBothByteOrders) {
  for (ByteOrder order : {ByteOrder::kLittle, ByteOrder::kBig}) {
    std::vector<uint8_t> buf;
    ByteWriter w(&buf, order);
    w.WriteU8(0xab);
    w.WriteI16(-12345);
    w.WriteU32(0xdeadbeef);
    w.WriteU64(0x0123456789abcdefull);
    w.WriteF32(3.25f);
    w.WriteF64(-1e-300);
    ByteReader r(buf, order);
    uint8_t a;
    int16_t b;
    uint32_t c;
    uint64_t d;
    float e;
    double f;
    ASSERT_TRUE(r.ReadU8(&a) && r.ReadI16(&b) && r.ReadU32(&c) && r.ReadU64(&d) && r.ReadF32(&e) &&
                r.ReadF64(&f));
    EXPECT_EQ(a, 0xab);
    EXPECT_EQ(b, -12345);
    EXPECT_EQ(c, 0xdeadbeefu);
    EXPECT_EQ(d, 0x0123456789abcdefull);
    EXPECT_EQ(e, 3.25f);
    EXPECT_EQ(f, -1e-300);
    EXPECT_EQ(r.remaining(), 0u);
  }
}

TEST(ByteIoTest, LittleEndianLayoutIsExplicit) {
  std::vector<uint8_t> buf;
  ByteWriter(&buf).WriteU32(0x01020304);
  EXPECT_EQ(buf, (std::vector<uint8_t>{4, 3, 2, 1}));
}

TEST(ByteIoTest, ReadsPastTheEndFailWithoutMoving) {
  const std::vector<uint8_t> buf = {1, 2, 3};
  ByteReader r(buf);
  uint32_t v;
  EXPECT_FALSE(r.ReadU32(&v));
  EXPECT_EQ(r.offset(), 0u);
  EXPECT_FALSE(r.Skip(4));
  EXPECT_FALSE(r.Seek(4));
  EXPECT_TRUE(r.Seek(3));
  uint8_t b;
  EXPECT_FALSE(r.ReadU8(&b));
  std::string s;
  EXPECT_TRUE(r.Seek(0));
  EXPECT_FALSE(r.ReadString(4, &s));
}

TEST(ByteIoTest, DecodesVaxFloats) {
  // 1.0 in VAX F is 0x4080 0x0000 stored as little-endian words: 80 40 00 00.
  const std::vector<uint8_t> one = {0x80, 0x40, 0x00, 0x00};
  ByteReader r(one, ByteOrder::kLittle, FloatFormat::kVax);
  float v;
  ASSERT_TRUE(r.ReadF32(&v));
  EXPECT_EQ(v, 1.0f);
  for (float x : {0.0f, -2.5f, 1234.5678f, 1e-20f}) {
    std::vector<uint8_t> buf;
    ByteWriter(&buf, ByteOrder::kLittle, FloatFormat::kVax).WriteF32(x);
    ByteReader back(buf, ByteOrder::kLittle, FloatFormat::kVax);
    ASSERT_TRUE(back.ReadF32(&v));
    EXPECT_EQ(v, x);
  }
}

}  // namespace
}  // namespace mocapd
