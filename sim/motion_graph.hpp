// A skeletal motion graph over a library of takes (after Kovar et al. 2002 and Huang et
// al. 2015): the takes are its nodes and blended transitions between similar frames its
// edges. This file holds the library (takes of one skeleton, resampled to one rate), the
// pose dissimilarity, the graph's building and its file, and the rendering of a path
// through the graph into motion (blends with the root aligned in heading and position).
// Planning paths under constraints is in sim/graph_planner.hpp, random walks for streams
// in sim/graph_walker.hpp, retrieval in sim/graph_match.hpp.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "filters/skeleton.hpp"
#include "formats/bvh.hpp"

namespace mocapd {

/// A planar rigid motion about the vertical (Y) axis: p -> Ry(yaw) p + (shift_x, 0, shift_z).
struct PlanarTransform {
  double yaw_rad = 0.0;
  double shift_x = 0.0;
  double shift_z = 0.0;
  Vec3 Apply(const Vec3& p) const;
  Quat Rotation() const;
  /// this after other: p -> this(other(p)).
  PlanarTransform Compose(const PlanarTransform& other) const;
};

/// The takes a graph is built over: one skeleton, every take resampled to one rate.
struct MotionLibrary {
  std::shared_ptr<const Skeleton> skeleton;
  BvhTake layout;     ///< The first take's hierarchy and channels (no frames), for writing BVH.
  int body_root = 0;  ///< The first translating joint: the one that carries the travel.
  double rate_hz = 30.0;
  std::vector<std::string> names;  ///< File stems, unique.
  std::vector<std::string> paths;
  std::vector<uint64_t> file_hashes;  ///< FNV-1a of each file's bytes.
  std::vector<std::vector<Pose>> takes;
  /// Per take, per frame: the body root's world position, and its heading (yaw about Y).
  std::vector<std::vector<Vec3>> root_position;
  std::vector<std::vector<double>> root_yaw;
  /// Per take: cumulative horizontal path of the body root; [f] = path from frame 0 to f.
  std::vector<std::vector<double>> path_m;
  /// The direction of travel relative to the root's yaw (mean over frames moving faster
  /// than 0.3 m/s): which way a body faces, for any rig's rest orientation.
  double forward_yaw_offset = 0.0;
  double ground_y = 0.0;  ///< The lowest the feet get (1st percentile), for contacts.
  /// Per take, per frame: the feet's world positions (left, right), and whether each is
  /// planted (within 5 cm of the ground and moving under 0.5 m/s); empty for a rig
  /// without recognisable feet.
  std::vector<std::vector<std::array<Vec3, 2>>> foot_position;
  std::vector<std::vector<std::array<bool, 2>>> foot_planted;
  /// Per side (left, right): hip, knee and ankle joints (-1: no recognisable legs).
  std::array<std::array<int, 3>, 2> legs{{{-1, -1, -1}, {-1, -1, -1}}};
  /// The body root's parent's world transform (constant: its ancestors never move).
  Mat3 parent_rotation = Mat3::Identity();
  Vec3 parent_position = Vec3::Zero();

  int num_takes() const { return static_cast<int>(takes.size()); }
  int num_frames(int take) const {
    return static_cast<int>(takes[static_cast<size_t>(take)].size());
  }
  /// Index of the take with this name; throws std::invalid_argument listing the names.
  int TakeIndex(const std::string& name) const;
  /// The horizontal distance the body root covers stepping from frame f-1 to f (0 at f=0).
  double Step(int take, int f) const;
};

/// A take's frame rate, a whole number of hertz when its printed frame time means one.
double TakeRate(const BvhTake& take);

/// Reads BVH takes into a library. rate_hz 0: the first take's rate. units: as for
/// ReadBvh ("" guesses from bone lengths). Throws std::runtime_error naming the file when a
/// take cannot be read, is empty, has no translating joint, or has another skeleton than
/// the first take (joint names, parents or bone lengths beyond 2 %).
MotionLibrary LoadMotionLibrary(const std::vector<std::string>& paths, double rate_hz,
                                const std::string& units = "");

/// The same from takes in memory: paths name them (their stems become the take names)
/// and file_hashes identify them (0 for takes that are no file).
MotionLibrary MakeMotionLibrary(const std::vector<BvhTake>& takes,
                                const std::vector<std::string>& paths,
                                const std::vector<uint64_t>& file_hashes, double rate_hz);

/// Per frame, the pose features the dissimilarity compares: every weighted joint's
/// position in the body root's heading frame and its velocity (times velocity_weight_s),
/// scaled so that the distance between two rows is the weighted RMS joint distance in m.
Eigen::MatrixXd PoseFeatures(const MotionLibrary& library, int take, double velocity_weight_s);

struct GraphBuildOptions {
  /// Top N per ordered pair of takes (a take with itself too), and the largest blend
  /// distortion kept: more and looser transitions connect more of the library (the build
  /// reports how much a walk can reach) at the cost of smoothness (see the benchmark).
  int transitions_per_pair = 5;
  double max_cost_m = 0.25;
  double velocity_weight_s = 0.1;  ///< Velocity differences count as positions this much later.
  double min_window_s = 0.1;       ///< The overlap half-window L, from this ...
  double max_window_s = 0.5;       ///< ... to this (L < 1 s).
  double min_separation_s = 0.5;   ///< Two transitions of a pair leave this far apart at least.
  double min_loop_s = 0.5;         ///< A take's transition to itself jumps at least this far.
};

struct GraphTransition {
  int from_take = 0, from_frame = 0;  ///< The window's centre in the source take.
  int to_take = 0, to_frame = 0;      ///< The matching centre in the destination take.
  int half_window = 1;                ///< L: the blend spans frames centre-L .. centre+L.
  double cost_m = 0.0;                ///< Blend distortion (weighted RMS joint distance, m).
  PlanarTransform align;              ///< Maps the destination take onto the source at the centre.
  double blend_path_m = 0.0;          ///< Horizontal root path inside the blend's 2L+1 frames.
  /// The blend's first frame is the source's exit_frame (nothing of the source plays
  /// after it); play resumes in the destination at entry_frame.
  int exit_frame() const { return from_frame - half_window; }
  int entry_frame() const { return to_frame + half_window + 1; }
  int blend_frames() const { return 2 * half_window + 1; }
};

struct GraphTakeRef {
  std::string name;
  /// As given at build time; in the file relative to its folder where it can be, and read
  /// back resolved against that folder.
  std::string path;
  int frames = 0;  ///< At the graph's rate.
  uint64_t file_hash = 0;
};

struct MotionGraph {
  double rate_hz = 30.0;
  std::string units;  ///< The units the takes were read with ("" = guessed).
  GraphBuildOptions options;
  std::vector<GraphTakeRef> takes;
  std::vector<GraphTransition> transitions;
};

/// Figures from a build, for the terminal and the tests.
struct GraphBuildReport {
  int candidates = 0;  ///< Local minima of the dissimilarity considered.
  int kept = 0;
  double seconds = 0.0;
};

/// Builds the graph: per ordered pair of takes, the local minima of the dissimilarity,
/// each with the half-window that minimises its blend distortion, the best N under
/// max_cost_m kept. Deterministic.
MotionGraph BuildMotionGraph(const MotionLibrary& library, const GraphBuildOptions& options,
                             GraphBuildReport* report = nullptr);

/// The blend distortion of a transition (i in take a, j in take b) with half-window L,
/// and the alignment it uses: the weighted RMS joint distance over the window in the
/// aligned frame, inflated by the velocity the blend adds spreading it over 2L frames.
double BlendDistortion(const MotionLibrary& library, const Eigen::MatrixXd& features_a,
                       const Eigen::MatrixXd& features_b, int a, int i, int b, int j, int L,
                       double velocity_weight_s);

/// Writes the graph as JSON (takes, options, transitions), paths relative to the file's
/// folder where they can be. Throws std::runtime_error naming the file on failure.
void WriteMotionGraph(const std::string& path, const MotionGraph& graph);
/// Reads a graph file. Throws std::runtime_error naming the file and the field for a
/// corrupt or inconsistent file (a transition outside its takes, an unknown take ...).
MotionGraph ReadMotionGraph(const std::string& path);
/// Loads the takes a graph was built over and checks they are the same files. Throws
/// std::runtime_error naming a changed take.
MotionLibrary LoadGraphLibrary(const MotionGraph& graph, const std::string& graph_path);

/// One step of a path: play frames [first, first+count) of a take, or blend through a
/// transition (its 2L+1 frames).
struct PathStep {
  int take = -1;
  int first = 0;
  int count = 0;
  int transition = -1;  ///< >= 0: a blend; take/first/count unused.
};
using GraphPath = std::vector<PathStep>;

/// Checks a path is continuous (each play ends where the next blend leaves, each blend's
/// destination resumes where the next play starts). Throws std::invalid_argument.
void ValidatePath(const MotionLibrary& library, const MotionGraph& graph, const GraphPath& path);
/// Renders a path into frames at the graph's rate, starting in the first take's own
/// coordinates. Blends slerp every joint's rotation and lerp translations; the body root is
/// aligned in heading and position by the transition's alignment.
std::vector<Pose> RenderPath(const MotionLibrary& library, const MotionGraph& graph,
                             const GraphPath& path);
/// Frames and the horizontal root path a path covers, as rendering it would give.
int PathFrames(const MotionGraph& graph, const GraphPath& path);
double PathDistance(const MotionLibrary& library, const MotionGraph& graph, const GraphPath& path);

/// Appends one step's frames to out with the running transform (updated by blends).
void RenderStep(const MotionLibrary& library, const MotionGraph& graph, const PathStep& step,
                PlanarTransform* transform, std::vector<Pose>* out);
/// The same, also flagging each appended frame (1: blended).
void RenderStep(const MotionLibrary& library, const MotionGraph& graph, const PathStep& step,
                PlanarTransform* transform, std::vector<Pose>* out, std::vector<uint8_t>* blended);

/// How smooth motion is, per frame: the joints' mean acceleration (m/s^2, second
/// differences of world positions) and the feet's slide (m/s: the horizontal speed of a
/// foot while it is on the ground, i.e. within contact_height_m of the lowest the feet
/// get in the library; 0 when no foot is down). Frames at either end get 0. Throws
/// std::invalid_argument if the skeleton is not a recognisable humanoid (no feet).
struct MotionSmoothness {
  std::vector<double> acceleration;
  std::vector<double> foot_slide;
};
MotionSmoothness MeasureSmoothness(const MotionLibrary& library, const std::vector<Pose>& frames,
                                   double contact_height_m = 0.05);

/// The horizontal root path of rendered frames.
double RootPathLength(const MotionLibrary& library, const std::vector<Pose>& frames);

}  // namespace mocapd
