// Industry marker sets (Vicon Plug-in Gait, CMU 41, OptiTrack Motive baseline, Qualisys
// Sports, mocapd's own), read from editable TOML (config/marker_sets/, built into the
// binary too): which body segment each label rides on and where on it, in anatomical
// terms. From them: recognising a capture's set from its labels, a template subject to
// start a calibration from, markers placed on any humanoid skeleton for synthesis, and
// the channels of a real C3D that are not markers at all (model outputs, joint centres).
//
// Anatomical placement: a marker sits `along` its segment's bone (0 at the segment's
// joint, 1 at its end) plus `offset_m` = [left, up, forward] metres, for a 1.75 m adult
// standing in the anatomical position (arms at the sides, palms forward). On another
// skeleton the offset is turned with the segment (the minimal rotation from the bone's
// anatomical direction to its rest direction) and scaled by height.
#pragma once

#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "filters/marker_model.hpp"
#include "formats/bvh.hpp"
#include "formats/marker_layout.hpp"

namespace mocapd {

struct MarkerSetMarker {
  std::string name;
  std::vector<std::string> aliases;
  std::string segment;  ///< A role: pelvis, spine, chest, neck, head, clavicle_l, ... toe_r.
  double along = 0.0;
  Vec3 offset_m = Vec3::Zero();  ///< [left, up, forward], anatomical position, 1.75 m adult.
  std::string landmark;
  bool optional = false;
};

struct MarkerSetDefinition {
  std::string name;  ///< e.g. "plug-in-gait-full"
  std::string description;
  std::string source;  ///< The file it came from.
  std::vector<MarkerSetMarker> markers;
  /// The marker a label names (case-insensitive, name or alias), or nullopt.
  std::optional<int> Find(const std::string& label) const;
};

/// Parses a marker set (format: config/marker_sets/*.toml). Throws std::runtime_error
/// "FILE:LINE: field 'a.b': problem" (unknown keys, wrong types, an unknown segment role,
/// a repeated name or alias).
MarkerSetDefinition ParseMarkerSet(const std::string& text, const std::string& source_name);
MarkerSetDefinition ReadMarkerSet(const std::string& path);
/// The sets built into the binary (the files of config/marker_sets/ at build time).
const std::vector<MarkerSetDefinition>& BuiltInMarkerSets();
/// A built-in set by name, or a path to a set file. Throws std::runtime_error listing the
/// built-in names when neither.
MarkerSetDefinition FindMarkerSet(const std::string& name_or_path);

/// A label without a subject prefix or padding ("Actor1:LASI", " LASI " -> "LASI").
std::string BareLabel(const std::string& label);

/// Why a C3D point is not used as a marker, or kMarker.
enum class ChannelKind { kMarker, kModelOutput, kJointCentre, kBoneOutput, kSparse };
const char* to_string(ChannelKind kind);
/// Recognises non-marker channels by label (Plug-in Gait bone outputs such as LFEO,
/// modelled joint centres such as LHJC, centres of mass, angles, forces, moments,
/// powers) and markers valid in fewer than min_valid_fraction of the frames.
/// is_model_output: the C3D itself says the point is a model output.
ChannelKind ClassifyChannel(const std::string& label, bool is_model_output, double valid_fraction,
                            double min_valid_fraction = 0.5);

/// How well a set matches a capture's labels.
struct MarkerSetMatch {
  const MarkerSetDefinition* set = nullptr;  ///< nullptr: no set matches (auto found none).
  std::vector<int> marker_of_label;          ///< Per label, the set's marker or -1.
  int matched = 0;                           ///< Labels recognised.
  int required = 0;                          ///< The set's non-optional markers...
  int required_found = 0;                    ///< ...and how many the labels hold.
};
/// Matches labels against one set.
MarkerSetMatch MatchMarkerSet(const MarkerSetDefinition& set, std::span<const std::string> labels);
/// The share of a set's required markers the labels must hold for the set to explain them.
inline constexpr double kMarkerSetMinRequiredShare = 0.6;
/// Whether match a explains a capture's labels better than b: more labels recognised less
/// required markers absent, then the larger share of its required markers present, then
/// more labels recognised. Ranked by share first, a lower-body set all present beat the
/// full-body set one label short (a studio's extra head marker), and the upper body's
/// 23 markers were placed as the studio's own: calibration failed.
bool ExplainsLabelsBetter(const MarkerSetMatch& a, const MarkerSetMatch& b);
/// Picks the set that best explains the labels (ExplainsLabelsBetter) among those with at
/// least kMarkerSetMinRequiredShare of their required markers present. set == nullptr if
/// none.
MarkerSetMatch RecognizeMarkerSet(std::span<const MarkerSetDefinition> sets,
                                  std::span<const std::string> labels);

/// The canonical humanoid a calibration starts from: role-named joints (pelvis at the
/// midpoint of the hip centres, thigh_l at the left hip centre, shin at the knee, foot at
/// the ankle, upper_arm at the shoulder, forearm at the elbow, hand at the wrist...),
/// standing in the anatomical position facing +z with +y up and +x to its left, at
/// height_m. The pelvis is free, every other joint a ball.
Skeleton MakeTemplateHumanoid(double height_m = 1.75);
/// The bone of a role's segment on the template (end of segment minus its origin), m.
Vec3 TemplateBone(const std::string& role, double height_m = 1.75);

/// Places a set's markers on a humanoid skeleton's rest pose (rigid, one joint each).
/// Markers on roles the skeleton lacks (spine, neck, clavicles, toes) go to the nearest
/// ancestor role it has. Throws std::invalid_argument naming a marker whose segment and
/// its ancestors are all missing.
std::vector<MarkerDefinition> PlaceMarkerSet(const Skeleton& skeleton, const HumanoidRoles& roles,
                                             const MarkerSetDefinition& set,
                                             std::span<const BvhEndSite> end_sites = {});

}  // namespace mocapd
