// Strict TOML field reading over toml++.
#include "formats/toml_reader.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string_view>

#include <boost/algorithm/string/predicate.hpp>

#include "formats/file_paths.hpp"

namespace mocapd {
namespace {

std::string Str(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

const toml::table& EmptyTable() {
  static const toml::table empty;
  return empty;
}

}  // namespace

namespace {

// What a file that is not TOML looks like, for the error: a BVH or a C3D given where a
// subject or config goes got the parser's "expected '=', saw '\n'".
std::string NotTomlHint(const std::string& text) {
  const std::string_view head(text.data(), std::min<size_t>(text.size(), 512));
  if (head.find('\0') != std::string_view::npos)
    return " (the file is binary data, not TOML text: a C3D take?)";
  const size_t word = head.find_first_not_of(" \t\r\n\xEF\xBB\xBF");
  if (word != std::string_view::npos &&
      boost::algorithm::istarts_with(head.substr(word), "HIERARCHY"))
    return " (the file is a BVH, not TOML: a subject file is written by mocapd calibrate or "
           "mocap-sim synth --subject-out)";
  return "";
}

}  // namespace

toml::table ParseToml(const std::string& text, const std::string& source_name) {
  try {
    return toml::parse(text, source_name);
  } catch (const toml::parse_error& e) {
    throw std::runtime_error(source_name + ":" + std::to_string(e.source().begin.line) + ": " +
                             std::string(e.description()) + NotTomlHint(text));
  }
}

toml::table ReadTomlFile(const std::string& path) { return ParseToml(ReadWholeFile(path), path); }

TomlTable::TomlTable(const toml::table& table, std::string path, std::string source)
    : table_(table), path_(std::move(path)), source_(std::move(source)) {}

void TomlTable::Fail(const toml::node* node, const std::string& key,
                     const std::string& what) const {
  const auto line = node != nullptr ? node->source().begin.line : table_.source().begin.line;
  throw std::runtime_error(source_ + ":" + std::to_string(line) + ": field '" + Join(key) +
                           "': " + what);
}

namespace {

// Edits (insert, delete, replace) from one key to another, for "did you mean".
size_t EditDistance(std::string_view a, std::string_view b) {
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diagonal = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t above = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] != b[j - 1])});
      diagonal = above;
    }
  }
  return row[b.size()];
}

}  // namespace

// A required key that is missing beside one spelt nearly like it ("modle" for "model"):
// the message named the missing key alone, not the typo or its line.
void TomlTable::FailMissing(const std::string& key, const std::string& what) const {
  for (const auto& [other, node] : table_) {
    const std::string_view name = other.str();
    if (known_.count(std::string(name)) == 0 && key.size() >= 3 && EditDistance(name, key) <= 2)
      Fail(&node, key,
           what + " (is '" + std::string(name) + "' on line " +
               std::to_string(node.source().begin.line) + " meant for it?)");
  }
  Fail(nullptr, key, what);
}

const toml::node* TomlTable::Find(const std::string& key) {
  known_.insert(key);
  return table_.get(key);
}

std::optional<double> TomlTable::OptionalNumber(const std::string& key, double min, double max) {
  const toml::node* node = Find(key);
  if (node == nullptr) return std::nullopt;
  const auto v = node->value<double>();
  if (!v || !node->is_number()) Fail(node, key, "expected a number");
  if (!std::isfinite(*v) || *v < min || *v > max)
    Fail(node, key, "must be in [" + Str(min) + ", " + Str(max) + "], got " + Str(*v));
  return *v;
}

double TomlTable::Number(const std::string& key, double fallback, double min, double max) {
  return OptionalNumber(key, min, max).value_or(fallback);
}

int TomlTable::Integer(const std::string& key, int fallback, int min, int max) {
  const toml::node* node = Find(key);
  if (node == nullptr) return fallback;
  const auto v = node->value<int64_t>();
  if (!v || !node->is_integer()) Fail(node, key, "expected an integer");
  if (*v < min || *v > max)
    Fail(node, key,
         "must be in [" + std::to_string(min) + ", " + std::to_string(max) + "], got " +
             std::to_string(*v));
  return static_cast<int>(*v);
}

bool TomlTable::Bool(const std::string& key, bool fallback) {
  const toml::node* node = Find(key);
  if (node == nullptr) return fallback;
  if (!node->is_boolean()) Fail(node, key, "expected true or false");
  return *node->value<bool>();
}

std::string TomlTable::String(const std::string& key, const std::string& fallback, bool required) {
  const toml::node* node = Find(key);
  if (node == nullptr) {
    if (required) FailMissing(key, "missing");
    return fallback;
  }
  if (!node->is_string()) Fail(node, key, "expected a string");
  return *node->value<std::string>();
}

std::string TomlTable::Choice(const std::string& key, const std::string& fallback,
                              std::initializer_list<const char*> choices) {
  const std::string v = String(key, fallback);
  std::string list;
  for (const char* c : choices) {
    if (v == c) return v;
    list += (list.empty() ? "" : " | ") + std::string(c);
  }
  Fail(table_.get(key), key, "expected " + list + ", got '" + v + "'");
}

std::vector<double> TomlTable::Numbers(const std::string& key, size_t size, bool required) {
  const toml::node* node = Find(key);
  if (node == nullptr) {
    if (required) FailMissing(key, "missing");
    return {};
  }
  const toml::array* a = node->as_array();
  if (a == nullptr || a->size() != size)
    Fail(node, key, "expected an array of " + std::to_string(size) + " numbers");
  std::vector<double> out;
  for (const toml::node& x : *a) {
    const auto v = x.value<double>();
    if (!v || !x.is_number() || !std::isfinite(*v)) Fail(node, key, "expected finite numbers");
    out.push_back(*v);
  }
  return out;
}

Vec3 TomlTable::Vector3(const std::string& key, bool required, const Vec3& fallback) {
  const std::vector<double> v = Numbers(key, 3, required);
  return v.empty() ? fallback : Vec3(v[0], v[1], v[2]);
}

std::vector<std::string> TomlTable::Strings(const std::string& key) {
  const toml::node* node = Find(key);
  if (node == nullptr) return {};
  const toml::array* a = node->as_array();
  if (a == nullptr) Fail(node, key, "expected an array of strings");
  std::vector<std::string> out;
  for (const toml::node& x : *a) {
    if (!x.is_string()) Fail(&x, key, "expected an array of strings");
    out.push_back(*x.value<std::string>());
  }
  return out;
}

std::map<std::string, std::string> TomlTable::StringMap(const std::string& key) {
  const toml::node* node = Find(key);
  std::map<std::string, std::string> out;
  if (node == nullptr) return out;
  if (!node->is_table()) Fail(node, key, "expected a table of name = \"value\"");
  for (const auto& [name, value] : *node->as_table()) {
    if (!value.is_string()) Fail(&value, key + "." + std::string(name.str()), "expected a string");
    out[std::string(name.str())] = *value.value<std::string>();
  }
  return out;
}

TomlTable TomlTable::Table(const std::string& key) {
  const toml::node* node = Find(key);
  if (node != nullptr && !node->is_table()) Fail(node, key, "expected a table [" + Join(key) + "]");
  return TomlTable(node != nullptr ? *node->as_table() : EmptyTable(), Join(key), source_);
}

std::vector<TomlTable> TomlTable::Tables(const std::string& key, bool required) {
  const toml::node* node = Find(key);
  std::vector<TomlTable> out;
  if (node == nullptr) {
    if (required) FailMissing(key, "missing: expected one or more [[" + Join(key) + "]] tables");
    return out;
  }
  const toml::array* list = node->as_array();
  if (list == nullptr || (required && list->empty()))
    Fail(node, key, "expected [[" + Join(key) + "]] tables");
  for (size_t i = 0; i < list->size(); ++i) {
    const toml::table* t = (*list)[i].as_table();
    const std::string item = key + "[" + std::to_string(i) + "]";
    if (t == nullptr) Fail(&(*list)[i], item, "expected a table");
    out.emplace_back(*t, Join(item), source_);
  }
  return out;
}

void TomlTable::RejectUnknown() const {
  for (const auto& [key, node] : table_)
    if (known_.count(std::string(key.str())) == 0)
      Fail(&node, std::string(key.str()), "unknown field");
}

}  // namespace mocapd
