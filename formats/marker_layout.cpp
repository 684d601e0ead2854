// Humanoid segment matching and marker placement.
#include "formats/marker_layout.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include <boost/algorithm/string/case_conv.hpp>

#include "formats/toml_reader.hpp"

namespace mocapd {
namespace {

// Returns 'l', 'r' or 0, and the name with the side marker and punctuation removed.
std::pair<char, std::string> SplitSide(const std::string& original) {
  std::string name = original;
  const size_t colon = name.rfind(':');  // mixamorig:LeftArm
  if (colon != std::string::npos) name = name.substr(colon + 1);
  std::string lower = boost::algorithm::to_lower_copy(name);
  char side = 0;
  auto erase = [&](const std::string& word) {
    const size_t at = lower.find(word);
    if (at == std::string::npos) return false;
    lower.erase(at, word.size());
    return true;
  };
  if (erase("left"))
    side = 'l';
  else if (erase("right"))
    side = 'r';
  // Tokens split on punctuation: "_l", ".L", "l_" ...
  std::vector<std::string> tokens;
  std::string token;
  for (char c : lower) {
    if (std::isalnum(static_cast<unsigned char>(c))) {
      token += c;
    } else if (!token.empty()) {
      tokens.push_back(token);
      token.clear();
    }
  }
  if (!token.empty()) tokens.push_back(token);
  std::string joined;
  for (const std::string& t : tokens) {
    if (side == 0 && (t == "l" || t == "r")) {
      side = t[0];
      continue;
    }
    joined += t;
  }
  // CMU style: "LHipJoint", "RFoot": a capital L/R followed by another capital.
  if (side == 0 && name.size() > 2 && (name[0] == 'L' || name[0] == 'R') &&
      std::isupper(static_cast<unsigned char>(name[1]))) {
    side = static_cast<char>(std::tolower(name[0]));
    joined = boost::algorithm::to_lower_copy(name.substr(1));
  }
  return {side, joined};
}

bool Contains(const std::string& s, const char* word) { return s.find(word) != std::string::npos; }

// The role a joint name suggests, without side ("" if none).
std::string RoleOfName(const std::string& bare) {
  for (const char* finger :
       {"thumb", "index", "middle", "ring", "pinky", "finger", "end", "site", "twist", "roll"})
    if (Contains(bare, finger)) return "";
  if (Contains(bare, "hipjoint")) return "";
  if (Contains(bare, "forearm") || Contains(bare, "lowerarm") || Contains(bare, "elbow"))
    return "forearm";
  if (Contains(bare, "upperarm") || bare == "arm" || Contains(bare, "humerus")) return "upper_arm";
  if (Contains(bare, "shoulder") || Contains(bare, "clavicle") || Contains(bare, "collar"))
    return "clavicle";
  if (Contains(bare, "hand") || Contains(bare, "wrist")) return "hand";
  if (Contains(bare, "upleg") || Contains(bare, "upperleg") || Contains(bare, "thigh"))
    return "thigh";
  if (Contains(bare, "toe") || Contains(bare, "ball")) return "toe";
  if (Contains(bare, "foot") || Contains(bare, "ankle")) return "foot";
  if (Contains(bare, "leg") || Contains(bare, "calf") || Contains(bare, "shin") ||
      Contains(bare, "knee"))
    return "shin";
  if (Contains(bare, "head")) return "head";
  if (Contains(bare, "neck")) return "neck";
  if (Contains(bare, "hips") || Contains(bare, "pelvis")) return "pelvis";
  return "";
}

// A helper joint placed where its parent is (CMU's LowerBack, a NeckBase): it bends
// nothing a marker can see on its own, so a role goes to the real joint past it.
bool SitsOnItsParent(const Skeleton& skeleton, int joint) {
  constexpr double kZeroLengthM = 1e-3;
  return skeleton.joint(joint).parent.value >= 0 &&
         skeleton.joint(joint).offset.norm() < kZeroLengthM;
}

// Roles found by joint names alone; the first joint (closest to the root) wins, unless it
// sits on its parent and a later one does not.
std::map<std::string, int> RolesByName(const Skeleton& skeleton) {
  std::map<std::string, int> joint_of_role;
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    const auto [side, bare] = SplitSide(skeleton.joint(j).name);
    const std::string base = RoleOfName(bare);
    if (base.empty()) continue;
    const bool sided = base != "pelvis" && base != "head" && base != "neck";
    if (sided && side == 0) continue;
    const auto [it, added] = joint_of_role.emplace(sided ? base + "_" + side : base, j);
    if (!added && SitsOnItsParent(skeleton, it->second) && !SitsOnItsParent(skeleton, j))
      it->second = j;
  }
  return joint_of_role;
}

// The rest pose's extent, for nominal end-segment lengths.
double RestHeight(const KinematicsWorkspace& rest) {
  double lo = 1e300, hi = -1e300;
  for (const Vec3& p : rest.p_WJ) {
    lo = std::min(lo, p.minCoeff());
    hi = std::max(hi, p.maxCoeff());
  }
  return std::max(0.5, std::min(2.5, hi - lo));
}

}  // namespace

Vec3 SegmentBoneWorld(const Skeleton& skeleton, const HumanoidRoles& roles,
                      const KinematicsWorkspace& rest, std::span<const BvhEndSite> end_sites,
                      const std::string& role, int joint, double height, bool* is_nominal) {
  if (is_nominal != nullptr) *is_nominal = false;
  static const std::map<std::string, std::string> kNext = {
      {"clavicle", "upper_arm"}, {"upper_arm", "forearm"}, {"forearm", "hand"}, {"thigh", "shin"},
      {"shin", "foot"},          {"foot", "toe"},          {"neck", "head"}};
  const auto uj = static_cast<size_t>(joint);
  std::string base = role, side;
  if (role.size() > 2 && role[role.size() - 2] == '_') {
    base = role.substr(0, role.size() - 2);
    side = role.substr(role.size() - 2);
  }
  int next = -1;
  if (auto it = kNext.find(base); it != kNext.end()) {
    if (auto r = roles.joint_of_role.find(it->second + side); r != roles.joint_of_role.end())
      next = r->second;
  } else if (base == "pelvis" || base == "spine" || base == "chest") {
    // Up the torso: the next joint on the chain toward the neck.
    std::vector<int> chain = roles.spine_chain;
    if (auto n = roles.joint_of_role.find("neck"); n != roles.joint_of_role.end())
      chain.push_back(n->second);
    for (size_t i = 0; i < chain.size(); ++i) {
      if (base == "pelvis") {
        next = chain.empty() ? -1 : chain[0];
        break;
      }
      if (chain[i] == joint && i + 1 < chain.size()) next = chain[i + 1];
    }
  }
  if (next >= 0 && (rest.p_WJ[static_cast<size_t>(next)] - rest.p_WJ[uj]).norm() > 1e-6)
    return rest.p_WJ[static_cast<size_t>(next)] - rest.p_WJ[uj];
  for (const BvhEndSite& e : end_sites)
    if (e.parent == joint && e.offset.norm() > 1e-6) return rest.R_WJ[uj] * e.offset;
  // Zero-length end segment: continue the parent's bone with a nominal length.
  if (is_nominal != nullptr) *is_nominal = true;
  const double nominal = base == "head"   ? 0.10
                         : base == "hand" ? 0.06
                         : base == "toe"  ? 0.04
                         : base == "foot" ? 0.12
                                          : 0.08;
  const int parent = skeleton.joint(joint).parent.value;
  Vec3 dir =
      parent >= 0 ? Vec3(rest.p_WJ[uj] - rest.p_WJ[static_cast<size_t>(parent)]) : Vec3::UnitY();
  if (dir.norm() < 1e-9) dir = Vec3::UnitY();
  return dir.normalized() * nominal * height / 1.75;
}

std::vector<LayoutMarker> DefaultMarkerLayout() {
  std::vector<LayoutMarker> layout = {
      // Torso and head. Angles are around the bone; along is a fraction of its length.
      {"PEL1", "pelvis", -0.4, 20, 0.075}, {"PEL2", "pelvis", -0.2, 140, 0.07},
      {"PEL3", "pelvis", 0.3, 215, 0.065}, {"PEL4", "pelvis", 0.1, 300, 0.08},
      {"SPN1", "spine", 0.4, 95, 0.055},   {"SPN2", "spine", 0.7, 250, 0.05},
      {"CHS1", "chest", 0.3, 30, 0.07},    {"CHS2", "chest", 0.55, 160, 0.075},
      {"CHS3", "chest", 0.85, 275, 0.06},  {"NCK1", "neck", 0.4, 70, 0.045},
      {"NCK2", "neck", 0.6, 230, 0.04},    {"HED1", "head", 0.3, 10, 0.075},
      {"HED2", "head", 0.5, 105, 0.08},    {"HED3", "head", 0.8, 200, 0.07},
      {"HED4", "head", 0.6, 290, 0.065},
  };
  // Limbs: the right side is deliberately not the mirror of the left.
  for (const char* side : {"l", "r"}) {
    const bool left = side[0] == 'l';
    const std::string S = left ? "L" : "R";
    const std::string sfx = std::string("_") + side;
    const double a = left ? 0.0 : 25.0;    // angular offset of the right side
    const double d = left ? 0.0 : 0.07;    // along offset of the right side
    const double dr = left ? 0.0 : 0.004;  // radius offset of the right side
    auto add = [&](const std::string& name, const std::string& seg, double along, double angle,
                   double radius, double pw = 0.0) {
      layout.push_back({S + name, seg + sfx, along, angle + a, radius + dr, pw});
    };
    add("CLV1", "clavicle", 0.45 + d, 60, 0.045);
    add("CLV2", "clavicle", 0.75, 200, 0.04);
    add("UPA1", "upper_arm", 0.25 + d, 15, 0.05);
    add("UPA2", "upper_arm", 0.55, 135, 0.055);
    add("UPA3", "upper_arm", 0.8 - d, 250, 0.045);
    add("ELB", "forearm", 0.0, 80, 0.045, 0.5);
    add("FRM1", "forearm", 0.4 + d, 190, 0.045);
    add("FRM2", "forearm", 0.85, 310, 0.04);
    add("HND1", "hand", 0.2, 30 + 10 * d, 0.035);
    add("HND2", "hand", 0.6, 150, 0.04);
    add("HND3", "hand", 0.9 - d, 260, 0.035);
    add("THI1", "thigh", 0.3 + d, 10, 0.075);
    add("THI2", "thigh", 0.55, 130, 0.07);
    add("THI3", "thigh", 0.8, 245, 0.065);
    add("KNE", "shin", 0.0, 95, 0.055, 0.5);
    add("SHN1", "shin", 0.45 - d, 200, 0.055);
    add("SHN2", "shin", 0.8, 320, 0.05);
    add("FOT1", "foot", 0.1, 60, 0.05);
    add("FOT2", "foot", 0.5 + d, 180, 0.045);
    add("FOT3", "foot", 0.85, 300, 0.04);
    add("TOE1", "toe", 0.6, 45, 0.05);
    add("TOE2", "toe", 1.2 - d, 200, 0.045);
  }
  return layout;
}

std::vector<LayoutMarker> ReadMarkerLayout(const std::string& path) {
  const toml::table root = ReadTomlFile(path);
  TomlTable top(root, "", path);
  std::vector<LayoutMarker> layout;
  for (TomlTable& t : top.Tables("marker", /*required=*/true)) {
    LayoutMarker m;
    m.name = t.String("name", "", /*required=*/true);
    m.segment = t.String("segment", "", /*required=*/true);
    if (m.name.empty()) t.Fail(t.Find("name"), "name", "empty");
    if (m.segment.empty()) t.Fail(t.Find("segment"), "segment", "empty");
    m.along = t.Number("along", m.along, -10.0, 10.0);
    m.angle_deg = t.Number("angle_deg", m.angle_deg, -3600.0, 3600.0);
    m.radius_m = t.Number("radius_m", m.radius_m, 0.0, 0.999);
    m.parent_weight = t.Number("parent_weight", m.parent_weight, 0.0, 0.999);
    t.RejectUnknown();
    layout.push_back(m);
  }
  top.RejectUnknown();
  return layout;
}

std::string HumanoidRoles::Describe(const Skeleton& skeleton) const {
  std::string out;
  for (const auto& [role, joint] : joint_of_role)
    out += role + " -> " + skeleton.joint(joint).name + "\n";
  return out;
}

HumanoidRoles MatchHumanoidRoles(const Skeleton& skeleton) {
  HumanoidRoles roles;
  roles.joint_of_role = RolesByName(skeleton);
  if (!roles.joint_of_role.count("pelvis")) {
    for (int j = 0; j < skeleton.num_joints(); ++j) {
      if (skeleton.joint(j).type == JointType::kFree) {
        roles.joint_of_role["pelvis"] = j;
        break;
      }
    }
  }
  std::vector<std::string> missing;
  for (const char* role : {"pelvis", "head"})
    if (!roles.joint_of_role.count(role)) missing.push_back(role);
  for (const char* base : {"upper_arm", "forearm", "hand", "thigh", "shin", "foot"})
    for (const char* side : {"_l", "_r"})
      if (!roles.joint_of_role.count(std::string(base) + side))
        missing.push_back(std::string(base) + side);
  if (!missing.empty()) {
    std::string msg = "not a recognisable humanoid: no joint found for";
    for (const auto& m : missing) msg += " " + m;
    msg += " (joints:";
    for (const Joint& j : skeleton.joints()) msg += " " + j.name;
    throw std::invalid_argument(msg + ")");
  }
  // The spine chain: ancestors of the neck (or head) strictly below the pelvis.
  const int pelvis = roles.joint_of_role["pelvis"];
  const int top =
      roles.joint_of_role.count("neck") ? roles.joint_of_role["neck"] : roles.joint_of_role["head"];
  // Zero-length helpers are left out: the spine role on CMU's LowerBack (at the hips)
  // bent a retargeted character's back from the pelvis and left its real Spine untracked.
  std::vector<int> whole_chain;
  for (int j = skeleton.joint(top).parent.value; j >= 0 && j != pelvis;
       j = skeleton.joint(j).parent.value) {
    whole_chain.insert(whole_chain.begin(), j);
    if (!SitsOnItsParent(skeleton, j)) roles.spine_chain.insert(roles.spine_chain.begin(), j);
  }
  // Left with one joint where there were two, the helper stays: without it the rig has no
  // spine role and its spine markers would go unplaced.
  if (roles.spine_chain.size() < 2 && whole_chain.size() >= 2) roles.spine_chain = whole_chain;
  if (!roles.spine_chain.empty()) {
    roles.joint_of_role["chest"] = roles.spine_chain.back();
    if (roles.spine_chain.size() >= 2) roles.joint_of_role["spine"] = roles.spine_chain.front();
  }
  return roles;
}

std::vector<MarkerDefinition> PlaceMarkers(const Skeleton& skeleton, const HumanoidRoles& roles,
                                           std::span<const LayoutMarker> layout,
                                           std::span<const BvhEndSite> end_sites) {
  KinematicsWorkspace rest(skeleton);
  ForwardKinematics(skeleton, RestPose(skeleton), &rest);
  const double height = RestHeight(rest);
  std::vector<MarkerDefinition> out;
  for (const LayoutMarker& lm : layout) {
    std::string role = lm.segment;
    int joint = -1;
    if (auto it = roles.joint_of_role.find(lm.segment); it != roles.joint_of_role.end()) {
      joint = it->second;
    } else if (auto j = skeleton.FindJoint(lm.segment)) {
      joint = j->value;
      role = "";
      for (const auto& [r, jr] : roles.joint_of_role)
        if (jr == joint) role = r;
    } else {
      static const char* kOptional[] = {"neck",       "spine", "chest", "clavicle_l",
                                        "clavicle_r", "toe_l", "toe_r"};
      if (std::find(std::begin(kOptional), std::end(kOptional), lm.segment) != std::end(kOptional))
        continue;
      throw std::invalid_argument("marker '" + lm.name + "': unknown segment '" + lm.segment +
                                  "' (not a role on this skeleton or a joint name)");
    }
    const auto uj = static_cast<size_t>(joint);
    const Vec3 bone = SegmentBoneWorld(skeleton, roles, rest, end_sites, role, joint, height);
    const Vec3 axis = bone.normalized();
    // A reference direction far from the bone fixes "angle 0" around it.
    Vec3 ref = Vec3::UnitZ();
    if (std::abs(axis.dot(ref)) > 0.8) ref = Vec3::UnitX();
    const Vec3 u = axis.cross(ref).normalized();
    const Vec3 w = axis.cross(u);
    const double angle = lm.angle_deg * M_PI / 180.0;
    const Vec3 p_W =
        rest.p_WJ[uj] + lm.along * bone + lm.radius_m * (std::cos(angle) * u + std::sin(angle) * w);
    MarkerDefinition def;
    def.name = lm.name;
    const int parent = skeleton.joint(joint).parent.value;
    if (lm.parent_weight > 0.0 && parent >= 0) {
      const auto up = static_cast<size_t>(parent);
      def.num_attachments = 2;
      def.attachments[0] = {joint, 1.0 - lm.parent_weight,
                            rest.R_WJ[uj].transpose() * (p_W - rest.p_WJ[uj])};
      def.attachments[1] = {parent, lm.parent_weight,
                            rest.R_WJ[up].transpose() * (p_W - rest.p_WJ[up])};
    } else {
      def.attachments[0] = {joint, 1.0, rest.R_WJ[uj].transpose() * (p_W - rest.p_WJ[uj])};
    }
    out.push_back(def);
  }
  return out;
}

std::vector<BvhEndSite> NominalLeafEndSites(const Skeleton& skeleton) {
  KinematicsWorkspace rest(skeleton);
  ForwardKinematics(skeleton, RestPose(skeleton), &rest);
  HumanoidRoles roles;
  roles.joint_of_role = RolesByName(skeleton);
  const double height = RestHeight(rest);
  std::vector<uint8_t> has_child(static_cast<size_t>(skeleton.num_joints()), 0);
  for (const Joint& j : skeleton.joints())
    if (j.parent.is_valid()) has_child[static_cast<size_t>(j.parent.value)] = 1;
  std::vector<BvhEndSite> sites;
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    if (has_child[static_cast<size_t>(j)]) continue;
    std::string role;
    for (const auto& [r, jr] : roles.joint_of_role)
      if (jr == j) role = r;
    const Vec3 bone = SegmentBoneWorld(skeleton, roles, rest, {}, role, j, height);
    sites.push_back({j, rest.R_WJ[static_cast<size_t>(j)].transpose() * bone});
  }
  return sites;
}

}  // namespace mocapd
