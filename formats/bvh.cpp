// BVH parser and writer.
#include "formats/bvh.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string_view>

#include <boost/algorithm/string/case_conv.hpp>
#include <boost/algorithm/string/predicate.hpp>

#include "filters/cleanup_options.hpp"
#include "filters/rotation.hpp"
#include "formats/c3d.hpp"
#include "formats/file_paths.hpp"
#include "formats/marker_layout.hpp"

namespace mocapd {
namespace {

constexpr double kDegToRad = M_PI / 180.0;

struct Token {
  std::string text;
  int line;
};

class Tokens {
 public:
  Tokens(const std::string& text, std::string source) : source_(std::move(source)) {
    int line = 1;
    size_t i = 0;
    while (i < text.size()) {
      const char c = text[i];
      if (c == '\n') {
        ++line;
        ++i;
      } else if (std::isspace(static_cast<unsigned char>(c))) {
        ++i;
      } else {
        const size_t start = i;
        while (i < text.size() && !std::isspace(static_cast<unsigned char>(text[i]))) ++i;
        std::string token = text.substr(start, i - start);
        // "Frames:480" and "Time:0.00833", as some writers print them: the keyword and
        // its number. Only before a number: a joint may be named "mixamorig:Hips".
        const size_t keyword = KeywordBeforeNumber(token);
        if (keyword > 0) {
          tokens_.push_back({token.substr(0, keyword), line});
          token.erase(0, keyword);
        }
        tokens_.push_back({std::move(token), line});
      }
    }
  }
  static size_t KeywordBeforeNumber(const std::string& token) {
    for (const char* keyword : {"Frames:", "Time:"}) {
      const size_t n = std::strlen(keyword);
      if (token.size() > n && IsKeyword(token.substr(0, n), keyword) &&
          std::string_view("0123456789.+-").find(token[n]) != std::string_view::npos)
        return n;
    }
    return 0;
  }
  bool done() const { return pos_ >= tokens_.size(); }
  size_t remaining() const { return done() ? 0 : tokens_.size() - pos_; }
  int line() const {
    return done() ? (tokens_.empty() ? 1 : tokens_.back().line) : tokens_[pos_].line;
  }
  int last_line() const { return pos_ > 0 ? tokens_[pos_ - 1].line : 0; }
  const std::string& Peek() const {
    static const std::string kEnd;
    return done() ? kEnd : tokens_[pos_].text;
  }
  // Keywords match in any case: exporters write "End site", "Hierarchy" or "FRAMES:".
  static bool IsKeyword(const std::string& token, const char* keyword) {
    return boost::algorithm::iequals(token, keyword);
  }
  bool PeekIs(const char* keyword) const { return IsKeyword(Peek(), keyword); }
  std::string Next(const char* what) {
    if (done()) Fail(std::string("unexpected end of file, expected ") + what);
    return tokens_[pos_++].text;
  }
  void Expect(const std::string& word) {
    const int at = line();
    const std::string got = Next(word.c_str());
    if (!IsKeyword(got, word.c_str())) FailAt(at, "expected '" + word + "', found " + Shown(got));
  }
  double Number(const char* what) {
    const int at = line();
    const std::string t = Next(what);
    char* end = nullptr;
    const double v = std::strtod(t.c_str(), &end);
    if (end == t.c_str() || *end != '\0' || !std::isfinite(v))
      FailAt(at, std::string("expected a number for ") + what + ", found " + Shown(t));
    return v;
  }
  // A token as an error message may quote it: a binary file (a C3D given as a BVH) must
  // not print its bytes to the terminal.
  static std::string Shown(const std::string& token) {
    const bool printable = std::all_of(token.begin(), token.end(),
                                       [](unsigned char c) { return c >= 0x20 && c < 0x7f; });
    if (!printable) return "binary data (is this a BVH file?)";
    return "'" + (token.size() > 40 ? token.substr(0, 40) + "..." : token) + "'";
  }
  [[noreturn]] void Fail(const std::string& what) const { FailAt(line(), what); }
  // At the token just read (not the next one, which may be lines further on).
  [[noreturn]] void FailAtLast(const std::string& what) const {
    FailAt(pos_ > 0 ? last_line() : line(), what);
  }
  [[noreturn]] void FailAt(int at, const std::string& what) const {
    throw BvhError(source_ + ":" + std::to_string(at) + ": " + what);
  }

 private:
  std::vector<Token> tokens_;
  size_t pos_ = 0;
  std::string source_;
};

struct RawJoint {
  std::string name;
  int parent;
  Vec3 offset;  // file units
  std::vector<BvhChannel> channels;
};

BvhChannel ParseChannel(Tokens& t) {
  const int at = t.line();
  const std::string name = boost::algorithm::to_lower_copy(t.Next("a channel name"));
  if (name == "xposition") return BvhChannel::kXposition;
  if (name == "yposition") return BvhChannel::kYposition;
  if (name == "zposition") return BvhChannel::kZposition;
  if (name == "xrotation") return BvhChannel::kXrotation;
  if (name == "yrotation") return BvhChannel::kYrotation;
  if (name == "zrotation") return BvhChannel::kZrotation;
  t.FailAt(at, "unknown channel '" + name + "'");
}

bool IsRotation(BvhChannel c) { return c >= BvhChannel::kXrotation; }
int Axis(BvhChannel c) { return static_cast<int>(c) % 3; }

void ParseJoint(Tokens& t, int parent, std::vector<RawJoint>* joints,
                std::vector<std::pair<int, Vec3>>* end_sites) {
  const int at = t.line();
  RawJoint joint{t.Next("a joint name"), parent, Vec3::Zero(), {}};
  // Names may contain spaces in some exporters; join tokens up to the brace.
  while (t.Peek() != "{" && !t.done()) joint.name += " " + t.Next("'{'");
  t.Expect("{");
  t.Expect("OFFSET");
  for (int k = 0; k < 3; ++k) joint.offset[k] = t.Number("OFFSET");
  if (t.PeekIs("CHANNELS")) {
    t.Next("CHANNELS");
    const double n = t.Number("the channel count");
    if (n < 0 || n > 6 || n != std::floor(n))
      t.FailAt(at,
               "joint '" + joint.name + "' has " + std::to_string(n) + " channels, expected 0..6");
    for (int k = 0; k < static_cast<int>(n); ++k) joint.channels.push_back(ParseChannel(t));
  }
  int rot = 0, pos = 0;
  bool seen[6] = {false, false, false, false, false, false};
  for (BvhChannel c : joint.channels) {
    if (seen[static_cast<int>(c)]) t.FailAt(at, "joint '" + joint.name + "' repeats a channel");
    seen[static_cast<int>(c)] = true;
    (IsRotation(c) ? rot : pos)++;
  }
  if ((rot != 0 && rot != 3) || (pos != 0 && pos != 3) || (rot == 0 && pos == 3))
    t.FailAt(at, "joint '" + joint.name + "' has an unsupported channel set (" +
                     std::to_string(pos) + " position, " + std::to_string(rot) +
                     " rotation); supported: 3 rotations, optionally 3 positions");
  const int index = static_cast<int>(joints->size());
  joints->push_back(std::move(joint));
  while (true) {
    const std::string word = t.Next("JOINT, End Site or '}'");
    if (word == "}") return;
    if (Tokens::IsKeyword(word, "JOINT")) {
      ParseJoint(t, index, joints, end_sites);
    } else if (Tokens::IsKeyword(word, "End")) {
      t.Expect("Site");
      t.Expect("{");
      t.Expect("OFFSET");
      Vec3 offset;
      for (int k = 0; k < 3; ++k) offset[k] = t.Number("End Site OFFSET");
      t.Expect("}");
      end_sites->push_back({index, offset});
    } else {
      t.FailAtLast("expected JOINT, End Site or '}', found " + Tokens::Shown(word));
    }
  }
}

// Guesses the length unit from the skeleton's bones, never from where it stands: the
// longest chain of bones from the root, leaving out the root's OFFSET and any bone far
// longer than the typical one (exporters write the take's start position, metres away,
// into the root's or the hips' OFFSET).
std::string GuessUnits(const std::vector<RawJoint>& joints) {
  std::vector<double> lengths;
  for (const RawJoint& j : joints)
    if (j.parent >= 0 && j.offset.norm() > 0.0) lengths.push_back(j.offset.norm());
  if (lengths.empty()) return "cm";
  std::vector<double> sorted = lengths;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<long>(sorted.size() / 2),
                   sorted.end());
  const double typical = sorted[sorted.size() / 2];
  std::vector<double> chain(joints.size(), 0.0);
  double longest = 0.0;
  for (size_t j = 0; j < joints.size(); ++j) {
    if (joints[j].parent < 0) continue;  // parents come before children
    const double bone = joints[j].offset.norm();
    chain[j] = chain[static_cast<size_t>(joints[j].parent)] + (bone <= 5.0 * typical ? bone : 0.0);
    longest = std::max(longest, chain[j]);
  }
  if (longest < 5.0) return "m";
  if (longest < 400.0) return "cm";
  return "mm";
}

Quat RotationFromChannels(const std::vector<BvhChannel>& channels, const double* values) {
  Quat q = Quat::Identity();
  for (size_t c = 0; c < channels.size(); ++c) {
    if (!IsRotation(channels[c])) continue;
    q = q * Quat(Eigen::AngleAxisd(values[c] * kDegToRad, Vec3::Unit(Axis(channels[c]))));
  }
  return q.normalized();
}

// Exporters print the frame time to a few decimals: 0.0333333 is 30 Hz, not 30.00003 Hz,
// and 0.008342 is 119.88 Hz. A whole rate, or an NTSC one (n * 1000/1001), whose frame
// time prints as the file's digits is taken as the rate meant; any other frame time is
// kept as written. Below four significant digits a frame time is taken as exact (0.03 is
// 33.3 Hz, not 33 Hz): so few digits say nothing about a rounded rate. In scientific
// notation (8.333333e-03) the digits are the mantissa's, scaled by the exponent.
double ExactFrameTime(double printed, const std::string& text) {
  if (!(printed > 0.0)) return printed;
  const size_t e = text.find_first_of("eE");
  const std::string mantissa = text.substr(0, e);
  const long exponent = e == std::string::npos ? 0 : std::strtol(text.c_str() + e + 1, nullptr, 10);
  if (exponent < -30 || exponent > 30) return printed;
  const size_t first_significant = mantissa.find_first_of("123456789");
  const auto significant_digits = static_cast<int>(std::count_if(
      mantissa.begin() + static_cast<long>(std::min(first_significant, mantissa.size())),
      mantissa.end(), [](unsigned char c) { return std::isdigit(c) != 0; }));
  if (significant_digits < 4) return printed;
  const size_t point = mantissa.find('.');
  const int decimals =
      point == std::string::npos ? 0 : static_cast<int>(mantissa.size() - point - 1);
  const double half_last_digit = 0.5 * std::pow(10.0, static_cast<double>(exponent) - decimals);
  const double rate = 1.0 / printed;
  for (const double meant : {std::round(rate), std::round(rate * 1.001) / 1.001}) {
    if (meant >= 1.0 && std::abs(1.0 / meant - printed) <= half_last_digit * (1.0 + 1e-9))
      return 1.0 / meant;
  }
  return printed;
}

}  // namespace

BvhTake ParseBvh(const std::string& text, const std::string& source_name,
                 const BvhReadOptions& options) {
  // A UTF-8 byte order mark, which some Windows editors and exporters write, is no token.
  const std::string_view bom = "\xEF\xBB\xBF";
  const bool has_bom = text.compare(0, bom.size(), bom) == 0;
  Tokens t(has_bom ? text.substr(bom.size()) : text, source_name);
  t.Expect("HIERARCHY");
  t.Expect("ROOT");
  std::vector<RawJoint> raw;
  std::vector<std::pair<int, Vec3>> raw_end_sites;
  ParseJoint(t, -1, &raw, &raw_end_sites);
  if (t.PeekIs("ROOT")) t.Fail("more than one ROOT is not supported");
  t.Expect("MOTION");
  t.Expect("Frames:");
  const double frames_d = t.Number("the frame count");
  if (frames_d < 0 || frames_d != std::floor(frames_d) || frames_d > 1e8)
    t.Fail("invalid frame count");
  const auto num_frames = static_cast<size_t>(frames_d);
  t.Expect("Frame");
  t.Expect("Time:");
  const std::string frame_time_text = t.Peek();
  const double frame_time = ExactFrameTime(t.Number("the frame time"), frame_time_text);
  if (!(frame_time > 0.0)) t.FailAtLast("frame time must be > 0");
  // A take's rate must be one the cleanup runs at (a Frame Time of 1e30 was read as
  // 1e-30 Hz, and resampling it kept one frame of 146). A single pose (a character's rest
  // pose) has no rate to speak of, so its frame time is not judged.
  if (num_frames > 1 &&
      !(frame_time >= 1.0 / kMaxCaptureRateHz && frame_time <= 1.0 / kMinCaptureRateHz)) {
    char rate[96];
    std::snprintf(rate, sizeof(rate), "frame time %.6g s is a rate of %.6g Hz, outside %g to %g Hz",
                  frame_time, 1.0 / frame_time, kMinCaptureRateHz, kMaxCaptureRateHz);
    t.FailAtLast(rate);
  }

  size_t total_channels = 0;
  for (const RawJoint& j : raw) total_channels += j.channels.size();
  // Sized by the values the file holds, not by its frame count: a count far beyond the
  // data (a header left from a longer take) is a truncated file, not gigabytes reserved
  // and a bad_alloc. The loop fails at the first frame the file does not hold.
  const size_t frames_held =
      total_channels == 0 ? num_frames : std::min(num_frames, t.remaining() / total_channels + 1);
  std::vector<double> values(frames_held * total_channels);
  // The first row that breaks one frame per line. A row a value short or long shows only
  // at the end of the file, as a truncated last frame or data after it; the row itself
  // is what the user has to find.
  std::string first_odd_row;
  for (size_t f = 0; f < num_frames; ++f) {
    // A frame that starts where the last one ended is a row short and a row long that
    // happen to add up: read on, it put values of one frame in another (markers 8 m off).
    // A frame wrapped over several lines is read, as long as each frame starts a line.
    if (f > 0 && !t.done() && t.line() == t.last_line())
      t.Fail("frame " + std::to_string(f + 1) + " of " + std::to_string(num_frames) +
             " does not start a line" + first_odd_row);
    const int row_line = t.line();
    for (size_t c = 0; c < total_channels; ++c) {
      if (t.done())
        t.Fail("frame " + std::to_string(f + 1) + " of " + std::to_string(num_frames) +
               " is truncated: expected " + std::to_string(total_channels) + " values" +
               first_odd_row);
      if (first_odd_row.empty() && t.line() != row_line)
        first_odd_row = "; frame " + std::to_string(f + 1) + " (line " + std::to_string(row_line) +
                        ") has " + std::to_string(c) + " on its line";
      values[f * total_channels + c] = t.Number("a channel value");
    }
    if (first_odd_row.empty() && !t.done() && t.line() == row_line)
      first_odd_row = "; frame " + std::to_string(f + 1) + " (line " + std::to_string(row_line) +
                      ") has more than " + std::to_string(total_channels) + " on its line";
  }
  if (!t.done())
    t.Fail("unexpected data after frame " + std::to_string(num_frames) + ": '" + t.Peek() + "'" +
           first_odd_row);

  BvhTake take;
  take.units = options.units.empty() ? GuessUnits(raw) : options.units;
  take.units_guessed = options.units.empty();
  try {
    take.metres_per_unit = MetresPerUnit(take.units);
  } catch (const std::invalid_argument& e) {
    throw BvhError(source_name + ": " + e.what());
  }
  take.frame_time_s = frame_time;
  const double s = take.metres_per_unit;

  // Which channels move over the take, per joint.
  std::vector<size_t> channel_start;
  std::vector<uint8_t> moves(raw.size(), 0), translation_moves(raw.size(), 0);
  std::vector<Vec3> constant_translation(raw.size());
  size_t first_channel = 0;
  for (size_t j = 0; j < raw.size(); ++j) {
    const RawJoint& r = raw[j];
    channel_start.push_back(first_channel);
    constant_translation[j] = r.offset;
    for (size_t c = 0; c < r.channels.size(); ++c) {
      const double v0 = num_frames > 0 ? values[first_channel + c] : 0.0;
      double lowest = v0, highest = v0;
      for (size_t f = 1; f < num_frames; ++f) {
        const double v = values[f * total_channels + first_channel + c];
        lowest = std::min(lowest, v);
        highest = std::max(highest, v);
      }
      if (IsRotation(r.channels[c])) {
        moves[j] = moves[j] || highest - lowest > 1e-9 * std::max(1.0, std::abs(v0));
        continue;
      }
      // Exporters that key every joint's translation (Blender, MotionBuilder) rebuild it
      // from float matrices, and it wobbles in the last printed digits. Read as motion,
      // every bone became stretchable, and a character retargeted through it grew arms
      // twice their length. A bone whose length varies by less than this is fixed for any
      // capture (marker noise alone is ten times more).
      constexpr double kStillTranslationM = 1e-4;
      const bool moving = (highest - lowest) * s > kStillTranslationM;
      moves[j] = moves[j] || moving;
      translation_moves[j] = translation_moves[j] || moving;
      if (num_frames > 0) constant_translation[j][Axis(r.channels[c])] = 0.5 * (lowest + highest);
    }
    first_channel += r.channels.size();
  }
  std::vector<uint8_t> below_moves(raw.size(), 0);  // some joint below moves
  for (size_t j = raw.size(); j-- > 1;)
    if (moves[j] || below_moves[j]) below_moves[static_cast<size_t>(raw[j].parent)] = 1;

  // Each joint's type. The channel list says what a joint may do; the take says which of
  // those freedoms a skeleton really uses: a bone whose translation channels never change
  // is a bone of fixed length, and a root that never moves while a joint below it
  // carries the motion (Bandai's joint_Root above Hips) is a fixed frame. A take that
  // shows no motion at all (a one-frame character T-pose) cannot say that, so there the
  // channels decide: a root with position channels may translate.
  std::vector<Joint> joints;
  for (size_t j = 0; j < raw.size(); ++j) {
    const RawJoint& r = raw[j];
    Joint joint;
    joint.name = r.name;
    joint.parent = JointIndex(r.parent);
    joint.offset = r.offset * s;
    const bool has_translation = std::any_of(r.channels.begin(), r.channels.end(),
                                             [](BvhChannel c) { return !IsRotation(c); });
    if (r.channels.empty()) {
      joint.type = JointType::kFixed;
    } else if (r.parent < 0 && !moves[j] && below_moves[j]) {
      joint.type = JointType::kFixed;
      if (num_frames > 0)
        joint.rest_rotation = RotationFromChannels(r.channels, &values[channel_start[j]]);
      joint.offset = constant_translation[j] * s;
    } else if (has_translation && (translation_moves[j] || r.parent < 0)) {
      joint.type = JointType::kFree;
    } else {
      joint.type = JointType::kBall;
      joint.offset = constant_translation[j] * s;
    }
    joints.push_back(std::move(joint));
    take.channels.push_back(r.channels);
    take.file_offsets.push_back(r.offset * s);
  }
  try {
    take.skeleton = Skeleton(std::move(joints));
  } catch (const std::invalid_argument& e) {
    throw BvhError(source_name + ": " + e.what());
  }
  for (const auto& [parent, offset] : raw_end_sites) take.end_sites.push_back({parent, offset * s});

  take.frames.reserve(num_frames);
  const Pose rest = RestPose(take.skeleton);
  for (size_t f = 0; f < num_frames; ++f) {
    Pose pose = rest;
    for (size_t j = 0; j < raw.size(); ++j) {
      const double* v = &values[f * total_channels + channel_start[j]];
      const auto& ch = raw[j].channels;
      if (ch.empty()) continue;
      pose.rotation[j] = RotationFromChannels(ch, v);
      for (size_t c = 0; c < ch.size(); ++c)
        if (!IsRotation(ch[c])) pose.translation[j][Axis(ch[c])] = v[c] * s;
    }
    take.frames.push_back(std::move(pose));
  }
  return take;
}

BvhTake ReadBvh(const std::string& path, const BvhReadOptions& options) {
  return ParseBvh(ReadWholeFile(path), path, options);
}

namespace {

// Euler angles (radians) of q for rotation axes a0, a1, a2 (all distinct), choosing of
// the two equivalent solutions the one nearest to `near` so written curves stay continuous.
Vec3 EulerNear(const Quat& q, int a0, int a1, int a2, const Vec3& near) {
  const Vec3 e = q.toRotationMatrix().eulerAngles(a0, a1, a2);
  const Vec3 alt(e[0] + M_PI, M_PI - e[1], e[2] + M_PI);
  auto wrap_near = [&](Vec3 v) {
    for (int k = 0; k < 3; ++k) v[k] = near[k] + std::remainder(v[k] - near[k], 2.0 * M_PI);
    return v;
  };
  const Vec3 a = wrap_near(e), b = wrap_near(alt);
  return (a - near).squaredNorm() <= (b - near).squaredNorm() ? a : b;
}

void AppendNumber(std::string* out, double v) {
  char buf[32];
  if (std::abs(v) < 5e-10) v = 0.0;
  std::snprintf(buf, sizeof(buf), "%.9g", v);
  out->append(buf);
}

std::vector<BvhChannel> DefaultChannels(JointType type) {
  using C = BvhChannel;
  if (type == JointType::kFree)
    return {C::kXposition, C::kYposition, C::kZposition,
            C::kZrotation, C::kXrotation, C::kYrotation};
  return {C::kZrotation, C::kXrotation, C::kYrotation};
}

const char* ChannelName(BvhChannel c) {
  switch (c) {
    case BvhChannel::kXposition: return "Xposition";
    case BvhChannel::kYposition: return "Yposition";
    case BvhChannel::kZposition: return "Zposition";
    case BvhChannel::kXrotation: return "Xrotation";
    case BvhChannel::kYrotation: return "Yrotation";
    case BvhChannel::kZrotation: return "Zrotation";
  }
  return "?";
}

}  // namespace

BvhTake MakeBvhTake(Skeleton skeleton, std::vector<Pose> frames, double frame_time_s,
                    const std::string& units) {
  BvhTake take;
  take.units = units;
  take.metres_per_unit = MetresPerUnit(units);
  take.frame_time_s = frame_time_s;
  for (const Joint& j : skeleton.joints()) {
    take.channels.push_back(DefaultChannels(j.type));
    take.file_offsets.push_back(j.offset);
  }
  take.end_sites = NominalLeafEndSites(skeleton);
  take.skeleton = std::move(skeleton);
  take.frames = std::move(frames);
  return take;
}

std::string FormatBvh(const BvhTake& take) {
  const Skeleton& sk = take.skeleton;
  const double inv = 1.0 / take.metres_per_unit;
  auto channels_of = [&](int j) {
    return static_cast<size_t>(j) < take.channels.size() ? take.channels[static_cast<size_t>(j)]
                                                         : DefaultChannels(sk.joint(j).type);
  };
  std::string out = "HIERARCHY\n";
  // Recursive emit in child order; joints are stored parents-first, but not necessarily
  // depth-first (a subject calibrated from markers lists both legs before the arms), and
  // a reader takes the MOTION columns in the order the hierarchy lists the joints.
  std::vector<int> file_order;
  file_order.reserve(static_cast<size_t>(sk.num_joints()));
  auto emit = [&](auto&& self, int j, int depth) -> void {
    file_order.push_back(j);
    const std::string indent(static_cast<size_t>(2 * depth), ' ');
    out += indent + (depth == 0 ? "ROOT " : "JOINT ") + sk.joint(j).name + "\n" + indent + "{\n";
    const Vec3 offset = static_cast<size_t>(j) < take.file_offsets.size()
                            ? take.file_offsets[static_cast<size_t>(j)]
                            : sk.joint(j).offset;
    out += indent + "  OFFSET ";
    for (int k = 0; k < 3; ++k) {
      AppendNumber(&out, offset[k] * inv);
      out += k < 2 ? " " : "\n";
    }
    const auto ch = channels_of(j);
    if (!ch.empty()) {
      out += indent + "  CHANNELS " + std::to_string(ch.size());
      for (BvhChannel c : ch) out += std::string(" ") + ChannelName(c);
      out += "\n";
    }
    for (int c : sk.children(j)) self(self, c, depth + 1);
    for (const BvhEndSite& e : take.end_sites) {
      if (e.parent != j) continue;
      out += indent + "  End Site\n" + indent + "  {\n" + indent + "    OFFSET ";
      for (int k = 0; k < 3; ++k) {
        AppendNumber(&out, e.offset[k] * inv);
        out += k < 2 ? " " : "\n";
      }
      out += indent + "  }\n";
    }
    out += indent + "}\n";
  };
  emit(emit, 0, 0);
  out += "MOTION\nFrames: " + std::to_string(take.frames.size()) + "\nFrame Time: ";
  AppendNumber(&out, take.frame_time_s);
  out += "\n";
  std::vector<Vec3> previous(static_cast<size_t>(sk.num_joints()), Vec3::Zero());
  for (const Pose& pose : take.frames) {
    bool first_value = true;
    auto put = [&](double v) {
      if (!first_value) out += ' ';
      first_value = false;
      AppendNumber(&out, v);
    };
    for (const int j : file_order) {
      const auto uj = static_cast<size_t>(j);
      const auto ch = channels_of(j);
      int axes[3], n = 0;
      for (BvhChannel c : ch)
        if (IsRotation(c)) axes[n++] = Axis(c);
      Vec3 euler = Vec3::Zero();
      if (n == 3) {
        euler = EulerNear(pose.rotation[uj], axes[0], axes[1], axes[2], previous[uj]);
        previous[uj] = euler;
      }
      const Vec3& translation = LocalTranslation(sk, pose, j);
      int r = 0;
      for (BvhChannel c : ch)
        put(IsRotation(c) ? euler[r++] / kDegToRad : translation[Axis(c)] * inv);
    }
    out += "\n";
  }
  return out;
}

void WriteBvh(const std::string& path, const BvhTake& take) {
  std::ofstream out(path, std::ios::trunc);
  if (!out) throw std::runtime_error(path + ": cannot open for writing");
  out << FormatBvh(take);
  if (!out) throw std::runtime_error(path + ": write failed");
}

}  // namespace mocapd
