// TOML subject model reader and writer.
#include "sim/subject_file.hpp"

#include "sim/c3d.hpp"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <toml++/toml.h>

namespace mocapd {
namespace {

class FieldError {
 public:
  FieldError(std::string source) : source_(std::move(source)) {}
  [[noreturn]] void Fail(const toml::node* node, const std::string& field, const std::string& what) const {
    const auto line = node != nullptr ? node->source().begin.line : 0;
    throw std::runtime_error(source_ + ":" + std::to_string(line) + ": field '" + field + "': " + what);
  }

 private:
  std::string source_;
};

Vec3 ReadVec3(const toml::table& t, const char* key, const FieldError& err, const std::string& where, bool required,
              const Vec3& fallback = Vec3::Zero()) {
  const toml::node* node = t.get(key);
  if (node == nullptr) {
    if (required) err.Fail(&t, where + "." + key, "missing");
    return fallback;
  }
  const toml::array* a = node->as_array();
  if (a == nullptr || a->size() != 3) err.Fail(node, where + "." + key, "expected an array of 3 numbers");
  Vec3 v;
  for (size_t i = 0; i < 3; ++i) {
    const auto x = (*a)[i].value<double>();
    if (!x || !std::isfinite(*x)) err.Fail(node, where + "." + key, "expected finite numbers");
    v[static_cast<int>(i)] = *x;
  }
  return v;
}

std::string Num(double v) {
  char buf[40];
  std::snprintf(buf, sizeof(buf), "%.9g", std::abs(v) < 1e-15 ? 0.0 : v);
  std::string s = buf;
  if (s.find_first_of(".en") == std::string::npos) s += ".0";
  return s;
}

// A TOML basic string: quotes and backslashes escaped, control characters dropped.
std::string Quoted(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) >= 0x20) out += c;
  }
  return out + "\"";
}

std::string Array(std::initializer_list<double> values) {
  std::string out = "[";
  bool first = true;
  for (double v : values) {
    out += (first ? "" : ", ") + Num(v);
    first = false;
  }
  return out + "]";
}

}  // namespace

SubjectModel ParseSubjectModel(const std::string& text, const std::string& source_name) {
  toml::table root;
  try {
    root = toml::parse(text, source_name);
  } catch (const toml::parse_error& e) {
    throw std::runtime_error(source_name + ":" + std::to_string(e.source().begin.line) + ": " + std::string(e.description()));
  }
  const FieldError err(source_name);
  SubjectModel model;
  const int version = root["format_version"].value_or(0);
  if (version != 1) err.Fail(root.get("format_version"), "format_version", "expected 1, found " + std::to_string(version));
  model.name = root["subject"]["name"].value_or(std::string("subject"));
  model.bvh_units = root["subject"]["bvh_units"].value_or(std::string("cm"));
  try {
    (void)MetresPerUnit(model.bvh_units);
  } catch (const std::invalid_argument& e) {
    err.Fail(root["subject"]["bvh_units"].node(), "subject.bvh_units", e.what());
  }

  const toml::array* joints = root["joint"].as_array();
  if (joints == nullptr || joints->empty()) err.Fail(&root, "joint", "expected one or more [[joint]] tables");
  std::vector<Joint> js;
  for (const toml::node& node : *joints) {
    const toml::table* t = node.as_table();
    if (t == nullptr) err.Fail(&node, "joint", "expected a table");
    const std::string where = "joint[" + std::to_string(js.size()) + "]";
    Joint j;
    const auto name = (*t)["name"].value<std::string>();
    if (!name || name->empty()) err.Fail(&node, where + ".name", "missing or empty");
    j.name = *name;
    const std::string parent = (*t)["parent"].value_or(std::string());
    if (!parent.empty()) {
      int p = -1;
      for (size_t k = 0; k < js.size(); ++k)
        if (js[k].name == parent) p = static_cast<int>(k);
      if (p < 0) err.Fail(&node, where + ".parent", "'" + parent + "' is not a joint listed before '" + j.name + "'");
      j.parent = JointIndex(p);
    }
    const std::string type = (*t)["type"].value_or(std::string("ball"));
    if (type == "fixed") j.type = JointType::kFixed;
    else if (type == "hinge") j.type = JointType::kHinge;
    else if (type == "ball") j.type = JointType::kBall;
    else if (type == "free") j.type = JointType::kFree;
    else err.Fail(&node, where + ".type", "'" + type + "' (expected fixed, hinge, ball or free)");
    j.offset = ReadVec3(*t, "offset", err, where, true);
    j.hinge_axis = ReadVec3(*t, "hinge_axis", err, where, false, Vec3::UnitX());
    if (j.type == JointType::kHinge) {
      if (j.hinge_axis.norm() < 1e-9) err.Fail(&node, where + ".hinge_axis", "must be non-zero");
      j.hinge_axis.normalize();
    }
    if (const toml::array* q = (*t)["rest_rotation"].as_array()) {
      if (q->size() != 4) err.Fail(&node, where + ".rest_rotation", "expected [w, x, y, z]");
      double c[4];
      for (size_t i = 0; i < 4; ++i) {
        const auto x = (*q)[i].value<double>();
        if (!x) err.Fail(&node, where + ".rest_rotation", "expected numbers");
        c[i] = *x;
      }
      j.rest_rotation = Quat(c[0], c[1], c[2], c[3]);
      if (j.rest_rotation.norm() < 1e-9) err.Fail(&node, where + ".rest_rotation", "must be non-zero");
      j.rest_rotation.normalize();
    }
    if (auto limit = (*t)["max_angle_deg"].value<double>()) {
      if (!(*limit > 0.0)) err.Fail(&node, where + ".max_angle_deg", "must be > 0");
      j.max_angle_rad = *limit * M_PI / 180.0;
    }
    js.push_back(std::move(j));
  }
  try {
    model.skeleton = std::make_shared<const Skeleton>(std::move(js));
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(source_name + ": " + e.what());
  }
  const Skeleton& sk = *model.skeleton;

  const toml::array* markers = root["marker"].as_array();
  if (markers == nullptr || markers->empty()) err.Fail(&root, "marker", "expected one or more [[marker]] tables");
  std::vector<MarkerDefinition> defs;
  for (const toml::node& node : *markers) {
    const toml::table* t = node.as_table();
    if (t == nullptr) err.Fail(&node, "marker", "expected a table");
    const std::string where = "marker[" + std::to_string(defs.size()) + "]";
    MarkerDefinition d;
    const auto name = (*t)["name"].value<std::string>();
    if (!name || name->empty()) err.Fail(&node, where + ".name", "missing or empty");
    d.name = *name;
    auto joint_index = [&](const char* key) {
      const auto jn = (*t)[key].value<std::string>();
      if (!jn) err.Fail(&node, where + "." + key, "missing or not a string");
      const auto j = sk.FindJoint(*jn);
      if (!j) err.Fail(&node, where + "." + key, "unknown joint '" + *jn + "'");
      return j->value;
    };
    d.attachments[0].joint = joint_index("joint");
    d.attachments[0].offset = ReadVec3(*t, "offset", err, where, true);
    const double parent_weight = (*t)["parent_weight"].value_or(0.0);
    if (!(parent_weight >= 0.0 && parent_weight < 1.0)) err.Fail(&node, where + ".parent_weight", "expected 0 <= w < 1");
    if (parent_weight > 0.0) {
      const int parent = sk.joint(d.attachments[0].joint).parent.value;
      if (parent < 0) err.Fail(&node, where + ".parent_weight", "the root joint has no parent to blend with");
      d.num_attachments = 2;
      d.attachments[0].weight = 1.0 - parent_weight;
      d.attachments[1] = {parent, parent_weight, ReadVec3(*t, "parent_offset", err, where, true)};
    }
    model.fit_rms_m.push_back((*t)["fit_rms_mm"].value_or(std::nan("")) * 1e-3);
    defs.push_back(d);
  }
  try {
    model.markers = std::make_shared<const MarkerSet>(sk, std::move(defs));
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(source_name + ": " + e.what());
  }
  return model;
}

SubjectModel ReadSubjectModel(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open for reading");
  std::stringstream ss;
  ss << in.rdbuf();
  return ParseSubjectModel(ss.str(), path);
}

std::string FormatSubjectModel(const SubjectModel& model) {
  const Skeleton& sk = *model.skeleton;
  std::string out =
      "# mocapd subject model: a skeleton and the markers attached to it.\n"
      "# Units: metres; rotations: quaternions [w, x, y, z]. Format: config/subject.example.toml.\n"
      "format_version = 1\n\n[subject]\nname = " + Quoted(model.name) + "\nbvh_units = " + Quoted(model.bvh_units) + "\n";
  for (const Joint& j : sk.joints()) {
    out += "\n[[joint]]\nname = " + Quoted(j.name) + "\n";
    out += "parent = " + Quoted(j.parent.is_valid() ? sk.joint(j.parent.value).name : std::string()) + "\n";
    out += std::string("type = \"") + to_string(j.type) + "\"\n";
    out += "offset = " + Array({j.offset.x(), j.offset.y(), j.offset.z()}) + "\n";
    if (!j.rest_rotation.coeffs().isApprox(Quat::Identity().coeffs(), 1e-12))
      out += "rest_rotation = " + Array({j.rest_rotation.w(), j.rest_rotation.x(), j.rest_rotation.y(), j.rest_rotation.z()}) + "\n";
    if (j.type == JointType::kHinge) out += "hinge_axis = " + Array({j.hinge_axis.x(), j.hinge_axis.y(), j.hinge_axis.z()}) + "\n";
    if (j.max_angle_rad < 1e8) out += "max_angle_deg = " + Num(j.max_angle_rad * 180.0 / M_PI) + "\n";
  }
  const MarkerSet& ms = *model.markers;
  for (int m = 0; m < ms.num_markers(); ++m) {
    const MarkerDefinition& d = ms.marker(m);
    const MarkerAttachment& a = d.attachments[0];
    out += "\n[[marker]]\nname = " + Quoted(d.name) + "\njoint = " + Quoted(sk.joint(a.joint).name) + "\n";
    out += "offset = " + Array({a.offset.x(), a.offset.y(), a.offset.z()}) + "\n";
    if (d.num_attachments == 2) {
      const MarkerAttachment& b = d.attachments[1];
      out += "parent_weight = " + Num(b.weight) + "\n";
      out += "parent_offset = " + Array({b.offset.x(), b.offset.y(), b.offset.z()}) + "\n";
    }
    if (static_cast<size_t>(m) < model.fit_rms_m.size() && std::isfinite(model.fit_rms_m[static_cast<size_t>(m)]))
      out += "fit_rms_mm = " + Num(model.fit_rms_m[static_cast<size_t>(m)] * 1e3) + "\n";
  }
  return out;
}

void WriteSubjectModel(const std::string& path, const SubjectModel& model) {
  std::ofstream out(path, std::ios::trunc);
  if (!out) throw std::runtime_error(path + ": cannot open for writing");
  out << FormatSubjectModel(model);
  if (!out) throw std::runtime_error(path + ": write failed");
}

}  // namespace mocapd
