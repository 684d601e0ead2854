// BVH skeletal motion files (Biovision Hierarchy): hierarchy with OFFSET/CHANNELS in
// any channel order, End Sites, and the MOTION block. Reading converts to the SI
// skeleton model and per-frame poses; writing converts back to the take's units and
// channel layout, so a read->write->read round trip reproduces every global position.
//
// Channel semantics: position channels replace the joint's OFFSET (the common reading,
// and the one under which Bandai's and CMU's takes are self-consistent); rotation
// channels compose in file order, R = R_a1(v1) R_a2(v2) R_a3(v3), degrees.
// Joint types: 3 rotation channels -> ball; a 6-channel joint whose translation never
// changes -> ball at that fixed offset; one whose translation moves -> free; a root
// whose channels never change at all (e.g. Bandai's joint_Root) -> fixed.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include "filters/skeleton.hpp"

namespace mocapd {

class BvhError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class BvhChannel { kXposition, kYposition, kZposition, kXrotation, kYrotation, kZrotation };

struct BvhEndSite {
  int parent = -1;
  Vec3 offset = Vec3::Zero();  ///< Metres, parent frame.
};

struct BvhTake {
  Skeleton skeleton{{Joint{.name = "root", .parent = {}}}};
  std::vector<std::vector<BvhChannel>> channels;  ///< Per joint, in file order.
  std::vector<Vec3> file_offsets;                 ///< Per joint, the OFFSET line, metres.
  std::vector<BvhEndSite> end_sites;
  std::vector<Pose> frames;
  double frame_time_s = 1.0 / 30.0;
  std::string units = "cm";
  double metres_per_unit = 0.01;
  /// The units were guessed from the skeleton's size (no unit given): a guess cannot tell
  /// inches from centimetres, so commands say it was one.
  bool units_guessed = false;

  int num_frames() const { return static_cast<int>(frames.size()); }
  double rate_hz() const { return 1.0 / frame_time_s; }
};

struct BvhReadOptions {
  /// File length unit (mm, cm, m, in); empty = guess from the skeleton's size
  /// (under 5 units across: m; under 400: cm; else mm).
  std::string units;
};

/// Parses BVH text. source_name is used in messages. Throws BvhError naming the
/// source and line for malformed input.
BvhTake ParseBvh(const std::string& text, const std::string& source_name,
                 const BvhReadOptions& options = {});
/// Reads a BVH file. Throws BvhError (or std::runtime_error if it cannot be opened).
BvhTake ReadBvh(const std::string& path, const BvhReadOptions& options = {});

/// Formats a take as BVH text in its units and channel layout (a joint with no recorded
/// layout gets 6 channels if free, 3 rotation channels (ZXY) otherwise).
std::string FormatBvh(const BvhTake& take);
/// Writes a take. Throws std::runtime_error if the file cannot be written.
void WriteBvh(const std::string& path, const BvhTake& take);

/// Builds a take around a skeleton with default channel layouts, every leaf joint closed
/// by an End Site (NominalLeafEndSites: readers and DCC tools expect one, and draw a
/// leaf's bone to it).
BvhTake MakeBvhTake(Skeleton skeleton, std::vector<Pose> frames, double frame_time_s,
                    const std::string& units = "cm");

}  // namespace mocapd
