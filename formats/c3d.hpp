// C3D marker files (https://www.c3d.org, "The C3D File Format User Guide"): reads the
// header, the parameter section and the 3D point data of Intel, DEC and MIPS files in
// integer or float storage; writes float Intel files. Positions are converted to metres
// on read and back to the take's units on write, so a write->read round trip is exact.
// Analog channels are kept as stored and written back, so a cleaned take keeps them.
#pragma once

#include <algorithm>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "filters/types.hpp"

namespace mocapd {

/// Thrown for a malformed or truncated C3D file; the message names the file, the
/// section (header, parameters, data) and the byte offset.
class C3dError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A parameter of a C3D file kept as it was read (see C3dTake::other_parameters): numbers in
/// Intel byte order, floats in IEEE, whatever the file's processor.
struct C3dParameter {
  std::string group, name;  ///< Upper case, as the reader keys them.
  int8_t type = -1;         ///< -1 char, 1 byte, 2 int16, 4 float.
  std::vector<int> dims;
  std::vector<uint8_t> data;
};

struct C3dTake {
  std::vector<std::string> labels;  ///< One per point (trimmed); generated if the file has none.
  std::vector<std::string> descriptions;  ///< One per point, may be empty strings.
  /// Non-empty for points the file lists as model outputs (POINT:ANGLES, POWERS, FORCES,
  /// MOMENTS, SCALARS, REACTIONS): the group name, e.g. "ANGLES". Empty = physical marker.
  std::vector<std::string> model_output_kind;
  double rate_hz = 0.0;
  std::string units = "mm";       ///< POINT:UNITS as written in the file.
  double metres_per_unit = 1e-3;  ///< Scale from file units to metres.
  int first_frame = 1;
  int num_frames = 0;
  /// Marker samples the file marked valid at exactly (0, 0, 0), read as missing (how some
  /// exporters write a gap).
  int64_t origin_samples_missing = 0;
  /// What the reader found the file disagreeing with itself about, and which it believed
  /// (the header's rate against POINT:RATE), for a person to see.
  std::vector<std::string> notes;
  std::string processor = "Intel";  ///< Intel, DEC or MIPS (informational).
  bool float_storage = true;
  /// positions[frame * num_points() + point], metres, world frame; NaN when missing.
  std::vector<Vec3> positions;
  /// residual[frame * num_points() + point]: the sample's fourth word as the file stored it
  /// (camera mask in the high byte, residual in units of point_scale in the low byte: a
  /// float file holds it as a float, an integer file as an int16); negative when missing.
  std::vector<float> residuals;
  /// |POINT:SCALE|: the unit of the residual byte (and of integer storage). Written back,
  /// so a sample's residual means what it meant (it was rewritten as 0.1: a 2.00 mm
  /// residual at scale 1 became 0.20 mm).
  double point_scale = 0.1;
  /// The file's parameters that the writer does not make itself (FORCE_PLATFORM, EVENT,
  /// SUBJECTS, a manufacturer's groups, POINT:X_SCREEN...), written back as they were read,
  /// so a cleaned take keeps its force plates' geometry and its gait events (they were
  /// dropped in silence). Parameters of the analog data and the force plates go only with
  /// analog channels written.
  std::vector<C3dParameter> other_parameters;
  /// Analog channels (force plates, EMG) carried through as the file stored them, so a
  /// cleaned take keeps them: raw numbers, which ANALOG:SCALE, OFFSET and GEN_SCALE (kept
  /// here, written back as read) turn into units. A take without analog data has no
  /// labels and no values.
  struct Analog {
    std::vector<std::string> labels, descriptions, units;
    std::vector<double> scale, offset;  ///< Per channel (offset unsigned where format is).
    double gen_scale = 1.0;
    std::string format = "SIGNED";  ///< ANALOG:FORMAT: how integer storage holds the numbers.
    int samples_per_frame = 0;      ///< Analog samples per point frame.
    /// values[(frame * samples_per_frame + sample) * channels() + channel].
    std::vector<float> values;
    size_t channels() const { return labels.size(); }
    size_t values_per_frame() const {
      return channels() * static_cast<size_t>(std::max(samples_per_frame, 0));
    }
  } analog;

  int num_points() const { return static_cast<int>(labels.size()); }
  const Vec3& at(int frame, int point) const { return positions[Index(frame, point)]; }
  Vec3& at(int frame, int point) { return positions[Index(frame, point)]; }
  bool valid(int frame, int point) const { return residuals[Index(frame, point)] >= 0.0f; }
  bool is_marker(int point) const { return model_output_kind[static_cast<size_t>(point)].empty(); }
  /// Index of the point with this label, or else the one point whose label is it with a
  /// subject prefix ("Dan:"), padding or another case; -1 if none or several.
  int FindLabel(const std::string& label) const;
  /// The points whose label is this one exactly or, when none is, with a subject prefix,
  /// padding or another case; in file order.
  std::vector<int> MatchingLabels(const std::string& label) const;
  /// Sizes positions/residuals for num_frames x labels.size(), all missing.
  void Allocate(int frames);

 private:
  size_t Index(int frame, int point) const {
    return static_cast<size_t>(frame) * labels.size() + static_cast<size_t>(point);
  }
};

/// The subject prefixes of a take's labels ("Justin" of "Justin:LASI") that label three
/// points or more, in the order each reached three.
std::vector<std::string> ActorPrefixes(const C3dTake& take);
/// Keeps the points of one actor of a take that holds several (labels "Justin:*" and
/// "Copy:*"): actor is the prefix (its ':' optional), empty for a take of one actor. Throws
/// std::runtime_error naming `path` and the actors present when the take holds several and
/// none is chosen, or the one chosen is not among them.
void SelectActor(C3dTake* take, const std::string& actor, const std::string& path);

/// Parses a C3D file held in memory. source_name is used in error messages.
/// Throws C3dError if the file is malformed or truncated.
C3dTake ParseC3d(std::span<const uint8_t> bytes, const std::string& source_name);
/// Reads a C3D file. Throws C3dError (or std::runtime_error if it cannot be opened).
C3dTake ReadC3d(const std::string& path);

/// How EncodeC3d lays out the file. The default (float, Intel) is what every tool reads;
/// the others exist to produce the DEC, MIPS and integer files older systems wrote.
struct C3dEncoding {
  enum class Processor { kIntel, kDec, kMips };
  Processor processor = Processor::kIntel;
  bool integer_storage = false;
  double integer_scale = 0.1;  ///< File units per integer step, for integer storage.
};

/// Encodes a take. Throws std::invalid_argument if the take is inconsistent (sizes,
/// non-positive rate) or, for integer storage, a coordinate does not fit 16 bits.
std::vector<uint8_t> EncodeC3d(const C3dTake& take, const C3dEncoding& encoding = {});
/// Writes a take to a file (see EncodeC3d). Throws std::runtime_error if it cannot write.
void WriteC3d(const std::string& path, const C3dTake& take);

/// Returns metres per unit for a C3D/BVH unit string (mm, cm, m, in); throws
/// std::invalid_argument for anything else.
double MetresPerUnit(const std::string& units);

}  // namespace mocapd
