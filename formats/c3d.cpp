// C3D reader and writer. The reader trusts nothing: every count and offset in the file
// is checked against the buffer before use, and errors name the section and byte offset.
#include "formats/c3d.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <map>
#include <optional>

#include <boost/algorithm/string/case_conv.hpp>
#include <boost/algorithm/string/predicate.hpp>
#include <boost/algorithm/string/trim.hpp>

#include "formats/file_paths.hpp"
#include "formats/marker_set.hpp"
#include "protocol/byte_io.hpp"
#include "protocol/messages.hpp"

namespace mocapd {
namespace {

constexpr size_t kBlock = 512;
constexpr uint8_t kProcessorIntel = 84, kProcessorDec = 85, kProcessorMips = 86;

// A C3D string is space-padded; a C writer may end it with a NUL and leave whatever its
// buffer held after it ("PEL1\0XYZ"), so the string ends at its first NUL.
std::string TrimRight(std::string s) {
  if (const size_t nul = s.find('\0'); nul != std::string::npos) s.resize(nul);
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

// Whether EncodeC3d writes this parameter itself (from the take's fields): such a one read
// from a file is not kept as one of its other parameters.
bool WrittenByWriter(const std::string& group, const std::string& name) {
  // NAME, or NAME followed by a number (LABELS2: a continuation).
  const auto is = [&name](std::initializer_list<const char*> bases) {
    for (const char* base : bases) {
      const std::string_view b(base);
      if (!name.starts_with(b)) continue;
      const std::string_view rest = std::string_view(name).substr(b.size());
      if (std::all_of(rest.begin(), rest.end(), [](char c) { return c >= '0' && c <= '9'; }))
        return true;
    }
    return false;
  };
  if (group == "POINT")
    return is({"USED", "SCALE", "RATE", "FRAMES", "LONG_FRAMES", "DATA_START", "UNITS", "LABELS",
               "DESCRIPTIONS", "ANGLES", "POWERS", "FORCES", "MOMENTS", "SCALARS", "REACTIONS"});
  if (group == "ANALOG")
    return is({"USED", "RATE", "LABELS", "DESCRIPTIONS", "UNITS", "FORMAT", "SCALE", "OFFSET",
               "GEN_SCALE"});
  if (group == "TRIAL") return is({"ACTUAL_START_FIELD", "ACTUAL_END_FIELD"});
  return false;
}

// A parameter's numbers (int16s or floats) re-encoded from one byte order and float
// format to another; characters and bytes as they are.
std::vector<uint8_t> RecodeParameterData(std::span<const uint8_t> data, int8_t type,
                                         ByteOrder from_order, FloatFormat from_floats,
                                         ByteOrder to_order, FloatFormat to_floats) {
  if (type != 2 && type != 4) return {data.begin(), data.end()};
  std::vector<uint8_t> out;
  ByteReader r(data, from_order, from_floats);
  ByteWriter w(&out, to_order, to_floats);
  for (size_t i = 0; i < data.size() / static_cast<size_t>(type); ++i) {
    if (type == 2) {
      int16_t v = 0;
      (void)r.ReadI16(&v);
      w.WriteI16(v);
    } else {
      float v = 0.0f;
      (void)r.ReadF32(&v);
      w.WriteF32(v);
    }
  }
  return out;
}

struct Parameter {
  int8_t type = 0;  // -1 char, 1 byte, 2 int16, 4 float
  std::vector<int> dims;
  std::vector<uint8_t> data;
  size_t offset = 0;  // of the data in the file, for messages
};

class Parser {
 public:
  Parser(std::span<const uint8_t> bytes, const std::string& source)
      : bytes_(bytes), reader_(bytes), source_(source) {}

  C3dTake Parse() {
    ReadHeader();
    ReadParameters();
    C3dTake take = ReadData();
    KeepOtherParameters(&take);
    return take;
  }

 private:
  [[noreturn]] void Fail(const std::string& section, size_t offset, const std::string& what) const {
    throw C3dError(source_ + ": " + section + " section, byte " + std::to_string(offset) + ": " +
                   what);
  }
  // Takes C strings so the common (successful) case builds no std::string.
  void Require(bool ok, const char* section, const char* what) {
    if (!ok) Fail(section, reader_.offset(), what);
  }
  void Require(bool ok, const char* section, const std::string& what) {
    if (!ok) Fail(section, reader_.offset(), what);
  }

  // Every C3D's second byte is 0x50. A file that is text says what it starts with (a BVH
  // or TOML given where a take goes got "expected key byte 0x50, found 73").
  std::string NotC3d(uint8_t key) const {
    std::string what =
        "not a C3D file: its second byte is " + std::to_string(key) + " where a C3D has 0x50 (80)";
    const size_t n = std::min<size_t>(bytes_.size(), 16);
    std::string start;
    for (size_t i = 0; i < n; ++i) {
      const auto c = static_cast<char>(bytes_[i]);
      if (c == '\n' || c == '\r') break;
      if (bytes_[i] < 0x20 || bytes_[i] > 0x7e) return what;
      start += c;
    }
    if (!start.empty()) what += "; it is text starting \"" + start + "\"";
    if (boost::algorithm::istarts_with(start, "HIERARCHY")) what += " (a BVH file)";
    return what;
  }

  void ReadHeader() {
    if (bytes_.size() >= 2 && bytes_[1] != 0x50) Fail("header", 1, NotC3d(bytes_[1]));
    Require(
        reader_.size() >= kBlock, "header",
        "file is " + std::to_string(reader_.size()) + " bytes, shorter than the 512-byte header");
    uint8_t param_block = 0, key = 0;
    Require(reader_.ReadU8(&param_block) && reader_.ReadU8(&key), "header", "truncated");
    if (key != 0x50) Fail("header", 1, NotC3d(key));
    if (param_block < 1) Fail("header", 0, "parameter section block number is 0");
    param_start_ = (static_cast<size_t>(param_block) - 1) * kBlock;
    // The processor type (which fixes byte order) lives in the parameter section header.
    Require(reader_.Seek(param_start_ + 3), "header",
            "parameter section starts beyond the end of the file");
    Require(reader_.ReadU8(&processor_), "parameters", "truncated");
    switch (processor_) {
      case kProcessorIntel: reader_.set_format(ByteOrder::kLittle, FloatFormat::kIeee); break;
      case kProcessorDec: reader_.set_format(ByteOrder::kLittle, FloatFormat::kVax); break;
      case kProcessorMips: reader_.set_format(ByteOrder::kBig, FloatFormat::kIeee); break;
      default:
        Fail("parameters", param_start_ + 3,
             "unknown processor type " + std::to_string(processor_) + " (expected 84, 85 or 86)");
    }
    uint16_t points = 0, analog = 0, first = 0, last = 0, gap = 0, data_block = 0,
             analog_per_frame = 0;
    float scale = 0.0f, rate = 0.0f;
    Require(reader_.Seek(2), "header", "truncated");
    Require(reader_.ReadU16(&points) && reader_.ReadU16(&analog) && reader_.ReadU16(&first) &&
                reader_.ReadU16(&last) && reader_.ReadU16(&gap) && reader_.ReadF32(&scale) &&
                reader_.ReadU16(&data_block) && reader_.ReadU16(&analog_per_frame) &&
                reader_.ReadF32(&rate),
            "header", "truncated");
    header_points_ = points;
    header_analog_ = analog;
    header_analog_samples_ = analog_per_frame;
    header_first_ = first;
    header_last_ = last;
    header_scale_ = scale;
    header_data_block_ = data_block;
    header_rate_ = rate;
  }

  void ReadParameters() {
    Require(reader_.Seek(param_start_), "parameters", "starts beyond the end of the file");
    uint8_t reserved1 = 0, reserved2 = 0, blocks = 0, processor = 0;
    Require(reader_.ReadU8(&reserved1) && reader_.ReadU8(&reserved2) && reader_.ReadU8(&blocks) &&
                reader_.ReadU8(&processor),
            "parameters", "truncated section header");
    const size_t declared_end =
        std::min(reader_.size(), param_start_ + std::max<size_t>(blocks, 1) * kBlock);
    // Entries linked on past the declared blocks (a writer that counted the blocks wrong)
    // are read up to the data section: cut at the count, the POINT group went missing in
    // silence (no labels, no units, a take in metres read as millimetres).
    const size_t data_start = (static_cast<size_t>(header_data_block_) - 1) * kBlock;
    const size_t end = header_data_block_ >= 1 && data_start > declared_end
                           ? std::min(reader_.size(), data_start)
                           : declared_end;
    size_t last_entry_end = 0;
    std::map<int, std::string> group_names;
    struct Pending {
      int group;
      std::string name;
      Parameter param;
      bool beyond_declared;  // a leftover there must not override a declared entry
    };
    std::vector<Pending> pending;
    size_t pos = param_start_ + 4;
    while (pos + 2 <= end) {
      // Past the declared blocks, an entry that does not read is where the list ends (the
      // rest of the last block may be anything), not a broken file.
      const bool beyond_declared = pos >= declared_end;
      try {
        Require(reader_.Seek(pos), "parameters", "truncated");
        int8_t name_len_signed = 0, id = 0;
        Require(reader_.ReadI8(&name_len_signed) && reader_.ReadI8(&id), "parameters",
                "truncated entry");
        if (name_len_signed == 0 || id == 0) break;  // end of the list
        const size_t name_len = static_cast<size_t>(std::abs(static_cast<int>(name_len_signed)));
        std::string name;
        Require(reader_.ReadString(name_len, &name), "parameters",
                "name runs past the end of the file");
        const size_t next_field = reader_.offset();
        int16_t next = 0;
        Require(reader_.ReadI16(&next), "parameters", "truncated entry");
        if (id < 0) {
          uint8_t desc_len = 0;
          Require(reader_.ReadU8(&desc_len) && reader_.Skip(desc_len), "parameters",
                  "group '" + name + "' description runs past the end");
          if (!beyond_declared || !group_names.contains(-id))
            group_names[-id] = boost::algorithm::to_upper_copy(TrimRight(name));
        } else {
          Parameter p;
          uint8_t ndims = 0;
          Require(reader_.ReadI8(&p.type) && reader_.ReadU8(&ndims), "parameters",
                  "parameter '" + name + "' is truncated");
          if (p.type != -1 && p.type != 1 && p.type != 2 && p.type != 4)
            Fail("parameters", reader_.offset() - 2,
                 "parameter '" + name + "' has invalid type " + std::to_string(p.type));
          size_t count = 1;
          for (uint8_t d = 0; d < ndims; ++d) {
            uint8_t dim = 0;
            Require(reader_.ReadU8(&dim), "parameters",
                    "parameter '" + name + "' dimensions are truncated");
            p.dims.push_back(dim);
            count *= dim;
          }
          const size_t bytes = count * static_cast<size_t>(std::abs(static_cast<int>(p.type)));
          p.offset = reader_.offset();
          Require(reader_.ReadBytes(bytes, &p.data), "parameters",
                  "parameter '" + name + "' data (" + std::to_string(bytes) +
                      " bytes) runs past the end");
          pending.push_back({id, boost::algorithm::to_upper_copy(TrimRight(name)), std::move(p),
                             beyond_declared});
        }
        last_entry_end = reader_.offset();
        if (next <= 0) break;  // 0 marks the last entry; a negative link cannot move forward
        pos = next_field + static_cast<size_t>(next);
      } catch (const C3dError&) {
        if (!beyond_declared) throw;
        break;
      }
    }
    parameters_end_ = std::max(declared_end, last_entry_end);
    if (last_entry_end > declared_end)
      notes_.push_back("the parameter section's header says " + std::to_string(blocks) +
                       " blocks, its entries run on to block " +
                       std::to_string((last_entry_end - 1 - param_start_) / kBlock + 1) +
                       ": they are read to the last");
    for (Pending& p : pending) {
      auto g = group_names.find(p.group);
      const std::string group =
          g == group_names.end() ? "GROUP" + std::to_string(p.group) : g->second;
      if (p.beyond_declared)
        params_.emplace(group + ":" + p.name, std::move(p.param));
      else
        params_[group + ":" + p.name] = std::move(p.param);
    }
  }

  // Every parameter the writer does not make itself, in Intel order and IEEE floats.
  void KeepOtherParameters(C3dTake* take) const {
    const ByteOrder order = processor_ == kProcessorMips ? ByteOrder::kBig : ByteOrder::kLittle;
    const FloatFormat floats = processor_ == kProcessorDec ? FloatFormat::kVax : FloatFormat::kIeee;
    for (const auto& [key, p] : params_) {
      const size_t colon = key.find(':');
      C3dParameter kept{key.substr(0, colon), key.substr(colon + 1), p.type, p.dims, {}};
      // A parameter whose group entry is missing has no name to write it under.
      if (kept.group.starts_with("GROUP") || WrittenByWriter(kept.group, kept.name)) continue;
      kept.data = RecodeParameterData(p.data, p.type, order, floats, ByteOrder::kLittle,
                                      FloatFormat::kIeee);
      take->other_parameters.push_back(std::move(kept));
    }
  }

  const Parameter* Find(const std::string& key) const {
    auto it = params_.find(key);
    return it == params_.end() ? nullptr : &it->second;
  }

  // Reads element i of a numeric parameter as double.
  std::optional<double> Number(const std::string& key, size_t i = 0) const {
    const Parameter* p = Find(key);
    if (p == nullptr || p->type == -1) return std::nullopt;
    const size_t size = static_cast<size_t>(p->type);
    if ((i + 1) * size > p->data.size()) return std::nullopt;
    ByteReader r(p->data, processor_ == kProcessorMips ? ByteOrder::kBig : ByteOrder::kLittle,
                 processor_ == kProcessorDec ? FloatFormat::kVax : FloatFormat::kIeee);
    if (!r.Seek(i * size)) return std::nullopt;
    switch (p->type) {
      case 1: {
        uint8_t v;
        if (!r.ReadU8(&v)) return std::nullopt;
        return static_cast<double>(static_cast<int8_t>(v));
      }
      case 2: {
        int16_t v;
        if (!r.ReadI16(&v)) return std::nullopt;
        return static_cast<double>(v);
      }
      case 4: {
        float v;
        if (!r.ReadF32(&v)) return std::nullopt;
        return static_cast<double>(v);
      }
      default: return std::nullopt;
    }
  }

  std::vector<std::string> Strings(const std::string& key) const {
    std::vector<std::string> out;
    const Parameter* p = Find(key);
    if (p == nullptr || p->type != -1) return out;
    const std::string all(p->data.begin(), p->data.end());
    if (p->dims.size() <= 1) {
      out.push_back(TrimRight(all));
      return out;
    }
    const auto len = static_cast<size_t>(p->dims[0]);
    if (len == 0) return out;
    for (size_t k = 0; k * len < all.size(); ++k)
      out.push_back(TrimRight(all.substr(k * len, len)));
    return out;
  }

  // LABELS, LABELS2, LABELS3 ... concatenated.
  std::vector<std::string> StringsContinued(const std::string& group,
                                            const std::string& name) const {
    std::vector<std::string> out = Strings(group + ":" + name);
    for (int k = 2; Find(group + ":" + name + std::to_string(k)) != nullptr; ++k) {
      const auto more = Strings(group + ":" + name + std::to_string(k));
      out.insert(out.end(), more.begin(), more.end());
    }
    return out;
  }

  C3dTake ReadData() {
    C3dTake take;
    take.notes = notes_;
    take.processor = processor_ == kProcessorIntel ? "Intel"
                     : processor_ == kProcessorDec ? "DEC"
                                                   : "MIPS";
    double used_value = Number("POINT:USED").value_or(header_points_);
    const Parameter* used_parameter_entry = Find("POINT:USED");
    // Integer parameters above 32767 are stored as unsigned 16-bit words.
    if (used_parameter_entry != nullptr && used_parameter_entry->type == 2 && used_value < 0)
      used_value += 65536;
    // A float count of 1e9 (or NaN) would size the labels before any frame check.
    if (!std::isfinite(used_value) || used_value < 0 || used_value > 65535 ||
        used_value != std::floor(used_value))
      Fail("parameters", used_parameter_entry ? used_parameter_entry->offset : 0,
           "POINT:USED is " + std::to_string(used_value) +
               ", expected a whole number of points from 0 to 65535");
    auto used = static_cast<size_t>(used_value);
    double scale = Number("POINT:SCALE").value_or(header_scale_);
    if (!std::isfinite(scale) || scale == 0.0)
      Fail("parameters", Find("POINT:SCALE") ? Find("POINT:SCALE")->offset : 0,
           "POINT:SCALE is " + std::to_string(scale) + ", expected a non-zero number");
    take.float_storage = scale < 0.0;
    take.point_scale = std::abs(scale);
    take.rate_hz = Number("POINT:RATE").value_or(header_rate_);
    if (!(take.rate_hz > 0.0) || !std::isfinite(take.rate_hz))
      Fail("parameters", Find("POINT:RATE") ? Find("POINT:RATE")->offset : 0,
           "POINT:RATE is " + std::to_string(take.rate_hz) + ", expected > 0");
    // Some exporters rewrite one and not the other (a take resampled, or cut from a
    // longer one): the parameter is the one the standard calls authoritative, but a take
    // played at the wrong one runs fast or slow, so a person should hear of it.
    if (header_rate_ > 0.0f && std::isfinite(header_rate_) &&
        std::abs(header_rate_ - take.rate_hz) > 0.005 * take.rate_hz) {
      char note[160];
      std::snprintf(note, sizeof(note),
                    "the header's frame rate is %.6g Hz, POINT:RATE %.6g Hz: POINT:RATE is used",
                    static_cast<double>(header_rate_), take.rate_hz);
      take.notes.emplace_back(note);
    }
    const auto units = Strings("POINT:UNITS");
    // Trimmed both sides: " mm" was refused as an unknown unit while "mm " was read.
    take.units = units.empty() ? "" : boost::algorithm::trim_copy(units[0]);
    if (take.units.empty()) take.units = "mm";
    try {
      take.metres_per_unit = MetresPerUnit(take.units);
    } catch (const std::invalid_argument& e) {
      Fail("parameters", Find("POINT:UNITS")->offset, std::string("POINT:UNITS: ") + e.what());
    }

    const int64_t header_frames =
        static_cast<int64_t>(header_last_) - static_cast<int64_t>(header_first_) + 1;
    const bool header_capped = header_last_ == 65535;
    int64_t frames = header_frames;
    int64_t point_frames = -1;
    if (auto f = Number("POINT:FRAMES")) {
      double v = *f;
      if (Find("POINT:FRAMES")->type == 2 && v < 0) v += 65536;  // unsigned word
      if (!std::isfinite(v) || v < 0 || v > 2147483647.0)
        Fail("parameters", Find("POINT:FRAMES")->offset,
             "POINT:FRAMES is " + std::to_string(v) + ", expected a frame count");
      point_frames = static_cast<int64_t>(v);
      if (header_capped || frames <= 0 || point_frames > frames) frames = point_frames;
    }
    int64_t trial_frames = -1;
    if (auto end_lo = Number("TRIAL:ACTUAL_END_FIELD", 0)) {
      const auto lo = static_cast<int64_t>(static_cast<uint16_t>(static_cast<int16_t>(*end_lo)));
      const auto hi = static_cast<int64_t>(static_cast<uint16_t>(
          static_cast<int16_t>(Number("TRIAL:ACTUAL_END_FIELD", 1).value_or(0))));
      const auto slo = static_cast<int64_t>(static_cast<uint16_t>(
          static_cast<int16_t>(Number("TRIAL:ACTUAL_START_FIELD", 0).value_or(1))));
      trial_frames = (lo + (hi << 16)) - slo + 1;
    }
    take.first_frame = header_first_;

    size_t data_block = header_data_block_;
    size_t data_start_parameter = 0;  // 0: none, or none that can be a block
    if (auto d = Number("POINT:DATA_START")) {
      double v = *d;
      if (v < 0) v += 65536;
      // A float-typed value can be anything: only a block number a header word could hold.
      if (std::isfinite(v) && v >= 1 && v <= 65535)
        data_block = data_start_parameter = static_cast<size_t>(v);
    }
    // POINT:DATA_START is the standard's, but a tool that grew the parameter section can
    // move the data and update only the header's word (or the other way round). Read at
    // the wrong block, every frame was garbage, with no note. A start inside the
    // parameters is not the data; of two starts past them, the one where the data holds
    // the counted frames (and the other's not) is.
    if (header_data_block_ >= 1 && data_block != header_data_block_) {
      const size_t word = take.float_storage ? 4 : 2;
      const size_t frame_size = (used * 4 + header_analog_) * word;
      const auto start_of = [](size_t block) { return (block - 1) * kBlock; };
      const auto inside_parameters = [&](size_t block) {  // or the header
        return start_of(block) < kBlock ||
               (start_of(block) >= param_start_ && start_of(block) < parameters_end_);
      };
      const auto holds_counted = [&](size_t block) {
        const size_t start = start_of(block);
        return start <= reader_.size() &&
               (frame_size == 0 || frames <= 0 ||
                (reader_.size() - start) / frame_size >= static_cast<size_t>(frames));
      };
      std::string why;
      if (inside_parameters(data_block) && !inside_parameters(header_data_block_))
        why = "lies inside the parameter section";
      else if (!holds_counted(data_block) && holds_counted(header_data_block_))
        why = "leaves too little data for the " + std::to_string(frames) + " frames counted";
      take.notes.push_back("POINT:DATA_START says block " + std::to_string(data_block) +
                           ", the header block " + std::to_string(header_data_block_) +
                           (why.empty()
                                ? ": POINT:DATA_START is read"
                                : ": POINT:DATA_START " + why + ", so the header's is read"));
      if (!why.empty()) data_block = header_data_block_;
    }
    if (data_block < 1) Fail("header", 16, "data section block number is 0");
    const size_t data_start = (data_block - 1) * kBlock;
    size_t value_size = take.float_storage ? 4 : 2;
    size_t analog_values = header_analog_;
    const auto bytes_per_frame = [&](size_t points_per_frame, size_t analog, size_t word) {
      return (points_per_frame * 4 + analog) * word;
    };
    const auto frame_bytes_of = [&](size_t points_per_frame) {
      return bytes_per_frame(points_per_frame, analog_values, value_size);
    };
    const size_t available = data_start <= reader_.size() ? reader_.size() - data_start : 0;
    const auto holds_frames_of = [&](int64_t n, size_t bytes) {
      return bytes == 0 || static_cast<size_t>(std::max<int64_t>(n, 0)) <= available / bytes;
    };
    const auto holds = [&](int64_t n, size_t points_per_frame) {
      return holds_frames_of(n, frame_bytes_of(points_per_frame));
    };
    // Whether n frames of this size fill the data section: a writer pads it to a whole
    // 512-byte block and no more.
    const auto n_fill = [&](int64_t n, size_t frame_bytes) {
      const size_t bytes = frame_bytes * static_cast<size_t>(std::max<int64_t>(n, 0));
      return n > 0 && bytes <= available && available - bytes < kBlock;
    };
    const auto filled_by_frames_of = [&](size_t frame_bytes) {
      return n_fill(frames, frame_bytes);
    };
    // Where the header and the parameters disagree on the frame's layout, the one whose
    // frames the data holds (and the other's not), or fill it (and the other's leave more
    // than a block unread), is the layout. Read at the other, every frame is garbage. A
    // stale POINT:FRAMES longer than the header's count (given way to below) fits no
    // layout, so the header's count is tried too: with two quirks in one file, the file was
    // refused as truncated.
    const bool point_frames_may_be_stale = !header_capped && header_frames > 0 &&
                                           point_frames > header_frames && frames == point_frames &&
                                           !holds(point_frames, used);
    const auto layout_fits_better = [&](size_t frame_bytes, size_t instead_of) {
      const auto at = [&](int64_t n) {
        return holds_frames_of(n, frame_bytes) &&
               (!holds_frames_of(n, instead_of) ||
                (n_fill(n, frame_bytes) && !n_fill(n, instead_of)));
      };
      return at(frames) || (point_frames_may_be_stale && at(header_frames));
    };
    // Analog values a frame by the parameters: ANALOG:USED channels times the analog
    // samples per point frame (the header's count when they say nothing usable).
    size_t parameter_analog = analog_values;
    {
      const std::optional<double> channels = Number("ANALOG:USED");
      const std::optional<double> analog_rate = Number("ANALOG:RATE");
      if (channels && analog_rate && *channels >= 0 && *channels <= 65535 &&
          std::isfinite(*analog_rate) && *analog_rate >= take.rate_hz) {
        const double values = std::floor(*channels) * std::round(*analog_rate / take.rate_hz);
        if (values <= 65535) parameter_analog = static_cast<size_t>(values);
      }
    }
    // Each of the two checks below settles one field where the header and the parameters
    // disagree on that field alone: where two disagree, sizes alone cannot tell which
    // (2 points fewer and 8 analog values more make the same frame), and the file is read
    // by the standard's rules as before.
    const bool points_agree = used_parameter_entry == nullptr || header_points_ == used;
    const bool storage_agrees = Find("POINT:SCALE") == nullptr || !std::isfinite(header_scale_) ||
                                header_scale_ == 0.0f ||
                                (header_scale_ < 0.0f) == take.float_storage;
    const bool analog_agrees = parameter_analog == analog_values;
    // Float or integer storage: POINT:SCALE's sign, the header's where only it fits.
    if (!storage_agrees && points_agree && analog_agrees) {
      const size_t header_word = header_scale_ < 0.0f ? 4 : 2;
      if (layout_fits_better(bytes_per_frame(used, analog_values, header_word),
                             bytes_per_frame(used, analog_values, value_size))) {
        char note[200];
        std::snprintf(note, sizeof(note),
                      "POINT:SCALE is %g (%s samples), the header's scale %g: the data holds "
                      "frames of %s samples, so the header's is used",
                      scale, take.float_storage ? "float" : "integer",
                      static_cast<double>(header_scale_), header_word == 4 ? "float" : "integer");
        take.notes.emplace_back(note);
        scale = header_scale_;
        take.float_storage = scale < 0.0;
        take.point_scale = std::abs(scale);
        value_size = header_word;
      }
    }
    // Analog values stored per frame: the header's count, the parameters' where only that
    // fits.
    if (!analog_agrees && points_agree && storage_agrees &&
        layout_fits_better(bytes_per_frame(used, parameter_analog, value_size),
                           frame_bytes_of(used))) {
      take.notes.push_back("the header stores " + std::to_string(analog_values) +
                           " analog values a frame, ANALOG:USED x ANALOG:RATE / POINT:RATE " +
                           std::to_string(parameter_analog) + ": the data holds frames of " +
                           std::to_string(parameter_analog) + ", so the parameters' count is used");
      analog_values = parameter_analog;
    }
    // POINT:USED is the standard's count, but an exporter can rewrite it and not the
    // header (points added or dropped after the capture). Where the data holds frames of
    // the header's count and not of USED's (more points than stored), or frames of the
    // header's count fill the data section and USED's leave more than a block unread
    // (fewer), the header's is the layout, with a note. More was refused as a truncated
    // file; fewer read every frame at the wrong stride.
    const size_t used_in_parameter = used;
    if (used_parameter_entry != nullptr && header_points_ > 0 && header_points_ != used &&
        layout_fits_better(frame_bytes_of(header_points_), frame_bytes_of(used))) {
      used = header_points_;
      take.notes.push_back("POINT:USED says " + std::to_string(used_in_parameter) +
                           " points, the header " + std::to_string(used) +
                           ": the data holds frames of " + std::to_string(used) +
                           " points, so the header's count is used");
    }
    const size_t frame_bytes = frame_bytes_of(used);
    // TRIAL counts past 65535 frames, where the header cannot; but a cropping tool can
    // leave it behind, longer than the header and the data (even when they count none):
    // trusted over the header only when the data holds that many frames, or the header is
    // capped (and a frame stores something: with nothing per frame nothing confirms it).
    if (trial_frames > frames && frame_bytes > 0 &&
        (header_last_ == 65535 || holds(trial_frames, used)))
      frames = trial_frames;
    // Vicon writes the count past 65535 as a float, POINT:LONG_FRAMES.
    if (auto long_frames = Number("POINT:LONG_FRAMES");
        long_frames && std::isfinite(*long_frames) && *long_frames > static_cast<double>(frames) &&
        *long_frames < 2147483647.0 && frame_bytes > 0 &&
        holds(static_cast<int64_t>(*long_frames), used))
      frames = static_cast<int64_t>(*long_frames);
    // A POINT:FRAMES longer than the header's count and than the data (left behind when a
    // take was cropped) made the file unreadable: the header's count is read when the data
    // holds it.
    if (frame_bytes > 0 && !header_capped && frames == point_frames && header_frames > 0 &&
        point_frames > header_frames && !holds(point_frames, used) && holds(header_frames, used)) {
      take.notes.push_back("POINT:FRAMES says " + std::to_string(point_frames) +
                           " frames, the header " + std::to_string(header_frames) +
                           ": the data holds " + std::to_string(header_frames) +
                           ", so the header's count is read");
      frames = header_frames;
    }
    // The mirror: a crop that rewrote POINT:FRAMES but left the header's longer count was
    // refused as truncated. POINT:FRAMES is read when the data holds it and not the header's.
    if (frame_bytes > 0 && !header_capped && frames == header_frames && point_frames >= 0 &&
        point_frames < header_frames && !holds(header_frames, used) && holds(point_frames, used)) {
      take.notes.push_back("the header counts " + std::to_string(header_frames) +
                           " frames, POINT:FRAMES " + std::to_string(point_frames) +
                           ": the data holds " + std::to_string(point_frames) +
                           ", so POINT:FRAMES is read");
      frames = point_frames;
    }
    // POINT:FRAMES longer than the header's count, the data holding it: read, and said (the
    // two disagreeing was settled in silence).
    if (frame_bytes > 0 && !header_capped && header_frames > 0 && point_frames > header_frames &&
        frames == point_frames && holds(point_frames, used))
      take.notes.push_back("the header counts " + std::to_string(header_frames) +
                           " frames, POINT:FRAMES " + std::to_string(point_frames) +
                           ": the data holds " + std::to_string(point_frames) +
                           ", so POINT:FRAMES is read");
    // A header capped at 65535 counts at least that many: a smaller POINT:FRAMES (a 16-bit
    // count wrapped, or 0) dropped every frame past it, or all of them, and one capped at
    // 65535 too dropped the rest (54 s of a 72000-frame take, exit 0). The data's whole
    // frames are read then, less the last block's padding, with a note.
    if (frame_bytes > 0 && header_capped && header_frames > 0 && frames <= header_frames &&
        holds(header_frames, used)) {
      auto whole = static_cast<int64_t>(available / frame_bytes);
      // A writer pads the last block with zeros: an all-zero frame that lies wholly in the
      // file's last 511 bytes is that padding. Further back, all zeros is a frame whose
      // every sample is missing, as exporters write one, and is read.
      const auto is_padding = [&](int64_t frame) {
        const size_t start = static_cast<size_t>(frame) * frame_bytes;
        if (available - start >= kBlock) return false;
        const auto first = bytes_.begin() + static_cast<std::ptrdiff_t>(data_start + start);
        return std::all_of(first, first + static_cast<std::ptrdiff_t>(frame_bytes),
                           [](uint8_t b) { return b == 0; });
      };
      while (whole > header_frames && is_padding(whole - 1)) --whole;
      if (whole != frames) {
        take.notes.push_back("the header's frame count is capped at 65535 and POINT:FRAMES says " +
                             std::to_string(point_frames < 0 ? 0 : point_frames) +
                             ", and no count reaches past it: the " + std::to_string(whole) +
                             " whole frames the data holds are read");
        frames = whole;
      }
    }
    if (frames < 0) frames = 0;
    if (frame_bytes > 0 && static_cast<size_t>(frames) > available / frame_bytes) {
      const size_t whole = available / frame_bytes;
      std::string counts;
      if (used_parameter_entry != nullptr && header_points_ != used_in_parameter &&
          used == used_in_parameter)
        counts = "; POINT:USED says " + std::to_string(used_in_parameter) + " points, the header " +
                 std::to_string(header_points_) + ", and the data holds frames of neither";
      // Where the data was read from, and what each field said: data that sits at neither
      // start reads as a file too short, and the fields are what to check.
      std::string start = "; data read from block " + std::to_string(data_block);
      if (data_start_parameter == 0 || data_start_parameter == header_data_block_)
        start += data_start_parameter == 0 ? " (the header's; no usable POINT:DATA_START)"
                                           : " (the header's and POINT:DATA_START's)";
      else
        start += " (POINT:DATA_START says " + std::to_string(data_start_parameter) +
                 ", the header " + std::to_string(header_data_block_) + ")";
      Fail("data", data_start + whole * frame_bytes,
           "file ends inside frame " + std::to_string(whole + 1) + " of " + std::to_string(frames) +
               " (" + std::to_string(frame_bytes) + " bytes per frame" + counts + start + ")");
    }
    // More whole frames than counted, past a writer's block of padding: a take cropped by
    // rewriting its count alone, or a count from another version of the file. The count
    // is read; the rest is said, not dropped in silence.
    if (frames > 0 && frame_bytes > 0 && !filled_by_frames_of(frame_bytes)) {
      const size_t whole = available / frame_bytes;
      if (whole > static_cast<size_t>(frames))
        take.notes.push_back("the data section is larger than the " + std::to_string(frames) +
                             " frames the header and parameters count (room for " +
                             std::to_string(whole) + "): the " + std::to_string(frames) +
                             " counted are read");
    }
    take.labels = StringsContinued("POINT", "LABELS");
    take.descriptions = StringsContinued("POINT", "DESCRIPTIONS");
    take.labels.resize(used);
    take.descriptions.resize(used);
    for (size_t i = 0; i < used; ++i)
      if (take.labels[i].empty()) take.labels[i] = "unlabeled_" + std::to_string(i + 1);
    take.model_output_kind.assign(used, "");
    for (const char* kind : {"ANGLES", "POWERS", "FORCES", "MOMENTS", "SCALARS", "REACTIONS"}) {
      for (const std::string& label : StringsContinued("POINT", kind)) {
        for (size_t i = 0; i < used; ++i)
          if (!label.empty() && take.labels[i] == label) take.model_output_kind[i] = kind;
      }
    }

    if (frames > 0 && used > 0 && static_cast<uint64_t>(frames) * used > (1ull << 31))
      Fail("data", data_start,
           "implausible size: " + std::to_string(frames) + " frames x " + std::to_string(used) +
               " points");
    if (frame_bytes == 0 && frames > 0) {
      // Nothing is stored per frame (no points, no analog): a frame count alone, however
      // large, carries no samples -- keep it out of loops that would walk it.
      Fail("parameters", param_start_,
           std::to_string(frames) + " frames declared but no points or analog channels to store");
    }
    take.Allocate(static_cast<int>(frames));
    ReadAnalogParameters(analog_values, static_cast<size_t>(frames), &take.analog);
    // The analog rate is a whole number of samples a point frame: the stored data says how
    // many, and a write states that times the point rate. An ANALOG:RATE that is not (1000
    // Hz at 120 Hz) would be rewritten without a word. NTSC's 1000/1001 between the two
    // (119.88 Hz points, 1200 Hz analog) is the same rate labelled two ways, as elsewhere.
    if (const std::optional<double> analog_rate = Number("ANALOG:RATE");
        take.analog.channels() > 0 && analog_rate && std::isfinite(*analog_rate)) {
      const double stored = take.rate_hz * take.analog.samples_per_frame;
      if (std::abs(*analog_rate - stored) > 1.5e-3 * stored) {
        const int samples = take.analog.samples_per_frame;
        char note[300];
        std::snprintf(note, sizeof(note),
                      "ANALOG:RATE is %g Hz, but the data holds %d analog sample%s a %g Hz "
                      "frame for each of its %zu channels (%g Hz): read, and written, as %g Hz",
                      *analog_rate, samples, samples == 1 ? "" : "s", take.rate_hz,
                      take.analog.channels(), stored, stored);
        take.notes.emplace_back(note);
      }
    }
    const bool unsigned_analog = take.analog.format == "UNSIGNED";
    const double unit_scale = std::abs(scale);
    for (int64_t f = 0; f < frames; ++f) {
      Require(reader_.Seek(data_start + static_cast<size_t>(f) * frame_bytes), "data", "truncated");
      for (size_t p = 0; p < used; ++p) {
        double xyz[3];
        float residual;
        bool ok = true;
        if (take.float_storage) {
          float v[4];
          for (float& x : v) ok = ok && reader_.ReadF32(&x);
          xyz[0] = v[0];
          xyz[1] = v[1];
          xyz[2] = v[2];
          residual = v[3];
        } else {
          int16_t v[4];
          for (int16_t& x : v) ok = ok && reader_.ReadI16(&x);
          for (int k = 0; k < 3; ++k) xyz[k] = v[k] * unit_scale;
          // The word as stored (camera mask, residual in units of |scale|), as a float file
          // holds it; its sign marks invalid.
          residual = v[3] < 0 ? -1.0f : static_cast<float>(v[3]);
        }
        Require(ok, "data", "truncated frame");
        const size_t idx = static_cast<size_t>(f) * used + p;
        // A float residual holds an integer word; negative marks an invalid sample. So does
        // a marker exactly at the origin: exporters write gaps as 0, 0, 0 with residual 0,
        // and no capture puts a marker there to the last bit (a model output, an angle or
        // a force, may well be zero).
        const bool at_origin =
            xyz[0] == 0.0 && xyz[1] == 0.0 && xyz[2] == 0.0 && take.model_output_kind[p].empty();
        take.origin_samples_missing += at_origin && residual >= 0.0f;
        const bool valid = residual >= 0.0f && !at_origin && std::isfinite(xyz[0]) &&
                           std::isfinite(xyz[1]) && std::isfinite(xyz[2]);
        take.residuals[idx] = valid ? residual : -1.0f;
        if (valid) take.positions[idx] = Vec3(xyz[0], xyz[1], xyz[2]) * take.metres_per_unit;
      }
      float* analog = take.analog.values.data() + static_cast<size_t>(f) * analog_values;
      for (size_t a = 0; a < analog_values; ++a) {
        bool ok = true;
        if (take.float_storage) {
          ok = reader_.ReadF32(&analog[a]);
        } else {
          int16_t v = 0;
          ok = reader_.ReadI16(&v);
          analog[a] = unsigned_analog ? static_cast<float>(static_cast<uint16_t>(v))
                                      : static_cast<float>(v);
        }
        Require(ok, "data", "truncated analog samples");
      }
    }
    return take;
  }

  // What the analog values of each frame are: ANALOG:USED channels of samples_per_frame
  // samples each; where USED does not divide the frame's count, the header's samples a
  // frame say the channels; failing both, that many channels of one sample (numbers kept
  // either way, so a write gives back what was read).
  void ReadAnalogParameters(size_t values_per_frame, size_t frames, C3dTake::Analog* analog) {
    if (values_per_frame == 0) return;
    size_t channels = values_per_frame;
    std::optional<double> used = Number("ANALOG:USED");
    // Counts above 32767 are stored as unsigned 16-bit words.
    if (used && *used < 0 && Find("ANALOG:USED")->type == 2) *used += 65536;
    if (used && *used >= 1 && *used <= 65535 && *used == std::floor(*used) &&
        values_per_frame % static_cast<size_t>(*used) == 0)
      channels = static_cast<size_t>(*used);
    else if (header_analog_samples_ >= 1 && values_per_frame % header_analog_samples_ == 0)
      channels = values_per_frame / header_analog_samples_;
    analog->samples_per_frame = static_cast<int>(values_per_frame / channels);
    analog->labels = StringsContinued("ANALOG", "LABELS");
    analog->descriptions = StringsContinued("ANALOG", "DESCRIPTIONS");
    analog->units = StringsContinued("ANALOG", "UNITS");
    analog->labels.resize(channels);
    analog->descriptions.resize(channels);
    analog->units.resize(channels);
    for (size_t c = 0; c < channels; ++c)
      if (analog->labels[c].empty()) analog->labels[c] = "analog_" + std::to_string(c + 1);
    const std::vector<std::string> format = Strings("ANALOG:FORMAT");
    if (!format.empty() &&
        boost::algorithm::to_upper_copy(boost::algorithm::trim_copy(format.front())) == "UNSIGNED")
      analog->format = "UNSIGNED";
    const Parameter* offsets = Find("ANALOG:OFFSET");
    const bool offsets_unsigned = analog->format == "UNSIGNED" && offsets && offsets->type == 2;
    for (size_t c = 0; c < channels; ++c) {
      const std::optional<double> scale = Number("ANALOG:SCALE", c);
      double offset = Number("ANALOG:OFFSET", c).value_or(0.0);
      if (offsets_unsigned && offset < 0) offset += 65536;
      analog->scale.push_back(scale && std::isfinite(*scale) ? *scale : 1.0);
      analog->offset.push_back(std::isfinite(offset) ? offset : 0.0);
    }
    const std::optional<double> gen_scale = Number("ANALOG:GEN_SCALE");
    analog->gen_scale = gen_scale && std::isfinite(*gen_scale) ? *gen_scale : 1.0;
    analog->values.assign(frames * values_per_frame, 0.0f);
  }

  std::span<const uint8_t> bytes_;
  std::vector<std::string> notes_;  // said while reading the header and parameters
  ByteReader reader_;
  std::string source_;
  size_t param_start_ = 0;
  size_t parameters_end_ = 0;  // past the declared blocks and the last entry read
  uint8_t processor_ = kProcessorIntel;
  uint16_t header_points_ = 0, header_analog_ = 0, header_first_ = 1, header_last_ = 0,
           header_data_block_ = 0, header_analog_samples_ = 0;
  float header_scale_ = -1.0f, header_rate_ = 0.0f;
  std::map<std::string, Parameter> params_;
};

// Writes one parameter entry; the link to the next entry is patched by the caller.
void WriteParameter(ByteWriter& w, std::vector<uint8_t>& out, ByteOrder order, int8_t group,
                    const std::string& name, int8_t type, const std::vector<int>& dims,
                    const std::vector<uint8_t>& data) {
  w.WriteI8(static_cast<int8_t>(name.size()));
  w.WriteI8(group);
  w.WriteString(name);
  const size_t link = out.size();
  w.WriteI16(0);
  w.WriteI8(type);
  w.WriteU8(static_cast<uint8_t>(dims.size()));
  for (int d : dims) w.WriteU8(static_cast<uint8_t>(d));
  out.insert(out.end(), data.begin(), data.end());
  w.WriteU8(0);  // empty description
  const auto next = static_cast<uint16_t>(out.size() - link);
  std::vector<uint8_t> patch;
  ByteWriter(&patch, order).WriteU16(next);
  out[link] = patch[0];
  out[link + 1] = patch[1];
}

struct Layout {
  ByteOrder order = ByteOrder::kLittle;
  FloatFormat floats = FloatFormat::kIeee;
  uint8_t processor = kProcessorIntel;
};

std::vector<uint8_t> FloatData(const Layout& layout, std::initializer_list<float> values) {
  std::vector<uint8_t> out;
  ByteWriter w(&out, layout.order, layout.floats);
  for (float v : values) w.WriteF32(v);
  return out;
}

std::vector<uint8_t> Int16Data(const Layout& layout, std::initializer_list<int16_t> values) {
  std::vector<uint8_t> out;
  ByteWriter w(&out, layout.order, layout.floats);
  for (int16_t v : values) w.WriteI16(v);
  return out;
}

void WriteGroup(ByteWriter& w, int8_t id, const std::string& name) {
  w.WriteI8(static_cast<int8_t>(name.size()));
  w.WriteI8(static_cast<int8_t>(-id));
  w.WriteString(name);
  w.WriteI16(3);  // link: itself (2 bytes) + description length byte
  w.WriteU8(0);
}

void WriteStrings(ByteWriter& w, std::vector<uint8_t>& out, ByteOrder order, int8_t group,
                  const std::string& name, const std::vector<std::string>& values) {
  size_t len = 1;
  for (const auto& v : values) len = std::max(len, v.size());
  len = std::min<size_t>(len, 255);
  std::vector<uint8_t> data;
  for (const auto& v : values) {
    std::string padded = v.substr(0, len);
    padded.resize(len, ' ');
    data.insert(data.end(), padded.begin(), padded.end());
  }
  WriteParameter(w, out, order, group, name, -1,
                 {static_cast<int>(len), static_cast<int>(values.size())}, data);
}

}  // namespace

std::vector<int> C3dTake::MatchingLabels(const std::string& label) const {
  std::vector<int> exact, loose_matches;
  for (size_t i = 0; i < labels.size(); ++i)
    if (labels[i] == label) exact.push_back(static_cast<int>(i));
  if (!exact.empty()) return exact;
  // Exporters prefix the subject ("Dan:LBWT"), pad with spaces or change the case; the
  // subject file, written by `mocapd calibrate`, names the bare label. A prefixed name
  // keeps its prefix: "Dan:LBWT" is never Eve's.
  const bool prefixed = label.find(':') != std::string::npos;
  auto loose = [prefixed](const std::string& text) {
    return boost::algorithm::to_upper_copy(
        boost::algorithm::trim_copy(prefixed ? text : BareLabel(text)));
  };
  const std::string want = loose(label);
  for (size_t i = 0; i < labels.size(); ++i)
    if (loose(labels[i]) == want) loose_matches.push_back(static_cast<int>(i));
  return loose_matches;
}

int C3dTake::FindLabel(const std::string& label) const {
  const std::vector<int> matches = MatchingLabels(label);
  if (matches.empty()) return -1;
  // Only a unique loose match counts: two subjects' LBWT in one file is no answer. A
  // label repeated exactly is the file's own (its first point, as other readers take it).
  if (matches.size() > 1 && labels[static_cast<size_t>(matches[0])] != label) return -1;
  return matches[0];
}

namespace {
std::string PrefixOf(const std::string& label) {
  const size_t colon = label.rfind(':');
  return colon == std::string::npos ? "" : boost::algorithm::trim_copy(label.substr(0, colon));
}
}  // namespace

std::vector<std::string> ActorPrefixes(const C3dTake& take) {
  // An actor labels three points at least (what places a segment); a prefix on one or two
  // is a stray copy of a label, which the label matching warns of instead.
  std::vector<std::string> prefixes;
  std::map<std::string, int> points;
  for (const std::string& label : take.labels) {
    const std::string prefix = PrefixOf(label);
    if (prefix.empty() || ++points[prefix] != 3) continue;
    prefixes.push_back(prefix);
  }
  return prefixes;
}

void SelectActor(C3dTake* take, const std::string& actor, const std::string& path) {
  const std::vector<std::string> prefixes = ActorPrefixes(*take);
  std::string listed;
  // The prefixes are the take's label bytes: printed escaped.
  for (const std::string& p : prefixes)
    listed += (listed.empty() ? "" : ", ") + protocol::PrintableName(p);
  std::string want = boost::algorithm::trim_copy(actor);
  if (!want.empty() && want.back() == ':') want.pop_back();
  if (want.empty()) {
    // Two actors' LASI are no answer: the calibration took the first actor's and the
    // solve matched neither, so each command said something else about one take.
    if (prefixes.size() > 1)
      throw std::runtime_error(path + ": the take holds the markers of " +
                               std::to_string(prefixes.size()) + " actors (" + listed +
                               "): choose one with --actor");
    return;
  }
  std::vector<int> kept;
  for (int p = 0; p < take->num_points(); ++p)
    if (PrefixOf(take->labels[static_cast<size_t>(p)]) == want) kept.push_back(p);
  if (kept.empty())
    throw std::runtime_error(path + ": no point is labelled for actor '" +
                             protocol::PrintableName(want) + "' (" +
                             (prefixes.empty() ? std::string("the labels have no actor prefix")
                                               : "the take's actors: " + listed) +
                             ")");
  C3dTake out = *take;
  out.labels.clear();
  out.descriptions.clear();
  out.model_output_kind.clear();
  for (int p : kept) {
    out.labels.push_back(take->labels[static_cast<size_t>(p)]);
    out.descriptions.push_back(take->descriptions[static_cast<size_t>(p)]);
    out.model_output_kind.push_back(take->model_output_kind[static_cast<size_t>(p)]);
  }
  out.Allocate(take->num_frames);
  out.analog = take->analog;  // one actor's points; the force plates are the stage's
  for (int f = 0; f < take->num_frames; ++f) {
    for (size_t k = 0; k < kept.size(); ++k) {
      const auto from = static_cast<size_t>(f) * take->labels.size() + static_cast<size_t>(kept[k]);
      const auto to = static_cast<size_t>(f) * kept.size() + k;
      out.positions[to] = take->positions[from];
      out.residuals[to] = take->residuals[from];
    }
  }
  *take = std::move(out);
}

void C3dTake::Allocate(int frames) {
  num_frames = frames;
  const size_t n = static_cast<size_t>(frames) * labels.size();
  positions.assign(n, Vec3::Constant(kNaN));
  residuals.assign(n, -1.0f);
  descriptions.resize(labels.size());
  model_output_kind.resize(labels.size());
  analog = {};
}

double MetresPerUnit(const std::string& units) {
  const std::string u = boost::algorithm::to_upper_copy(boost::algorithm::trim_copy(units));
  // Exporters spell units out as well ("millimeters", "Meter"), in either spelling.
  const auto is = [&u](std::initializer_list<const char*> names) {
    return std::any_of(names.begin(), names.end(), [&u](const char* n) { return u == n; });
  };
  if (is({"MM", "MILLIMETER", "MILLIMETERS", "MILLIMETRE", "MILLIMETRES"})) return 1e-3;
  if (is({"CM", "CENTIMETER", "CENTIMETERS", "CENTIMETRE", "CENTIMETRES"})) return 1e-2;
  if (is({"M", "METER", "METERS", "METRE", "METRES"})) return 1.0;
  if (is({"IN", "INCH", "INCHES"})) return 0.0254;
  throw std::invalid_argument("unknown length unit '" + units + "' (expected mm, cm, m or in)");
}

C3dTake ParseC3d(std::span<const uint8_t> bytes, const std::string& source_name) {
  Parser parser(bytes, source_name);
  return parser.Parse();
}

C3dTake ReadC3d(const std::string& path) {
  const std::string bytes = ReadWholeFile(path);
  return ParseC3d(std::span(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()), path);
}

std::vector<uint8_t> EncodeC3d(const C3dTake& take, const C3dEncoding& encoding) {
  const size_t points = take.labels.size();
  if (take.positions.size() != static_cast<size_t>(take.num_frames) * points ||
      take.residuals.size() != take.positions.size())
    throw std::invalid_argument("C3D writer: positions/residuals do not match frames x points");
  const C3dTake::Analog& analog_in = take.analog;
  if (analog_in.channels() > 0 && (analog_in.samples_per_frame < 1 ||
                                   analog_in.values.size() != static_cast<size_t>(take.num_frames) *
                                                                  analog_in.values_per_frame() ||
                                   analog_in.scale.size() != analog_in.channels() ||
                                   analog_in.offset.size() != analog_in.channels() ||
                                   analog_in.descriptions.size() != analog_in.channels() ||
                                   analog_in.units.size() != analog_in.channels()))
    throw std::invalid_argument(
        "C3D writer: the analog channels' values or parameters do not match frames x channels");
  if (analog_in.values_per_frame() > 65535 || analog_in.channels() > 255)
    throw std::invalid_argument(
        "C3D writer: too many analog channels (at most 255, of 65535 values a frame)");
  if (!(take.rate_hz > 0.0)) throw std::invalid_argument("C3D writer: rate must be > 0");
  if (points > 65535) throw std::invalid_argument("C3D writer: too many points");
  if (encoding.integer_storage && !(encoding.integer_scale > 0.0))
    throw std::invalid_argument("C3D writer: integer scale must be > 0");
  Layout layout;
  switch (encoding.processor) {
    case C3dEncoding::Processor::kIntel: break;
    case C3dEncoding::Processor::kDec:
      layout = {ByteOrder::kLittle, FloatFormat::kVax, kProcessorDec};
      break;
    case C3dEncoding::Processor::kMips:
      layout = {ByteOrder::kBig, FloatFormat::kIeee, kProcessorMips};
      break;
  }
  const ByteOrder order = layout.order;
  const double units_per_metre = 1.0 / MetresPerUnit(take.units);
  // Negative scale marks float storage; its magnitude still scales residuals: the take's,
  // so each residual word keeps its meaning.
  const double residual_unit =
      std::isfinite(take.point_scale) && take.point_scale > 0.0 ? take.point_scale : 0.1;
  const auto scale =
      static_cast<float>(encoding.integer_storage ? encoding.integer_scale : -residual_unit);

  std::vector<uint8_t> params;
  ByteWriter pw(&params, layout.order, layout.floats);
  pw.WriteU8(1);
  pw.WriteU8(0x50);
  pw.WriteU8(0);  // block count, patched below
  pw.WriteU8(layout.processor);
  WriteGroup(pw, 1, "POINT");
  WriteGroup(pw, 2, "ANALOG");
  WriteGroup(pw, 3, "TRIAL");
  WriteParameter(pw, params, order, 1, "USED", 2, {},
                 Int16Data(layout, {static_cast<int16_t>(static_cast<uint16_t>(points))}));
  WriteParameter(pw, params, order, 1, "SCALE", 4, {}, FloatData(layout, {scale}));
  WriteParameter(pw, params, order, 1, "RATE", 4, {},
                 FloatData(layout, {static_cast<float>(take.rate_hz)}));
  // A take numbered from 0 keeps its numbering (an empty one starts at 1: its last
  // frame, first - 1, must not wrap to the header's 65535, which means "capped").
  const int first = std::clamp(take.first_frame, take.num_frames > 0 ? 0 : 1, 65535);
  const bool long_take = static_cast<int64_t>(first) + take.num_frames - 1 > 65535;
  if (take.num_frames <= 32767)
    WriteParameter(pw, params, order, 1, "FRAMES", 2, {},
                   Int16Data(layout, {static_cast<int16_t>(take.num_frames)}));
  else
    WriteParameter(pw, params, order, 1, "FRAMES", 4, {},
                   FloatData(layout, {static_cast<float>(take.num_frames)}));
  const size_t data_start_param = params.size();
  WriteParameter(pw, params, order, 1, "DATA_START", 2, {}, Int16Data(layout, {0}));
  WriteStrings(pw, params, order, 1, "UNITS", {take.units});
  for (size_t begin = 0, k = 1; begin < std::max<size_t>(points, 1); begin += 255, ++k) {
    const size_t end = std::min(points, begin + 255);
    const std::vector<std::string> labels(take.labels.begin() + static_cast<std::ptrdiff_t>(begin),
                                          take.labels.begin() + static_cast<std::ptrdiff_t>(end));
    std::vector<std::string> descriptions(labels.size());
    for (size_t i = begin; i < end && i < take.descriptions.size(); ++i)
      descriptions[i - begin] = take.descriptions[i];
    const std::string suffix = k == 1 ? "" : std::to_string(k);
    WriteStrings(pw, params, order, 1, "LABELS" + suffix, labels);
    WriteStrings(pw, params, order, 1, "DESCRIPTIONS" + suffix, descriptions);
    if (points == 0) break;
  }
  std::map<std::string, std::vector<std::string>> outputs;
  for (size_t i = 0; i < points && i < take.model_output_kind.size(); ++i)
    if (!take.model_output_kind[i].empty())
      outputs[take.model_output_kind[i]].push_back(take.labels[i]);
  for (const auto& [kind, labels] : outputs) WriteStrings(pw, params, order, 1, kind, labels);
  const C3dTake::Analog& analog = take.analog;
  const size_t analog_values = analog.values_per_frame();
  WriteParameter(pw, params, order, 2, "USED", 2, {},
                 Int16Data(layout, {static_cast<int16_t>(analog.channels())}));
  WriteParameter(pw, params, order, 2, "RATE", 4, {},
                 FloatData(layout, {static_cast<float>(take.rate_hz *
                                                       std::max(analog.samples_per_frame, 1))}));
  if (analog_values > 0) {
    WriteStrings(pw, params, order, 2, "LABELS", analog.labels);
    WriteStrings(pw, params, order, 2, "DESCRIPTIONS", analog.descriptions);
    WriteStrings(pw, params, order, 2, "UNITS", analog.units);
    WriteStrings(pw, params, order, 2, "FORMAT", {analog.format});
    std::vector<uint8_t> scales, offsets, gen_scale;
    ByteWriter scale_writer(&scales, layout.order, layout.floats),
        offset_writer(&offsets, layout.order, layout.floats),
        gen_writer(&gen_scale, layout.order, layout.floats);
    for (size_t c = 0; c < analog.channels(); ++c) {
      scale_writer.WriteF32(static_cast<float>(analog.scale[c]));
      // An unsigned format's offsets are 16-bit words read as 0..65535.
      offset_writer.WriteI16(static_cast<int16_t>(
          static_cast<uint16_t>(static_cast<int64_t>(std::llround(analog.offset[c])) & 0xffff)));
    }
    gen_writer.WriteF32(static_cast<float>(analog.gen_scale));
    const std::vector<int> per_channel = {static_cast<int>(analog.channels())};
    WriteParameter(pw, params, order, 2, "SCALE", 4, per_channel, scales);
    WriteParameter(pw, params, order, 2, "OFFSET", 2, per_channel, offsets);
    WriteParameter(pw, params, order, 2, "GEN_SCALE", 4, {}, gen_scale);
  }
  // The standard's frame range past the header's 65535 (POINT:FRAMES above is this
  // reader's own way, which other readers may not share): low word, high word.
  if (take.num_frames > 0) {
    const int64_t last = static_cast<int64_t>(first) + take.num_frames - 1;
    auto words = [&](int64_t frame) {
      return Int16Data(layout, {static_cast<int16_t>(static_cast<uint16_t>(frame & 0xffff)),
                                static_cast<int16_t>(static_cast<uint16_t>(frame >> 16))});
    };
    WriteParameter(pw, params, order, 3, "ACTUAL_START_FIELD", 2, {2}, words(first));
    WriteParameter(pw, params, order, 3, "ACTUAL_END_FIELD", 2, {2}, words(last));
  }
  // The file's other parameters, as read; new groups numbered after the three above.
  std::map<std::string, int8_t> group_ids = {{"POINT", 1}, {"ANALOG", 2}, {"TRIAL", 3}};
  for (const C3dParameter& p : take.other_parameters) {
    const bool of_analog = p.group == "ANALOG" || p.group == "FORCE_PLATFORM";
    const size_t width = static_cast<size_t>(std::abs(static_cast<int>(p.type)));
    size_t count = 1;
    for (int d : p.dims) count *= static_cast<size_t>(std::max(d, 0));
    if ((of_analog && analog_values == 0) || p.group.empty() || p.group.size() > 127 ||
        p.name.empty() || p.name.size() > 127 || p.dims.size() > 7 ||
        (p.type != -1 && p.type != 1 && p.type != 2 && p.type != 4) ||
        p.data.size() != count * width || p.data.size() > 32000)
      continue;
    auto id = group_ids.find(p.group);
    if (id == group_ids.end()) {
      if (group_ids.size() >= 127) continue;
      id = group_ids.emplace(p.group, static_cast<int8_t>(group_ids.size() + 1)).first;
      WriteGroup(pw, id->second, p.group);
    }
    WriteParameter(pw, params, order, id->second, p.name, p.type, p.dims,
                   RecodeParameterData(p.data, p.type, ByteOrder::kLittle, FloatFormat::kIeee,
                                       layout.order, layout.floats));
  }
  // Terminate the list: an entry whose name length is 0.
  pw.WriteU8(0);
  pw.WriteU8(0);
  const size_t param_blocks = (params.size() + kBlock - 1) / kBlock;
  if (param_blocks > 255) throw std::invalid_argument("C3D writer: parameter section too large");
  params.resize(param_blocks * kBlock, 0);
  params[2] = static_cast<uint8_t>(param_blocks);
  const size_t data_block = 2 + param_blocks;
  if (data_block > 65535) throw std::invalid_argument("C3D writer: data section starts too late");
  {
    // DATA_START's value follows: name length, group id, name, link (2), type, ndims.
    const size_t value = data_start_param + 2 + std::string("DATA_START").size() + 2 + 2;
    std::vector<uint8_t> patch;
    ByteWriter(&patch, order).WriteU16(static_cast<uint16_t>(data_block));
    params[value] = patch[0];
    params[value + 1] = patch[1];
  }

  std::vector<uint8_t> out;
  ByteWriter w(&out, layout.order, layout.floats);
  w.WriteU8(2);
  w.WriteU8(0x50);
  w.WriteU16(static_cast<uint16_t>(points));
  w.WriteU16(static_cast<uint16_t>(analog_values));
  w.WriteU16(static_cast<uint16_t>(first));
  w.WriteU16(static_cast<uint16_t>(long_take ? 65535 : first + take.num_frames - 1));
  w.WriteU16(10);
  w.WriteF32(scale);
  w.WriteU16(static_cast<uint16_t>(data_block));
  w.WriteU16(static_cast<uint16_t>(analog_values > 0 ? analog.samples_per_frame : 0));
  w.WriteF32(static_cast<float>(take.rate_hz));
  w.PadTo(kBlock);
  out.insert(out.end(), params.begin(), params.end());
  out.reserve(out.size() +
              static_cast<size_t>(take.num_frames) * points * (encoding.integer_storage ? 8 : 16));
  for (int f = 0; f < take.num_frames; ++f) {
    for (size_t p = 0; p < points; ++p) {
      const size_t idx = static_cast<size_t>(f) * points + p;
      const bool valid = take.residuals[idx] >= 0.0f && take.positions[idx].allFinite();
      const Vec3 v = valid ? Vec3(take.positions[idx] * units_per_metre) : Vec3::Zero();
      if (encoding.integer_storage) {
        for (int k = 0; k < 3; ++k) {
          const double steps = std::round(v[k] / encoding.integer_scale);
          if (std::abs(steps) > 32767)
            throw std::invalid_argument(
                "C3D writer: coordinate does not fit 16-bit integer storage");
          w.WriteI16(static_cast<int16_t>(steps));
        }
        // The camera mask as it was; the residual byte re-counted in this file's unit (its
        // scale is the positions' integer step, not the take's point_scale).
        const auto word =
            static_cast<int>(std::clamp(static_cast<double>(take.residuals[idx]), 0.0, 32767.0));
        const double residual = std::clamp(
            std::round((word & 0xff) * residual_unit / encoding.integer_scale), 0.0, 255.0);
        w.WriteI16(valid ? static_cast<int16_t>((word & 0x7f00) | static_cast<int>(residual))
                         : int16_t{-1});
      } else {
        w.WriteF32(static_cast<float>(v.x()));
        w.WriteF32(static_cast<float>(v.y()));
        w.WriteF32(static_cast<float>(v.z()));
        w.WriteF32(valid ? take.residuals[idx] : -1.0f);
      }
    }
    const float* values = analog.values.data() + static_cast<size_t>(f) * analog_values;
    for (size_t a = 0; a < analog_values; ++a) {
      if (!encoding.integer_storage) {
        w.WriteF32(values[a]);
        continue;
      }
      const double v = std::round(values[a]);
      const bool fits =
          analog.format == "UNSIGNED" ? v >= 0 && v <= 65535 : v >= -32768 && v <= 32767;
      if (!fits)
        throw std::invalid_argument("C3D writer: an analog sample does not fit 16-bit storage");
      w.WriteI16(static_cast<int16_t>(static_cast<uint16_t>(static_cast<int64_t>(v) & 0xffff)));
    }
  }
  w.PadTo((out.size() + kBlock - 1) / kBlock * kBlock);
  return out;
}

void WriteC3d(const std::string& path, const C3dTake& take) {
  const std::vector<uint8_t> bytes = EncodeC3d(take);
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw std::runtime_error(path + ": cannot open for writing");
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
  if (!out) throw std::runtime_error(path + ": write failed");
}

}  // namespace mocapd
