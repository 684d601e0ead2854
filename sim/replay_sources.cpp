// The replay's take sources.
#include "sim/replay_sources.hpp"

#include <cstdio>
#include <random>
#include <stdexcept>

#include "formats/bvh.hpp"
#include "formats/marker_layout.hpp"
#include "formats/subject_file.hpp"
#include "formats/subject_from_markers.hpp"
#include "sim/humanoid.hpp"
#include "sim/humanoid_subject.hpp"
#include "sim/synthesis.hpp"

namespace mocapd {

ReplaySource HumanoidReplaySource(const std::string& motion, double seconds, double rate_hz,
                                  double noise_mm, uint64_t seed) {
  ReplaySource s;
  const SubjectModel model = MakeHumanoidSubject("actor1");
  s.skeleton = model.skeleton;
  s.markers = model.markers;
  s.rate_hz = rate_hz;
  s.truth = MakeHumanoidMotion(*s.skeleton, ParseHumanoidMotion(motion), seconds, rate_hz);
  std::mt19937_64 rng(seed);
  s.take = SynthesizeMarkers(*s.skeleton, *s.markers, s.truth, rate_hz, noise_mm * 1e-3, &rng);
  char d[160];
  std::snprintf(d, sizeof(d), "built-in humanoid, %s, %.1f s at %.0f Hz, %.1f mm noise",
                motion.c_str(), seconds, rate_hz, noise_mm);
  s.description = d;
  return s;
}

ReplaySource BvhReplaySource(const std::string& path, double rate_hz, const std::string& units) {
  BvhReadOptions read;
  read.units = units;
  const BvhTake bvh = ReadBvh(path, read);
  if (bvh.frames.empty())
    throw std::runtime_error(path + ": the take has no frames (Frames: 0): nothing to replay");
  ReplaySource s;
  s.rate_hz = rate_hz > 0 ? rate_hz : bvh.rate_hz();
  s.skeleton = std::make_shared<const Skeleton>(bvh.skeleton);
  HumanoidRoles roles;
  try {
    roles = MatchHumanoidRoles(bvh.skeleton);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(path + ": " + e.what());  // a take from the user, named
  }
  s.markers = std::make_shared<const MarkerSet>(
      bvh.skeleton, PlaceMarkers(bvh.skeleton, roles, DefaultMarkerLayout(), bvh.end_sites));
  s.truth = ResampleMotion(bvh.skeleton, bvh.frames, bvh.rate_hz(), s.rate_hz);
  std::mt19937_64 rng(1);
  s.take = SynthesizeMarkers(*s.skeleton, *s.markers, s.truth, s.rate_hz, 0.0, &rng);
  s.description =
      path + " (markers synthesized, " + std::to_string(static_cast<int>(s.rate_hz)) + " Hz)";
  return s;
}

std::shared_ptr<const MarkerSet> GraphMarkers(const MotionLibrary& library) {
  const Skeleton& sk = *library.skeleton;
  return std::make_shared<const MarkerSet>(
      sk,
      PlaceMarkers(sk, MatchHumanoidRoles(sk), DefaultMarkerLayout(), library.layout.end_sites));
}

GraphReplaySource GraphSource(const std::string& graph_path) {
  GraphReplaySource s;
  if (graph_path == "humanoid") {
    const SubjectModel model = MakeHumanoidSubject("actor1");
    std::vector<BvhTake> takes;
    std::vector<std::string> names;
    for (const char* motion : {"walk", "turn", "reach", "mixed"}) {
      takes.push_back(
          MakeBvhTake(*model.skeleton,
                      MakeHumanoidMotion(*model.skeleton, ParseHumanoidMotion(motion), 30.0, 30.0),
                      1.0 / 30.0));
      names.push_back(motion);
    }
    auto library = std::make_shared<MotionLibrary>(
        MakeMotionLibrary(takes, names, std::vector<uint64_t>(takes.size(), 0), 30.0));
    s.graph = std::make_shared<const MotionGraph>(BuildMotionGraph(*library, GraphBuildOptions{}));
    s.library = std::move(library);
    s.markers = model.markers;
    s.description = "motion graph over the built-in humanoid's walk, turn, reach and mixed motion";
  } else {
    auto graph = std::make_shared<const MotionGraph>(ReadMotionGraph(graph_path));
    auto library = std::make_shared<const MotionLibrary>(LoadGraphLibrary(*graph, graph_path));
    s.markers = GraphMarkers(*library);
    s.graph = std::move(graph);
    s.library = std::move(library);
    s.description = "motion graph " + graph_path;
  }
  char d[96];
  std::snprintf(d, sizeof(d), " (%d takes, %zu transitions)", s.library->num_takes(),
                s.graph->transitions.size());
  s.description += d;
  return s;
}

ReplaySource C3dReplaySource(const std::string& path, const std::string& subject_path,
                             const std::string& marker_set) {
  ReplaySource s;
  SubjectModel model;
  if (!marker_set.empty()) {
    const MarkerSetDefinition set = FindMarkerSet(marker_set);
    std::vector<std::string> labels;
    for (const MarkerSetMarker& m : set.markers) labels.push_back(m.name);
    model = TemplateSubject(set, labels, 1.75, "actor1");
  } else {
    model = subject_path.empty() ? MakeHumanoidSubject("actor1") : ReadSubjectModel(subject_path);
  }
  s.skeleton = model.skeleton;
  s.markers = model.markers;
  s.take = ReadC3d(path);
  if (s.take.num_frames < 1) throw std::runtime_error(path + ": the take has no frames to replay");
  s.rate_hz = s.take.rate_hz;
  s.description = path;
  return s;
}

}  // namespace mocapd
