// Marker set files, recognition, the template humanoid and anatomical placement.
#include "formats/marker_set.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>

#include <boost/algorithm/string/case_conv.hpp>
#include <boost/algorithm/string/predicate.hpp>
#include <boost/algorithm/string/trim.hpp>

#include "formats/toml_reader.hpp"

namespace mocapd {

// Defined in the build's generated built_in_marker_sets.cpp: the files of
// config/marker_sets/ as (file name, text) pairs.
extern const std::vector<std::pair<std::string, std::string>>& BuiltInMarkerSetTexts();

namespace {

// The template at 1.75 m: each role's parent and joint offset (the joint's origin in its
// parent's frame), and the bone of its segment (to where the segment ends). Proportions
// after Winter's anthropometric tables (hip centre 0.53 H, knee 0.285 H, ankle 0.039 H,
// shoulder 0.818 H); a spine of three segments.
struct TemplateRole {
  std::string role;
  std::string parent;  // "" for the root
  Vec3 offset;
  Vec3 bone;
};
const std::vector<TemplateRole>& TemplateRoles() {
  static const std::vector<TemplateRole> roles = [] {
    std::vector<TemplateRole> r = {
        {"pelvis", "", Vec3(0, 0.93, 0), Vec3(0, 0.10, -0.02)},
        {"spine", "pelvis", Vec3(0, 0.10, -0.02), Vec3(0, 0.18, -0.01)},
        {"chest", "spine", Vec3(0, 0.18, -0.01), Vec3(0, 0.25, 0.0)},
        {"neck", "chest", Vec3(0, 0.25, 0.0), Vec3(0, 0.10, 0.02)},
        {"head", "neck", Vec3(0, 0.10, 0.02), Vec3(0, 0.20, 0.0)},
    };
    for (const char* x : {"_l", "_r"}) {
      const double s = std::string(x) == "_l" ? 1.0 : -1.0;
      auto n = [&](const char* base) { return std::string(base) + x; };
      r.push_back(
          {n("clavicle"), "chest", Vec3(s * 0.02, 0.22, 0.06), Vec3(s * 0.17, 0.02, -0.06)});
      r.push_back({n("upper_arm"), n("clavicle"), Vec3(s * 0.17, 0.02, -0.06), Vec3(0, -0.29, 0)});
      r.push_back({n("forearm"), n("upper_arm"), Vec3(0, -0.29, 0), Vec3(0, -0.26, 0)});
      r.push_back({n("hand"), n("forearm"), Vec3(0, -0.26, 0), Vec3(0, -0.10, 0)});
      r.push_back({n("thigh"), "pelvis", Vec3(s * 0.085, 0, 0), Vec3(0, -0.43, 0)});
      r.push_back({n("shin"), n("thigh"), Vec3(0, -0.43, 0), Vec3(0, -0.43, 0)});
      r.push_back({n("foot"), n("shin"), Vec3(0, -0.43, 0), Vec3(0, -0.04, 0.14)});
      r.push_back({n("toe"), n("foot"), Vec3(0, -0.04, 0.14), Vec3(0, -0.01, 0.06)});
    }
    return r;
  }();
  return roles;
}

const TemplateRole* FindTemplateRole(const std::string& role) {
  for (const TemplateRole& r : TemplateRoles())
    if (role == r.role) return &r;
  return nullptr;
}

// Each role's joint origin on the 1.75 m template, world frame.
Vec3 TemplateOrigin(const std::string& role) {
  const TemplateRole* r = FindTemplateRole(role);
  return r->parent.empty() ? r->offset : Vec3(TemplateOrigin(r->parent) + r->offset);
}

// The minimal rotation taking direction a onto direction b.
Mat3 RotationBetween(const Vec3& a, const Vec3& b) {
  return Quat::FromTwoVectors(a.normalized(), b.normalized()).toRotationMatrix();
}

bool IsBoneOutput(const std::string& bare) {
  // Plug-in Gait writes each bone's origin and axes as points: PELO, LFEA, RTIL ...
  static const char* kBones[] = {"PEL", "LFE", "RFE", "LTI", "RTI", "LFO", "RFO", "LTO",
                                 "RTO", "HED", "TRX", "LCL", "RCL", "LHU", "RHU", "LRA",
                                 "RRA", "LHN", "RHN", "LTL", "RTL", "LFT", "RFT"};
  if (bare.size() != 4) return false;
  const char axis = bare[3];
  if (axis != 'O' && axis != 'A' && axis != 'L' && axis != 'P') return false;
  for (const char* b : kBones)
    if (bare.compare(0, 3, b) == 0) return true;
  return false;
}

}  // namespace

std::optional<int> MarkerSetDefinition::Find(const std::string& label) const {
  const std::string want = BareLabel(label);
  for (size_t m = 0; m < markers.size(); ++m) {
    if (boost::algorithm::iequals(markers[m].name, want)) return static_cast<int>(m);
    for (const std::string& a : markers[m].aliases)
      if (boost::algorithm::iequals(a, want)) return static_cast<int>(m);
  }
  return std::nullopt;
}

std::string BareLabel(const std::string& label) {
  const size_t colon = label.rfind(':');
  // Padding on either side: C3D labels are padded with trailing spaces, and some
  // exporters centre them or write "Actor 1: LASI".
  return boost::algorithm::trim_copy(colon == std::string::npos ? label : label.substr(colon + 1));
}

MarkerSetDefinition ParseMarkerSet(const std::string& text, const std::string& source_name) {
  const toml::table root = ParseToml(text, source_name);
  TomlTable top(root, "", source_name);
  const int version = top.Integer("format_version", 0, 0, 1 << 20);
  if (version != 1)
    top.Fail(root.get("format_version"), "format_version",
             "expected 1, found " + std::to_string(version));
  MarkerSetDefinition set;
  set.source = source_name;
  set.name = top.String("name", "", /*required=*/true);
  set.description = top.String("description", "");
  std::set<std::string> seen;
  for (TomlTable& t : top.Tables("marker", /*required=*/true)) {
    MarkerSetMarker m;
    m.name = t.String("name", "", /*required=*/true);
    if (m.name.empty()) t.Fail(t.Find("name"), "name", "empty");
    m.aliases = t.Strings("aliases");
    m.segment = t.String("segment", "", /*required=*/true);
    if (FindTemplateRole(m.segment) == nullptr)
      t.Fail(t.Find("segment"), "segment",
             "'" + m.segment +
                 "' is not a role (pelvis, spine, chest, neck, head, and per side "
                 "_l/_r: clavicle, upper_arm, forearm, hand, thigh, shin, foot, toe)");
    m.along = t.Number("along", 0.0, -2.0, 3.0);
    m.offset_m = t.Vector3("offset_m", /*required=*/true);
    if (m.offset_m.norm() > 0.5)
      t.Fail(t.Find("offset_m"), "offset_m", "more than 0.5 m off the bone");
    m.landmark = t.String("landmark", "");
    m.optional = t.Bool("optional", false);
    t.RejectUnknown();
    for (const std::string& n : [&] {
           std::vector<std::string> all = m.aliases;
           all.push_back(m.name);
           return all;
         }()) {
      if (!seen.insert(boost::algorithm::to_lower_copy(n)).second)
        t.Fail(t.Find("name"), "name", "'" + n + "' names two markers of the set");
    }
    set.markers.push_back(std::move(m));
  }
  top.RejectUnknown();
  return set;
}

MarkerSetDefinition ReadMarkerSet(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open for reading");
  std::ostringstream text;
  text << in.rdbuf();
  return ParseMarkerSet(text.str(), path);
}

const std::vector<MarkerSetDefinition>& BuiltInMarkerSets() {
  static const std::vector<MarkerSetDefinition> sets = [] {
    std::vector<MarkerSetDefinition> out;
    for (const auto& [file, text] : BuiltInMarkerSetTexts())
      out.push_back(ParseMarkerSet(text, "config/marker_sets/" + file));
    return out;
  }();
  return sets;
}

MarkerSetDefinition FindMarkerSet(const std::string& name_or_path) {
  std::string names;
  for (const MarkerSetDefinition& s : BuiltInMarkerSets()) {
    if (s.name == name_or_path) return s;
    names += (names.empty() ? "" : ", ") + s.name;
  }
  if (name_or_path.find('/') != std::string::npos || name_or_path.ends_with(".toml"))
    return ReadMarkerSet(name_or_path);
  throw std::runtime_error("unknown marker set '" + name_or_path + "' (built in: " + names +
                           "; or give a path to a set file)");
}

const char* to_string(ChannelKind kind) {
  switch (kind) {
    case ChannelKind::kMarker: return "marker";
    case ChannelKind::kModelOutput: return "model output";
    case ChannelKind::kJointCentre: return "modelled joint centre";
    case ChannelKind::kBoneOutput: return "bone output";
    case ChannelKind::kSparse: return "sparse (valid in too few frames)";
  }
  return "?";
}

ChannelKind ClassifyChannel(const std::string& label, bool is_model_output, double valid_fraction,
                            double min_valid_fraction) {
  const std::string bare = BareLabel(label);
  const std::string lower = boost::algorithm::to_lower_copy(bare);
  if (is_model_output) return ChannelKind::kModelOutput;
  for (const char* word :
       {"angle", "force", "moment", "power", "centreofmass", "centerofmass", "com"})
    if (lower.find(word) != std::string::npos && (std::string(word) != "com" || lower.size() <= 6))
      return ChannelKind::kModelOutput;
  if (bare.size() >= 3 && bare.size() <= 6 && lower.ends_with("jc"))
    return ChannelKind::kJointCentre;
  if (IsBoneOutput(bare)) return ChannelKind::kBoneOutput;
  if (valid_fraction < min_valid_fraction) return ChannelKind::kSparse;
  return ChannelKind::kMarker;
}

MarkerSetMatch MatchMarkerSet(const MarkerSetDefinition& set, std::span<const std::string> labels) {
  MarkerSetMatch match;
  match.set = &set;
  std::vector<uint8_t> found(set.markers.size(), 0);
  for (const std::string& label : labels) {
    const auto m = set.Find(label);
    match.marker_of_label.push_back(m ? *m : -1);
    if (m && !found[static_cast<size_t>(*m)]) {
      found[static_cast<size_t>(*m)] = 1;
      ++match.matched;
    }
  }
  for (size_t m = 0; m < set.markers.size(); ++m) {
    if (set.markers[m].optional) continue;
    ++match.required;
    match.required_found += found[m];
  }
  return match;
}

namespace {
double RequiredShare(const MarkerSetMatch& m) {
  return m.required > 0 ? static_cast<double>(m.required_found) / m.required : 0.0;
}
}  // namespace

bool ExplainsLabelsBetter(const MarkerSetMatch& a, const MarkerSetMatch& b) {
  const int explained_a = a.matched - (a.required - a.required_found);
  const int explained_b = b.matched - (b.required - b.required_found);
  if (explained_a != explained_b) return explained_a > explained_b;
  const double share_a = RequiredShare(a), share_b = RequiredShare(b);
  if (std::abs(share_a - share_b) > 1e-9) return share_a > share_b;
  return a.matched > b.matched;
}

MarkerSetMatch RecognizeMarkerSet(std::span<const MarkerSetDefinition> sets,
                                  std::span<const std::string> labels) {
  MarkerSetMatch best;
  best.marker_of_label.assign(labels.size(), -1);
  for (const MarkerSetDefinition& set : sets) {
    MarkerSetMatch m = MatchMarkerSet(set, labels);
    if (RequiredShare(m) < kMarkerSetMinRequiredShare) continue;
    if (best.set == nullptr || ExplainsLabelsBetter(m, best)) best = std::move(m);
  }
  return best;
}

Skeleton MakeTemplateHumanoid(double height_m) {
  const double s = height_m / 1.75;
  std::vector<Joint> joints;
  for (const TemplateRole& r : TemplateRoles()) {
    Joint j;
    j.name = r.role;
    j.offset = r.offset * s;
    if (r.parent.empty()) {
      j.type = JointType::kFree;
    } else {
      int parent = -1;
      for (size_t k = 0; k < joints.size(); ++k)
        if (joints[k].name == r.parent) parent = static_cast<int>(k);
      j.parent = JointIndex(parent);
      j.type = JointType::kBall;
    }
    joints.push_back(std::move(j));
  }
  return Skeleton(std::move(joints));
}

Vec3 TemplateBone(const std::string& role, double height_m) {
  const TemplateRole* r = FindTemplateRole(role);
  if (r == nullptr) throw std::invalid_argument("no template role '" + role + "'");
  return r->bone * (height_m / 1.75);
}

std::vector<MarkerDefinition> PlaceMarkerSet(const Skeleton& skeleton, const HumanoidRoles& roles,
                                             const MarkerSetDefinition& set,
                                             std::span<const BvhEndSite> end_sites) {
  KinematicsWorkspace rest(skeleton);
  ForwardKinematics(skeleton, RestPose(skeleton), &rest);
  auto origin_of = [&](const char* role) {
    return rest.p_WJ[static_cast<size_t>(roles.joint_of_role.at(role))];
  };
  // The skeleton's body frame (columns: its left, up and forward), and its size against
  // the template's by leg length.
  const Vec3 pelvis = origin_of("pelvis");
  const char* top = roles.joint_of_role.count("neck") ? "neck" : "head";
  const Vec3 up = (origin_of(top) - pelvis).normalized();
  Vec3 left = origin_of("thigh_l") - origin_of("thigh_r");
  left = (left - left.dot(up) * up).normalized();
  Mat3 body;
  body << left, up, left.cross(up);
  const double legs = (origin_of("thigh_l") - origin_of("shin_l")).norm() +
                      (origin_of("shin_l") - origin_of("foot_l")).norm();
  const double scale = legs / 0.86;
  double height = 0.0;
  for (const Vec3& p : rest.p_WJ) height = std::max(height, (p - rest.p_WJ[0]).norm());
  std::vector<MarkerDefinition> out;
  for (const MarkerSetMarker& m : set.markers) {
    // The segment the marker rides, or its nearest ancestor the skeleton has.
    std::string role = m.segment;
    while (!roles.joint_of_role.count(role)) {
      const TemplateRole* r = FindTemplateRole(role);
      if (r->parent.empty())
        throw std::invalid_argument("marker '" + m.name + "': no segment for '" + m.segment + "'");
      role = r->parent;
    }
    // Where it sits on the template, relative to that segment's origin and bone.
    const Vec3 bone_c = TemplateBone(role);
    const Vec3 p_c = TemplateOrigin(m.segment) + m.along * TemplateBone(m.segment) + m.offset_m -
                     TemplateOrigin(role);
    const double f = p_c.dot(bone_c) / bone_c.squaredNorm();
    const Vec3 q = p_c - f * bone_c;
    const int joint = roles.joint_of_role.at(role);
    const auto uj = static_cast<size_t>(joint);
    const Vec3 bone_t = SegmentBoneWorld(skeleton, roles, rest, end_sites, role, joint,
                                         std::max(0.5, std::min(2.5, height)));
    const Mat3 turn = RotationBetween(body * bone_c, bone_t);
    // The pelvis's anatomical origin is the midpoint of the hip centres, wherever a
    // skeleton puts its pelvis joint (often a hand's breadth above them).
    const Vec3 origin = role == "pelvis" ? Vec3(0.5 * (origin_of("thigh_l") + origin_of("thigh_r")))
                                         : rest.p_WJ[uj];
    const Vec3 p_W = origin + f * bone_t + scale * (turn * (body * q));
    MarkerDefinition def;
    def.name = m.name;
    def.attachments[0] = {joint, 1.0, rest.R_WJ[uj].transpose() * (p_W - rest.p_WJ[uj])};
    out.push_back(def);
  }
  return out;
}

}  // namespace mocapd
