// Tests for subject model files: round trip and errors naming file, line and field.
#include "formats/subject_file.hpp"

#include <gtest/gtest.h>

#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

TEST(SubjectFileTest, WriteThenReadReproducesTheModel) {
  const auto f = testing::MakeHumanoidFixture("walk", 0.1, 60.0);
  SubjectModel model;
  model.name = "actor \"one\"";
  model.skeleton = f.skeleton;
  model.markers = f.markers;
  model.fit_rms_m.assign(static_cast<size_t>(f.markers->num_markers()), 0.00025);
  const SubjectModel dut = ParseSubjectModel(FormatSubjectModel(model), "mem.toml");
  EXPECT_EQ(dut.name, model.name);
  ASSERT_EQ(dut.skeleton->num_joints(), f.skeleton->num_joints());
  ASSERT_EQ(dut.markers->num_markers(), f.markers->num_markers());
  for (int j = 0; j < f.skeleton->num_joints(); ++j) {
    EXPECT_EQ(dut.skeleton->joint(j).name, f.skeleton->joint(j).name);
    EXPECT_EQ(dut.skeleton->joint(j).type, f.skeleton->joint(j).type);
    EXPECT_LT((dut.skeleton->joint(j).offset - f.skeleton->joint(j).offset).norm(), 1e-9);
  }
  KinematicsWorkspace a(*f.skeleton), b(*dut.skeleton);
  ForwardKinematics(*f.skeleton, f.motion[3], &a);
  ForwardKinematics(*dut.skeleton, f.motion[3], &b);
  for (int m = 0; m < f.markers->num_markers(); ++m) {
    EXPECT_EQ(dut.markers->marker(m).num_attachments, f.markers->marker(m).num_attachments);
    EXPECT_LT((EvaluateMarker(dut.markers->marker(m), b) - EvaluateMarker(f.markers->marker(m), a))
                  .norm(),
              1e-8);
  }
  EXPECT_NEAR(dut.fit_rms_m[0], 0.00025, 1e-12);
}

void ExpectError(const std::string& text, const std::string& expected) {
  try {
    ParseSubjectModel(text, "s.toml");
    FAIL() << "expected: " << expected;
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
  }
}

TEST(SubjectFileTest, BadFilesNameTheLineAndField) {
  const std::string head =
      "format_version = 1\n[[joint]]\nname = \"root\"\ntype = \"free\"\noffset = [0, 0, 0]\n";
  const std::string marker = "[[marker]]\nname = \"m\"\njoint = \"root\"\noffset = [0, 0.1, 0]\n";
  ExpectError("format_version = 2\n", "field 'format_version': expected 1, found 2");
  ExpectError("format_version = 1\n", "field 'joint'");
  ExpectError(head + "[[joint]]\nname = \"a\"\nparent = \"nope\"\noffset = [0, 0, 0]\n" + marker,
              "s.toml:8: field 'joint[1].parent'");
  ExpectError(
      head + "[[joint]]\nname = \"a\"\nparent = \"root\"\ntype = \"spring\"\noffset = [0, 0, 0]\n" +
          marker,
      "joint[1].type");
  ExpectError(head + "[[joint]]\nname = \"a\"\nparent = \"root\"\noffset = [0, 0]\n" + marker,
              "joint[1].offset");
  ExpectError(head, "field 'marker'");
  ExpectError(head + "[[marker]]\nname = \"m\"\njoint = \"elbow\"\noffset = [0, 0, 0]\n",
              "s.toml:8: field 'marker[0].joint': unknown joint 'elbow'");
  ExpectError(head +
                  "[[marker]]\nname = \"m\"\njoint = \"root\"\noffset = [0, 0, 0]\nparent_weight = "
                  "0.5\nparent_offset = [0,0,0]\n",
              "has no parent");
  ExpectError(head + marker + marker, "'m' is repeated");
  // Finite but absurd: chained, such offsets overflow the solves to infinity, and a
  // quaternion this long normalised to zero.
  ExpectError(
      head + "[[joint]]\nname = \"a\"\nparent = \"root\"\noffset = [0, 1e308, 0]\n" + marker,
      "s.toml:9: field 'joint[1].offset': beyond 1000 m");
  ExpectError(head + "[[marker]]\nname = \"m\"\njoint = \"root\"\noffset = [0, 0, -2e3]\n",
              "field 'marker[0].offset': beyond 1000 m");
  ExpectError(head +
                  "[[joint]]\nname = \"a\"\nparent = \"root\"\noffset = [0, 1, 0]\n"
                  "rest_rotation = [1e200, 1e200, 0, 0]\n" +
                  marker,
              "field 'joint[1].rest_rotation': must be non-zero and finite");
  // A hinge about a zero axis, or one whose length overflows, has no direction to turn about.
  const std::string hinge =
      "[[joint]]\nname = \"a\"\nparent = \"root\"\ntype = \"hinge\"\noffset = [0, 1, 0]\n";
  ExpectError(head + hinge + "hinge_axis = [0, 0, 0]\n" + marker,
              "s.toml:11: field 'joint[1].hinge_axis': must be non-zero and finite");
  ExpectError(head + hinge + "hinge_axis = [1e200, 1e200, 0]\n" + marker,
              "s.toml:11: field 'joint[1].hinge_axis': must be non-zero and finite");
  ExpectError(head + hinge + "hinge_axis = [nan, 0, 1]\n" + marker,
              "s.toml:11: field 'joint[1].hinge_axis'");
  ExpectError("format_version = 1\n[[joint]\n", "s.toml:2");
}

// A typo in a subject file must be an error, as it is in the daemon's config: a
// misspelt field silently left at its default would solve the wrong skeleton.
TEST(SubjectFileTest, UnknownKeysAndWrongTypesNameFileLineAndField) {
  const std::string head =
      "format_version = 1\n[[joint]]\nname = \"root\"\ntype = \"free\"\noffset = [0, 0, 0]\n";
  const std::string marker = "[[marker]]\nname = \"m\"\njoint = \"root\"\noffset = [0, 0.1, 0]\n";
  ExpectError(head + "ofset = [0, 1, 0]\n" + marker,
              "s.toml:6: field 'joint[0].ofset': unknown field");
  ExpectError(head + marker + "fit_rms_mm = \"0.2\"\n",
              "s.toml:10: field 'marker[0].fit_rms_mm': expected a number");
  ExpectError(head + marker + "parent_weight = 0.5\n",
              "s.toml:10: field 'marker[0].parent_weight': the root joint");
  ExpectError(
      "format_version = 1\n[subject]\nname = \"a\"\nunits = \"cm\"\n" + head.substr(19) + marker,
      "s.toml:4: field 'subject.units': unknown field");
  ExpectError(head + marker + "[extra]\nx = 1\n", "s.toml:10: field 'extra': unknown field");
  ExpectError(
      head + "[[joint]]\nname = \"a\"\nparent = \"root\"\noffset = [0, \"1\", 0]\n" + marker,
      "s.toml:9: field 'joint[1].offset': expected finite numbers");
}

TEST(SubjectFileTest, DocumentedExampleParses) {
  const SubjectModel dut =
      ReadSubjectModel(std::string(MOCAPD_CONFIG_DIR) + "/subject.example.toml");
  EXPECT_EQ(dut.name, "example");
  EXPECT_EQ(dut.skeleton->num_joints(), 3);
  ASSERT_EQ(dut.markers->num_markers(), 3);
  EXPECT_EQ(dut.markers->marker(2).num_attachments, 2);
  EXPECT_NEAR(dut.fit_rms_m[0], 0.21e-3, 1e-12);
}

TEST(SubjectFileTest, MissingFileIsAClearError) {
  EXPECT_THROW(ReadSubjectModel("/nonexistent/s.toml"), std::runtime_error);
}

}  // namespace
}  // namespace mocapd
