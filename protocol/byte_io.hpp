// Bounds-checked binary reading and writing with explicit byte order. Reads never
// throw and never touch memory outside the buffer: each returns false instead, so both
// the wire decoders (status values) and the file readers (exceptions naming the byte
// offset) can build on it. Also decodes the DEC (VAX F) floats found in old C3D files.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace mocapd {

enum class ByteOrder { kLittle, kBig };
/// How 32-bit floats are laid out: IEEE 754 in the reader's byte order, or VAX F
/// (DEC processors: little-endian 16-bit words, high word first, exponent bias 129).
enum class FloatFormat { kIeee, kVax };

class ByteReader {
 public:
  explicit ByteReader(std::span<const uint8_t> data, ByteOrder order = ByteOrder::kLittle,
                      FloatFormat floats = FloatFormat::kIeee)
      : data_(data), order_(order), floats_(floats) {}

  size_t offset() const { return offset_; }
  size_t size() const { return data_.size(); }
  size_t remaining() const { return data_.size() - offset_; }
  void set_format(ByteOrder order, FloatFormat floats) {
    order_ = order;
    floats_ = floats;
  }

  [[nodiscard]] bool Seek(size_t offset);
  [[nodiscard]] bool Skip(size_t count);
  [[nodiscard]] bool ReadU8(uint8_t* out);
  [[nodiscard]] bool ReadI8(int8_t* out);
  [[nodiscard]] bool ReadU16(uint16_t* out);
  [[nodiscard]] bool ReadI16(int16_t* out);
  [[nodiscard]] bool ReadU32(uint32_t* out);
  [[nodiscard]] bool ReadU64(uint64_t* out);
  [[nodiscard]] bool ReadF32(float* out);
  [[nodiscard]] bool ReadF64(double* out);
  /// Copies count bytes into out (replacing its contents).
  [[nodiscard]] bool ReadBytes(size_t count, std::vector<uint8_t>* out);
  /// Reads count bytes as text (no terminator handling).
  [[nodiscard]] bool ReadString(size_t count, std::string* out);

 private:
  std::span<const uint8_t> data_;
  size_t offset_ = 0;
  ByteOrder order_;
  FloatFormat floats_;
};

/// Appends little-endian (or big-endian) values to a caller-owned byte vector.
class ByteWriter {
 public:
  explicit ByteWriter(std::vector<uint8_t>* out, ByteOrder order = ByteOrder::kLittle,
                      FloatFormat floats = FloatFormat::kIeee)
      : out_(out), order_(order), floats_(floats) {}
  void WriteU8(uint8_t v) { out_->push_back(v); }
  void WriteI8(int8_t v) { out_->push_back(static_cast<uint8_t>(v)); }
  void WriteU16(uint16_t v);
  void WriteI16(int16_t v) { WriteU16(static_cast<uint16_t>(v)); }
  void WriteU32(uint32_t v);
  void WriteU64(uint64_t v);
  void WriteF32(float v);
  void WriteF64(double v);
  void WriteString(const std::string& s) { out_->insert(out_->end(), s.begin(), s.end()); }
  void PadTo(size_t size) {
    if (out_->size() < size) out_->resize(size, 0);
  }
  size_t size() const { return out_->size(); }

 private:
  std::vector<uint8_t>* out_;
  ByteOrder order_;
  FloatFormat floats_;
};

}  // namespace mocapd
