// Tests for the daemon config: the shipped default parses, the demo subject file is the
// built-in humanoid, and every kind of mistake is an error naming file, line and field.
#include "runtime/daemon_config.hpp"

#include <gtest/gtest.h>

#include <array>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <sstream>
#include <vector>

#include "formats/bvh.hpp"
#include "formats/toml_reader.hpp"
#include "sim/humanoid.hpp"
#include "sim/humanoid_subject.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// Parses text as if it were config.toml in config/ (so model paths resolve to the
// shipped demo subject) and returns the error message, or "" if it parsed.
std::string ErrorOf(const std::string& text) {
  try {
    ParseDaemonConfig(text, "test.toml", MOCAPD_CONFIG_DIR);
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

const char* kMinimal = R"(format_version = 1
[[subject]]
name = "actor1"
model = "demo_subject.toml"
)";

TEST(DaemonConfigTest, ShippedDefaultParsesWithDocumentedValues) {
  const DaemonConfig c = LoadDaemonConfig(std::string(MOCAPD_CONFIG_DIR) + "/mocapd.toml");
  EXPECT_EQ(c.input_endpoint, "tcp://127.0.0.1:5555");
  EXPECT_EQ(c.input_pattern, InputPattern::kSub);
  EXPECT_EQ(c.output_endpoint, "tcp://127.0.0.1:5556");
  EXPECT_EQ(c.http_port, 8480);
  ASSERT_EQ(c.subjects.size(), 1u);
  EXPECT_EQ(c.subjects[0].name, "actor1");
  EXPECT_EQ(c.subjects[0].cleanup.lookahead, 12);
  EXPECT_EQ(c.subjects[0].model.markers->num_markers(), 59);
  // The values written in the file are the defaults: a minimal config means the same.
  const DaemonConfig minimal = ParseDaemonConfig(kMinimal, "minimal.toml", MOCAPD_CONFIG_DIR);
  EXPECT_EQ(SubjectFingerprint(minimal.subjects[0], minimal), SubjectFingerprint(c.subjects[0], c));
  EXPECT_EQ(minimal.watchdog_timeout_s, c.watchdog_timeout_s);
  EXPECT_EQ(minimal.max_gap_s, c.max_gap_s);
  EXPECT_EQ(minimal.restart_backjump_s, c.restart_backjump_s);
  EXPECT_EQ(c.output_protocol_version, 2);
}

TEST(DaemonConfigTest, DemoSubjectFileIsTheBuiltInHumanoid) {
  EXPECT_EQ(ReadText(std::string(MOCAPD_CONFIG_DIR) + "/demo_subject.toml"),
            FormatSubjectModel(MakeHumanoidSubject("actor1")))
      << "regenerate config/demo_subject.toml from MakeHumanoidSubject(\"actor1\")";
}

TEST(DaemonConfigTest, ErrorsNameFileLineAndField) {
  EXPECT_EQ(ErrorOf(kMinimal), "");
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[input]\nendpont = \"tcp://127.0.0.1:1\"\n"),
            "test.toml:6: field 'input.endpont': unknown field");
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[pipeline]\nlookahead = -3\n"),
            "test.toml:6: field 'pipeline.lookahead': must be in [0, 1000], got -3");
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[input]\npattern = \"push\"\n"),
            "test.toml:6: field 'input.pattern': expected sub | pull, got 'push'");
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[control]\nwatchdog_timeout_s = \"1s\"\n"),
            "test.toml:6: field 'control.watchdog_timeout_s': expected a number");
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[pipeline.detectors]\nspike_mm = 0.0\n"),
            "test.toml:6: field 'pipeline.detectors.spike_mm': must be in [1, 100000], got 0");
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[output]\nendpoint = \"udp://x\"\n"),
            "test.toml:6: field 'output.endpoint': expected tcp://HOST:PORT, ipc://PATH or "
            "inproc://NAME, got 'udp://x'");
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[output]\nprotocol_version = 3\n"),
            "test.toml:6: field 'output.protocol_version': must be in [1, 2], got 3");
  EXPECT_NE(ErrorOf("format_version = 1\n").find("field 'subject': no [[subject]] tables"),
            std::string::npos);
  // A subject file given as the config says what it is (it said "expected [[subject]]").
  std::ifstream subject_file(std::string(MOCAPD_CONFIG_DIR) + "/demo_subject.toml");
  const std::string subject_text((std::istreambuf_iterator<char>(subject_file)),
                                 std::istreambuf_iterator<char>());
  EXPECT_NE(ErrorOf(subject_text).find("field 'subject': this is a subject file"),
            std::string::npos)
      << ErrorOf(subject_text);
  EXPECT_NE(ErrorOf("[[subject]]\nname = \"a\"\nmodel = \"demo_subject.toml\"\n")
                .find("field 'format_version'"),
            std::string::npos);
  EXPECT_NE(ErrorOf("format_version = 1\n[[subject]\n").find("test.toml:2:"),
            std::string::npos);  // TOML syntax
  // A subject's model misspelt: named with its line (the README's example said so, while
  // the daemon gave the [[subject]] line and no hint).
  EXPECT_EQ(ErrorOf("format_version = 1\n[[subject]]\nname = \"a\"\nrate_hz = 120\n"
                    "modle = \"demo_subject.toml\"\n"),
            "test.toml:5: field 'subject[0].model': missing: give the subject's model file, or "
            "calibrate = \"live\" with a marker_set (is 'modle' on line 5 meant for it?)");
}

TEST(DaemonConfigTest, ShardsSplitTheSubjectListSoEachIsSolvedOnce) {
  std::string subjects;
  for (int k = 1; k <= 16; ++k)
    subjects +=
        "[[subject]]\nname = \"actor" + std::to_string(k) + "\"\nmodel = \"demo_subject.toml\"\n";
  std::map<std::string, int> owner;
  for (int i = 0; i < 3; ++i) {
    const std::string text =
        "format_version = 1\n[input]\nshard = \"" + std::to_string(i) + "/3\"\n" + subjects;
    const DaemonConfig c = ParseDaemonConfig(text, "shard.toml", MOCAPD_CONFIG_DIR);
    EXPECT_EQ(c.subjects.size() + c.other_shards_subjects.size(), 16u);
    for (const SubjectConfig& s : c.subjects) {
      EXPECT_EQ(SubjectShard(s.name, 3), i);
      EXPECT_TRUE(owner.emplace(s.name, i).second) << s.name << " solved by two shards";
    }
  }
  EXPECT_EQ(owner.size(), 16u);  // every subject has a shard, and only one
  // The split is the wire's hash of the name: anyone can compute it.
  EXPECT_EQ(SubjectShard("actor1", 2), 1);
  EXPECT_EQ(SubjectShard("actor2", 2), 0);
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[input]\nshard = \"2/2\"\n"),
            "test.toml:6: field 'input.shard': expected I/N with 0 <= I < N <= 1024, got '2/2'");
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "[input]\nshard = \"1/2x\"\n").find("expected I/N"),
            std::string::npos);
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "[input]\npattern = \"pull\"\nshard = \"0/2\"\n")
                .find("needs pattern = \"sub\""),
            std::string::npos);
  // A subject listed twice is found even when the first lies in another shard.
  EXPECT_NE(ErrorOf("format_version = 1\n[input]\nshard = \"0/2\"\n" + subjects +
                    "[[subject]]\nname = \"actor1\"\nmodel = \"demo_subject.toml\"\n")
                .find("listed twice"),
            std::string::npos);
}

TEST(DaemonConfigTest, AnHttpTokenFileMustHoldOneLongToken) {
  const std::string dir = std::filesystem::temp_directory_path() / "mocapd_token_test";
  std::filesystem::create_directories(dir);
  auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir + "/" + name) << text;
    return dir + "/" + name;
  };
  const std::string good = write("good.token", "0123456789abcdef-token\n");
  const DaemonConfig c =
      ParseDaemonConfig(std::string(kMinimal) + "[control]\nhttp_token_file = \"" + good + "\"\n",
                        "test.toml", MOCAPD_CONFIG_DIR);
  EXPECT_EQ(c.http_token, "0123456789abcdef-token");  // the trailing newline is not part of it
  const std::string short_token = write("short.token", "abc\n");
  EXPECT_NE(
      ErrorOf(std::string(kMinimal) + "[control]\nhttp_token_file = \"" + short_token + "\"\n")
          .find("at least 16 characters"),
      std::string::npos);
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "[control]\nhttp_token_file = \"" + dir +
                    "/missing.token\"\n")
                .find("test.toml:6: field 'control.http_token_file': cannot read"),
            std::string::npos);
  std::filesystem::remove_all(dir);
}

TEST(DaemonConfigTest, SubjectsAreValidatedOneByOne) {
  EXPECT_EQ(
      ErrorOf("format_version = 1\n[[subject]]\nname = \"a/b\"\nmodel = \"demo_subject.toml\"\n"),
      "test.toml:3: field 'subject[0].name': must be 1..63 bytes (UTF-8) without '/', spaces, "
      "control or invisible characters");
  // Controls, and what looks like nothing or a space, or turns the text around (a name that
  // reads as the sender's spelling and matches none of its frames): a no-break space, a
  // zero-width space and joiner, a right-to-left override, a byte-order mark, an
  // ideographic space, a C1 control.
  for (const char* name :
       {"a\\u001b[31mRED", "a\\rb", "a\\u007f", "a\\tb", "actor\\u00a01", "actor\\u200b1",
        "actor\\u200d1", "actor\\u202e1", "\\ufeffactor1", "actor\\u30001", "actor\\u00851",
        "actor1\\ufe0f", "\\u3164actor1", "actor\\u061c1", "actor1\\U000e0041"})
    EXPECT_NE(ErrorOf("format_version = 1\n[[subject]]\nname = \"" + std::string(name) +
                      "\"\nmodel = \"demo_subject.toml\"\n")
                  .find("control or invisible characters"),
              std::string::npos)
        << name;
  // Letters of any script are names.
  for (const char* name :
       {"acteur\\u00e91", "\\u4fb3\\u512a", "\\u0410\\u043a\\u0442\\u0451\\u0440"})
    EXPECT_EQ(ErrorOf("format_version = 1\n[[subject]]\nname = \"" + std::string(name) +
                      "\"\nmodel = \"demo_subject.toml\"\n"),
              "")
        << name;
  EXPECT_EQ(ErrorOf(std::string(kMinimal) +
                    "[[subject]]\nname = \"actor1\"\nmodel = \"demo_subject.toml\"\n"),
            "test.toml:6: field 'subject[1].name': subject 'actor1' is listed twice");
  const std::string missing =
      ErrorOf("format_version = 1\n[[subject]]\nname = \"a\"\nmodel = \"nope.toml\"\n");
  EXPECT_NE(missing.find("test.toml:4: field 'subject[0].model':"), std::string::npos) << missing;
  EXPECT_NE(missing.find("nope.toml: cannot open"), std::string::npos) << missing;
  EXPECT_EQ(ErrorOf("format_version = 1\n[[subject]]\nname = \"a\"\n"),
            "test.toml:2: field 'subject[0].model': missing: give the subject's model file, or "
            "calibrate = \"live\" with a marker_set");
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "rate = 120\n"),
            "test.toml:5: field 'subject[0].rate': unknown field");
}

TEST(DaemonConfigTest, NonLoopbackBindsMustBeAskedFor) {
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[output]\nendpoint = \"tcp://0.0.0.0:5556\"\n"),
            "test.toml:6: field 'output.endpoint': binds a non-loopback address; set "
            "control.allow_remote = true to allow it");
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "[control]\nhttp_address = \"0.0.0.0\"\n")
                .find("control.http_address"),
            std::string::npos);
  EXPECT_NE(
      ErrorOf(std::string(kMinimal) + "[input]\npattern = \"pull\"\nendpoint = \"tcp://*:5555\"\n")
          .find("input.endpoint"),
      std::string::npos);
  EXPECT_TRUE(IsLocalEndpoint("ipc:///tmp/x"));
  EXPECT_TRUE(IsLocalEndpoint("tcp://[::1]:5"));
  EXPECT_FALSE(IsLocalEndpoint("tcp://*:5"));
  // All of 127/8 is loopback; an address that is none is said to be none.
  EXPECT_TRUE(IsLocalEndpoint("tcp://127.0.0.2:5"));
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[control]\nhttp_address = \"127.0.0.2\"\n"), "");
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "[control]\nhttp_address = \"nowhere\"\n")
                .find("'nowhere' is not an IP address"),
            std::string::npos);
}

// Host names are case-insensitive: "LOCALHOST" was taken for a remote address (so CURVE
// was demanded) and then failed to bind; an IPv4-mapped loopback is loopback.
TEST(DaemonConfigTest, LocalhostInAnyCaseIsTheLoopbackHost) {
  const DaemonConfig c =
      ParseDaemonConfig(std::string(kMinimal) +
                            "[input]\nendpoint = \"tcp://LocalHost:6555\"\n[output]\nendpoint = "
                            "\"tcp://LOCALHOST:6556\"\n[control]\nhttp_address = \"LOCALHOST\"\n",
                        "test.toml", MOCAPD_CONFIG_DIR);
  EXPECT_EQ(c.input_endpoint, "tcp://localhost:6555");
  EXPECT_EQ(c.output_endpoint, "tcp://localhost:6556");
  EXPECT_EQ(c.http_address, "localhost");
  EXPECT_TRUE(IsLocalEndpoint("tcp://[::ffff:127.0.0.1]:5"));
  EXPECT_FALSE(IsLocalEndpoint("tcp://[::ffff:192.168.1.4]:5"));
}

// ZeroMQ wrapped a port past 65535 (99999 listened on 34463) and bound an unlogged one for
// 0: both are refused, naming the field.
TEST(DaemonConfigTest, AnEndpointsPortIsANumberFrom1To65535) {
  for (const char* port : {"99999", "0", "65536", "55a", "-1"}) {
    const std::string error =
        ErrorOf(std::string(kMinimal) + "[output]\nendpoint = \"tcp://127.0.0.1:" + port + "\"\n");
    EXPECT_NE(error.find("field 'output.endpoint': port '" + std::string(port) +
                         "' in 'tcp://127.0.0.1:" + port + "' is not a number from 1 to 65535"),
              std::string::npos)
        << error;
  }
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[input]\nendpoint = \"tcp://127.0.0.1:65535\"\n"), "");
  // Named at the endpoint's own line, not its table's (it said line 5 for line 7).
  const std::string far = ErrorOf(std::string(kMinimal) +
                                  "[output]\ncleaned_markers = true\n\nendpoint = \"udp://x:1\"\n");
  EXPECT_NE(far.find("test.toml:8: field 'output.endpoint': expected tcp://"), std::string::npos)
      << far;
}

// An output on the input's address would take the capture bridge's place, or feed the
// daemon its own frames: refused at load, however the address is spelled.
TEST(DaemonConfigTest, TheOutputMayNotUseTheInputsAddress) {
  const auto both = [](const std::string& in, const std::string& pattern, const std::string& out) {
    return ErrorOf(std::string(kMinimal) + "[input]\nendpoint = \"" + in + "\"\npattern = \"" +
                   pattern + "\"\n[output]\nendpoint = \"" + out + "\"\n");
  };
  for (const auto& [in, pattern, out] : std::vector<std::array<std::string, 3>>{
           {"tcp://127.0.0.1:5555", "sub", "tcp://127.0.0.1:5555"},
           {"tcp://localhost:5555", "sub", "tcp://127.0.0.1:5555"},
           {"tcp://*:6000", "pull", "tcp://127.0.0.1:6000"},
           {"tcp://localhost:5555", "sub", "tcp://0.0.0.0:5555"},
           {"tcp://192.168.1.4:5555", "sub", "tcp://192.168.1.4:5555"},
           {"tcp://127.0.0.1:05555", "sub", "tcp://127.0.0.1:5555"},
           {"tcp://LOCALHOST:5555", "sub", "tcp://127.0.0.1:5555"},
           {"tcp://Stage-PC:5555", "sub", "tcp://stage-pc:5555"},  // DNS names: any case
           {"tcp://[::ffff:127.0.0.1]:5555", "sub", "tcp://127.0.0.1:5555"},
           {"tcp://[::1]:5555", "sub", "tcp://[0:0:0:0:0:0:0:1]:5555"},
           {"tcp://[::1]:5555", "sub", "tcp://[::]:5555"},
           {"tcp://127.0.0.1:5555", "sub", "tcp://[::]:5555"},
           {"ipc:///tmp/mocap.sock", "sub", "ipc:///tmp/mocap.sock"},
           {"ipc:///tmp/mocap.sock", "pull", "ipc:///tmp/./sub/../mocap.sock"}}) {
    const std::string error = both(in, pattern, out);
    EXPECT_NE(error.find("field 'output.endpoint': '" + out + "' is the input's address"),
              std::string::npos)
        << in << " / " << out << ": " << error;
  }
  EXPECT_EQ(both("tcp://127.0.0.1:5555", "sub", "tcp://127.0.0.1:5556"), "");
  EXPECT_EQ(both("tcp://[::1]:5555", "sub", "tcp://127.0.0.1:5555"), "");
  // ZeroMQ binds "*" for IPv4 alone (an IPv6 endpoint, "[::]", takes both).
  EXPECT_EQ(both("tcp://[::1]:5555", "sub", "tcp://*:5555").find("input's address"),
            std::string::npos);
  EXPECT_EQ(both("tcp://[::1]:5555", "sub", "tcp://0.0.0.0:5555").find("input's address"),
            std::string::npos);
  // Another machine's bridge on the port this daemon binds on every interface: two sockets
  // (refused only for want of CURVE on a non-loopback output).
  EXPECT_EQ(both("tcp://192.168.1.4:5555", "sub", "tcp://*:5555").find("input's address"),
            std::string::npos);
  EXPECT_EQ(both("ipc:///tmp/in.sock", "sub", "ipc:///tmp/out.sock"), "");
  // An input on the output's default address is the input's mistake, named at its line.
  const std::string on_default =
      ErrorOf(std::string(kMinimal) + "[input]\nendpoint = \"tcp://127.0.0.1:5556\"\n");
  EXPECT_NE(on_default.find("test.toml:6: field 'input.endpoint': 'tcp://127.0.0.1:5556' is "
                            "the output's default address"),
            std::string::npos)
      << on_default;
}

// A live calibration's output never writes over a file the config names: the config
// itself (it was replaced by a subject file, and the next start failed), another subject's
// model or character, or another live subject's output.
TEST(DaemonConfigTest, ALiveCalibrationNeverWritesOverAFileTheConfigNames) {
  const std::string dir = testing::TempDir("config_calibration_out");
  const std::string config = dir + "/live.toml";
  std::filesystem::copy_file(std::string(MOCAPD_CONFIG_DIR) + "/demo_subject.toml",
                             dir + "/demo_subject.toml");
  const auto live = [](const std::string& name, const std::string& out) {
    return "[[subject]]\nname = \"" + name +
           "\"\ncalibrate = \"live\"\nmarker_set = \"cmu-41\"\ncalibration_out = \"" + out + "\"\n";
  };
  const auto error_of = [&](const std::string& text) {
    try {
      ParseDaemonConfig("format_version = 1\n" + text, config, dir);
    } catch (const std::exception& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  const std::string over_config = error_of(live("a", "live.toml"));
  EXPECT_NE(
      over_config.find("field 'subject[0].calibration_out': '" + config + "' is the config file"),
      std::string::npos)
      << over_config;
  const std::string model = "[[subject]]\nname = \"m\"\nmodel = \"demo_subject.toml\"\n";
  EXPECT_NE(error_of(model + live("a", "demo_subject.toml")).find("is subject 'm''s model"),
            std::string::npos);
  EXPECT_NE(error_of(live("a", "demo_subject.toml") + model)
                .find("field 'subject[1].model': '" + dir +
                      "/demo_subject.toml' is subject 'a''s calibration_out"),
            std::string::npos);
  EXPECT_NE(error_of(live("a", "x.toml") + live("b", "./x.toml"))
                .find("is subject 'a''s calibration_out"),
            std::string::npos);
  EXPECT_EQ(error_of(live("a", "a.toml") + live("b", "b.toml") + model), "");
}

// Keys for a CURVE config in dir: the daemon's pair, a capture publisher's public key and
// one authorized client. Returns the [security] table that names them.
std::string WriteCurveKeys(const std::string& dir) {
  std::filesystem::create_directories(dir + "/authorized");
  curve::WriteCertificates(dir + "/mocapd", curve::GenerateKeyPair());
  curve::WriteCertificates(dir + "/capture", curve::GenerateKeyPair());
  curve::WriteCertificates(dir + "/authorized/viewer", curve::GenerateKeyPair());
  return "[security]\ncurve = true\nkey_file = \"" + dir + "/mocapd.key_secret\"\n" +
         "authorized_keys = \"" + dir + "/authorized\"\ninput_server_key_file = \"" + dir +
         "/capture.key\"\n";
}

TEST(DaemonConfigTest, RemoteEndpointsNeedCurveAndRemoteHttpNeedsAToken) {
  const std::string dir = testing::TempDir("config_remote_curve");
  const std::string security = WriteCurveKeys(dir);
  const std::string remote_output =
      "[output]\nendpoint = \"tcp://0.0.0.0:5556\"\n[control]\nallow_remote = true\n";
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + remote_output),
            "test.toml:6: field 'output.endpoint': is reachable from other machines: set "
            "security.curve = true (mocapd keygen) to allow it");
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + remote_output + security), "");
  // A SUB reaching out to a remote publisher could be fed by a forged one just the same.
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "[input]\nendpoint = \"tcp://10.0.0.5:5555\"\n")
                .find("field 'input.endpoint': is reachable from other machines"),
            std::string::npos);
  EXPECT_EQ(
      ErrorOf(std::string(kMinimal) + "[input]\nendpoint = \"tcp://10.0.0.5:5555\"\n" + security),
      "");
  EXPECT_NE(ErrorOf(std::string(kMinimal) +
                    "[control]\nallow_remote = true\nhttp_address = \"0.0.0.0\"\n")
                .find("set control.http_token_file to allow it"),
            std::string::npos);
}

TEST(DaemonConfigTest, CurveKeysAreReadAndEveryMistakeNamesItsField) {
  const std::string dir = testing::TempDir("config_curve");
  const std::string security = WriteCurveKeys(dir);
  const DaemonConfig c =
      ParseDaemonConfig(std::string(kMinimal) + security, "test.toml", MOCAPD_CONFIG_DIR);
  EXPECT_TRUE(c.curve);
  EXPECT_EQ(c.curve_keys.public_key, curve::ReadCertificate(dir + "/mocapd.key", false).public_key);
  EXPECT_EQ(c.curve_keys.secret_key.size(), curve::kZ85KeyLength);
  ASSERT_EQ(c.curve_authorized_keys.size(), 1u);  // the .key_secret beside it is not a client
  EXPECT_EQ(c.curve_input_server_key,
            curve::ReadCertificate(dir + "/capture.key", false).public_key);

  const std::string base = std::string(kMinimal) + "[security]\ncurve = true\n";
  EXPECT_NE(ErrorOf(base).find("field 'security.key_file': missing"), std::string::npos);
  EXPECT_NE(ErrorOf(base + "key_file = \"" + dir + "/mocapd.key\"\n")
                .find("no secret-key (give the .key_secret file"),
            std::string::npos);
  EXPECT_NE(ErrorOf(base + "key_file = \"" + dir + "/mocapd.key_secret\"\n")
                .find("field 'security.authorized_keys': missing"),
            std::string::npos);
  EXPECT_NE(ErrorOf(base + "key_file = \"" + dir + "/mocapd.key_secret\"\nauthorized_keys = \"" +
                    dir + "/nowhere\"\n")
                .find("cannot list the authorized keys"),
            std::string::npos);
  EXPECT_NE(ErrorOf(base + "key_file = \"" + dir + "/mocapd.key_secret\"\nauthorized_keys = \"" +
                    dir + "/authorized\"\n")
                .find("field 'security.input_server_key_file': missing"),
            std::string::npos);
  EXPECT_NE(
      ErrorOf(std::string(kMinimal) + "[security]\nkey_file = \"" + dir + "/mocapd.key_secret\"\n")
          .find("keys are given but curve = false"),
      std::string::npos);
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "[security]\ncurves = true\n").find("unknown field"),
            std::string::npos);
  // A secret key others can read is refused, as ssh refuses one.
  std::filesystem::permissions(dir + "/mocapd.key_secret", std::filesystem::perms::group_read,
                               std::filesystem::perm_options::add);
  EXPECT_NE(ErrorOf(std::string(kMinimal) + security).find("chmod 600"), std::string::npos);
}

// The subject description carries names of at most 63 bytes: a longer one is refused when
// the config loads, not met by the data plane when it describes the subject.
TEST(DaemonConfigTest, AModelNameTooLongForTheWireIsRefusedAtLoad) {
  const std::string dir = testing::TempDir("config_long_name");
  const std::string long_name(64, 'M');
  std::string model = ReadText(std::string(MOCAPD_CONFIG_DIR) + "/demo_subject.toml");
  model.replace(model.find("\"PEL1\""), 6, "\"" + long_name + "\"");
  std::ofstream(dir + "/long.toml") << model;
  const std::string error =
      ErrorOf("format_version = 1\n[[subject]]\nname = \"a\"\nmodel = \"" + dir + "/long.toml\"\n");
  EXPECT_NE(error.find("test.toml:4: field 'subject[0].model': marker name '" + long_name +
                       "' is longer than 63 bytes"),
            std::string::npos)
      << error;
}

TEST(DaemonConfigTest, ASubjectCanDriveACharacterFromABvh) {
  const std::string dir = testing::TempDir("config_character");
  const Skeleton humanoid = MakeHumanoidSkeleton(2.1);  // an ogre-sized character
  WriteBvh(dir + "/ogre.bvh", MakeBvhTake(humanoid, {RestPose(humanoid)}, 1.0 / 120.0, "cm"));
  const std::string with = std::string(kMinimal) + "character = \"" + dir +
                           "/ogre.bvh\"\ncharacter_joint_map = { head = \"Head\" }\n" +
                           "[retarget]\ndamping = 0.05\ncontact_speed_m_s = 0.2\n";
  const DaemonConfig c = ParseDaemonConfig(with, "t.toml", MOCAPD_CONFIG_DIR);
  ASSERT_TRUE(c.subjects[0].character);
  EXPECT_EQ(c.subjects[0].character->num_joints(), humanoid.num_joints());
  EXPECT_NEAR(c.subjects[0].character_map.target_leg_length_m /
                  c.subjects[0].character_map.source_leg_length_m,
              2.1 / 1.75, 0.01);
  EXPECT_DOUBLE_EQ(c.subjects[0].retarget.damping, 0.05);
  EXPECT_DOUBLE_EQ(c.subjects[0].retarget.contact_speed_m_s, 0.2);
  const std::string missing =
      ErrorOf(std::string(kMinimal) + "character = \"" + dir + "/nope.bvh\"\n");
  EXPECT_NE(missing.find("test.toml:5: field 'subject[0].character':"), std::string::npos)
      << missing;
  const std::string bad_map = ErrorOf(std::string(kMinimal) + "character = \"" + dir +
                                      "/ogre.bvh\"\ncharacter_joint_map = { hand_l = \"Paw\" }\n");
  EXPECT_NE(bad_map.find("the character has no joint 'Paw'"), std::string::npos) << bad_map;
  // The joint map's own mistake is named at its own field and line (it was the character's).
  EXPECT_NE(bad_map.find("test.toml:6: field 'subject[0].character_joint_map':"), std::string::npos)
      << bad_map;
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "character_joint_map = { head = \"Head\" }\n")
                .find("given without a character"),
            std::string::npos);
}

TEST(DaemonConfigTest, ThresholdsAndOverridesReachThePipelineOptions) {
  const DaemonConfig c = ParseDaemonConfig(
      std::string(kMinimal) +
          "lookahead = 3\nrate_hz = 240\n[pipeline.detectors]\nspike_mm = 45\n"
          "disagreement_rotation_deg = 20\nstray_residual_mm = 150\nstray_ms = 200\n"
          "[pipeline]\nwindow_ms = 500\n",
      "t.toml", MOCAPD_CONFIG_DIR);
  const CleanupOptions& o = c.subjects[0].cleanup;
  EXPECT_EQ(o.lookahead, 3);
  EXPECT_EQ(o.rate_hz, 240.0);
  EXPECT_DOUBLE_EQ(o.spike_m, 0.045);
  EXPECT_NEAR(o.disagreement_rotation_rad, 20.0 * M_PI / 180.0, 1e-12);
  EXPECT_DOUBLE_EQ(o.window_s, 0.5);
  EXPECT_DOUBLE_EQ(o.stray_residual_m, 0.15);
  EXPECT_DOUBLE_EQ(o.stray_s, 0.2);
}

// Frame accounting and a foot's release are in time, counted at each subject's rate; a
// config of older versions may still give them in frames (the same count at any rate).
TEST(DaemonConfigTest, GapsRestartsAndFootReleasesAreInTimeAtEachSubjectsRate) {
  const DaemonConfig defaults = ParseDaemonConfig(kMinimal, "test.toml", MOCAPD_CONFIG_DIR);
  EXPECT_EQ(defaults.MaxGapFrames(120.0), 240);
  EXPECT_EQ(defaults.MaxGapFrames(360.0), 720);
  EXPECT_EQ(defaults.RestartBackjumpFrames(120.0), 120);
  EXPECT_EQ(defaults.RestartBackjumpFrames(60.0), 60);
  EXPECT_DOUBLE_EQ(defaults.subjects[0].retarget.release_s, 0.07);

  const std::string at_240 = std::string(kMinimal) + "rate_hz = 240.0\n";
  const DaemonConfig in_time = ParseDaemonConfig(
      at_240 +
          "[frames]\nmax_gap_ms = 500\nrestart_backjump_ms = 250\n[retarget]\nrelease_ms = 100\n",
      "test.toml", MOCAPD_CONFIG_DIR);
  EXPECT_EQ(in_time.MaxGapFrames(in_time.subjects[0].rate_hz), 120);
  EXPECT_EQ(in_time.RestartBackjumpFrames(in_time.subjects[0].rate_hz), 60);
  EXPECT_DOUBLE_EQ(in_time.subjects[0].retarget.release_s, 0.1);

  const DaemonConfig in_frames = ParseDaemonConfig(
      at_240 +
          "[frames]\nmax_gap_frames = 100\nrestart_backjump_frames = 30\n[retarget]\n"
          "release_frames = 12\n",
      "test.toml", MOCAPD_CONFIG_DIR);
  EXPECT_EQ(in_frames.MaxGapFrames(240.0), 100);
  EXPECT_EQ(in_frames.MaxGapFrames(60.0), 100);
  EXPECT_EQ(in_frames.RestartBackjumpFrames(240.0), 30);
  EXPECT_DOUBLE_EQ(in_frames.subjects[0].retarget.release_s, 12 / 240.0);

  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[frames]\nmax_gap_ms = 500\nmax_gap_frames = 60\n"),
            "test.toml:7: field 'frames.max_gap_frames': given as well as max_gap_ms: give one "
            "(max_gap_ms holds at any capture rate)");
  EXPECT_EQ(ErrorOf(std::string(kMinimal) + "[retarget]\nrelease_frames = 8\nrelease_ms = 70\n"),
            "test.toml:6: field 'retarget.release_frames': given as well as release_ms: give one "
            "(release_ms holds at any capture rate)");
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "[frames]\nmax_gap_ms = -1\n"), "");
  // Bridged frames are inserted at once: a minute at 2000 Hz is too many.
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "rate_hz = 2000.0\n[frames]\nmax_gap_ms = 60000\n")
                .find("field 'subject[0].rate_hz': frames.max_gap_ms is 120000 frames at this "
                      "rate, more than the 100000 a gap may bridge"),
            std::string::npos);
  // A reload re-creates a subject when what it does changes: the frames a gap spans.
  const auto fingerprint_with_gap = [&](const char* ms) {
    const DaemonConfig c =
        ParseDaemonConfig(std::string(kMinimal) + "[frames]\nmax_gap_ms = " + ms + "\n",
                          "test.toml", MOCAPD_CONFIG_DIR);
    return SubjectFingerprint(c.subjects[0], c);
  };
  EXPECT_EQ(fingerprint_with_gap("2001"), fingerprint_with_gap("2000"));  // 240 frames either way
  EXPECT_NE(fingerprint_with_gap("2100"), fingerprint_with_gap("2000"));
  EXPECT_NE(ErrorOf(std::string(kMinimal) + "[frames]\nrestart_backjump_ms = 0\n"), "");
}

// config/mocapd.toml promises that its values are the defaults: every cleanup option a
// config may set must be written there, with the value the code uses.
TEST(DaemonConfigTest, ShippedConfigDocumentsEveryCleanupOptionAtItsDefault) {
  const toml::table doc = ReadTomlFile(std::string(MOCAPD_CONFIG_DIR) + "/mocapd.toml");
  const CleanupOptions defaults;
  int documented = 0;
  for (const CleanupOptionField& f : CleanupOptionFields()) {
    if (f.section == nullptr) continue;
    const toml::node* node = doc.at_path(std::string(f.section) + "." + f.key).node();
    ASSERT_NE(node, nullptr) << f.section << "." << f.key << " is not in config/mocapd.toml";
    const double code =
        std::visit([&](auto member) { return static_cast<double>(defaults.*member); }, f.member);
    const double file =
        node->is_boolean() ? (*node->value<bool>() ? 1.0 : 0.0) : *node->value<double>() * f.to_si;
    EXPECT_NEAR(file, code, 1e-12 * std::max(1.0, std::abs(code))) << f.section << "." << f.key;
    ++documented;
  }
  EXPECT_GT(documented, 10);
}

}  // namespace
}  // namespace mocapd
