// Tests for live calibration, without sockets: a subject configured with calibrate = "live"
// is solved from its first usable frame with the template scaled to the actor, its joints'
// readiness is reported, and the calibrated subject swaps in at a frame boundary with no
// frame lost and no pop; it is written to a file that reads back. Bad configurations are
// clear errors.
#include "runtime/live_calibration.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <random>

#include "formats/bvh.hpp"
#include "formats/subject_from_markers.hpp"
#include "runtime/subject_runner.hpp"
#include "sim/humanoid.hpp"
#include "sim/synthesis.hpp"
#include "tests/support/allocation_counter.hpp"

namespace mocapd {
namespace {

class RecordingSink : public OutputSink {
 public:
  void Send(std::string_view topic, std::span<const uint8_t> message) override {
    if (topic.starts_with("skeleton/")) {
      protocol::SkeletonFrameMessage m;
      ASSERT_EQ(protocol::DecodeSkeletonFrame(message, &m), protocol::DecodeStatus::kOk);
      skeletons.push_back(m);
    } else if (protocol::MessageType type;
               topic.starts_with("character/") &&
               protocol::PeekType(message, &type) == protocol::DecodeStatus::kOk &&
               type == protocol::MessageType::kSkeletonFrame) {
      protocol::SkeletonFrameMessage m;
      ASSERT_EQ(protocol::DecodeSkeletonFrame(message, &m), protocol::DecodeStatus::kOk);
      characters.push_back(m);
    } else if (topic.starts_with("subject/")) {
      protocol::SubjectDescriptionMessage m;
      ASSERT_EQ(protocol::DecodeSubjectDescription(message, &m), protocol::DecodeStatus::kOk);
      descriptions.push_back(m);
      description_at.push_back(skeletons.size());
    } else if (topic.starts_with("calibration/")) {
      protocol::CalibrationStatusMessage m;
      ASSERT_EQ(protocol::DecodeCalibrationStatus(message, &m), protocol::DecodeStatus::kOk);
      calibrations.push_back(m);
    }
  }
  std::vector<protocol::SkeletonFrameMessage> skeletons, characters;
  std::vector<protocol::SubjectDescriptionMessage> descriptions;
  std::vector<size_t> description_at;  ///< Skeletons published before each description.
  std::vector<protocol::CalibrationStatusMessage> calibrations;
};

double AngleDeg(const Quat& a, const Quat& b) {
  return std::abs(a.angularDistance(b)) * 180.0 / 3.14159265358979;
}

class LiveCalibrationTest : public ::testing::Test {
 protected:
  static constexpr double kRate = 60.0;

  LiveCalibrationTest()
      : dir_(std::filesystem::temp_directory_path() /
             ("mocapd_live_calibration_" + std::to_string(::getpid()))),
        truth_(MakeHumanoidSkeleton(1.62)),
        markers_(truth_,
                 PlaceMarkerSet(truth_, MatchHumanoidRoles(truth_), FindMarkerSet("cmu-41"))) {
    std::filesystem::create_directories(dir_);
    const std::vector<Pose> motion = MakeHumanoidMotion(truth_, HumanoidMotion::kRom, 24.0, kRate);
    SynthesisNoise noise;
    noise.noise_sigma_m = 0.001;
    noise.soft_tissue_m = 0.005;
    take_ = SynthesizeMarkers(truth_, markers_, motion, kRate, noise);
  }
  ~LiveCalibrationTest() override { std::filesystem::remove_all(dir_); }

  // tables: what goes before the subject ("[output]\n...").
  DaemonConfig Config(const std::string& subject_lines, const std::string& tables = "") const {
    return ParseDaemonConfig("format_version = 1\n" + tables +
                                 "[[subject]]\nname = \"actor1\"\nrate_hz = 60\n" + subject_lines,
                             "live.toml", dir_.string());
  }

  // shift: where the capture stands, from the take's origin.
  protocol::MarkerFrameMessage Frame(const SubjectConfig& subject, int f,
                                     const Vec3& shift = Vec3::Zero()) const {
    protocol::MarkerFrameMessage m;
    m.subject = "actor1";
    m.model_hash = protocol::MarkerSetHash(*subject.model.markers);
    m.frame_number = static_cast<uint64_t>(f) + 1;
    m.rate_hz = static_cast<float>(kRate);
    for (const std::string& label : subject.live.labels) {
      const int p = take_.FindLabel(label);
      const bool valid = p >= 0 && take_.valid(f, p);
      m.positions.push_back(valid ? Vec3(take_.at(f, p) + shift) : Vec3::Constant(kNaN));
      m.valid.push_back(valid);
    }
    return m;
  }

  // A live subject's runner with its calibration, as a daemon's worker holds them. One
  // solve per refinement keeps the tests quick under the sanitizers; the mean of several
  // is the default the live_calibration_process test runs.
  struct LiveSubject {
    LiveSubject(const LiveCalibrationTest& test, const std::string& lines,
                const std::string& tables = "")
        : config(test.Config(
              "calibrate = \"live\"\nmarker_set = \"cmu-41\"\ncalibration_subsets = 1\n" + lines,
              tables)),
          subject(config.subjects[0]),
          calibration(board.Attach(subject, config)),
          runner(subject, config) {
      runner.AttachLiveCalibration(calibration);
    }
    DaemonConfig config;
    const SubjectConfig& subject;
    LiveCalibrationBoard board;
    std::shared_ptr<LiveCalibration> calibration;
    SubjectRunner runner;
  };

  // A character file beside the config; the subject line that drives it.
  std::string WriteCharacter(const Skeleton& character) const {
    WriteBvh((dir_ / "char.bvh").string(),
             MakeBvhTake(character, {RestPose(character)}, 1.0 / 30.0, "cm"));
    return "character = \"char.bvh\"\n";
  }

  std::filesystem::path dir_;
  Skeleton truth_;
  MarkerSet markers_;
  C3dTake take_;
};

TEST_F(
    LiveCalibrationTest,
    ATemplateScaledToTheActorSolvesAtOnceThenTheCalibratedSubjectSwapsInWithNoLostFrameAndNoPop) {
  LiveSubject live(*this,
                   "calibration_min_s = 12\n"
                   "calibration_out = \"actor1.live.toml\"\n");
  const SubjectConfig& subject = live.subject;
  SubjectRunner& runner = live.runner;
  LiveCalibration* calibration = live.calibration.get();
  RecordingSink sink;

  const int frames = take_.num_frames;
  std::vector<double> model_distance(static_cast<size_t>(frames));
  bool suspect = false;
  for (int f = 0; f < frames; ++f) {
    EXPECT_FALSE(runner.Accept(Frame(subject, f), 0, sink).has_value()) << "frame " << f;
    model_distance[static_cast<size_t>(f)] = runner.model_distance_m();
    suspect = suspect || runner.model_suspect();
    // The calibration thread's turn, once a second of capture (synchronous here).
    if (f % static_cast<int>(kRate) == 0) {
      calibration->Collect();
      (void)calibration->Refine();
    }
    if (f == 0) {
      // Published from the first usable frame on, at the actor's size.
      const LiveCalibrationStatus status = calibration->Status();
      EXPECT_EQ(status.state, LiveCalibrationState::kCollecting);
      EXPECT_NEAR(status.height_m, 1.62, 0.1);
    }
    if (f % 30 == 0) runner.PublishStatus(0, sink);
  }
  runner.EndOfStream(sink);
  calibration->Collect();

  // Every frame out, once, in order.
  ASSERT_EQ(sink.skeletons.size(), static_cast<size_t>(frames));
  for (int f = 0; f < frames; ++f)
    ASSERT_EQ(sink.skeletons[static_cast<size_t>(f)].frame_number, static_cast<uint64_t>(f) + 1);

  const LiveCalibrationStatus status = calibration->Status();
  ASSERT_EQ(status.state, LiveCalibrationState::kCalibrated) << status.message;
  EXPECT_EQ(runner.swaps(), 1);
  EXPECT_EQ(status.swaps, 1u);
  for (const JointReadiness& j : status.joints) EXPECT_TRUE(j.ready) << j.name;

  // Two descriptions: the scaled template's before the first frame, the calibrated
  // subject's (same joints, new rest offsets) just before its first frame.
  ASSERT_EQ(sink.descriptions.size(), 2u);
  EXPECT_EQ(sink.description_at[0], 0u);
  EXPECT_NE(sink.descriptions[0].rest_offsets[1], sink.descriptions[1].rest_offsets[1]);
  const size_t swap = sink.description_at[1];
  ASSERT_LT(swap, sink.skeletons.size());
  ASSERT_GT(swap, static_cast<size_t>(12 * kRate));

  // No pop: joint angles change across the swap and its cross-fade no more than the
  // motion itself turns them in the second before, plus 2 degrees, however much the two
  // subjects' solves differed.
  auto change = [&](size_t f) {
    double worst = 0.0;
    const auto& a = sink.skeletons[f - 1].rotations;
    const auto& b = sink.skeletons[f].rotations;
    for (size_t j = 0; j < a.size(); ++j) worst = std::max(worst, AngleDeg(a[j], b[j]));
    return worst;
  };
  double natural = 0.0;
  for (size_t f = swap - static_cast<size_t>(kRate); f < swap; ++f)
    natural = std::max(natural, change(f));
  double across = 0.0;
  const auto fade = static_cast<size_t>(std::lround(runner.fade_seconds() * kRate));
  ASSERT_LT(swap + fade + 2, sink.skeletons.size());
  for (size_t f = swap; f < swap + fade + 2; ++f) across = std::max(across, change(f));
  EXPECT_LT(across, natural + 2.0) << "natural motion " << natural << " deg per frame; "
                                   << runner.fade_differ_deg() << " deg apart at the swap";
  std::printf(
      "swap at %.2f s: solves %.1f deg apart, faded over %.2f s; largest change per frame "
      "%.2f deg across it, %.2f deg in the second before\n",
      static_cast<double>(swap) / kRate, runner.fade_differ_deg(), runner.fade_seconds(), across,
      natural);

  // Neither the template nor the cross-fade is taken for a wrong model.
  EXPECT_FALSE(suspect);
  // The calibrated subject fits the markers better than the scaled template did.
  const double before = model_distance[swap - 1];
  const double after = model_distance.back();
  EXPECT_LT(after, 0.6 * before) << before << " -> " << after;

  // Written, and readable as a subject, in the stream's marker order.
  const SubjectModel written = ReadSubjectModel((dir_ / "actor1.live.toml").string());
  ASSERT_EQ(written.markers->num_markers(), subject.model.markers->num_markers());
  EXPECT_EQ(protocol::MarkerSetHash(*written.markers),
            protocol::MarkerSetHash(*subject.model.markers));
  ASSERT_TRUE(written.calibration.has_value());

  // The wire carried the progress: collecting, then calibrated, one entry per joint.
  ASSERT_FALSE(sink.calibrations.empty());
  EXPECT_EQ(sink.calibrations.front().state, protocol::CalibrationState::kCollecting);
  EXPECT_EQ(sink.calibrations.back().state, protocol::CalibrationState::kCalibrated);
  EXPECT_EQ(sink.calibrations.back().joints.size(), status.joints.size());
  EXPECT_EQ(sink.calibrations.back().skeleton_hash, sink.skeletons.back().model_hash);
}

// The character a live subject drives comes through the swap as smoothly as it moved
// before: it was retargeted from the faded actor pose by the incoming subject's
// retargeter, and the new subject's bones threw a CMU actor's character hand 20 cm in one
// frame.
TEST_F(LiveCalibrationTest, TheCharacterComesThroughTheSwapWithNoPop) {
  // A character as Bandai's files are: a fixed root at the floor, the hips free below it
  // (their translation is on the wire only in the global block).
  std::vector<Joint> joints{Joint{.name = "Reference", .parent = {}, .type = JointType::kFree}};
  const Skeleton humanoid = MakeHumanoidSkeleton(1.9);
  for (Joint j : humanoid.joints()) {
    j.parent = j.parent.is_valid() ? JointIndex(j.parent.value + 1) : JointIndex(0);
    joints.push_back(j);
  }
  LiveSubject live(*this, "calibration_min_s = 12\n" + WriteCharacter(Skeleton(std::move(joints))),
                   "[output]\nglobal_transforms = true\n");
  RecordingSink sink;
  // Away from the origin, which the character is scaled about: the new subject's scale
  // moves it there.
  const Vec3 away(3.0, 0.0, 2.0);
  for (int f = 0; f < take_.num_frames; ++f) {
    ASSERT_FALSE(live.runner.Accept(Frame(live.subject, f, away), 0, sink).has_value()) << f;
    if (f % static_cast<int>(kRate) == 0) {
      live.calibration->Collect();
      (void)live.calibration->Refine();
    }
  }
  live.runner.EndOfStream(sink);
  ASSERT_EQ(live.runner.swaps(), 1);
  ASSERT_EQ(sink.characters.size(), sink.skeletons.size());
  ASSERT_EQ(sink.description_at.size(), 2u);
  const size_t swap = sink.description_at[1];

  // The character's largest joint move per frame.
  auto move = [&](size_t f) {
    const auto& a = sink.characters[f - 1].global_positions;
    const auto& b = sink.characters[f].global_positions;
    double worst = 0.0;
    for (size_t j = 0; j < a.size(); ++j) worst = std::max(worst, (b[j] - a[j]).norm());
    return worst;
  };
  ASSERT_FALSE(sink.characters[swap].global_positions.empty());
  double natural = 0.0, across = 0.0;
  for (size_t f = swap - static_cast<size_t>(kRate); f < swap; ++f)
    natural = std::max(natural, move(f));
  // Through the character's fade, and a frame after it.
  const size_t end = std::min(
      sink.characters.size(),
      swap + static_cast<size_t>(std::lround(live.runner.character_fade_seconds() * kRate)) + 2);
  for (size_t f = swap; f < end; ++f) across = std::max(across, move(f));
  EXPECT_LT(across, natural + 0.01)
      << "natural motion " << natural << " m per frame; " << live.runner.character_fade_differ_deg()
      << " deg apart at the swap";
  std::printf(
      "character: largest joint move %.1f cm per frame across the swap, %.1f cm in the "
      "second before\n",
      across * 100.0, natural * 100.0);
}

TEST_F(LiveCalibrationTest, TheDataPlaneAllocatesNothingWhileCollectingSwappingAndCrossFading) {
  // With a character: its retargeter swaps and fades too.
  LiveSubject live(*this, "calibration_min_s = 12\n" + WriteCharacter(MakeHumanoidSkeleton(1.9)));
  const SubjectConfig& subject = live.subject;
  SubjectRunner& runner = live.runner;
  LiveCalibration* calibration = live.calibration.get();
  class NullSink : public OutputSink {
   public:
    void Send(std::string_view, std::span<const uint8_t>) override {}
  } sink;
  std::vector<protocol::MarkerFrameMessage> messages;
  for (int f = 0; f < take_.num_frames; ++f) messages.push_back(Frame(subject, f));
  // The first usable frame builds the scaled template (once, like construction).
  (void)runner.Accept(messages[0], 0, sink);
  size_t allocations = 0;
  for (int f = 1; f < take_.num_frames; ++f) {
    if (f % static_cast<int>(kRate) == 0) {
      calibration->Collect();  // the calibration thread's work, not the data plane's
      (void)calibration->Refine();
    }
    testing::ScopedAllocationCounter counter;
    (void)runner.Accept(messages[static_cast<size_t>(f)], 0, sink);
    if (f % 30 == 0) runner.PublishStatus(0, sink);
    allocations += counter.count();
  }
  EXPECT_EQ(runner.swaps(), 1);
  EXPECT_EQ(allocations, 0u);
}

TEST_F(LiveCalibrationTest,
       AnEndOfStreamMidFadeKeepsFadingAndSentinelSamplesNeverReachTheCalibration) {
  LiveSubject live(*this, "calibration_min_s = 12\n");
  const SubjectConfig& subject = live.subject;
  SubjectRunner& runner = live.runner;
  LiveCalibration* calibration = live.calibration.get();
  RecordingSink sink;
  int f = 0;
  size_t ended_at = 0;
  for (; f < take_.num_frames; ++f) {
    protocol::MarkerFrameMessage m = Frame(subject, f);
    m.positions[3] = Vec3::Constant(1e30);  // an exporter's "not seen", every frame
    EXPECT_FALSE(runner.Accept(m, 0, sink).has_value());
    if (f % static_cast<int>(kRate) == 0) (void)calibration->Refine();
    // Five frames into the cross-fade, the stream ends: the lookahead is flushed.
    if (sink.descriptions.size() == 2 && runner.fading() &&
        sink.skeletons.size() == sink.description_at[1] + 5) {
      runner.EndOfStream(sink);
      ended_at = sink.skeletons.size();
      break;
    }
  }
  ASSERT_GT(ended_at, 0u) << calibration->Status().message;
  EXPECT_EQ(calibration->Status().state, LiveCalibrationState::kCalibrated);
  EXPECT_EQ(sink.skeletons.size(), static_cast<size_t>(f) + 1);  // every frame out
  // The flushed frames went on fading: no frame turns a joint more than the motion does.
  auto change = [&](size_t k) {
    double worst = 0.0;
    for (size_t j = 0; j < sink.skeletons[k].rotations.size(); ++j)
      worst = std::max(
          worst, AngleDeg(sink.skeletons[k - 1].rotations[j], sink.skeletons[k].rotations[j]));
    return worst;
  };
  const size_t swap = sink.description_at[1];
  double natural = 0.0, across = 0.0;
  for (size_t k = swap - static_cast<size_t>(kRate); k < swap; ++k)
    natural = std::max(natural, change(k));
  for (size_t k = swap; k < ended_at; ++k) across = std::max(across, change(k));
  EXPECT_LT(across, natural + 2.0) << "natural " << natural;
  // A runner built afterwards (a reload) starts from the calibrated subject.
  SubjectRunner rebuilt(subject, live.config);
  rebuilt.AttachLiveCalibration(live.calibration);
  const auto& offsets = rebuilt.description().rest_offsets;
  ASSERT_EQ(offsets.size(), sink.descriptions[1].rest_offsets.size());
  for (size_t j = 0; j < offsets.size(); ++j)  // the wire carries floats
    EXPECT_LT((offsets[j] - sink.descriptions[1].rest_offsets[j]).norm(), 1e-6) << j;
}

TEST_F(LiveCalibrationTest, AStreamWithoutMotionFailsAtTheTimeLimitAndKeepsTheScaledTemplate) {
  LiveSubject live(*this,
                   "calibration_min_s = 2\n"
                   "calibration_max_s = 4\n");
  const SubjectConfig& subject = live.subject;
  SubjectRunner& runner = live.runner;
  LiveCalibration* calibration = live.calibration.get();
  RecordingSink sink;
  const protocol::MarkerFrameMessage still = Frame(subject, 0);
  for (int f = 0; f < static_cast<int>(5 * kRate); ++f) {
    protocol::MarkerFrameMessage m = still;
    m.frame_number = static_cast<uint64_t>(f) + 1;
    EXPECT_FALSE(runner.Accept(m, 0, sink).has_value());
    if (f % static_cast<int>(kRate) == 0) (void)calibration->Refine();
  }
  (void)calibration->Refine(/*force=*/true);
  const LiveCalibrationStatus status = calibration->Status();
  EXPECT_EQ(status.state, LiveCalibrationState::kFailed);
  EXPECT_NE(status.message.find("no motion"), std::string::npos) << status.message;
  EXPECT_EQ(runner.swaps(), 0);
  EXPECT_EQ(sink.skeletons.size() + runner.pending(), static_cast<size_t>(5 * kRate));
}

// A take shorter than calibration_max_s whose joints never all became ready (the README's
// own 30 s range of motion, its toes never moved) stayed collecting for ever: nothing was
// written, and a stop threw it away. An end of stream is the last chance once
// calibration_min_s was collected; before that, collecting goes on with the next stream.
TEST_F(LiveCalibrationTest, AnEndOfStreamFinishesACalibrationThatHasItsMinimumOfMotion) {
  LiveSubject live(*this,
                   "calibration_min_s = 2\n"
                   "calibration_max_s = 600\n");
  SubjectRunner& runner = live.runner;
  LiveCalibration* calibration = live.calibration.get();
  RecordingSink sink;
  int f = 0;
  // One second, then an end: short of the minimum, it goes on collecting.
  for (; f < static_cast<int>(kRate); ++f)
    ASSERT_FALSE(runner.Accept(Frame(live.subject, f), 0, sink).has_value());
  runner.EndOfStream(sink);
  EXPECT_FALSE(calibration->Refine());
  EXPECT_EQ(calibration->Status().state, LiveCalibrationState::kCollecting);
  // Three seconds more in a second stream: refined, not every joint ready yet.
  for (; f < static_cast<int>(4 * kRate); ++f) {
    ASSERT_FALSE(runner.Accept(Frame(live.subject, f), 0, sink).has_value());
    if (f % static_cast<int>(kRate) == 0) (void)calibration->Refine();
  }
  LiveCalibrationStatus status = calibration->Status();
  ASSERT_EQ(status.state, LiveCalibrationState::kCollecting) << status.message;
  ASSERT_GT(status.refinements, 0);
  EXPECT_TRUE(std::any_of(status.joints.begin(), status.joints.end(),
                          [](const JointReadiness& j) { return !j.ready; }));
  runner.EndOfStream(sink);
  // What a stop right after the end runs (before the calibration thread's next pass).
  EXPECT_TRUE(calibration->RefineIfStreamEnded());
  EXPECT_FALSE(calibration->RefineIfStreamEnded());  // owed once
  status = calibration->Status();
  EXPECT_EQ(status.state, LiveCalibrationState::kCalibrated) << status.message;
  ASSERT_FALSE(status.written_to.empty());
  EXPECT_NO_THROW(ReadSubjectModel(status.written_to));
}

TEST_F(LiveCalibrationTest, TheTemplatesHeightComesFromOneFrameOfMarkersOnTheSameSegments) {
  const SubjectModel templ =
      TemplateSubject(FindMarkerSet("cmu-41"), std::vector<std::string>{}, 1.75, "a");
  EXPECT_EQ(templ.markers->num_markers(), 0);
  const DaemonConfig config = Config("calibrate = \"live\"\nmarker_set = \"cmu-41\"\n");
  const SubjectConfig& subject = config.subjects[0];
  for (const double height : {1.2, 1.62, 1.95}) {
    const SubjectModel actor =
        TemplateSubject(subject.live.set, subject.live.labels, height, "actor1");
    KinematicsWorkspace ws(*actor.skeleton);
    ForwardKinematics(*actor.skeleton, RestPose(*actor.skeleton), &ws);
    std::vector<Vec3> frame(static_cast<size_t>(actor.markers->num_markers()));
    EvaluateMarkers(*actor.markers, ws, frame);
    const auto estimate =
        EstimateHeight(*subject.model.skeleton, *subject.model.markers, 1.75, frame);
    ASSERT_TRUE(estimate.has_value());
    EXPECT_NEAR(*estimate, height, 0.01 * height);
  }
  // Too few markers seen: no guess.
  std::vector<Vec3> sparse(static_cast<size_t>(subject.model.markers->num_markers()),
                           Vec3::Constant(kNaN));
  sparse[0] = Vec3::Zero();
  EXPECT_FALSE(EstimateHeight(*subject.model.skeleton, *subject.model.markers, 1.75, sparse));
}

TEST_F(LiveCalibrationTest, BadLiveConfigurationsNameTheirField) {
  auto error = [&](const std::string& lines) {
    try {
      (void)Config(lines);
    } catch (const std::exception& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(error("calibrate = \"live\"\n").find("'subject[0].marker_set'"), std::string::npos);
  EXPECT_NE(error("calibrate = \"live\"\nmarker_set = \"vicon-42\"\n").find("marker_set"),
            std::string::npos);
  EXPECT_NE(
      error("calibrate = \"live\"\nmarker_set = \"cmu-41\"\nmodel = \"a.toml\"\n").find("not both"),
      std::string::npos);
  EXPECT_NE(error("calibrate = \"live\"\nmarker_set = \"cmu-41\"\nmarkers = [\"LFHD\", \"XYZ\"]\n")
                .find("XYZ"),
            std::string::npos);
  EXPECT_NE(error("model = \"a.toml\"\nmarker_set = \"cmu-41\"\n").find("only for calibrate"),
            std::string::npos);
  EXPECT_NE(error("calibrate = \"later\"\nmarker_set = \"cmu-41\"\n").find("calibrate"),
            std::string::npos);
  EXPECT_NE(error("calibrate = \"live\"\nmarker_set = \"cmu-41\"\ncalibration_min_s = 30\n"
                  "calibration_max_s = 20\n")
                .find("calibration_max_s"),
            std::string::npos);
  EXPECT_NE(error("marker_set = \"cmu-41\"\n").find("add calibrate = \"live\""), std::string::npos);
  EXPECT_NE(error("calibrate = \"live\"\nmarker_set = \"cmu-41\"\ncalibration_subsets = 0\n")
                .find("calibration_subsets"),
            std::string::npos);
  EXPECT_NE(error("model = \"a.toml\"\ncalibration_subsets = 2\n").find("only for calibrate"),
            std::string::npos);
  EXPECT_EQ(Config("calibrate = \"live\"\nmarker_set = \"cmu-41\"\ncalibration_subsets = 2\n")
                .subjects[0]
                .live.interleaved_solves,
            2);
  EXPECT_NE(error("").find("give the subject's model file, or calibrate"), std::string::npos);
  EXPECT_NE(error("calibrate = \"live\"\n").find("cmu-41"), std::string::npos);  // names the sets
  EXPECT_NE(error("calibrate = \"live\"\nmarker_set = \"cmu-41\"\nmarkers = [\"LFHD\", \"RFHD\"]\n")
                .find("at least 3"),
            std::string::npos);
  EXPECT_NE(error("calibrate = \"live\"\nmarker_set = \"cmu-41\"\n"
                  "calibration_out = \"no/such/dir/a.toml\"\n")
                .find("not a directory"),
            std::string::npos);
  // A label subset in the stream's own order is fine.
  const DaemonConfig config = Config(
      "calibrate = \"live\"\nmarker_set = \"cmu-41\"\nmarkers = [\"RFHD\", \"LFHD\", \"LBHD\"]\n");
  EXPECT_EQ(config.subjects[0].model.markers->marker(0).name, "RFHD");
}

}  // namespace
}  // namespace mocapd
