// A subject from labelled markers alone (`mocapd calibrate --markers`, and the daemon's
// live calibration): recognises the marker set from the labels, skips what is not a
// marker, starts from the template humanoid with the set's markers placed on it (a
// studio's own markers attached to the segment they ride rigidly with; the hip centres'
// prior from the pelvis markers by Harrington et al. 2007's regression where the set has
// them), and runs the bundle adjustment of filters/subject_calibration.hpp.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <vector>

#include "filters/cleanup_options.hpp"
#include "filters/subject_calibration.hpp"
#include "formats/c3d.hpp"
#include "formats/marker_set.hpp"
#include "formats/subject_file.hpp"

namespace mocapd {

struct MarkersOnlyOptions {
  /// "auto" (recognise from the labels, else place by clustering), "none" (clustering
  /// alone), a built-in set's name, or a path to a set file.
  std::string marker_set = "auto";
  double min_valid_fraction = 0.5;  ///< Markers seen in fewer frames are skipped.
  /// A studio's marker joins the segment whose set markers keep their distances to it
  /// within this (standard deviation over the take), or is rejected.
  double rigid_std_m = 0.012;
  /// Markers whose residual RMS after calibration exceeds this are rejected (and the
  /// calibration re-run without them).
  double max_marker_rms_m = 0.03;
  SubjectCalibrationOptions solve;
  /// Samples no body gives are left out, as the live cleanup's ingest gates leave them
  /// out: beyond this from the origin along any axis (1e30, an exporter's sentinel)...
  double capture_volume_m = CleanupOptions{}.capture_volume_m;
  /// ...and every sample of a frame whose markers (their median) jumped faster than this
  /// from both neighbouring frames (a broken frame between good ones). One such frame
  /// failed a calibration, and one 1 km off made 11 cm bone-length errors with exit 0.
  double glitch_speed_mps = CleanupOptions{}.glitch_speed_mps;
};

struct ChannelNote {
  std::string label;
  std::string reason;
};

/// The marker_set a calibration reports when the labels match no set and every marker
/// was placed by clustering (formats/marker_clusters.hpp).
inline constexpr const char* kClusteredSetName = "none (rigid clusters)";

/// How a set nobody described was placed.
struct ClusterSummary {
  std::string up_axis;    ///< The capture's up, e.g. "+z"...
  double tilt_deg = 0.0;  ///< ...and how far the fitted body's up is from it.
  double height_m = 0.0;
  int reference_take = 0;        ///< The fitted frame: its take (0-based)...
  int reference_take_frame = 0;  ///< ...and its frame in that take.
  double landmark_rms_m = 0.0;
  int moved_by_rigidity = 0;
  bool turned_round = false;  ///< The fit faced backwards; the walk's direction turned it.
  /// Markers the shape placed that did not fit there, placed again on the segment they
  /// ride rigidly (offsets from the motion).
  int placed_again_by_rigidity = 0;
};

struct MarkersOnlyCalibration {
  SubjectModel model;
  SubjectCalibrationResult solve;
  std::string marker_set;                   ///< The set's name, or "none (rigid clusters)".
  std::vector<std::string> markers;         ///< The calibrated markers' labels (model order).
  std::vector<std::string> set_missing;     ///< The set's required markers the takes lack.
  std::vector<ChannelNote> skipped;         ///< Not markers (model outputs, joint centres, sparse).
  std::vector<ChannelNote> rejected;        ///< Markers that could not be placed, and why.
  std::vector<std::string> studio_markers;  ///< Labels outside the set, placed by rigidity.
  bool hip_regression = false;              ///< The hip prior came from the pelvis markers.
  std::optional<ClusterSummary> clusters;   ///< Set when no set matched (marker_set none).
  std::string clustered_because;            ///< Why clustering placed the markers.
  int frames_total = 0;
  int64_t samples_out_of_volume = 0;  ///< Left out: beyond options.capture_volume_m.
  int glitch_frames = 0;              ///< Left out whole: a jump no body makes.
};

/// Calibrates a subject from one or more takes of the same actor (the same labels,
/// rates may differ). Throws std::runtime_error with a clear message (and nothing is
/// calibrated) when: no take has markers, every marker is NaN or sparse, the labels match
/// no set and too few markers remain to cluster, the take shows no motion, or most
/// markers cannot be placed.
MarkersOnlyCalibration CalibrateFromMarkers(std::span<const C3dTake> takes,
                                            const MarkersOnlyOptions& options,
                                            const std::string& subject_name);

/// What the subject file records of a calibration from markers.
SubjectCalibrationRecord CalibrationRecordOf(const MarkersOnlyCalibration& calibration);

/// The subject a live calibration starts from: the template humanoid at height_m with the
/// set's markers placed on it, in the order of `labels` (the stream's). Throws
/// std::runtime_error naming the labels the set does not have.
SubjectModel TemplateSubject(const MarkerSetDefinition& set, std::span<const std::string> labels,
                             double height_m, const std::string& subject_name);

/// An actor's height from one frame of the template subject's markers (NaN: missing): the
/// median ratio of observed to template distances between markers on the same segment
/// (rigid in any pose), times the template's height. Nothing when fewer than three such
/// pairs are seen or the answer is no human's (0.5-2.6 m).
std::optional<double> EstimateHeight(const Skeleton& template_skeleton,
                                     const MarkerSet& template_markers, double template_height_m,
                                     std::span<const Vec3> frame);

/// A calibration's subject with its markers in the template subject's order (the stream's):
/// a marker the calibration could not place keeps its template placement on the calibrated
/// skeleton, so the marker-set hash, and every frame's layout, stay the same.
SubjectModel InTemplateOrder(const MarkersOnlyCalibration& calibration,
                             const SubjectModel& template_subject);

/// The name of a joint's mirror image ("thigh_l" <-> "thigh_r"), or "" if it has none.
std::string MirrorRole(const std::string& role);

}  // namespace mocapd
