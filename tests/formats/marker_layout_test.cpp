// Tests for humanoid segment matching across naming schemes and the default layout's
// production-like properties.
#include "formats/marker_layout.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <map>

#include "sim/humanoid.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

// The humanoid with its joints renamed by a naming scheme.
Skeleton Renamed(const std::map<std::string, std::string>& names) {
  const Skeleton base = MakeHumanoidSkeleton();
  std::vector<Joint> joints(base.joints().begin(), base.joints().end());
  for (Joint& j : joints) {
    auto it = names.find(j.name);
    if (it != names.end()) j.name = it->second;
  }
  return Skeleton(joints);
}

const std::map<std::string, std::string> kBandai = {
    {"LeftShoulder", "Shoulder_L"}, {"LeftArm", "UpperArm_L"},       {"LeftForeArm", "LowerArm_L"},
    {"LeftHand", "Hand_L"},         {"RightShoulder", "Shoulder_R"}, {"RightArm", "UpperArm_R"},
    {"RightForeArm", "LowerArm_R"}, {"RightHand", "Hand_R"},         {"LeftUpLeg", "UpperLeg_L"},
    {"LeftLeg", "LowerLeg_L"},      {"LeftFoot", "Foot_L"},          {"LeftToeBase", "Toes_L"},
    {"RightUpLeg", "UpperLeg_R"},   {"RightLeg", "LowerLeg_R"},      {"RightFoot", "Foot_R"},
    {"RightToeBase", "Toes_R"}};
const std::map<std::string, std::string> kUnreal = {
    {"Hips", "pelvis"},         {"Spine", "spine_01"},
    {"Chest", "spine_02"},      {"Neck", "neck_01"},
    {"Head", "head"},           {"LeftShoulder", "clavicle_l"},
    {"LeftArm", "upperarm_l"},  {"LeftForeArm", "lowerarm_l"},
    {"LeftHand", "hand_l"},     {"RightShoulder", "clavicle_r"},
    {"RightArm", "upperarm_r"}, {"RightForeArm", "lowerarm_r"},
    {"RightHand", "hand_r"},    {"LeftUpLeg", "thigh_l"},
    {"LeftLeg", "calf_l"},      {"LeftFoot", "foot_l"},
    {"LeftToeBase", "ball_l"},  {"RightUpLeg", "thigh_r"},
    {"RightLeg", "calf_r"},     {"RightFoot", "foot_r"},
    {"RightToeBase", "ball_r"}};

std::map<std::string, std::string> Mixamo() {
  std::map<std::string, std::string> names;
  const Skeleton base = MakeHumanoidSkeleton();
  for (const Joint& j : base.joints()) names[j.name] = "mixamorig:" + j.name;
  return names;
}

TEST(MarkerLayoutTest, MatchesRolesAcrossNamingSchemes) {
  for (const auto& names : {std::map<std::string, std::string>{}, kBandai, kUnreal, Mixamo()}) {
    const Skeleton sk = Renamed(names);
    const HumanoidRoles roles = MatchHumanoidRoles(sk);
    SCOPED_TRACE(roles.Describe(sk));
    EXPECT_EQ(sk.joint(roles.joint_of_role.at("thigh_l")).name,
              names.empty() ? "LeftUpLeg" : names.at("LeftUpLeg"));
    EXPECT_EQ(sk.joint(roles.joint_of_role.at("forearm_r")).name,
              names.empty() ? "RightForeArm" : names.at("RightForeArm"));
    EXPECT_EQ(sk.joint(roles.joint_of_role.at("toe_l")).name,
              names.empty() ? "LeftToeBase" : names.at("LeftToeBase"));
    EXPECT_EQ(roles.joint_of_role.at("pelvis"), 0);
    EXPECT_EQ(roles.spine_chain.size(), 2u);
  }
}

// The humanoid with a zero-length helper joint inserted above each named joint, as CMU's
// rigs have LowerBack (at the hips) above Spine.
Skeleton WithHelpersAbove(const std::map<std::string, std::string>& helper_above) {
  const Skeleton base = MakeHumanoidSkeleton();
  std::vector<Joint> joints;
  std::vector<int> new_index;
  for (const Joint& old : base.joints()) {
    Joint j = old;
    if (j.parent.is_valid()) j.parent = JointIndex(new_index[static_cast<size_t>(j.parent.value)]);
    if (auto it = helper_above.find(j.name); it != helper_above.end()) {
      Joint helper;
      helper.name = it->second;
      helper.parent = j.parent;
      joints.push_back(helper);
      j.parent = JointIndex(static_cast<int>(joints.size()) - 1);
    }
    joints.push_back(j);
    new_index.push_back(static_cast<int>(joints.size()) - 1);
  }
  return Skeleton(joints);
}

// A joint that sits on its parent bends nothing a marker sees: as the spine, CMU's
// LowerBack bent a retargeted character's back from its pelvis and left Spine untracked.
TEST(MarkerLayoutTest, AHelperJointOnItsParentTakesNoRole) {
  const Skeleton sk = WithHelpersAbove({{"Spine", "LowerBack"}, {"Neck", "NeckBase"}});
  const HumanoidRoles roles = MatchHumanoidRoles(sk);
  SCOPED_TRACE(roles.Describe(sk));
  EXPECT_EQ(sk.joint(roles.joint_of_role.at("spine")).name, "Spine");
  EXPECT_EQ(sk.joint(roles.joint_of_role.at("chest")).name, "Chest");
  EXPECT_EQ(sk.joint(roles.joint_of_role.at("neck")).name, "Neck");
  ASSERT_EQ(roles.spine_chain.size(), 2u);
  // The default layout's markers land where they do on the rig without helpers.
  const Skeleton plain = MakeHumanoidSkeleton();
  const auto layout = DefaultMarkerLayout();
  const auto with_helpers = PlaceMarkers(sk, roles, layout, {});
  const auto without = PlaceMarkers(plain, MatchHumanoidRoles(plain), layout, {});
  ASSERT_EQ(with_helpers.size(), without.size());
  KinematicsWorkspace a(sk), b(plain);
  ForwardKinematics(sk, RestPose(sk), &a);
  ForwardKinematics(plain, RestPose(plain), &b);
  for (size_t m = 0; m < without.size(); ++m) {
    const auto& x = with_helpers[m].attachments[0];
    const auto& y = without[m].attachments[0];
    const Vec3 p =
        a.p_WJ[static_cast<size_t>(x.joint)] + a.R_WJ[static_cast<size_t>(x.joint)] * x.offset;
    const Vec3 q =
        b.p_WJ[static_cast<size_t>(y.joint)] + b.R_WJ[static_cast<size_t>(y.joint)] * y.offset;
    EXPECT_LT((p - q).norm(), 1e-9) << with_helpers[m].name;
    EXPECT_EQ(sk.joint(x.joint).name, plain.joint(y.joint).name) << with_helpers[m].name;
  }
}

// Where leaving the helpers out would leave a single spine joint, they stay: the rig
// keeps its spine role and its spine markers.
TEST(MarkerLayoutTest, AChainOfHelpersKeepsItsSpineRole) {
  const Skeleton helped = WithHelpersAbove({{"Spine", "LowerBack"}});
  std::vector<Joint> joints(helped.joints().begin(), helped.joints().end());
  joints[static_cast<size_t>(helped.FindJoint("Chest")->value)].offset = Vec3::Zero();
  const Skeleton sk(joints);
  const HumanoidRoles roles = MatchHumanoidRoles(sk);
  SCOPED_TRACE(roles.Describe(sk));
  EXPECT_EQ(roles.spine_chain.size(), 3u);
  EXPECT_EQ(roles.joint_of_role.count("spine"), 1u);
  EXPECT_EQ(roles.joint_of_role.count("chest"), 1u);
}

TEST(MarkerLayoutTest, ExplainsWhatIsMissingOnANonHumanoid) {
  std::vector<Joint> joints(2);
  joints[0].name = "base";
  joints[0].type = JointType::kFree;
  joints[1].name = "boom";
  joints[1].parent = JointIndex(0);
  try {
    MatchHumanoidRoles(Skeleton(joints));
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("head"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("thigh_l"), std::string::npos);
  }
}

TEST(MarkerLayoutTest, DefaultLayoutIsProductionLike) {
  const Skeleton sk = MakeHumanoidSkeleton();
  const HumanoidRoles roles = MatchHumanoidRoles(sk);
  const MarkerSet dut(sk, PlaceMarkers(sk, roles, DefaultMarkerLayout(), {}));
  EXPECT_GE(dut.num_markers(), 40);
  EXPECT_LE(dut.num_markers(), 60);
  // >= 3 markers carried by every major segment (blends count for both joints).
  std::map<int, int> per_joint;
  for (const MarkerDefinition& m : dut.markers())
    for (int k = 0; k < m.num_attachments; ++k)
      ++per_joint[m.attachments[static_cast<size_t>(k)].joint];
  for (const char* role :
       {"pelvis", "chest", "head", "upper_arm_l", "upper_arm_r", "forearm_l", "forearm_r", "hand_l",
        "hand_r", "thigh_l", "thigh_r", "shin_l", "shin_r", "foot_l", "foot_r"})
    EXPECT_GE(per_joint[roles.joint_of_role.at(role)], 3) << role;
  // 3-8 cm off the bone: measured from the segment's axis in the rest pose.
  KinematicsWorkspace rest(sk);
  ForwardKinematics(sk, RestPose(sk), &rest);
  const auto layout = DefaultMarkerLayout();
  for (const LayoutMarker& lm : layout)
    EXPECT_TRUE(lm.radius_m >= 0.03 && lm.radius_m <= 0.08) << lm.name;
  // Not mirror-symmetric: no left marker sits at the mirror image of its right twin.
  for (int m = 0; m < dut.num_markers(); ++m) {
    const std::string& name = dut.marker(m).name;
    if (name[0] != 'L') continue;
    const auto twin = dut.FindMarker("R" + name.substr(1));
    ASSERT_TRUE(twin.has_value()) << name;
    Vec3 mirrored = EvaluateMarker(dut.marker(m), rest);
    mirrored.x() = -mirrored.x();
    EXPECT_GT((mirrored - EvaluateMarker(dut.marker(twin->value), rest)).norm(), 0.005) << name;
  }
}

TEST(MarkerLayoutTest, UnknownSegmentIsNamed) {
  const Skeleton sk = MakeHumanoidSkeleton();
  const std::vector<LayoutMarker> layout = {{"X1", "tail", 0.5, 0, 0.05}};
  try {
    PlaceMarkers(sk, MatchHumanoidRoles(sk), layout, {});
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("marker 'X1': unknown segment 'tail'"), std::string::npos);
  }
}

TEST(MarkerLayoutTest, DocumentedExampleLayoutPlacesOnTheHumanoid) {
  const auto layout = ReadMarkerLayout(std::string(MOCAPD_CONFIG_DIR) + "/layout.example.toml");
  const Skeleton sk = MakeHumanoidSkeleton();
  const auto markers = PlaceMarkers(sk, MatchHumanoidRoles(sk), layout, {});
  ASSERT_EQ(markers.size(), 2u);
  EXPECT_EQ(markers[1].num_attachments, 2);
}

TEST(MarkerLayoutTest, ReadsLayoutFilesAndReportsBadFields) {
  const std::string dir = testing::TempDir("layout");
  {
    std::ofstream(dir + "/good.toml") << "[[marker]]\nname = \"A\"\nsegment = \"thigh_l\"\nalong = "
                                         "0.3\nangle_deg = 45\nradius_m = 0.06\n"
                                         "[[marker]]\nname = \"B\"\nsegment = \"Head\"\n";
    std::ofstream(dir + "/bad.toml")
        << "[[marker]]\nname = \"A\"\nsegment = \"thigh_l\"\nradius_m = 3.0\n";
    std::ofstream(dir + "/syntax.toml") << "[[marker]\nname = \n";
  }
  const auto layout = ReadMarkerLayout(dir + "/good.toml");
  ASSERT_EQ(layout.size(), 2u);
  EXPECT_EQ(layout[0].segment, "thigh_l");
  EXPECT_DOUBLE_EQ(layout[0].radius_m, 0.06);
  EXPECT_DOUBLE_EQ(layout[1].along, 0.5);
  try {
    ReadMarkerLayout(dir + "/bad.toml");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(
                  "bad.toml:4: field 'marker[0].radius_m': must be in [0, 0.999], got 3"),
              std::string::npos)
        << e.what();
  }
  try {
    ReadMarkerLayout(dir + "/syntax.toml");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("syntax.toml:1"), std::string::npos) << e.what();
  }
}

// A typo or a wrong type in a layout must stop the reader, never turn into a default.
TEST(MarkerLayoutTest, UnknownKeysAndWrongTypesNameFileLineAndField) {
  const std::string dir = testing::TempDir("layout_strict");
  std::ofstream(dir + "/typo.toml")
      << "[[marker]]\nname = \"A\"\nsegment = \"thigh_l\"\nradius = 0.06\n";
  std::ofstream(dir + "/type.toml")
      << "[[marker]]\nname = \"A\"\nsegment = \"thigh_l\"\n\n[[marker]]\nname = \"B\"\nsegment = "
         "\"Head\"\nalong = \"0.4\"\n";
  std::ofstream(dir + "/top.toml")
      << "version = 3\n[[marker]]\nname = \"A\"\nsegment = \"thigh_l\"\n";
  auto error_of = [&](const std::string& file) {
    try {
      ReadMarkerLayout(dir + "/" + file);
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_EQ(error_of("typo.toml"), dir + "/typo.toml:4: field 'marker[0].radius': unknown field");
  EXPECT_EQ(error_of("type.toml"),
            dir + "/type.toml:8: field 'marker[1].along': expected a number");
  EXPECT_EQ(error_of("top.toml"), dir + "/top.toml:1: field 'version': unknown field");
}

}  // namespace
}  // namespace mocapd
