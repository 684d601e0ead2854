// Marker-to-label mapping for recorded takes.
#include "formats/take_frames.hpp"

#include <algorithm>
#include <stdexcept>

namespace mocapd {

TakeMarkerMap::TakeMarkerMap(const MarkerSet& markers, const C3dTake& take, int min_matched) {
  for (const MarkerDefinition& m : markers.markers()) {
    const std::vector<int> matches = take.MatchingLabels(m.name);
    const int p = take.FindLabel(m.name);
    point_of_marker_.push_back(p);
    if (p >= 0) {
      ++matched_;
      if (matches.size() > 1) duplicated_.push_back(m.name);
    } else if (matches.size() > 1) {
      std::string competing;
      for (int q : matches)
        competing += (competing.empty() ? "" : ", ") + take.labels[static_cast<size_t>(q)];
      ambiguous_.push_back(m.name + " (" + competing + ")");
    } else {
      unmatched_.push_back(m.name);
    }
  }
  if (matched_ < min_matched) {
    std::string msg = "take has " + std::to_string(matched_) + " of the subject's " +
                      std::to_string(markers.num_markers()) + " markers (need " +
                      std::to_string(min_matched) + "); missing:";
    for (const auto& n : unmatched_) msg += " " + n;
    for (const auto& n : ambiguous_) msg += " " + n;
    // A file with no labels at all: say so, not only which of the subject's are missing.
    const bool unlabelled =
        !take.labels.empty() &&
        std::all_of(take.labels.begin(), take.labels.end(),
                    [](const std::string& label) { return label.starts_with("unlabeled_"); });
    if (unlabelled)
      msg += " (the take's " + std::to_string(take.labels.size()) +
             " points carry no labels: its POINT:LABELS is missing or empty, so they read as "
             "unlabeled_1..)";
    throw std::invalid_argument(msg);
  }
}

void TakeMarkerMap::Observe(const C3dTake& take, int frame, std::span<Vec3> p_WM,
                            std::span<double> weights) const {
  for (size_t m = 0; m < point_of_marker_.size(); ++m) {
    const int p = point_of_marker_[m];
    const bool ok = p >= 0 && take.valid(frame, p);
    weights[m] = ok ? 1.0 : 0.0;
    p_WM[m] = ok ? take.at(frame, p) : Vec3::Constant(kNaN);
  }
}

void TakeMarkerMap::FillMessage(const C3dTake& take, int frame,
                                protocol::MarkerFrameMessage* message) const {
  message->positions.resize(point_of_marker_.size());
  message->valid.resize(point_of_marker_.size());
  for (size_t m = 0; m < point_of_marker_.size(); ++m) {
    const int p = point_of_marker_[m];
    const bool ok = p >= 0 && take.valid(frame, p);
    message->valid[m] = ok ? 1 : 0;
    message->positions[m] = ok ? take.at(frame, p) : Vec3::Constant(kNaN);
  }
}

}  // namespace mocapd
