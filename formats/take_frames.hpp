// Feeding a recorded C3D take to a solver: maps the subject's markers to the take's
// point labels once, then copies each frame's observations without allocating.
#pragma once

#include <span>
#include <string>
#include <vector>

#include "filters/marker_model.hpp"
#include "formats/c3d.hpp"
#include "protocol/messages.hpp"

namespace mocapd {

class TakeMarkerMap {
 public:
  /// Matches markers to labels by exact name. Throws std::invalid_argument listing the
  /// subject's markers the take lacks if fewer than min_matched are found.
  TakeMarkerMap(const MarkerSet& markers, const C3dTake& take, int min_matched = 3);

  /// Fills p_WM and weights (1 observed, 0 missing or absent from the take) for a frame.
  void Observe(const C3dTake& take, int frame, std::span<Vec3> p_WM,
               std::span<double> weights) const;
  /// Fills a marker frame's positions and validity (subject's marker order) for a frame;
  /// the caller sets subject, hash, frame number, time and rate. Allocates only the
  /// first time the message holds this many markers.
  void FillMessage(const C3dTake& take, int frame, protocol::MarkerFrameMessage* message) const;
  int matched() const { return matched_; }
  /// The take's point a subject's marker reads, or -1 (not in the take, or ambiguous).
  int point_of_marker(int marker) const { return point_of_marker_[static_cast<size_t>(marker)]; }
  const std::vector<std::string>& unmatched() const { return unmatched_; }
  /// The subject's markers whose exact label the take gives to more than one point (the
  /// first such point is used): an exporter's merge or a labelling mistake.
  const std::vector<std::string>& duplicated() const { return duplicated_; }
  /// The subject's markers that no label names exactly and several name loosely (two
  /// subjects' Dan:LBWT and Eve:LBWT, or LBWT padded twice), each with the competing
  /// labels: none is used, so the marker stays missing.
  const std::vector<std::string>& ambiguous() const { return ambiguous_; }

 private:
  std::vector<int> point_of_marker_;
  std::vector<std::string> unmatched_, duplicated_, ambiguous_;
  int matched_ = 0;
};

}  // namespace mocapd
