// `mocapd calibrate` implementation.
#include "runtime/calibrate_command.hpp"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include "filters/resample.hpp"
#include "formats/bvh.hpp"
#include "formats/c3d.hpp"
#include "formats/subject_file.hpp"

namespace mocapd {

int RunCalibrateCommand(const CalibrateCommandOptions& options, std::ostream& out) {
  BvhReadOptions bvh_options;
  bvh_options.units = options.bvh_units;
  const BvhTake bvh = ReadBvh(options.skeleton_bvh, bvh_options);
  const C3dTake c3d = ReadC3d(options.markers_c3d);
  std::vector<Pose> motion = bvh.frames;
  if (std::abs(bvh.rate_hz() - c3d.rate_hz) > 1e-6 * c3d.rate_hz) {
    out << "resampling " << options.skeleton_bvh << " from " << bvh.rate_hz()
        << " Hz to the capture's " << c3d.rate_hz << " Hz\n";
    motion = ResampleMotion(bvh.skeleton, bvh.frames, bvh.rate_hz(), c3d.rate_hz);
  }
  const int frames = std::min(static_cast<int>(motion.size()), c3d.num_frames);
  const int longer = std::max(static_cast<int>(motion.size()), c3d.num_frames);
  // Resampling can round the last frame either way; anything more means different takes.
  if (frames == 0 || longer - frames > 1)
    throw std::runtime_error("calibrate: the skeleton motion has " + std::to_string(motion.size()) +
                             " frames at the capture's rate but " + options.markers_c3d + " has " +
                             std::to_string(c3d.num_frames) + ": they are not the same take");

  std::vector<KinematicsWorkspace> fk(static_cast<size_t>(frames),
                                      KinematicsWorkspace(bvh.skeleton));
  for (int f = 0; f < frames; ++f)
    ForwardKinematics(bvh.skeleton, motion[static_cast<size_t>(f)], &fk[static_cast<size_t>(f)]);
  std::vector<std::string> names;
  std::vector<int> points;
  for (int p = 0; p < c3d.num_points(); ++p) {
    if (!c3d.is_marker(p)) continue;
    names.push_back(c3d.labels[static_cast<size_t>(p)]);
    points.push_back(p);
  }
  std::vector<Vec3> observed(static_cast<size_t>(frames) * names.size());
  for (int f = 0; f < frames; ++f)
    for (size_t m = 0; m < names.size(); ++m)
      observed[static_cast<size_t>(f) * names.size() + m] = c3d.at(f, points[m]);

  const auto results = CalibrateMarkers(bvh.skeleton, fk, names, observed, options.calibration);
  std::vector<MarkerDefinition> accepted;
  std::vector<double> rms;
  char line[256];
  std::snprintf(line, sizeof(line), "%-16s %-28s %8s %8s  %s\n", "marker", "attached to", "rms mm",
                "frames", "status");
  out << line;
  for (const MarkerCalibration& r : results) {
    std::string where = "-";
    if (r.definition.attachments[0].joint >= 0) {
      where = bvh.skeleton.joint(r.definition.attachments[0].joint).name;
      if (r.definition.num_attachments == 2)
        where += " + " + bvh.skeleton.joint(r.definition.attachments[1].joint).name;
    }
    std::snprintf(line, sizeof(line), "%-16s %-28s %8.3f %8d  %s\n", r.name.c_str(), where.c_str(),
                  r.rms_m * 1e3, r.frames_used,
                  r.accepted ? "ok" : ("REJECTED: " + r.reason).c_str());
    out << line;
    if (r.accepted) {
      accepted.push_back(r.definition);
      rms.push_back(r.rms_m);
    }
  }
  if (accepted.size() < 3)
    throw std::runtime_error("calibrate: only " + std::to_string(accepted.size()) +
                             " markers fit the skeleton; a subject needs at least 3");
  SubjectModel model;
  model.name = options.subject_name.empty()
                   ? std::filesystem::path(options.out_subject).stem().string()
                   : options.subject_name;
  model.skeleton = std::make_shared<const Skeleton>(bvh.skeleton);
  model.markers = std::make_shared<const MarkerSet>(bvh.skeleton, std::move(accepted));
  model.fit_rms_m = rms;
  model.bvh_units = bvh.units;
  WriteSubjectModel(options.out_subject, model);
  out << "wrote " << options.out_subject << ": " << model.markers->num_markers()
      << " markers accepted, " << results.size() - static_cast<size_t>(model.markers->num_markers())
      << " rejected, " << frames << " frames used\n";
  return model.markers->num_markers();
}

}  // namespace mocapd
