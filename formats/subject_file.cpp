// TOML subject model reader and writer.
#include "formats/subject_file.hpp"

#include "formats/c3d.hpp"
#include "formats/file_paths.hpp"
#include "formats/toml_reader.hpp"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace mocapd {
namespace {

// No offset of a capture subject reaches a kilometre: past that the file is not in metres,
// and a chain of such offsets overflows to infinity in the solves.
constexpr double kMaxOffsetM = 1000.0;

// An offset field, refused beyond kMaxOffsetM.
Vec3 Offset(TomlTable& t, const std::string& key, bool required) {
  const Vec3 v = t.Vector3(key, required);
  if (!(v.cwiseAbs().maxCoeff() <= kMaxOffsetM))
    t.Fail(t.Find(key), key, "beyond 1000 m (a subject file is in metres)");
  return v;
}

// A direction or rotation's length that normalises to a unit one (NaN fails too).
bool UsableLength(double length) { return length >= 1e-9 && std::isfinite(length); }

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
  const toml::table root = ParseToml(text, source_name);
  TomlTable top(root, "", source_name);
  SubjectModel model;
  const int version = top.Integer("format_version", 0, 0, 1 << 20);
  if (version != 1)
    top.Fail(root.get("format_version"), "format_version",
             "expected 1, found " + std::to_string(version));
  TomlTable subject = top.Table("subject");
  model.name = subject.String("name", "subject");
  model.bvh_units = subject.String("bvh_units", "cm");
  try {
    (void)MetresPerUnit(model.bvh_units);
  } catch (const std::invalid_argument& e) {
    subject.Fail(subject.Find("bvh_units"), "bvh_units", e.what());
  }
  subject.RejectUnknown();
  if (top.Has("calibration")) {
    TomlTable c = top.Table("calibration");
    SubjectCalibrationRecord record;
    record.marker_set = c.String("marker_set", "");
    record.poses = c.Integer("poses", 0, 0, 1 << 30);
    record.median_residual_mm = c.Number("median_residual_mm", 0.0, 0.0, 1e6);
    c.RejectUnknown();
    model.calibration = record;
  }

  std::vector<Joint> js;
  for (TomlTable& t : top.Tables("joint", /*required=*/true)) {
    Joint j;
    j.name = t.String("name", "", /*required=*/true);
    if (j.name.empty()) t.Fail(t.Find("name"), "name", "empty");
    const std::string parent = t.String("parent", "");
    if (!parent.empty()) {
      int p = -1;
      for (size_t k = 0; k < js.size(); ++k)
        if (js[k].name == parent) p = static_cast<int>(k);
      if (p < 0)
        t.Fail(t.Find("parent"), "parent",
               "'" + parent + "' is not a joint listed before '" + j.name + "'");
      j.parent = JointIndex(p);
    }
    const std::string type = t.Choice("type", "ball", {"fixed", "hinge", "ball", "free"});
    j.type = type == "fixed"   ? JointType::kFixed
             : type == "hinge" ? JointType::kHinge
             : type == "ball"  ? JointType::kBall
                               : JointType::kFree;
    j.offset = Offset(t, "offset", /*required=*/true);
    j.hinge_axis = t.Vector3("hinge_axis", /*required=*/false, Vec3::UnitX());
    if (j.type == JointType::kHinge) {
      if (!UsableLength(j.hinge_axis.norm()))
        t.Fail(t.Find("hinge_axis"), "hinge_axis", "must be non-zero and finite in length");
      j.hinge_axis.normalize();
    }
    const std::vector<double> q = t.Numbers("rest_rotation", 4, /*required=*/false);
    if (!q.empty()) {
      j.rest_rotation = Quat(q[0], q[1], q[2], q[3]);
      if (!UsableLength(j.rest_rotation.norm()))
        t.Fail(t.Find("rest_rotation"), "rest_rotation", "must be non-zero and finite in length");
      j.rest_rotation.normalize();
    }
    if (const auto limit = t.OptionalNumber("max_angle_deg", 1e-9, 1e12))
      j.max_angle_rad = *limit * M_PI / 180.0;
    // How a markers-only calibration found this joint (recorded, not used by solves).
    const std::string method = t.String("calibration", "");
    const double uncertainty = t.Number("uncertainty_mm", kNaN, 0.0, 1e6);
    if (model.calibration) {
      model.calibration->joint_method.push_back(method);
      model.calibration->joint_uncertainty_mm.push_back(uncertainty);
    }
    t.RejectUnknown();
    js.push_back(std::move(j));
  }
  try {
    model.skeleton = std::make_shared<const Skeleton>(std::move(js));
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(source_name + ": " + e.what());
  }
  const Skeleton& sk = *model.skeleton;

  std::vector<MarkerDefinition> defs;
  for (TomlTable& t : top.Tables("marker", /*required=*/true)) {
    MarkerDefinition d;
    d.name = t.String("name", "", /*required=*/true);
    if (d.name.empty()) t.Fail(t.Find("name"), "name", "empty");
    const std::string joint = t.String("joint", "", /*required=*/true);
    const auto j = sk.FindJoint(joint);
    if (!j) t.Fail(t.Find("joint"), "joint", "unknown joint '" + joint + "'");
    d.attachments[0].joint = j->value;
    d.attachments[0].offset = Offset(t, "offset", /*required=*/true);
    const double parent_weight = t.Number("parent_weight", 0.0, 0.0, 0.999999);
    const int parent = sk.joint(d.attachments[0].joint).parent.value;
    if (parent_weight > 0.0 && parent < 0)
      t.Fail(t.Find("parent_weight"), "parent_weight",
             "the root joint has no parent to blend with");
    const Vec3 parent_offset = Offset(t, "parent_offset", /*required=*/parent_weight > 0.0);
    if (parent_weight > 0.0) {
      d.num_attachments = 2;
      d.attachments[0].weight = 1.0 - parent_weight;
      d.attachments[1] = {parent, parent_weight, parent_offset};
    }
    model.fit_rms_m.push_back(t.Number("fit_rms_mm", std::nan(""), 0.0, 1e9) * 1e-3);
    t.RejectUnknown();
    defs.push_back(d);
  }
  top.RejectUnknown();
  try {
    model.markers = std::make_shared<const MarkerSet>(sk, std::move(defs));
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(source_name + ": " + e.what());
  }
  return model;
}

SubjectModel ReadSubjectModel(const std::string& path) {
  return ParseSubjectModel(ReadWholeFile(path), path);
}

std::string FormatSubjectModel(const SubjectModel& model) {
  const Skeleton& sk = *model.skeleton;
  std::string out =
      "# mocapd subject model: a skeleton and the markers attached to it.\n"
      "# Units: metres; rotations: quaternions [w, x, y, z]. Format: config/subject.example.toml.\n"
      "format_version = 1\n\n[subject]\nname = " +
      Quoted(model.name) + "\nbvh_units = " + Quoted(model.bvh_units) + "\n";
  const SubjectCalibrationRecord* record = model.calibration ? &*model.calibration : nullptr;
  if (record != nullptr)
    out +=
        "\n# Calibrated from markers alone: per joint, how its centre was found and its\n"
        "# uncertainty (mm); per marker, its fit (mm).\n[calibration]\nmarker_set = " +
        Quoted(record->marker_set) + "\nposes = " + std::to_string(record->poses) +
        "\nmedian_residual_mm = " + Num(record->median_residual_mm) + "\n";
  for (const Joint& j : sk.joints()) {
    out += "\n[[joint]]\nname = " + Quoted(j.name) + "\n";
    out +=
        "parent = " + Quoted(j.parent.is_valid() ? sk.joint(j.parent.value).name : std::string()) +
        "\n";
    out += std::string("type = \"") + to_string(j.type) + "\"\n";
    out += "offset = " + Array({j.offset.x(), j.offset.y(), j.offset.z()}) + "\n";
    if (!j.rest_rotation.coeffs().isApprox(Quat::Identity().coeffs(), 1e-12))
      out += "rest_rotation = " +
             Array({j.rest_rotation.w(), j.rest_rotation.x(), j.rest_rotation.y(),
                    j.rest_rotation.z()}) +
             "\n";
    if (j.type == JointType::kHinge)
      out += "hinge_axis = " + Array({j.hinge_axis.x(), j.hinge_axis.y(), j.hinge_axis.z()}) + "\n";
    if (j.max_angle_rad < 1e8)
      out += "max_angle_deg = " + Num(j.max_angle_rad * 180.0 / M_PI) + "\n";
    const auto uj = static_cast<size_t>(&j - sk.joints().data());
    if (record != nullptr && uj < record->joint_method.size() && !record->joint_method[uj].empty())
      out += "calibration = " + Quoted(record->joint_method[uj]) + "\n";
    if (record != nullptr && uj < record->joint_uncertainty_mm.size() &&
        std::isfinite(record->joint_uncertainty_mm[uj]))
      out += "uncertainty_mm = " + Num(record->joint_uncertainty_mm[uj]) + "\n";
  }
  const MarkerSet& ms = *model.markers;
  for (int m = 0; m < ms.num_markers(); ++m) {
    const MarkerDefinition& d = ms.marker(m);
    const MarkerAttachment& a = d.attachments[0];
    out += "\n[[marker]]\nname = " + Quoted(d.name) +
           "\njoint = " + Quoted(sk.joint(a.joint).name) + "\n";
    out += "offset = " + Array({a.offset.x(), a.offset.y(), a.offset.z()}) + "\n";
    if (d.num_attachments == 2) {
      const MarkerAttachment& b = d.attachments[1];
      out += "parent_weight = " + Num(b.weight) + "\n";
      out += "parent_offset = " + Array({b.offset.x(), b.offset.y(), b.offset.z()}) + "\n";
    }
    if (static_cast<size_t>(m) < model.fit_rms_m.size() &&
        std::isfinite(model.fit_rms_m[static_cast<size_t>(m)]))
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
