// The motion graph on the built-in humanoid's takes: building and its file, constrained
// synthesis, smooth transitions, the endless walk, retrieval, and every bad input.
#include "sim/motion_graph.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "filters/resample.hpp"
#include "sim/graph_match.hpp"
#include "sim/graph_planner.hpp"
#include "sim/graph_walker.hpp"
#include "sim/humanoid.hpp"

namespace mocapd {
namespace {

namespace fs = std::filesystem;

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

void WriteText(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

class MotionGraphTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    folder_ = new std::string(
        (fs::temp_directory_path() / ("mocapd_motion_graph_test_" + std::to_string(::getpid())))
            .string());
    fs::create_directories(*folder_);
    const Skeleton sk = MakeHumanoidSkeleton();
    paths_ = new std::vector<std::string>;
    for (const char* motion : {"walk", "turn", "reach", "mixed"}) {
      const std::string path = *folder_ + "/" + motion + ".bvh";
      WriteBvh(path,
               MakeBvhTake(sk, MakeHumanoidMotion(sk, ParseHumanoidMotion(motion), 12.0, 30.0),
                           1.0 / 30.0));
      paths_->push_back(path);
    }
    library_ = new MotionLibrary(LoadMotionLibrary(*paths_, 0.0));
    graph_ = new MotionGraph(BuildMotionGraph(*library_, GraphBuildOptions{}));
  }
  static void TearDownTestSuite() {
    delete graph_;
    delete library_;
    delete paths_;
    fs::remove_all(*folder_);
    delete folder_;
  }
  static const MotionLibrary& lib() { return *library_; }
  static const MotionGraph& graph() { return *graph_; }
  static std::string Folder() { return *folder_; }
  static const std::vector<std::string>& Paths() { return *paths_; }

 private:
  static inline std::string* folder_ = nullptr;
  static inline std::vector<std::string>* paths_ = nullptr;
  static inline MotionLibrary* library_ = nullptr;
  static inline MotionGraph* graph_ = nullptr;
};

TEST_F(MotionGraphTest, BuildFindsTransitionsBetweenAndWithinTakesAndAnEndlessPart) {
  ASSERT_GT(graph().transitions.size(), 8u);
  bool within = false, between = false;
  for (const GraphTransition& t : graph().transitions) {
    within = within || t.from_take == t.to_take;
    between = between || t.from_take != t.to_take;
    EXPECT_LE(t.cost_m, graph().options.max_cost_m);
    EXPECT_GE(t.exit_frame(), 0);
    EXPECT_LE(t.entry_frame(), lib().num_frames(t.to_take));
    EXPECT_LT(t.half_window, lib().rate_hz);  // L < 1 s
  }
  EXPECT_TRUE(within);
  EXPECT_TRUE(between);
  const GraphConnectivity c = AnalyseConnectivity(lib(), graph());
  EXPECT_GT(c.walk_nodes, 2);
  EXPECT_GE(c.walk_takes, 2);
}

TEST_F(MotionGraphTest, GraphFileRoundTripsAndBuildingIsDeterministic) {
  const std::string a = Folder() + "/a.json", b = Folder() + "/b.json";
  WriteMotionGraph(a, graph());
  WriteMotionGraph(b, BuildMotionGraph(lib(), GraphBuildOptions{}));
  EXPECT_EQ(ReadText(a), ReadText(b));
  const MotionGraph read = ReadMotionGraph(a);
  ASSERT_EQ(read.transitions.size(), graph().transitions.size());
  for (size_t k = 0; k < read.transitions.size(); ++k) {
    const GraphTransition &x = read.transitions[k], &y = graph().transitions[k];
    EXPECT_EQ(x.from_take, y.from_take);
    EXPECT_EQ(x.from_frame, y.from_frame);
    EXPECT_EQ(x.to_take, y.to_take);
    EXPECT_EQ(x.to_frame, y.to_frame);
    EXPECT_EQ(x.half_window, y.half_window);
    EXPECT_DOUBLE_EQ(x.cost_m, y.cost_m);
    EXPECT_NEAR(x.align.yaw_rad, y.align.yaw_rad, 1e-12);
    EXPECT_DOUBLE_EQ(x.blend_path_m, y.blend_path_m);
  }
  // Written again, the read graph gives the same bytes; and its takes load back.
  const std::string c = Folder() + "/c.json";
  WriteMotionGraph(c, read);
  EXPECT_EQ(ReadText(a), ReadText(c));
  EXPECT_EQ(LoadGraphLibrary(read, a).num_takes(), lib().num_takes());
}

TEST_F(MotionGraphTest, TakesOfAnotherSkeletonAreRefusedNamingTheFile) {
  const std::string other = Folder() + "/small.bvh";
  const Skeleton small = MakeHumanoidSkeleton(1.45);
  WriteBvh(other, MakeBvhTake(small, MakeHumanoidMotion(small, HumanoidMotion::kWalk, 2.0, 30.0),
                              1.0 / 30.0));
  try {
    LoadMotionLibrary({Paths()[0], other}, 0.0);
    FAIL() << "a take of another skeleton was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("small.bvh"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("skeleton differs"), std::string::npos) << e.what();
  }
}

// A one-frame take (a T-pose file among the walks) shows no motion and is typed by its
// channels alone; merged in, it could move the graph's root onto a joint that never moves
// and every transition was lost, under a warning to check the units. Refused, named.
TEST_F(MotionGraphTest, ATakeOfOneFrameIsRefusedNamingTheFile) {
  const std::string still = Folder() + "/tpose.bvh";
  const Skeleton sk = MakeHumanoidSkeleton();
  WriteBvh(still, MakeBvhTake(sk, {RestPose(sk)}, 1.0 / 30.0));
  try {
    LoadMotionLibrary({Paths()[0], still}, 0.0);
    FAIL() << "a take of one frame was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("tpose.bvh: the take has 1 frame(s)"), std::string::npos)
        << e.what();
  }
}

TEST_F(MotionGraphTest, CorruptGraphFilesNameTheFileAndField) {
  const std::string good = Folder() + "/good.json";
  WriteMotionGraph(good, graph());
  const std::string text = ReadText(good);
  struct Case {
    std::string text, expect;
  };
  std::string bad_frame = text;
  const size_t at = bad_frame.find("\"from_frame\": ");
  bad_frame.replace(at, std::string("\"from_frame\": ").size(), "\"from_frame\": 99999, \"x\": ");
  std::string bad_take = text;
  const size_t to = bad_take.find("\"to\": \"");
  bad_take.replace(to, 7, "\"to\": \"nosuchtake");
  const std::vector<Case> cases = {
      {text.substr(0, text.size() / 2), "not a JSON motion graph"},
      {"{\"format\": \"something else\"}", "not a mocapd motion graph"},
      {bad_frame, "transitions[0].from_frame"},
      {bad_take, "names no take"},
      {"{\"format\": \"mocapd motion graph\", \"version\": 1, \"rate_hz\": 30}", "'units'"},
  };
  for (const Case& c : cases) {
    const std::string path = Folder() + "/bad.json";
    WriteText(path, c.text);
    try {
      ReadMotionGraph(path);
      FAIL() << "accepted: " << c.expect;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("bad.json"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(c.expect), std::string::npos) << e.what();
    }
  }
}

TEST_F(MotionGraphTest, AChangedTakeIsRefusedWhenTheGraphIsLoaded) {
  const std::string folder = Folder() + "/changed";
  fs::create_directories(folder);
  std::vector<std::string> copies;
  for (const std::string& p : Paths()) {
    copies.push_back(folder + "/" + fs::path(p).filename().string());
    fs::copy_file(p, copies.back(), fs::copy_options::overwrite_existing);
  }
  const MotionLibrary l = LoadMotionLibrary(copies, 0.0);
  const std::string graph_path = folder + "/g.json";
  WriteMotionGraph(graph_path, BuildMotionGraph(l, GraphBuildOptions{}));
  std::ofstream(copies[1], std::ios::app) << "0 ";  // one more value: another file
  try {
    LoadGraphLibrary(ReadMotionGraph(graph_path), graph_path);
    FAIL() << "a changed take was accepted";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("turn"), std::string::npos) << e.what();
  }
}

TEST_F(MotionGraphTest, SynthesisMeetsDistanceAndTimeOverAGridOfTargets) {
  const GraphPoint from{lib().TakeIndex("walk"), 0};
  GraphPlanner planner(lib(), graph());
  planner.Prepare(from, std::nullopt, 21.0, 20.0);
  double worst_distance = 0.0, worst_time = 0.0;
  for (int d = 2; d <= 14; d += 3) {
    for (int t = 4; t <= 20; t += 4) {
      // Paces the humanoid's takes reach from a walk (it walks at about 1.1 m/s, and its
      // in-place motion is several metres of walking away from the walk's start).
      if (d > 1.2 * t || d < 0.4 * t) continue;
      const SynthesisResult r = planner.Solve(d, t);
      ValidatePath(lib(), graph(), r.path);
      // What the planner added up is what the rendered path covers.
      EXPECT_NEAR(r.planned_distance_m, r.distance_m, 1e-6) << d << " m in " << t << " s";
      EXPECT_EQ(r.frames, static_cast<int>(RenderPath(lib(), graph(), r.path).size()));
      worst_distance = std::max(worst_distance, std::abs(r.distance_miss_m));
      EXPECT_LE(std::abs(r.distance_miss_m), 0.2)
          << d << " m in " << t << " s: " << r.distance_m << " m";
      worst_time = std::max(worst_time, std::abs(r.time_miss_s));
      EXPECT_TRUE(r.exact_time) << d << " m in " << t << " s";
    }
  }
  EXPECT_LE(worst_distance, 0.2);
  EXPECT_LE(worst_time, 0.5 / lib().rate_hz + 1e-9);
}

TEST_F(MotionGraphTest, SynthesisEndsOnTheRequestedFrame) {
  const int walk = lib().TakeIndex("walk");
  const GraphPoint from{walk, 3}, to{walk, lib().num_frames(walk) - 40};
  const SynthesisResult r = Synthesize(lib(), graph(), from, to, 14.0, 15.0);
  EXPECT_TRUE(r.exact_time);
  const PathStep& last = r.path.back();
  ASSERT_LT(last.transition, 0);
  EXPECT_EQ(last.take, walk);
  EXPECT_EQ(last.first + last.count - 1, to.frame);
  EXPECT_EQ(r.path.front().take, walk);
  EXPECT_EQ(r.path.front().first, from.frame);
}

TEST_F(MotionGraphTest, AnImpossibleTargetGivesTheNearestPathAndItsMiss) {
  const GraphPoint from{lib().TakeIndex("walk"), 0};
  const SynthesisResult r = Synthesize(lib(), graph(), from, std::nullopt, 60.0, 3.0);
  EXPECT_TRUE(r.exact_time);
  EXPECT_LT(r.distance_miss_m, -50.0);  // nobody walks 60 m in 3 s: the fastest path instead
  EXPECT_NEAR(r.planned_distance_m, r.distance_m, 1e-3);
  // The other way: no path of 30 s stays within 1 m, so the shortest one, exactly.
  const SynthesisResult slow = Synthesize(lib(), graph(), from, std::nullopt, 0.0, 30.0);
  EXPECT_TRUE(slow.exact_time);
  EXPECT_NEAR(slow.planned_distance_m, slow.distance_m, 1e-3);
  GraphPlanner extremes(lib(), graph());
  extremes.PrepareExtremes(from, std::nullopt, 31.0);
  bool inside = true;
  const SynthesisResult shortest = extremes.SolveExtremes(0.0, 30.0, &inside);
  EXPECT_FALSE(inside);
  EXPECT_NEAR(slow.distance_m, shortest.distance_m, 0.01);
  // Limits are errors, not crashes: beyond the planner's 4 hours, and an end no path reaches.
  GraphPlanner planner(lib(), graph());
  EXPECT_THROW(planner.Prepare(from, std::nullopt, 5 * 3600.0, 10.0), std::invalid_argument);
  const int reach = lib().TakeIndex("reach");
  try {
    Synthesize(lib(), graph(), from, GraphPoint{reach, 0}, 5.0, 10.0);
    FAIL() << "reached a frame no transition enters";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("reach:0"), std::string::npos) << e.what();
  }
  EXPECT_THROW(ParseGraphPoint(lib(), "walk:100000"), std::invalid_argument);
  EXPECT_THROW(ParseGraphPoint(lib(), "nosuch:1"), std::invalid_argument);
  EXPECT_THROW(ParseGraphPoint(lib(), "walk"), std::invalid_argument);
}

TEST_F(MotionGraphTest, BlendedFramesAreAsSmoothAsTheTakes) {
  std::vector<double> source_acc, source_slide;
  for (int t = 0; t < lib().num_takes(); ++t) {
    const MotionSmoothness m = MeasureSmoothness(lib(), lib().takes[static_cast<size_t>(t)]);
    source_acc.insert(source_acc.end(), m.acceleration.begin() + 1, m.acceleration.end() - 1);
    source_slide.insert(source_slide.end(), m.foot_slide.begin() + 1, m.foot_slide.end() - 1);
  }
  std::sort(source_acc.begin(), source_acc.end());
  std::sort(source_slide.begin(), source_slide.end());
  const double acc99 = source_acc[source_acc.size() * 99 / 100];
  const double slide99 = source_slide[source_slide.size() * 99 / 100];
  GraphWalker walker(lib(), graph(), WalkOptions{});
  std::vector<Pose> walk;
  std::vector<uint8_t> blended;
  while (walk.size() < static_cast<size_t>(180 * lib().rate_hz)) walker.NextFrames(&walk, &blended);
  ASSERT_GT(walker.transitions_taken(), 10);
  const MotionSmoothness m = MeasureSmoothness(lib(), walk);
  int frames = 0, over_acc = 0, over_slide = 0;
  for (size_t f = 1; f + 1 < walk.size(); ++f) {
    if (!blended[f]) continue;
    ++frames;
    over_acc += m.acceleration[f] > acc99;
    over_slide += m.foot_slide[f] > slide99;
  }
  // Inside the takes 1 % of frames are above their p99; blends may not do worse.
  double worst_acc = 0.0, worst_slide = 0.0;
  for (size_t f = 1; f + 1 < walk.size(); ++f)
    if (blended[f]) {
      worst_acc = std::max(worst_acc, m.acceleration[f]);
      worst_slide = std::max(worst_slide, m.foot_slide[f]);
    }
  std::printf(
      "source p99: acceleration %.2f m/s^2, foot slide %.3f m/s; blended worst %.2f, %.3f\n", acc99,
      slide99, worst_acc, worst_slide);
  EXPECT_LE(over_acc, frames / 100 + 1) << over_acc << " of " << frames;
  EXPECT_LE(over_slide, frames / 100 + 1) << over_slide << " of " << frames;
}

TEST_F(MotionGraphTest, TheWalkNeverJumpsAndStaysNearHome) {
  GraphWalker walker(lib(), graph(), WalkOptions{.seed = 7});
  std::vector<Pose> walk;
  while (walk.size() < static_cast<size_t>(600 * lib().rate_hz)) walker.NextFrames(&walk);
  double max_source_step = 0.0;
  for (int t = 0; t < lib().num_takes(); ++t)
    for (int f = 1; f < lib().num_frames(t); ++f)
      max_source_step = std::max(max_source_step, lib().Step(t, f));
  const auto b = static_cast<size_t>(lib().body_root);
  double max_step = 0.0, max_radius = 0.0;
  for (size_t f = 1; f < walk.size(); ++f) {
    Vec3 d = walk[f].translation[b] - walk[f - 1].translation[b];
    d.y() = 0.0;
    max_step = std::max(max_step, d.norm());
    max_radius =
        std::max(max_radius, std::hypot(walk[f].translation[b].x(), walk[f].translation[b].z()));
  }
  std::printf("10 min walk: largest step %.3f m (takes' %.3f), farthest from home %.2f m\n",
              max_step, max_source_step, max_radius);
  EXPECT_LE(max_step, 1.5 * max_source_step);
  EXPECT_LT(max_radius, 15.0);
  // Seeded: the same seed walks the same way.
  GraphWalker again(lib(), graph(), WalkOptions{.seed = 7});
  std::vector<Pose> walk2;
  while (walk2.size() < 300) again.NextFrames(&walk2);
  for (size_t f = 0; f < 300; ++f)
    EXPECT_TRUE(walk2[f].translation[b].isApprox(walk[f].translation[b]));
}

TEST_F(MotionGraphTest, RetrievalOfALibraryTakeReturnsItAndFollowsAnotherSkeleton) {
  const int walk = lib().TakeIndex("walk");
  const BvhTake own =
      MakeBvhTake(*lib().skeleton, lib().takes[static_cast<size_t>(walk)], 1.0 / 30.0);
  const MatchResult self = MatchQuery(lib(), graph(), own);
  EXPECT_LT(self.velocity_difference_cm, 0.05);
  // A shorter person walking at another pace: the graph's walk, within a few cm/frame.
  const Skeleton small = MakeHumanoidSkeleton(1.5);
  const BvhTake query =
      MakeBvhTake(small, MakeHumanoidMotion(small, HumanoidMotion::kWalk, 6.0, 60.0), 1.0 / 60.0);
  const MatchResult r = MatchQuery(lib(), graph(), query);
  EXPECT_EQ(r.query_frames,
            static_cast<int>(ResampleMotion(small, query.frames, 60.0, 30.0).size()));
  EXPECT_EQ(PathFrames(graph(), r.path), r.query_frames);
  EXPECT_LT(r.velocity_difference_cm, 2.0);
  // A rig that is not a humanoid is refused by name.
  const BvhTake stick = MakeBvhTake(
      Skeleton({Joint{.name = "a", .parent = {}, .type = JointType::kFree}}),
      {RestPose(Skeleton({Joint{.name = "a", .parent = {}, .type = JointType::kFree}}))},
      1.0 / 30.0);
  EXPECT_THROW(MatchQuery(lib(), graph(), stick), std::invalid_argument);
}

TEST_F(MotionGraphTest, DiscontinuousPathsAreRejected) {
  const int walk = lib().TakeIndex("walk");
  EXPECT_THROW(ValidatePath(lib(), graph(), {{walk, 0, 10, -1}, {walk, 20, 5, -1}}),
               std::invalid_argument);
  EXPECT_THROW(ValidatePath(lib(), graph(), {{walk, 0, 100000, -1}}), std::invalid_argument);
  EXPECT_THROW(ValidatePath(lib(), graph(), {{-1, 0, 0, 100000}}), std::invalid_argument);
  EXPECT_NO_THROW(ValidatePath(lib(), graph(), {{walk, 0, 10, -1}, {walk, 10, 5, -1}}));
}

}  // namespace
}  // namespace mocapd
