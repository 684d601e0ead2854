// Tests for the strict TOML reader: typed fields, bounds, and unknown keys, every error
// naming the file, the line and the dotted field.
#include "formats/toml_reader.hpp"

#include <gtest/gtest.h>

namespace mocapd {
namespace {

std::string ErrorOf(const std::function<void()>& read) {
  try {
    read();
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "no error";
}

TEST(TomlReaderTest, ReadsTypedFieldsWithDefaults) {
  const toml::table doc = ParseToml(
      "a = 1.5\nn = 3\nflag = true\nname = \"x\"\nv = [1, 2, 3]\n[sub]\nk = \"v\"\n", "t.toml");
  TomlTable dut(doc, "", "t.toml");
  EXPECT_DOUBLE_EQ(dut.Number("a", 0, 0, 10), 1.5);
  EXPECT_DOUBLE_EQ(dut.Number("n", 0, 0, 10), 3.0);  // an integer is a number
  EXPECT_DOUBLE_EQ(dut.Number("absent", 7.0, 0, 10), 7.0);
  EXPECT_EQ(dut.Integer("n", 0, 0, 10), 3);
  EXPECT_TRUE(dut.Bool("flag", false));
  EXPECT_EQ(dut.String("name", ""), "x");
  EXPECT_EQ(dut.Vector3("v", true), Vec3(1, 2, 3));
  EXPECT_EQ(dut.StringMap("sub").at("k"), "v");
  EXPECT_NO_THROW(dut.RejectUnknown());
}

TEST(TomlReaderTest, WrongTypesAndRangesNameLineAndField) {
  const toml::table doc = ParseToml(
      "[pipeline]\nwindow = \"120\"\nlookahead = 2.5\nrate = 5000\nok = \"yes\"\n", "c.toml");
  TomlTable top(doc, "", "c.toml");
  TomlTable p = top.Table("pipeline");
  EXPECT_EQ(ErrorOf([&] { p.Number("window", 0, 0, 1e6); }),
            "c.toml:2: field 'pipeline.window': expected a number");
  EXPECT_EQ(ErrorOf([&] { p.Integer("lookahead", 0, 0, 100); }),
            "c.toml:3: field 'pipeline.lookahead': expected an integer");
  EXPECT_EQ(ErrorOf([&] { p.Number("rate", 0, 1, 2000); }),
            "c.toml:4: field 'pipeline.rate': must be in [1, 2000], got 5000");
  EXPECT_EQ(ErrorOf([&] { p.Bool("ok", false); }),
            "c.toml:5: field 'pipeline.ok': expected true or false");
  EXPECT_EQ(ErrorOf([&] {
              p.Choice("ok", "a", {"a", "b"});
            }),
            "c.toml:5: field 'pipeline.ok': expected a | b, got 'yes'");
}

TEST(TomlReaderTest, UnknownKeysAreErrorsInNestedTablesAndArraysOfTables) {
  const toml::table doc =
      ParseToml("[[item]]\nname = \"a\"\n[[item]]\nname = \"b\"\nnmae = \"c\"\n", "l.toml");
  TomlTable top(doc, "", "l.toml");
  std::vector<TomlTable> items = top.Tables("item", true);
  ASSERT_EQ(items.size(), 2u);
  for (TomlTable& item : items) (void)item.String("name", "", true);
  EXPECT_NO_THROW(items[0].RejectUnknown());
  EXPECT_EQ(ErrorOf([&] { items[1].RejectUnknown(); }),
            "l.toml:5: field 'item[1].nmae': unknown field");
  EXPECT_NO_THROW(top.RejectUnknown());
  EXPECT_EQ(ErrorOf([&] { (void)top.Tables("missing", true); }),
            "l.toml:1: field 'missing': missing: expected one or more [[missing]] tables");
}

// A required key spelt wrong ("modle" for "model") was reported as missing, with neither
// the typo nor its line: the unknown-key check that would name it comes after.
TEST(TomlReaderTest, AMissingRequiredKeyNamesTheTypoBesideIt) {
  const toml::table doc =
      ParseToml("[[subject]]\nname = \"a\"\n\nmodle = \"x.toml\"\n", "typo.toml");
  TomlTable top(doc, "", "typo.toml");
  std::vector<TomlTable> subjects = top.Tables("subject", true);
  EXPECT_EQ(ErrorOf([&] { (void)subjects[0].String("model", "", true); }),
            "typo.toml:4: field 'subject[0].model': missing (is 'modle' on line 4 meant for it?)");
  // A key unlike any present is missing, as before.
  EXPECT_EQ(ErrorOf([&] { (void)subjects[0].String("rate_hz_x", "", true); }),
            "typo.toml:1: field 'subject[0].rate_hz_x': missing");
}

TEST(TomlReaderTest, SyntaxErrorsAndMissingFilesNameTheFile) {
  EXPECT_EQ(ErrorOf([] { (void)ParseToml("a = 1\nb = \n", "s.toml"); }).rfind("s.toml:2: ", 0), 0u);
  EXPECT_EQ(ErrorOf([] { (void)ReadTomlFile("/nonexistent/x.toml"); }),
            "/nonexistent/x.toml: cannot open for reading");
}

// A BVH or a C3D given where a subject or config goes says so; the parser alone said
// "expected '=', saw '\n'".
TEST(TomlReaderTest, AFileThatIsNotTomlSaysWhatItLooksLike) {
  EXPECT_NE(ErrorOf([] {
              (void)ParseToml("HIERARCHY\nROOT Hips\n{\n", "actor.bvh");
            }).find("(the file is a BVH, not TOML"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              (void)ParseToml(std::string("\x02\x50\0\0", 4), "take.c3d");
            }).find("(the file is binary data, not TOML text"),
            std::string::npos);
}

}  // namespace
}  // namespace mocapd
