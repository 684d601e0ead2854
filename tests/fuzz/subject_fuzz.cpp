// libFuzzer entry point over subject files, the model every solve trusts: any input must
// parse or throw std::runtime_error, and a subject that parses must format back and
// clean a short take of its own markers (moving, with a gap and a pop) without a crash,
// a hang or a non-finite published value.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <vector>

#include "filters/cleanup_pipeline.hpp"
#include "filters/marker_model.hpp"
#include "filters/skeleton.hpp"
#include "formats/subject_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  mocapd::SubjectModel subject;
  try {
    subject =
        mocapd::ParseSubjectModel(std::string(reinterpret_cast<const char*>(data), size), "fuzz");
  } catch (const std::runtime_error&) {
    return 0;
  }
  (void)mocapd::FormatSubjectModel(subject);
  const mocapd::Skeleton& skeleton = *subject.skeleton;
  const mocapd::MarkerSet& markers = *subject.markers;
  // A model this large is valid but would only slow the search down (a solve's cost grows
  // with the cube of the degrees of freedom).
  if (skeleton.num_joints() > 40 || markers.num_markers() > 100) return 0;
  mocapd::CleanupPipeline pipeline(subject.skeleton, subject.markers, mocapd::CleanupOptions{});
  mocapd::KinematicsWorkspace ws(skeleton);
  const mocapd::Pose rest = mocapd::RestPose(skeleton);
  ForwardKinematics(skeleton, rest, &ws);
  std::vector<mocapd::Vec3> rest_markers(static_cast<size_t>(markers.num_markers()));
  mocapd::EvaluateMarkers(markers, ws, rest_markers);
  std::vector<mocapd::Vec3> frame(rest_markers.size());
  // What is published is finite: the pose always, a marker unless marked unrecoverable.
  auto check = [&] {
    const mocapd::CleanFrame& out = pipeline.output();
    for (size_t m = 0; m < out.markers.size(); ++m)
      if (!out.markers[m].allFinite() && out.status[m] != mocapd::MarkerStatus::kUnrecoverable)
        std::abort();
    ForwardKinematics(skeleton, out.pose, &ws);
    for (const mocapd::Vec3& p : ws.p_WJ)
      if (!p.allFinite()) std::abort();
  };
  for (int t = 0; t < 24; ++t) {
    for (size_t m = 0; m < frame.size(); ++m) {
      frame[m] = rest_markers[m] + mocapd::Vec3(0.01 * t, 0.0, 0.002 * std::sin(t));
      if (t >= 8 && t < 12 && m % 3 == 0) frame[m] = mocapd::Vec3::Constant(std::nan(""));
    }
    if (t == 15 && !frame.empty()) frame[0] += mocapd::Vec3(0.3, 0.0, 0.0);
    if (pipeline.Push(frame)) check();
  }
  while (pipeline.Flush()) check();
  return 0;
}
