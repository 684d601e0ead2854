// Tests for the BVH reader and writer: channel orders, joint typing, end sites, units,
// round trips and clear errors for malformed files.
#include "formats/bvh.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "formats/marker_layout.hpp"
#include "sim/humanoid.hpp"

namespace mocapd {
namespace {

const std::string kTinyPath = std::string(MOCAPD_TEST_DATA_DIR) + "/tiny_static_root.bvh";

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

Quat Euler(std::initializer_list<std::pair<int, double>> axes_deg) {
  Quat q = Quat::Identity();
  for (const auto& [axis, deg] : axes_deg)
    q = q * Quat(Eigen::AngleAxisd(deg * M_PI / 180.0, Vec3::Unit(axis)));
  return q;
}

std::vector<std::vector<Vec3>> GlobalPositions(const BvhTake& take) {
  std::vector<std::vector<Vec3>> out;
  KinematicsWorkspace ws(take.skeleton);
  for (const Pose& pose : take.frames) {
    ForwardKinematics(take.skeleton, pose, &ws);
    out.push_back(ws.p_WJ);
  }
  return out;
}

TEST(BvhTest, TypesJointsByHowTheirChannelsMove) {
  const BvhTake dut = ReadBvh(kTinyPath);
  ASSERT_EQ(dut.skeleton.num_joints(), 5);
  EXPECT_EQ(dut.skeleton.joint(0).type, JointType::kFixed);  // static root
  EXPECT_EQ(dut.skeleton.joint(1).type, JointType::kFree);   // moving translation
  EXPECT_EQ(dut.skeleton.joint(2).type, JointType::kBall);   // 6 channels, constant translation
  EXPECT_EQ(dut.skeleton.joint(3).type, JointType::kBall);
  EXPECT_EQ(dut.units, "cm");
  EXPECT_DOUBLE_EQ(dut.metres_per_unit, 0.01);
  EXPECT_EQ(dut.num_frames(), 3);
  EXPECT_NEAR(dut.rate_hz(), 30.0, 1e-3);
  ASSERT_EQ(dut.end_sites.size(), 1u);
  EXPECT_EQ(dut.end_sites[0].parent, 4);
  EXPECT_LT((dut.end_sites[0].offset - Vec3(0, 0, 0.08)).norm(), 1e-12);
}

TEST(BvhTest, AppliesRotationChannelsInFileOrder) {
  const BvhTake dut = ReadBvh(kTinyPath);
  EXPECT_TRUE(dut.frames[0].rotation[3].isApprox(Euler({{0, 40}, {1, -30}, {2, 20}}), 1e-12));
  EXPECT_TRUE(dut.frames[0].rotation[4].isApprox(Euler({{1, 10}, {2, 80}, {0, -170}}), 1e-12));
  EXPECT_TRUE(dut.frames[1].rotation[1].isApprox(Euler({{2, -10}, {0, 25}, {1, 35}}), 1e-12));
  // Position channels replace the OFFSET; units converted to metres.
  EXPECT_LT((dut.frames[1].translation[1] - Vec3(0.02, 0.92, -0.03)).norm(), 1e-12);
  EXPECT_LT((dut.skeleton.joint(2).offset - Vec3(0.15, 0, 0)).norm(), 1e-12);
}

TEST(BvhTest, WriteThenReadReproducesGlobalPositions) {
  const BvhTake original = ReadBvh(kTinyPath);
  const BvhTake again = ParseBvh(FormatBvh(original), "round-trip");
  EXPECT_EQ(again.channels, original.channels);
  EXPECT_EQ(again.units, original.units);
  const auto a = GlobalPositions(original), b = GlobalPositions(again);
  for (size_t f = 0; f < a.size(); ++f)
    for (size_t j = 0; j < a[f].size(); ++j)
      EXPECT_LT((a[f][j] - b[f][j]).norm() / original.metres_per_unit, 1e-6);
}

TEST(BvhTest, HumanoidMotionRoundTripsThroughBvh) {
  Skeleton sk = MakeHumanoidSkeleton();
  auto frames = MakeHumanoidMotion(sk, HumanoidMotion::kMixed, 3.0, 30.0);
  const BvhTake take = MakeBvhTake(std::move(sk), std::move(frames), 1.0 / 30.0, "cm");
  const BvhTake again = ParseBvh(FormatBvh(take), "humanoid");
  EXPECT_EQ(again.skeleton.joint(0).type, JointType::kFree);
  const auto a = GlobalPositions(take), b = GlobalPositions(again);
  for (size_t f = 0; f < a.size(); ++f)
    for (size_t j = 0; j < a[f].size(); ++j)
      ASSERT_LT((a[f][j] - b[f][j]).norm(), 1e-6) << f << " " << j;
}

// A skeleton stored parents-first but not depth-first (a subject calibrated from markers
// lists both legs before the arms): the MOTION columns follow the hierarchy as written.
// They followed the stored order, so a calibrated subject's solved BVH gave its left
// leg's angles to the right arm (hands 82 cm off).
TEST(BvhTest, ASkeletonStoredBreadthFirstRoundTripsThroughBvh) {
  const Skeleton depth_first = MakeHumanoidSkeleton();
  const auto motion = MakeHumanoidMotion(depth_first, HumanoidMotion::kMixed, 2.0, 30.0);
  std::vector<int> depth(static_cast<size_t>(depth_first.num_joints()), 0), order;
  for (int j = 1; j < depth_first.num_joints(); ++j)
    depth[static_cast<size_t>(j)] =
        depth[static_cast<size_t>(depth_first.joint(j).parent.value)] + 1;
  for (int d = 0; d <= *std::max_element(depth.begin(), depth.end()); ++d)
    for (int j = 0; j < depth_first.num_joints(); ++j)
      if (depth[static_cast<size_t>(j)] == d) order.push_back(j);
  std::vector<int> new_index(order.size());
  for (size_t k = 0; k < order.size(); ++k)
    new_index[static_cast<size_t>(order[k])] = static_cast<int>(k);
  std::vector<Joint> joints;
  for (const int j : order) {
    Joint joint = depth_first.joint(j);
    if (joint.parent.is_valid())
      joint.parent = JointIndex(new_index[static_cast<size_t>(joint.parent.value)]);
    joints.push_back(joint);
  }
  Skeleton breadth_first(std::move(joints));
  ASSERT_NE(breadth_first.joint(5).name, depth_first.joint(5).name);  // really reordered
  std::vector<Pose> frames;
  for (const Pose& p : motion) {
    Pose q;
    for (const int j : order) {
      q.rotation.push_back(p.rotation[static_cast<size_t>(j)]);
      q.translation.push_back(p.translation[static_cast<size_t>(j)]);
    }
    frames.push_back(q);
  }
  const BvhTake take = MakeBvhTake(std::move(breadth_first), std::move(frames), 1.0 / 30.0, "cm");
  const BvhTake again = ParseBvh(FormatBvh(take), "breadth-first");
  const auto a = GlobalPositions(take), b = GlobalPositions(again);
  for (int j = 0; j < take.skeleton.num_joints(); ++j) {
    const int k = again.skeleton.FindJoint(take.skeleton.joint(j).name)->value;
    for (size_t f = 0; f < a.size(); ++f)
      ASSERT_LT((a[f][static_cast<size_t>(j)] - b[f][static_cast<size_t>(k)]).norm(), 1e-6)
          << take.skeleton.joint(j).name << " frame " << f;
  }
}

// Every BVH writer closes a leaf joint with an End Site, and tools draw the leaf's bone
// to it; ours wrote a leaf's block with none. The End Sites continue each end segment by
// the nominal length marker placement assumes without one, so read back they place every
// marker where the skeleton alone did.
TEST(BvhTest, EveryLeafJointIsClosedByAnEndSiteThatKeepsMarkerPlacement) {
  const Skeleton sk = MakeHumanoidSkeleton();
  const BvhTake again =
      ParseBvh(FormatBvh(MakeBvhTake(sk, {RestPose(sk)}, 1.0 / 30.0, "cm")), "written.bvh");
  std::vector<int> children(static_cast<size_t>(sk.num_joints()), 0);
  for (const Joint& j : sk.joints())
    if (j.parent.is_valid()) ++children[static_cast<size_t>(j.parent.value)];
  int leaves = 0;
  for (int j = 0; j < sk.num_joints(); ++j) {
    if (children[static_cast<size_t>(j)] > 0) continue;
    ++leaves;
    const auto site = std::find_if(again.end_sites.begin(), again.end_sites.end(),
                                   [&](const BvhEndSite& e) { return e.parent == j; });
    ASSERT_NE(site, again.end_sites.end()) << sk.joint(j).name << " has no End Site";
    EXPECT_GT(site->offset.norm(), 0.02) << sk.joint(j).name;
    EXPECT_LT(site->offset.norm(), 0.2) << sk.joint(j).name;
  }
  EXPECT_EQ(static_cast<int>(again.end_sites.size()), leaves);
  const HumanoidRoles roles = MatchHumanoidRoles(sk);
  const auto bare = PlaceMarkers(sk, roles, DefaultMarkerLayout(), {});
  const auto with_sites = PlaceMarkers(again.skeleton, MatchHumanoidRoles(again.skeleton),
                                       DefaultMarkerLayout(), again.end_sites);
  ASSERT_EQ(bare.size(), with_sites.size());
  for (size_t m = 0; m < bare.size(); ++m)
    for (int a = 0; a < bare[m].num_attachments; ++a)
      EXPECT_LT((bare[m].attachments[static_cast<size_t>(a)].offset -
                 with_sites[m].attachments[static_cast<size_t>(a)].offset)
                    .norm(),
                1e-6)
          << bare[m].name;
  // A skeleton that is no humanoid still gets its End Sites.
  const Skeleton stick({Joint{.name = "root", .parent = {}, .type = JointType::kFree},
                        Joint{.name = "tip", .parent = JointIndex(0), .offset = Vec3(0, 0.3, 0)}});
  EXPECT_EQ(ParseBvh(FormatBvh(MakeBvhTake(stick, {RestPose(stick)}, 1.0 / 30.0)), "stick.bvh")
                .end_sites.size(),
            1u);
}

// Exporters often write the take's start position into the hips' OFFSET (here 4 m away
// under a static root): the unit guess must come from the bones, not from where the
// actor stands, or a cm file is read as mm and every solve is off by metres.
TEST(BvhTest, UnitsAreGuessedFromBonesNotFromAFarRootOffset) {
  Skeleton sk = MakeHumanoidSkeleton();
  const BvhTake take = MakeBvhTake(sk, {RestPose(sk)}, 1.0 / 30.0, "cm");
  std::string text = FormatBvh(take);
  // Put the humanoid under a static root, its hips 4 m away.
  const size_t root = text.find("ROOT ");
  const size_t brace = text.find('{', root);
  const size_t offset = text.find("OFFSET", brace);
  const size_t line_end = text.find('\n', offset);
  text = text.substr(0, offset) + "OFFSET -400.0 93.0 250.0" + text.substr(line_end);
  text.replace(
      root, 5,
      "ROOT joint_Root\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  JOINT ");
  const size_t motion = text.find("MOTION");
  text.insert(motion, "}\n");
  const size_t frame_line = text.find('\n', text.find("Frame Time:"));
  text.insert(frame_line + 1, "0 0 0 ");
  const BvhTake dut = ParseBvh(text, "far_root.bvh");
  EXPECT_EQ(dut.units, "cm");
  ASSERT_EQ(dut.skeleton.num_joints(), sk.num_joints() + 1);
  // The thigh bone comes out in metres as the humanoid has it.
  const int knee = dut.skeleton.FindJoint("LeftLeg")->value;
  EXPECT_NEAR(dut.skeleton.joint(knee).offset.norm(),
              sk.joint(sk.FindJoint("LeftLeg")->value).offset.norm(), 1e-6);
}

// A character file is usually one frame (its T-pose): nothing moves, so the channel list
// alone says what each joint may do, and a root with position channels may translate.
TEST(BvhTest, AOneFrameFileTypesTheRootByItsChannels) {
  Skeleton sk = MakeHumanoidSkeleton();
  const BvhTake one_frame =
      ParseBvh(FormatBvh(MakeBvhTake(sk, {RestPose(sk)}, 1.0 / 30.0, "cm")), "character.bvh");
  EXPECT_EQ(one_frame.skeleton.joint(0).type, JointType::kFree);
  EXPECT_EQ(one_frame.skeleton.joint(1).type, JointType::kBall);
  // The tiny take's static root stays fixed: a joint below it carries the motion.
  EXPECT_EQ(ReadBvh(kTinyPath).skeleton.joint(0).type, JointType::kFixed);
}

// Blender and MotionBuilder can key every joint's translation, rebuilt from float matrices
// so it wobbles in the last printed digit. Read as motion, every bone was stretchable and a
// character retargeted through it grew arms two or three times their length. A bone that
// truly changes length (1 mm here) stays free; the fixed one takes its mid value.
TEST(BvhTest, TranslationsThatWobbleInTheLastDigitAreAFixedBone) {
  const auto file = [](const char* second_frame_forearm) {
    return std::string(
               "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n"
               "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
               "  JOINT Arm\n  {\n    OFFSET 0 10.5 0\n"
               "    CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
               "    JOINT Forearm\n    {\n      OFFSET 0 25.6 0\n"
               "      CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
               "      End Site\n      {\n        OFFSET 0 20 0\n      }\n    }\n  }\n}\n"
               "MOTION\nFrames: 3\nFrame Time: 0.008333\n"
               "0 90 0 0 0 0 -0.000001 10.500000 0.000001 0 10 0 0 25.600000 0 0 20 0\n"
               "1 90 0 0 5 0 0.000001 10.499999 0.000000 0 15 0 ") +
           second_frame_forearm + " 0 25 0\n" +
           "2 90 0 0 9 0 0.000000 10.500001 -0.000001 0 20 0 0 25.600001 0 0 30 0\n";
  };
  const BvhTake wobbling = ParseBvh(file("0.000001 25.599999 0"), "blender.bvh");
  EXPECT_EQ(wobbling.skeleton.joint(0).type, JointType::kFree);
  EXPECT_EQ(wobbling.skeleton.joint(1).type, JointType::kBall);
  EXPECT_EQ(wobbling.skeleton.joint(2).type, JointType::kBall);
  EXPECT_NEAR(wobbling.skeleton.joint(2).offset.y(), 0.256, 1e-8);
  const BvhTake stretching = ParseBvh(file("0 25.7 0"), "stretch.bvh");
  EXPECT_EQ(stretching.skeleton.joint(1).type, JointType::kBall);
  EXPECT_EQ(stretching.skeleton.joint(2).type, JointType::kFree);
}

// Some Windows editors and exporters start a text file with a UTF-8 byte order mark; the
// file was refused as "binary data".
TEST(BvhTest, AByteOrderMarkIsNotPartOfTheFile) {
  const std::string text = ReadText(kTinyPath);
  const BvhTake plain = ParseBvh(text, "plain.bvh");
  const BvhTake marked = ParseBvh("\xEF\xBB\xBF" + text, "marked.bvh");
  EXPECT_EQ(marked.skeleton.num_joints(), plain.skeleton.num_joints());
  EXPECT_EQ(marked.frames.size(), plain.frames.size());
}

TEST(BvhTest, KeywordsAreReadInAnyCase) {
  std::string text = ReadText(kTinyPath);
  const BvhTake plain = ParseBvh(text, "plain.bvh");
  for (const auto& [from, to] :
       std::vector<std::pair<std::string, std::string>>{{"HIERARCHY", "Hierarchy"},
                                                        {"ROOT", "root"},
                                                        {"CHANNELS", "channels"},
                                                        {"JOINT", "Joint"},
                                                        {"End Site", "end site"},
                                                        {"OFFSET", "Offset"},
                                                        {"MOTION", "motion"},
                                                        {"Frames:", "FRAMES:"},
                                                        {"Frame Time:", "frame time:"}}) {
    for (size_t at = text.find(from); at != std::string::npos; at = text.find(from, at))
      text.replace(at, from.size(), to);
  }
  const BvhTake mixed = ParseBvh(text, "mixed.bvh");
  ASSERT_EQ(mixed.skeleton.num_joints(), plain.skeleton.num_joints());
  ASSERT_EQ(mixed.frames.size(), plain.frames.size());
  EXPECT_EQ(mixed.skeleton.joint(4).name, "Hand");
  EXPECT_LT((mixed.frames[2].translation[1] - plain.frames[2].translation[1]).norm(), 1e-12);
  EXPECT_TRUE(mixed.frames[2].rotation[4].isApprox(plain.frames[2].rotation[4]));
}

TEST(BvhTest, AFrameTimeRoundedToItsDigitsMeansTheRateItWasPrintedFrom) {
  const std::string text = ReadText(kTinyPath);
  const auto rate_for = [&](const std::string& frame_time) {
    std::string edited = text;
    edited.replace(edited.find("0.0333333"), 9, frame_time);
    return ParseBvh(edited, "rate.bvh").rate_hz();
  };
  EXPECT_NEAR(rate_for("0.0333333"), 30.0, 1e-9);
  EXPECT_NEAR(rate_for("0.008333"), 120.0, 1e-9);
  EXPECT_NEAR(rate_for("0.00834167"), 120000.0 / 1001.0, 1e-9);
  EXPECT_NEAR(rate_for("0.008342"), 120000.0 / 1001.0, 1e-9);
  // Kept as written: too few digits to say, or no whole or NTSC rate prints this way.
  EXPECT_NEAR(rate_for("0.03"), 1.0 / 0.03, 1e-9);
  EXPECT_NEAR(rate_for("0.007100"), 1.0 / 0.0071, 1e-9);
  // In scientific notation likewise, by the mantissa's digits: taken as written,
  // 8.333333e-03 lost a frame of 480 when resampled to 120 Hz.
  EXPECT_NEAR(rate_for("8.333333e-03"), 120.0, 1e-9);
  EXPECT_NEAR(rate_for("1.666667E-02"), 60.0, 1e-9);
  EXPECT_NEAR(rate_for("3.33333e-2"), 30.0, 1e-9);
  EXPECT_NEAR(rate_for("3.0e-2"), 1.0 / 0.03, 1e-9);
  EXPECT_NEAR(rate_for("7.100e-3"), 1.0 / 0.0071, 1e-9);
}

// "Frames:2" and "Time:0.0333333", keyword and number with no space between, as some
// writers print them; a joint name with a colon is still one name.
TEST(BvhTest, AFrameCountOrTimeWrittenAgainstItsKeywordIsRead) {
  std::string text = ReadText(kTinyPath);
  const BvhTake plain = ParseBvh(text, "plain.bvh");
  text.replace(text.find("Frame Time: "), 12, "Frame Time:");
  text.replace(text.find("Frames: "), 8, "Frames:");
  text.replace(text.find("ROOT "), 5, "ROOT Frames:");
  const BvhTake joined = ParseBvh(text, "joined.bvh");
  EXPECT_EQ(joined.frames.size(), plain.frames.size());
  EXPECT_DOUBLE_EQ(joined.frame_time_s, plain.frame_time_s);
  EXPECT_EQ(joined.skeleton.joint(0).name, "Frames:" + plain.skeleton.joint(0).name);
}

TEST(BvhTest, UnitsCanBeForced) {
  BvhReadOptions options;
  options.units = "mm";
  const BvhTake dut = ReadBvh(kTinyPath, options);
  EXPECT_LT((dut.skeleton.joint(2).offset - Vec3(0.015, 0, 0)).norm(), 1e-12);
  options.units = "furlongs";
  EXPECT_THROW(ReadBvh(kTinyPath, options), BvhError);
}

void ExpectError(const std::string& text, const std::string& expected) {
  try {
    ParseBvh(text, "bad.bvh");
    FAIL() << "expected an error containing: " << expected;
  } catch (const BvhError& e) {
    EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
  }
}

TEST(BvhTest, MalformedFilesGetErrorsNamingTheLine) {
  const std::string good = ReadText(kTinyPath);
  ExpectError("", "bad.bvh:1: unexpected end of file, expected HIERARCHY");
  ExpectError("HIERARCHIE", "bad.bvh:1: expected 'HIERARCHY', found 'HIERARCHIE'");
  ExpectError("HIERARCHY\nROOT a\n{\n  OFFSET 0 0\n", "bad.bvh:");
  ExpectError("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Qrotation Zrotation\n}\n",
              "bad.bvh:5: unknown channel");
  ExpectError(
      "HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 2 Xrotation Yrotation\n}\nMOTION\nFrames: "
      "0\nFrame Time: 0.1\n",
      "unsupported channel set");
  ExpectError("HIERARCHY\nROOT a\n{\nOFFSET 0 x 0\n}\n", "bad.bvh:4: expected a number");
  std::string truncated = good.substr(0, good.rfind("20 89"));
  ExpectError(truncated, "frame 3 of 3 is truncated");
  // A frame count far beyond the data is the same truncation, found without reserving
  // memory for the count (it reserved 19 GB and failed with a bare std::bad_alloc).
  std::string overcounted = good;
  overcounted.replace(overcounted.find("Frames: 3"), 9, "Frames: 100000000");
  ExpectError(overcounted, "bad.bvh:36: frame 4 of 100000000 is truncated");
  // A row a value short or long is named by its frame and line, not only the file's end.
  std::string short_row = good;
  short_row.erase(short_row.find(" 10 80 -170"), 4);
  ExpectError(short_row,
              "bad.bvh:35: frame 2 of 3 does not start a line; frame 1 (line 34) has 23 on its "
              "line");
  std::string long_row = good;
  long_row.insert(long_row.find(" 15 85 175"), " 9");
  ExpectError(long_row,
              "bad.bvh:35: frame 3 of 3 does not start a line; frame 2 (line 35) has more "
              "than 24 on its line");
  // A row short and the next one long add up to the frames the header counts: read on,
  // frame 2 took frame 3's first value and frame 3 the extra one (markers 8 m off).
  std::string short_then_long = short_row;
  short_then_long.insert(short_then_long.find(" 15 85 175"), " 9");
  ExpectError(short_then_long,
              "bad.bvh:35: frame 2 of 3 does not start a line; frame 1 (line 34) has 23 on its "
              "line");
  // A frame wrapped over two lines, each frame starting its own, is the same take.
  std::string wrapped = good;
  for (size_t at = wrapped.find("MOTION"); (at = wrapped.find(" 10 80", at)) != std::string::npos;
       at += 7)
    wrapped[at] = '\n';
  EXPECT_NO_THROW(ParseBvh(wrapped, "wrapped.bvh")) << wrapped;
  // An error on the last token of a line names that line, not the next token's.
  std::string zero_time = good;
  zero_time.replace(zero_time.find("0.0333333"), 9, "0");
  ExpectError(zero_time, "bad.bvh:33: frame time must be > 0");
  // A rate the cleanup cannot run at (1e30 read as 1e-30 Hz, one frame of 146 resampled).
  std::string huge_time = good;
  huge_time.replace(huge_time.find("0.0333333"), 9, "1e30");
  ExpectError(huge_time,
              "bad.bvh:33: frame time 1e+30 s is a rate of 1e-30 Hz, outside 1 to 10000 Hz");
  std::string tiny_time = good;
  tiny_time.replace(tiny_time.find("0.0333333"), 9, "1e-9");
  ExpectError(tiny_time, "bad.bvh:33: frame time 1e-09 s is a rate of 1e+09 Hz");
  // One pose (a character's rest pose) has no rate: its frame time is not judged.
  EXPECT_NO_THROW(
      ParseBvh("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation "
               "Yrotation\nEnd Site\n{\nOFFSET 0 1 0\n}\n}\nMOTION\nFrames: 1\nFrame "
               "Time: 1e30\n0 0 0\n",
               "rest.bvh"));
  ExpectError(good + " 7", "unexpected data after frame 3");
  std::string unclosed = good.substr(0, good.find("MOTION"));
  unclosed.erase(unclosed.rfind('}'));
  ExpectError(unclosed + "MOTION\nFrames: 3\n", "bad.bvh:30: expected JOINT, End Site or '}'");
  // A C3D given as a BVH: named as binary, its bytes never printed.
  ExpectError(std::string("\x02\x50\x3b\x00\x01", 5) + "\x90\xff junk",
              "bad.bvh:1: expected 'HIERARCHY', found binary data (is this a BVH file?)");
}

TEST(BvhTest, MissingFileIsAClearError) {
  try {
    ReadBvh("/nonexistent/take.bvh");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/take.bvh: cannot open"), std::string::npos);
  }
}

}  // namespace
}  // namespace mocapd
