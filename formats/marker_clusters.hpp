// Placing the markers of a set nobody described (labels of no known marker set) on the
// template humanoid, from the shape of the body and the motion alone:
//  1. the template fitted to a well-seen frame: a multi-start similarity ICP against
//     anatomical landmarks (every built-in set's markers placed on the template), over
//     the arm poses people stand in and every axis as "up" (exporters differ), then an
//     articulated ICP (the template's IK) that turns its limbs to the frame's pose; the
//     way the take walks says which way it faces (people walk forwards), since the
//     body looks much the same from behind;
//  2. each marker on the segment of its nearest landmark, generic points on each
//     segment's surface included (a marker where no set puts one); its first offset is
//     the nearest set landmark's on that segment, or the surface point's;
//  3. a marker that does not keep its distances to its own segment's markers but does
//     to a neighbouring segment's moves there (rigid clustering by the motion).
// The bundle adjustment of filters/subject_calibration.hpp then refines everything.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "filters/marker_model.hpp"
#include "formats/marker_layout.hpp"

namespace mocapd {

/// The spread (over frames, every `stride`-th: 1.4826 x the median absolute deviation, a
/// standard deviation that swapped or popped frames do not inflate) of the distance
/// between markers a and b of frame-major positions with `num_markers` per frame; NaN when
/// they are seen together in fewer than 10 of those frames.
double DistanceSpread(std::span<const Vec3> positions, int num_markers, int frames, int a, int b,
                      int stride);

struct ClusterPlacementOptions {
  /// Markers keep their distances within this (standard deviation over the take) when
  /// they ride one segment.
  double rigid_std_m = 0.012;
  int min_markers = 8;  ///< Fewer cannot show a body.
};

struct ClusterPlacement {
  std::vector<int> joint;    ///< Per marker, the template joint it rides.
  std::vector<Vec3> offset;  ///< Per marker, its first guess in that joint's frame.
  /// Per marker: a known set puts a landmark on its segment within 10 cm of it, and its
  /// offset is that landmark's (else a point of the segment's surface, no landmark).
  std::vector<uint8_t> anatomical;
  int reference_frame = -1;     ///< The frame the template was fitted to.
  std::string up_axis;          ///< The capture's up, e.g. "+z" (the nearest axis)...
  double tilt_deg = 0.0;        ///< ...and how far the fitted body's up is from it.
  double height_m = 0.0;        ///< The fitted template's height.
  double landmark_rms_m = 0.0;  ///< Markers to their nearest landmarks in that fit.
  int moved_by_rigidity = 0;    ///< Markers whose segment the motion changed (step 3).
  /// The best fit faced backwards (the take walks the other way) and was turned round.
  bool turned_round = false;
};

/// Places every marker. templ: the 1.75 m template humanoid (MakeTemplateHumanoid) with
/// its roles; landmarks: markers placed on it (one joint each, offsets in its frames).
/// positions: frame-major, metres, NaN missing. Throws std::runtime_error when fewer than
/// options.min_markers markers are given or no frame sees half of them;
/// std::invalid_argument when positions do not hold frames x num_markers or there are no
/// landmarks.
ClusterPlacement PlaceByClustering(const Skeleton& templ, const HumanoidRoles& roles,
                                   std::span<const MarkerDefinition> landmarks,
                                   std::span<const Vec3> positions, int num_markers, int frames,
                                   const ClusterPlacementOptions& options = {});

}  // namespace mocapd
