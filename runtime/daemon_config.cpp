// Reading and validating the daemon's TOML configuration.
#include "runtime/daemon_config.hpp"

#include <algorithm>
#include <boost/algorithm/string/predicate.hpp>
#include <boost/asio/ip/address.hpp>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string_view>
#include <type_traits>
#include <variant>

#include "formats/bvh.hpp"
#include "formats/retarget_map.hpp"
#include "formats/subject_from_markers.hpp"
#include "formats/toml_reader.hpp"
#include "protocol/messages.hpp"

namespace mocapd {
namespace {

// "tcp://HOST:PORT": host and port; other transports have no host.
bool SplitTcp(const std::string& endpoint, std::string* host, std::string* port) {
  if (endpoint.rfind("tcp://", 0) != 0) return false;
  const std::string rest = endpoint.substr(6);
  const size_t colon = rest.rfind(':');
  if (colon == std::string::npos) return false;
  *host = rest.substr(0, colon);
  *port = rest.substr(colon + 1);
  if (host->size() >= 2 && host->front() == '[' && host->back() == ']')
    *host = host->substr(1, host->size() - 2);
  return true;
}

// Host names are case-insensitive: "LOCALHOST" is the loopback host too (it was taken as
// a remote address, and then failed to bind).
bool IsLocalhostName(const std::string& host) {
  return boost::algorithm::iequals(host, "localhost");
}

// The address a host literal names, an IPv4-mapped IPv6 one (::ffff:127.0.0.1) as its IPv4
// address; nullopt for a name (an interface, a wildcard).
std::optional<boost::asio::ip::address> HostAddress(const std::string& host) {
  if (IsLocalhostName(host)) return boost::asio::ip::make_address_v4("127.0.0.1");
  boost::system::error_code ec;
  const auto address = boost::asio::ip::make_address(host, ec);
  if (ec) return std::nullopt;
  if (address.is_v6() && address.to_v6().is_v4_mapped())
    return boost::asio::ip::make_address_v4(boost::asio::ip::v4_mapped, address.to_v6());
  return address;
}

// All of 127/8 and ::1 (127.0.0.2 was refused as "not loopback").
bool IsLoopbackHost(const std::string& host) {
  const auto address = HostAddress(host);
  return address && address->is_loopback();
}

std::string Endpoint(TomlTable& t, const std::string& key, const std::string& fallback) {
  const std::string e = t.String(key, fallback);
  std::string host, port;
  const bool ok = e.rfind("ipc://", 0) == 0 ? e.size() > 6
                  : e.rfind("inproc://", 0) == 0
                      ? e.size() > 9
                      : SplitTcp(e, &host, &port) && !host.empty() && !port.empty();
  if (!ok)
    t.Fail(t.Find(key), key,
           "expected tcp://HOST:PORT, ipc://PATH or inproc://NAME, got '" + e + "'");
  // ZeroMQ wraps a port past 65535 (99999 listened on 34463) and binds an unlogged one for
  // 0: the port is a number from 1 to 65535.
  if (e.rfind("tcp://", 0) == 0 &&
      (port.size() > 5 ||
       !std::all_of(port.begin(), port.end(),
                    [](unsigned char ch) { return std::isdigit(ch) != 0; }) ||
       std::stoi(port) < 1 || std::stoi(port) > 65535))
    t.Fail(t.Find(key), key, "port '" + port + "' in '" + e + "' is not a number from 1 to 65535");
  // The daemon binds "localhost" as 127.0.0.1, spelled in lower case.
  if (IsLocalhostName(host) && host != "localhost") return "tcp://localhost:" + port;
  return e;
}

// Whether two endpoints name one socket address: equal ipc/inproc names, or one TCP port
// on hosts that overlap: the same address however it is written ("localhost" in any case
// for 127.0.0.1, ::ffff:127.0.0.1 too), or a wildcard beside a loopback address or another
// wildcard. The output bound on the input's address would take the bridge's place, or feed
// the daemon its own messages. A wildcard output beside an input on another machine's
// address is two sockets; so is IPv4's ("*", 0.0.0.0) beside IPv6's loopback, since ZeroMQ
// binds "*" for IPv4 alone unless the endpoint is IPv6 ("[::]" takes both).
bool SameSocketAddress(const std::string& a, const std::string& b) {
  std::string host_a, port_a, host_b, port_b;
  if (a.rfind("ipc://", 0) == 0 && b.rfind("ipc://", 0) == 0) {
    // One socket file however its path is written ("./", "..", a link): the output's bind
    // took the input's file, no frame arrived, and /health said ok.
    namespace fs = std::filesystem;
    std::error_code ec_a, ec_b;
    const fs::path pa = fs::weakly_canonical(fs::absolute(a.substr(6)), ec_a);
    const fs::path pb = fs::weakly_canonical(fs::absolute(b.substr(6)), ec_b);
    return ec_a || ec_b ? a == b : pa == pb;
  }
  if (!SplitTcp(a, &host_a, &port_a) || !SplitTcp(b, &host_b, &port_b)) return a == b;
  if (std::stoi(port_a) != std::stoi(port_b)) return false;  // digits, checked by Endpoint
  const auto address_a = HostAddress(host_a), address_b = HostAddress(host_b);
  if (address_a && address_b
          ? *address_a == *address_b
          : !address_a && !address_b && boost::algorithm::iequals(host_a, host_b))
    return true;
  const auto any_v4 = [](const std::string& h, const auto& address) {
    return h == "*" || (address && address->is_v4() && address->is_unspecified());
  };
  const auto any_v6 = [](const auto& address) {
    return address && address->is_v6() && address->is_unspecified();
  };
  const auto covers = [&](const std::string& wild, const auto& wild_address,
                          const std::string& other, const auto& other_address) {
    if (any_v6(wild_address))
      return any_v4(other, other_address) || any_v6(other_address) || IsLoopbackHost(other);
    return any_v4(wild, wild_address) &&
           (any_v4(other, other_address) ||
            (other_address && other_address->is_v4() && other_address->is_loopback()));
  };
  return covers(host_a, address_a, host_b, address_b) ||
         covers(host_b, address_b, host_a, address_a);
}

// Whether a name holds a code point that shows as nothing or as a space, or turns the text
// around (bidirectional controls, as in "Trojan Source"): "actor\u00a01" and "actor\u200b1"
// look like names the sender spells otherwise, and every frame would be dropped as an
// unknown subject. Also variation selectors, tag characters and the blank Hangul fillers.
// The joiners U+200C/U+200D go too, though some Persian and Indic spellings use them: a
// subject name is an identifier typed twice, not prose. TOML has already checked UTF-8.
bool HasInvisibleCodePoint(const std::string& text) {
  for (size_t i = 0; i < text.size();) {
    const auto lead = static_cast<unsigned char>(text[i]);
    const size_t length = lead < 0x80 ? 1 : lead < 0xe0 ? 2 : lead < 0xf0 ? 3 : 4;
    char32_t code = length == 1 ? lead : lead & (0x7f >> length);
    for (size_t k = 1; k < length && i + k < text.size(); ++k)
      code = (code << 6) | (static_cast<unsigned char>(text[i + k]) & 0x3f);
    i += length;
    if ((code >= 0x80 && code <= 0xa0) || code == 0xad || code == 0x34f || code == 0x61c ||
        code == 0x115f || code == 0x1160 || code == 0x1680 || (code >= 0x180b && code <= 0x180f) ||
        (code >= 0x2000 && code <= 0x200f) || (code >= 0x2028 && code <= 0x202f) ||
        (code >= 0x205f && code <= 0x206f) || code == 0x2800 || code == 0x3000 || code == 0x3164 ||
        (code >= 0xfe00 && code <= 0xfe0f) || code == 0xfeff || code == 0xffa0 ||
        (code >= 0xfff9 && code <= 0xfffb) || (code >= 0x1d173 && code <= 0x1d17a) ||
        (code >= 0xe0000 && code <= 0xe007f) || (code >= 0xe0100 && code <= 0xe01ef))
      return true;
  }
  return false;
}

// Reads every cleanup option a config may set (CleanupOptionFields: the one place their
// names, units and bounds are written) from its section's table.
void ReadCleanupOptions(TomlTable& table, const std::string& section, CleanupOptions* o) {
  for (const CleanupOptionField& f : CleanupOptionFields()) {
    if (f.section == nullptr || section != f.section) continue;
    std::visit(
        [&](auto member) {
          using T = std::remove_reference_t<decltype(o->*member)>;
          if constexpr (std::is_same_v<T, bool>) {
            o->*member = table.Bool(f.key, o->*member);
          } else if constexpr (std::is_same_v<T, int>) {
            o->*member =
                table.Integer(f.key, o->*member, static_cast<int>(f.min), static_cast<int>(f.max));
          } else if (const auto v = table.OptionalNumber(f.key, f.min, f.max)) {
            o->*member = *v * f.to_si;
          }
        },
        f.member);
  }
}

// What keeps a model off the wire (too many markers or joints, a name too long for the
// subject description), or empty: refused at load, so the data plane never meets it.
std::string WireProblem(const Skeleton& skeleton, const MarkerSet* markers) {
  const auto too_long = [](const std::string& name) {
    return name.size() > protocol::kMaxSubjectName;
  };
  if (skeleton.num_joints() > static_cast<int>(protocol::kMaxJoints))
    return "more joints than the wire protocol carries (" + std::to_string(protocol::kMaxJoints) +
           ")";
  for (int j = 0; j < skeleton.num_joints(); ++j)
    if (too_long(skeleton.joint(j).name))
      return "joint name '" + skeleton.joint(j).name + "' is longer than 63 bytes";
  if (!markers) return {};
  if (markers->num_markers() > static_cast<int>(protocol::kMaxMarkers))
    return "more markers than the wire protocol carries (" + std::to_string(protocol::kMaxMarkers) +
           ")";
  for (int m = 0; m < markers->num_markers(); ++m)
    if (too_long(markers->marker(m).name))
      return "marker name '" + markers->marker(m).name + "' is longer than 63 bytes";
  return {};
}

const CleanupOptionField& OptionField(const char* name) {
  for (const CleanupOptionField& f : CleanupOptionFields())
    if (std::string(f.name) == name) return f;
  throw std::logic_error(std::string("no cleanup option ") + name);
}

}  // namespace

int DaemonConfig::MaxGapFrames(double rate_hz) const {
  return max_gap_frames >= 0 ? max_gap_frames : static_cast<int>(std::lround(max_gap_s * rate_hz));
}

int DaemonConfig::RestartBackjumpFrames(double rate_hz) const {
  return restart_backjump_frames >= 1
             ? restart_backjump_frames
             : std::max(1, static_cast<int>(std::lround(restart_backjump_s * rate_hz)));
}

const SubjectConfig* DaemonConfig::FindSubject(const std::string& name) const {
  for (const SubjectConfig& s : subjects)
    if (s.name == name) return &s;
  return nullptr;
}

std::string SubjectFingerprint(const SubjectConfig& s, const DaemonConfig& c) {
  std::ostringstream f;
  f.precision(17);
  f << FormatSubjectModel(s.model) << '\n' << s.name << ' ' << s.rate_hz;
  for (const CleanupOptionField& field : CleanupOptionFields())
    std::visit([&](auto member) { f << ' ' << s.cleanup.*member; }, field.member);
  f << ' ' << c.MaxGapFrames(s.rate_hz) << ' ' << c.RestartBackjumpFrames(s.rate_hz) << ' '
    << c.publish_cleaned_markers << ' ' << c.publish_global_transforms << ' '
    << c.output_protocol_version << '\n'
    << s.character_path << ' ' << s.character_map.report << ' ' << s.retarget.damping << ' '
    << s.retarget.contact_height_m << ' ' << s.retarget.contact_speed_m_s << ' '
    << s.retarget.release_s << ' ' << s.retarget.points_per_bone;
  if (s.live.enabled) {
    f << "\nlive " << s.live.marker_set << ' ' << s.live.out_path << ' ' << s.live.min_seconds
      << ' ' << s.live.max_seconds << ' ' << s.live.interleaved_solves;
    for (const std::string& label : s.live.labels) f << ' ' << label;
  }
  return f.str();
}

bool IsLocalEndpoint(const std::string& endpoint) {
  if (endpoint.rfind("ipc://", 0) == 0 || endpoint.rfind("inproc://", 0) == 0) return true;
  std::string host, port;
  return SplitTcp(endpoint, &host, &port) && IsLoopbackHost(host);
}

DaemonConfig ParseDaemonConfig(const std::string& text, const std::string& source_name,
                               const std::string& base_dir) {
  const toml::table root = ParseToml(text, source_name);
  DaemonConfig c;
  c.source = source_name;
  TomlTable top(root, "", source_name);
  const int version = top.Integer("format_version", 0, 1, 1);
  if (version != 1) top.Fail(nullptr, "format_version", "missing (this daemon reads version 1)");

  TomlTable input = top.Table("input");
  c.input_endpoint = Endpoint(input, "endpoint", c.input_endpoint);
  c.input_pattern = input.Choice("pattern", "sub", {"sub", "pull"}) == "sub" ? InputPattern::kSub
                                                                             : InputPattern::kPull;
  c.subscribe_all = input.Choice("subscribe", "subjects", {"subjects", "all"}) == "all";
  c.receive_high_water_mark =
      input.Integer("receive_high_water_mark", c.receive_high_water_mark, 1, 10'000'000);
  c.max_message_bytes = static_cast<size_t>(
      input.Integer("max_message_bytes", static_cast<int>(c.max_message_bytes), 64, 64 << 20));
  c.workers = input.Integer("workers", c.workers, 0, 64);
  c.pin_workers = input.Bool("pin_workers", c.pin_workers);
  if (input.Has("shard")) {
    const std::string shard = input.String("shard", "0/1");
    int index = -1, count = 0;
    char tail = 0;
    if (std::sscanf(shard.c_str(), "%d/%d%c", &index, &count, &tail) != 2 || count < 1 ||
        count > 1024 || index < 0 || index >= count)
      input.Fail(root["input"]["shard"].node(), "shard",
                 "expected I/N with 0 <= I < N <= 1024, got '" + shard + "'");
    // Each daemon must see only its own subjects' frames: PULL deals messages out to its
    // peers in turn, and subscribing to everything would count the others' as unknown.
    if (count > 1 && (c.input_pattern != InputPattern::kSub || c.subscribe_all))
      input.Fail(root["input"]["shard"].node(), "shard",
                 "needs pattern = \"sub\" and subscribe = \"subjects\"");
    c.shard_index = index;
    c.shard_count = count;
  }
  input.RejectUnknown();

  TomlTable output = top.Table("output");
  c.output_endpoint = Endpoint(output, "endpoint", c.output_endpoint);
  if (SameSocketAddress(c.output_endpoint, c.input_endpoint)) {
    // Named at the field the file wrote: an input set on the output's default is the
    // input's mistake.
    if (output.Has("endpoint"))
      output.Fail(output.Find("endpoint"), "endpoint",
                  "'" + c.output_endpoint + "' is the input's address (input.endpoint = '" +
                      c.input_endpoint + "'): the cleaned frames need an address of their own");
    input.Fail(input.Find("endpoint"), "endpoint",
               "'" + c.input_endpoint + "' is the output's default address (" + c.output_endpoint +
                   "): set output.endpoint to another");
  }
  c.send_high_water_mark =
      output.Integer("send_high_water_mark", c.send_high_water_mark, 1, 10'000'000);
  c.publish_cleaned_markers = output.Bool("cleaned_markers", c.publish_cleaned_markers);
  c.publish_global_transforms = output.Bool("global_transforms", c.publish_global_transforms);
  c.output_protocol_version = output.Integer("protocol_version", c.output_protocol_version,
                                             protocol::kVersion1, protocol::kVersion2);
  output.RejectUnknown();

  TomlTable control = top.Table("control");
  c.http_enabled = control.Bool("http", c.http_enabled);
  c.http_address = control.String("http_address", c.http_address);
  if (IsLocalhostName(c.http_address)) c.http_address = "localhost";
  if (c.http_address != "localhost") {
    boost::system::error_code ec;
    (void)boost::asio::ip::make_address(c.http_address, ec);
    if (ec)
      control.Fail(root["control"]["http_address"].node(), "http_address",
                   "'" + c.http_address + "' is not an IP address");
  }
  c.http_port = control.Integer("http_port", c.http_port, 0, 65535);
  c.stats_interval_s = control.Number("stats_interval_s", c.stats_interval_s, 0.05, 3600);
  c.watchdog_timeout_s = control.Number("watchdog_timeout_s", c.watchdog_timeout_s, 0.01, 3600);
  c.log_interval_s = control.Number("log_interval_s", c.log_interval_s, 0.1, 86400);
  c.model_suspect_mm = control.Number("model_suspect_mm", c.model_suspect_mm, 1.0, 10000.0);
  c.allow_remote = control.Bool("allow_remote", c.allow_remote);
  c.http_max_connections =
      control.Integer("http_max_connections", c.http_max_connections, 1, 10000);
  c.live_view = control.Bool("live_view", c.live_view);
  c.live_view_rate_hz = control.Number("live_view_rate_hz", c.live_view_rate_hz, 1.0, 120.0);
  c.live_view_max_viewers =
      control.Integer("live_view_max_viewers", c.live_view_max_viewers, 1, 256);
  c.live_view_close_stalled_s =
      control.Number("live_view_close_stalled_s", c.live_view_close_stalled_s, 0.1, 3600.0);
  c.http_token_file = control.String("http_token_file", "");
  if (!c.http_token_file.empty()) {
    if (std::filesystem::path(c.http_token_file).is_relative())
      c.http_token_file =
          (std::filesystem::path(base_dir) / c.http_token_file).lexically_normal().string();
    std::ifstream token_in(c.http_token_file, std::ios::binary);
    std::ostringstream token;
    token << token_in.rdbuf();
    c.http_token = token.str();
    while (!c.http_token.empty() && std::isspace(static_cast<unsigned char>(c.http_token.back())))
      c.http_token.pop_back();
    // A short or spaced token is a mistake (a path, a placeholder), not a secret.
    const bool spaced = std::any_of(c.http_token.begin(), c.http_token.end(),
                                    [](unsigned char ch) { return std::isspace(ch) != 0; });
    if (!token_in)
      control.Fail(root["control"]["http_token_file"].node(), "http_token_file",
                   "cannot read '" + c.http_token_file + "'");
    if (c.http_token.size() < 16 || spaced)
      control.Fail(root["control"]["http_token_file"].node(), "http_token_file",
                   "'" + c.http_token_file +
                       "' must hold one token of at least 16 characters without spaces");
  }
  control.RejectUnknown();

  TomlTable security = top.Table("security");
  c.curve = security.Bool("curve", c.curve);
  const auto resolve = [&](const std::string& path) {
    return path.empty() || std::filesystem::path(path).is_absolute()
               ? path
               : (std::filesystem::path(base_dir) / path).lexically_normal().string();
  };
  c.curve_key_file = resolve(security.String("key_file", ""));
  c.curve_authorized_keys_dir = resolve(security.String("authorized_keys", ""));
  c.curve_input_server_key_file = resolve(security.String("input_server_key_file", ""));
  security.RejectUnknown();
  if (c.curve) {
    const auto node = [&](const char* key) { return root["security"][key].node(); };
    if (!curve::Available())
      security.Fail(node("curve"), "curve", "this libzmq was built without CURVE");
    if (c.curve_key_file.empty())
      security.Fail(nullptr, "key_file",
                    "missing: curve = true needs this daemon's key pair (mocapd keygen)");
    try {
      c.curve_keys = curve::ReadCertificate(c.curve_key_file, true);
    } catch (const std::exception& e) {
      security.Fail(node("key_file"), "key_file", e.what());
    }
    if (c.curve_authorized_keys_dir.empty())
      security.Fail(nullptr, "authorized_keys",
                    "missing: curve = true needs the directory of clients' public keys");
    try {
      c.curve_authorized_keys = curve::ReadAuthorizedKeys(c.curve_authorized_keys_dir);
    } catch (const std::exception& e) {
      security.Fail(node("authorized_keys"), "authorized_keys", e.what());
    }
    if (c.input_pattern == InputPattern::kSub) {
      if (c.curve_input_server_key_file.empty())
        security.Fail(nullptr, "input_server_key_file",
                      "missing: a SUB input with curve = true needs the capture publisher's "
                      "public key");
      try {
        c.curve_input_server_key =
            curve::ReadCertificate(c.curve_input_server_key_file, false).public_key;
      } catch (const std::exception& e) {
        security.Fail(node("input_server_key_file"), "input_server_key_file", e.what());
      }
    }
  } else if (!c.curve_key_file.empty() || !c.curve_authorized_keys_dir.empty() ||
             !c.curve_input_server_key_file.empty()) {
    security.Fail(root["security"].node(), "curve",
                  "keys are given but curve = false; set curve = true to use them");
  }

  // Anything reachable from other machines must be asked for (a stage network is
  // shared), and then authenticated: CURVE on the sockets, a token on HTTP.
  {
    TomlTable in = top.Table("input"), out = top.Table("output"), ctl = top.Table("control");
    const char* const ask =
        "binds a non-loopback address; set control.allow_remote = true to allow it";
    const char* const secure =
        "is reachable from other machines: set security.curve = true (mocapd keygen) to allow it";
    if (!c.allow_remote) {
      if (c.input_pattern == InputPattern::kPull && !IsLocalEndpoint(c.input_endpoint))
        in.Fail(root["input"]["endpoint"].node(), "endpoint", ask);
      if (!IsLocalEndpoint(c.output_endpoint))
        out.Fail(root["output"]["endpoint"].node(), "endpoint", ask);
      if (c.http_enabled && !IsLoopbackHost(c.http_address))
        ctl.Fail(root["control"]["http_address"].node(), "http_address",
                 "is not loopback; set control.allow_remote = true to allow it");
    }
    // A SUB input reaching out to another machine is as exposed as a bound one: a forged
    // publisher there would feed the stage.
    if (!IsLocalEndpoint(c.input_endpoint) && !c.curve)
      in.Fail(root["input"]["endpoint"].node(), "endpoint", secure);
    if (!IsLocalEndpoint(c.output_endpoint) && !c.curve)
      out.Fail(root["output"]["endpoint"].node(), "endpoint", secure);
    if (c.http_enabled && !IsLoopbackHost(c.http_address) && c.http_token.empty())
      ctl.Fail(root["control"]["http_address"].node(), "http_address",
               "is reachable from other machines: set control.http_token_file to allow it");
  }

  TomlTable frames = top.Table("frames");
  // Each rule in time (ms), or as older configs gave it, in frames at every rate; not both.
  const auto time_or_frames = [&frames](const char* ms_key, const char* frames_key, double* s,
                                        int* n, double min_ms, int min_frames, int max_frames) {
    if (frames.Has(ms_key) && frames.Has(frames_key))
      frames.Fail(frames.Find(frames_key), frames_key,
                  std::string("given as well as ") + ms_key + ": give one (" + ms_key +
                      " holds at any capture rate)");
    *s = frames.Number(ms_key, *s * 1e3, min_ms, 3'600'000.0) * 1e-3;
    *n = frames.Integer(frames_key, *n, min_frames, max_frames);
  };
  // Bridged frames are inserted at once on the data plane: at most kMaxGapFrames (also
  // checked per subject, for max_gap_ms at its rate).
  time_or_frames("max_gap_ms", "max_gap_frames", &c.max_gap_s, &c.max_gap_frames, 0.0, 0,
                 DaemonConfig::kMaxGapFrames);
  time_or_frames("restart_backjump_ms", "restart_backjump_frames", &c.restart_backjump_s,
                 &c.restart_backjump_frames, 1e-3, 1, 1'000'000);
  frames.RejectUnknown();

  CleanupOptions defaults;
  TomlTable pipeline = top.Table("pipeline");
  ReadCleanupOptions(pipeline, "pipeline", &defaults);
  TomlTable detectors = pipeline.Table("detectors");
  ReadCleanupOptions(detectors, "pipeline.detectors", &defaults);
  detectors.RejectUnknown();
  pipeline.RejectUnknown();

  RetargetOptions retarget;
  int release_frames = 0;  // as older configs gave it: in frames at each subject's rate
  {
    TomlTable r = top.Table("retarget");
    retarget.damping = r.Number("damping", retarget.damping, 0, 10);
    retarget.contact_height_m =
        r.Number("contact_height_mm", retarget.contact_height_m * 1e3, 0, 1000) * 1e-3;
    retarget.contact_speed_m_s = r.Number("contact_speed_m_s", retarget.contact_speed_m_s, 0, 100);
    if (r.Has("release_ms") && r.Has("release_frames"))
      r.Fail(r.Find("release_frames"), "release_frames",
             "given as well as release_ms: give one (release_ms holds at any capture rate)");
    retarget.release_s = r.Number("release_ms", retarget.release_s * 1e3, 1, 60'000) * 1e-3;
    release_frames = r.Integer("release_frames", 0, 1, 10000);
    retarget.points_per_bone = r.Integer("points_per_bone", retarget.points_per_bone, 1, 32);
    r.RejectUnknown();
  }

  if (!top.Has("subject"))
    top.Fail(nullptr, "subject", "no [[subject]] tables: name at least one subject to solve");
  // A subject file given as the config (its one [subject] table and its [[joint]]s) read
  // as "expected [[subject]] tables", which did not say what the file was.
  if (root["subject"].is_table() && top.Has("joint"))
    top.Fail(root["subject"].node(), "subject",
             "this is a subject file (a [subject] table and [[joint]] tables), not a daemon "
             "config: name it in a config's [[subject]] table as model = \"" +
                 std::filesystem::path(source_name).filename().string() +
                 "\" (config/mocapd.toml shows one)");
  // The files the config names, so that no live calibration writes over one: a
  // calibration_out naming the config itself replaced it with a subject file (the next
  // start failed), and one naming another subject's model or output overwrote it.
  struct NamedFile {
    std::filesystem::path path;
    std::string what;
    bool written;  // a live calibration's output
  };
  std::vector<NamedFile> named_files;
  const auto same_file = [](const std::string& path) {
    std::error_code ec;
    const std::filesystem::path p = std::filesystem::weakly_canonical(path, ec);
    return ec ? std::filesystem::path(path).lexically_normal() : p;
  };
  if (!source_name.empty())
    named_files.push_back({same_file(source_name), "the config file", false});
  // What else the config names at that path (only outputs, if written_only).
  const auto named_at = [&](const std::string& path, bool written_only) -> std::string {
    const std::filesystem::path p = same_file(path);
    for (const NamedFile& f : named_files)
      if (f.path == p && (f.written || !written_only)) return f.what;
    return {};
  };
  for (TomlTable& t : top.Tables("subject", /*required=*/true)) {
    const toml::table* table = &t.table();
    SubjectConfig s;
    s.name = t.String("name", "", true);
    // No control character either: ESC, CR or NUL went raw into the log, the topic and
    // Prometheus label values (a name could colour the operator's terminal).
    if (s.name.empty() || s.name.size() > protocol::kMaxSubjectName ||
        s.name.find_first_of("/ ") != std::string::npos ||
        std::any_of(s.name.begin(), s.name.end(),
                    [](unsigned char ch) { return ch < 0x20 || ch == 0x7f; }) ||
        HasInvisibleCodePoint(s.name))
      t.Fail(table->get("name"), "name",
             "must be 1..63 bytes (UTF-8) without '/', spaces, control or invisible "
             "characters");
    if (c.FindSubject(s.name) != nullptr ||
        std::count(c.other_shards_subjects.begin(), c.other_shards_subjects.end(), s.name) > 0)
      t.Fail(table->get("name"), "name", "subject '" + s.name + "' is listed twice");
    s.live.enabled = t.Choice("calibrate", "no", {"no", "live"}) == "live";
    s.model_path = resolve(t.String("model", ""));
    if (!s.model_path.empty()) {
      if (const std::string other = named_at(s.model_path, true); !other.empty())
        t.Fail(table->get("model"), "model",
               "'" + s.model_path + "' is " + other + ": a live calibration writes over it");
      named_files.push_back({same_file(s.model_path), "subject '" + s.name + "''s model", false});
    }
    if (!s.live.enabled && s.model_path.empty()) {
      if (t.Has("marker_set"))
        t.Fail(nullptr, "marker_set",
               "a marker_set is for a subject calibrated live: add calibrate = \"live\" (or "
               "give a model instead)");
      // Through FailMissing, so 'modle = ...' is named with its line.
      t.FailMissing("model",
                    "missing: give the subject's model file, or calibrate = \"live\" with a "
                    "marker_set");
    }
    if (s.live.enabled && !s.model_path.empty())
      t.Fail(table->get("model"), "model",
             "give a model or calibrate = \"live\", not both (a live calibration starts from "
             "the template humanoid)");
    const std::string marker_set = t.String("marker_set", "");
    if (s.live.enabled && marker_set.empty()) {
      std::string names;
      for (const MarkerSetDefinition& set : BuiltInMarkerSets())
        names += (names.empty() ? "" : ", ") + set.name;
      t.Fail(nullptr, "marker_set",
             "missing: calibrate = \"live\" needs the stream's marker set, one of " + names +
                 ", or a set file (.toml)");
    }
    std::vector<std::string> labels = t.Strings("markers");
    const std::string calibration_out = t.String("calibration_out", "");
    // At most what a live calibration keeps (LiveCalibration::kMaxKeptSeconds).
    s.live.min_seconds = t.Number("calibration_min_s", s.live.min_seconds, 1, 120);
    s.live.max_seconds = t.Number("calibration_max_s", s.live.max_seconds, 1, 36000);
    s.live.interleaved_solves =
        t.Integer("calibration_subsets", s.live.interleaved_solves, 1, kMaxInterleavedSolves);
    if (!s.live.enabled)
      for (const char* key : {"marker_set", "markers", "calibration_out", "calibration_min_s",
                              "calibration_max_s", "calibration_subsets"})
        if (t.Has(key)) t.Fail(table->get(key), key, "only for calibrate = \"live\"");
    if (s.live.max_seconds < s.live.min_seconds)
      t.Fail(table->get("calibration_max_s"), "calibration_max_s",
             "shorter than calibration_min_s");
    s.rate_hz = t.Number("rate_hz", s.rate_hz, 1, 2000);
    if (c.MaxGapFrames(s.rate_hz) > DaemonConfig::kMaxGapFrames)
      t.Fail(table->get("rate_hz"), "rate_hz",
             "frames.max_gap_ms is " + std::to_string(c.MaxGapFrames(s.rate_hz)) +
                 " frames at this rate, more than the " +
                 std::to_string(DaemonConfig::kMaxGapFrames) + " a gap may bridge");
    s.cleanup = defaults;
    s.cleanup.rate_hz = s.rate_hz;
    const CleanupOptionField& lookahead = OptionField("lookahead");
    s.cleanup.lookahead =
        t.Integer("lookahead", defaults.lookahead, static_cast<int>(lookahead.min),
                  static_cast<int>(lookahead.max));
    s.character_path = t.String("character", "");
    if (!s.character_path.empty() && std::filesystem::path(s.character_path).is_relative())
      s.character_path =
          (std::filesystem::path(base_dir) / s.character_path).lexically_normal().string();
    if (!s.character_path.empty()) {
      if (const std::string other = named_at(s.character_path, true); !other.empty())
        t.Fail(table->get("character"), "character",
               "'" + s.character_path + "' is " + other + ": a live calibration writes over it");
      named_files.push_back(
          {same_file(s.character_path), "subject '" + s.name + "''s character", false});
    }
    const std::map<std::string, std::string> joint_map = t.StringMap("character_joint_map");
    t.RejectUnknown();
    if (s.live.enabled) {
      try {
        s.live.marker_set = marker_set.ends_with(".toml") ? resolve(marker_set) : marker_set;
        s.live.set = FindMarkerSet(s.live.marker_set);
      } catch (const std::exception& e) {
        t.Fail(table->get("marker_set"), "marker_set", e.what());
      }
      if (labels.empty())
        for (const MarkerSetMarker& m : s.live.set.markers) labels.push_back(m.name);
      s.live.labels = labels;
      s.live.out_path =
          resolve(calibration_out.empty() ? s.name + ".calibrated.toml" : calibration_out);
      // Found out now, not after a minute of calibrating.
      const std::filesystem::path out_dir =
          std::filesystem::path(s.live.out_path).parent_path().empty()
              ? std::filesystem::path(".")
              : std::filesystem::path(s.live.out_path).parent_path();
      if (!std::filesystem::is_directory(out_dir))
        t.Fail(table->get("calibration_out"), "calibration_out",
               "'" + out_dir.string() +
                   "' is not a directory: the calibrated subject could not be "
                   "written there");
      if (const std::string other = named_at(s.live.out_path, false); !other.empty())
        t.Fail(table->get("calibration_out"), "calibration_out",
               "'" + s.live.out_path + "' is " + other +
                   ": the calibrated subject would be written over it");
      named_files.push_back(
          {same_file(s.live.out_path), "subject '" + s.name + "''s calibration_out", true});
      try {
        s.model = TemplateSubject(s.live.set, s.live.labels, 1.75, s.name);
      } catch (const std::exception& e) {
        t.Fail(table->get("markers"), "markers", e.what());
      }
      if (labels.size() < 3)
        t.Fail(table->get("markers"), "markers",
               "a live calibration needs at least 3 markers, " + std::to_string(labels.size()) +
                   " given");
    } else {
      try {
        s.model = ReadSubjectModel(s.model_path);
      } catch (const std::exception& e) {
        t.Fail(table->get("model"), "model", e.what());
      }
    }
    if (const std::string problem = WireProblem(*s.model.skeleton, s.model.markers.get());
        !problem.empty())
      t.Fail(table->get("model"), "model", problem);
    try {
      s.cleanup.Validate();
    } catch (const std::exception& e) {
      t.Fail(nullptr, "pipeline", e.what());
    }
    s.retarget = retarget;
    s.retarget.rate_hz = s.rate_hz;
    if (release_frames > 0) s.retarget.release_s = release_frames / s.rate_hz;
    if (!s.character_path.empty()) {
      try {
        const BvhTake character = ReadBvh(s.character_path);
        s.character =
            std::make_shared<const Skeleton>(CharacterSkeleton(character, CharacterOutput::kWire));
        s.character_map =
            MakeRetargetMap(*s.model.skeleton, {}, *s.character, character.end_sites, joint_map);
        s.character_end_sites = character.end_sites;
        s.character_joint_map = joint_map;
      } catch (const std::exception& e) {
        // The map's own mistakes (an unknown role or joint) are the joint map's field.
        const bool map_error = std::string_view(e.what()).starts_with("retarget joint map");
        t.Fail(table->get(map_error ? "character_joint_map" : "character"),
               map_error ? "character_joint_map" : "character", e.what());
      }
      if (const std::string problem = WireProblem(*s.character, nullptr); !problem.empty())
        t.Fail(table->get("character"), "character", problem);
    } else if (!joint_map.empty()) {
      t.Fail(table->get("character_joint_map"), "character_joint_map", "given without a character");
    }
    // Every subject is validated, whichever daemon solves it: the shards share one list.
    if (SubjectShard(s.name, c.shard_count) == c.shard_index)
      c.subjects.push_back(std::move(s));
    else
      c.other_shards_subjects.push_back(s.name);
  }
  top.RejectUnknown();
  return c;
}

int SubjectShard(const std::string& name, int shard_count) {
  const std::string names[] = {name};
  return static_cast<int>(protocol::NamesHash(names) % static_cast<uint64_t>(shard_count));
}

DaemonConfig LoadDaemonConfig(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open for reading");
  std::ostringstream text;
  text << in.rdbuf();
  const std::string base = std::filesystem::path(path).parent_path().string();
  return ParseDaemonConfig(text.str(), path, base.empty() ? "." : base);
}

}  // namespace mocapd
