// The built-in humanoid subject.
#include "sim/humanoid_subject.hpp"

#include "formats/marker_layout.hpp"
#include "sim/humanoid.hpp"

namespace mocapd {

SubjectModel MakeHumanoidSubject(const std::string& name) {
  auto skeleton = std::make_shared<const Skeleton>(MakeHumanoidSkeleton());
  const HumanoidRoles roles = MatchHumanoidRoles(*skeleton);
  SubjectModel model;
  model.name = name;
  model.bvh_units = "cm";
  model.markers = std::make_shared<const MarkerSet>(
      *skeleton, PlaceMarkers(*skeleton, roles, DefaultMarkerLayout(), {}));
  model.skeleton = std::move(skeleton);
  return model;
}

}  // namespace mocapd
