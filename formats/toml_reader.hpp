// The one strict TOML reader behind every file mocapd reads (daemon config, subject
// files, marker layouts, marker sets): typed fields with bounds, and every key a reader
// did not ask for reported, so a typo or a field from another version is an error, never
// a silently kept default. Every error reads "FILE:LINE: field 'a.b': problem".
#pragma once

#include <initializer_list>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <toml++/toml.h>

#include "filters/types.hpp"

namespace mocapd {

/// Parses TOML text. Throws std::runtime_error "SOURCE:LINE: problem" on a syntax error.
toml::table ParseToml(const std::string& text, const std::string& source_name);
/// Reads and parses a file. Throws std::runtime_error naming the file if it cannot be
/// read or parsed.
toml::table ReadTomlFile(const std::string& path);

/// Reads typed fields from one table, remembering which keys it was asked for; call
/// RejectUnknown() once every field is read. The table (and the document it belongs to)
/// must outlive the reader. Every accessor throws std::runtime_error
/// "SOURCE:LINE: field 'PATH.key': problem" for a wrong type or a value out of range.
class TomlTable {
 public:
  /// path: the table's dotted name in the document ("" for the root), for messages.
  TomlTable(const toml::table& table, std::string path, std::string source);

  [[noreturn]] void Fail(const toml::node* node, const std::string& key,
                         const std::string& what) const;
  /// The node under key (nullptr when absent), marking the key as known.
  const toml::node* Find(const std::string& key);
  bool Has(const std::string& key) const { return table_.contains(key); }

  /// A number (integer or float) in [min, max]; fallback when absent.
  double Number(const std::string& key, double fallback, double min, double max);
  std::optional<double> OptionalNumber(const std::string& key, double min, double max);
  int Integer(const std::string& key, int fallback, int min, int max);
  bool Bool(const std::string& key, bool fallback);
  /// A string; required: absent is an error.
  std::string String(const std::string& key, const std::string& fallback, bool required = false);
  /// One of choices (a string); fallback when absent.
  std::string Choice(const std::string& key, const std::string& fallback,
                     std::initializer_list<const char*> choices);
  /// An array of `size` finite numbers.
  std::vector<double> Numbers(const std::string& key, size_t size, bool required);
  /// [x, y, z] of finite numbers; fallback when absent and not required.
  Vec3 Vector3(const std::string& key, bool required, const Vec3& fallback = Vec3::Zero());
  /// An array of strings (absent: empty).
  std::vector<std::string> Strings(const std::string& key);
  /// A table of key = "string" pairs with keys of the caller's choosing (absent: empty).
  std::map<std::string, std::string> StringMap(const std::string& key);

  /// A sub-table [path.key]; an absent one reads as empty (all defaults).
  TomlTable Table(const std::string& key);
  /// The [[key]] array of tables, each with path "key[i]"; absent: empty, or an error
  /// if required.
  std::vector<TomlTable> Tables(const std::string& key, bool required);

  /// Throws for the first key present that no accessor asked for.
  void RejectUnknown() const;
  /// A required key that is missing: names a key spelt nearly like it, and its line.
  [[noreturn]] void FailMissing(const std::string& key, const std::string& what) const;

  const std::string& source() const { return source_; }
  const std::string& path() const { return path_; }
  const toml::table& table() const { return table_; }

 private:
  std::string Join(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }
  const toml::table& table_;
  std::string path_;
  std::string source_;
  std::set<std::string> known_;
};

}  // namespace mocapd
