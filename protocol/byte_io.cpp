// Byte-order aware, bounds-checked primitive reads and writes.
#include "protocol/byte_io.hpp"

#include <bit>
#include <cstring>

namespace mocapd {
namespace {
template <typename T>
T Assemble(const uint8_t* p, ByteOrder order) {
  T v = 0;
  for (size_t i = 0; i < sizeof(T); ++i) {
    const size_t shift = order == ByteOrder::kLittle ? i : sizeof(T) - 1 - i;
    v |= static_cast<T>(static_cast<T>(p[i]) << (8 * shift));
  }
  return v;
}
}  // namespace

bool ByteReader::Seek(size_t offset) {
  if (offset > data_.size()) return false;
  offset_ = offset;
  return true;
}

bool ByteReader::Skip(size_t count) {
  if (count > remaining()) return false;
  offset_ += count;
  return true;
}

bool ByteReader::ReadU8(uint8_t* out) {
  if (remaining() < 1) return false;
  *out = data_[offset_++];
  return true;
}

bool ByteReader::ReadI8(int8_t* out) {
  uint8_t v;
  if (!ReadU8(&v)) return false;
  *out = static_cast<int8_t>(v);
  return true;
}

bool ByteReader::ReadU16(uint16_t* out) {
  if (remaining() < 2) return false;
  *out = Assemble<uint16_t>(&data_[offset_], order_);
  offset_ += 2;
  return true;
}

bool ByteReader::ReadI16(int16_t* out) {
  uint16_t v;
  if (!ReadU16(&v)) return false;
  *out = static_cast<int16_t>(v);
  return true;
}

bool ByteReader::ReadU32(uint32_t* out) {
  if (remaining() < 4) return false;
  *out = Assemble<uint32_t>(&data_[offset_], order_);
  offset_ += 4;
  return true;
}

bool ByteReader::ReadU64(uint64_t* out) {
  if (remaining() < 8) return false;
  *out = Assemble<uint64_t>(&data_[offset_], order_);
  offset_ += 8;
  return true;
}

bool ByteReader::ReadF32(float* out) {
  if (remaining() < 4) return false;
  const uint8_t* p = &data_[offset_];
  offset_ += 4;
  if (floats_ == FloatFormat::kVax) {
    // VAX F: bytes (b0 b1 b2 b3) hold the IEEE bit pattern of (b2 b3 b0 b1) times 4.
    const uint8_t swapped[4] = {p[2], p[3], p[0], p[1]};
    const auto bits = Assemble<uint32_t>(swapped, ByteOrder::kLittle);
    if ((bits & 0x7f800000u) == 0) {  // VAX has no denormals: a zero exponent is zero
      *out = 0.0f;
      return true;
    }
    *out = std::bit_cast<float>(bits) * 0.25f;
    return true;
  }
  *out = std::bit_cast<float>(Assemble<uint32_t>(p, order_));
  return true;
}

bool ByteReader::ReadF64(double* out) {
  uint64_t bits;
  if (!ReadU64(&bits)) return false;
  *out = std::bit_cast<double>(bits);
  return true;
}

bool ByteReader::ReadBytes(size_t count, std::vector<uint8_t>* out) {
  if (count > remaining()) return false;
  out->assign(data_.begin() + static_cast<std::ptrdiff_t>(offset_),
              data_.begin() + static_cast<std::ptrdiff_t>(offset_ + count));
  offset_ += count;
  return true;
}

bool ByteReader::ReadString(size_t count, std::string* out) {
  if (count > remaining()) return false;
  out->assign(reinterpret_cast<const char*>(&data_[offset_]), count);
  offset_ += count;
  return true;
}

void ByteWriter::WriteU16(uint16_t v) {
  for (size_t i = 0; i < 2; ++i) {
    const size_t shift = order_ == ByteOrder::kLittle ? i : 1 - i;
    out_->push_back(static_cast<uint8_t>(v >> (8 * shift)));
  }
}

void ByteWriter::WriteU32(uint32_t v) {
  for (size_t i = 0; i < 4; ++i) {
    const size_t shift = order_ == ByteOrder::kLittle ? i : 3 - i;
    out_->push_back(static_cast<uint8_t>(v >> (8 * shift)));
  }
}

void ByteWriter::WriteU64(uint64_t v) {
  for (size_t i = 0; i < 8; ++i) {
    const size_t shift = order_ == ByteOrder::kLittle ? i : 7 - i;
    out_->push_back(static_cast<uint8_t>(v >> (8 * shift)));
  }
}

void ByteWriter::WriteF32(float v) {
  if (floats_ == FloatFormat::kVax) {
    // Inverse of the reader: scale by 4 (exponent bias 129), then swap the 16-bit words.
    const uint32_t bits = v == 0.0f ? 0u : std::bit_cast<uint32_t>(v * 4.0f);
    const uint8_t b[4] = {static_cast<uint8_t>(bits), static_cast<uint8_t>(bits >> 8),
                          static_cast<uint8_t>(bits >> 16), static_cast<uint8_t>(bits >> 24)};
    out_->insert(out_->end(), {b[2], b[3], b[0], b[1]});
    return;
  }
  WriteU32(std::bit_cast<uint32_t>(v));
}
void ByteWriter::WriteF64(double v) { WriteU64(std::bit_cast<uint64_t>(v)); }

}  // namespace mocapd
