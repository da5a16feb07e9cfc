// Scene configuration: a TOML file with dotted keys plus `key=value` command-line overrides
// (AMReX ParmParse semantics), typed getters that name the key in every error, and the
// "every key must be read" rule (amrex.abort_on_unused_inputs, always on).
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <toml++/toml.h>

namespace cfddem {

class SceneConfig {
public:
  // Parse a TOML file; throws ConfigError naming the file, line and column.
  static SceneConfig from_file(const std::string& path);
  // Parse TOML text (tests, embedded defaults). `origin` names it in errors.
  static SceneConfig from_string(std::string_view text, const std::string& origin);

  // Apply `a.b.c=value`: the value is read as TOML; a bare word that is not valid TOML is a
  // string (so dem.scheme=orb and dem.scheme='"orb"' mean the same).
  void apply_override(const std::string& assignment);

  bool has(const std::string& key) const;
  // The key is present and holds a string (a key that takes a number or a word).
  bool holds_string(const std::string& key) const;
  double get_double(const std::string& key, double fallback);
  double require_double(const std::string& key);
  std::int64_t get_int(const std::string& key, std::int64_t fallback);
  bool get_bool(const std::string& key, bool fallback);
  std::string get_string(const std::string& key, const std::string& fallback);
  std::array<double, 3> get_vec3(const std::string& key, std::array<double, 3> fallback);
  std::array<double, 3> require_vec3(const std::string& key);
  std::array<bool, 3> get_bool3(const std::string& key, std::array<bool, 3> fallback);
  // Mark a key (or a whole sub-table) as consumed without reading it through a getter.
  void mark_used(const std::string& key);

  // Throw ConfigError naming the first key that no getter asked for.
  void check_all_used() const;
  // Every leaf key with its value as TOML text, sorted (for `cfddem check` and run.json).
  std::vector<std::pair<std::string, std::string>> flatten() const;
  const std::string& origin() const { return origin_; }
  // True when the key was set by a command-line override (paths then resolve against the working
  // directory, not the scene file's folder).
  bool overridden(const std::string& key) const { return overridden_.count(key) > 0; }
  // Keys the command line set more than once, each once, in order, with the last value as typed
  // (the one that holds): legal but likely a slip, which `check` and `run` warn about.
  const std::vector<std::pair<std::string, std::string>>& repeated_overrides() const {
    return repeated_;
  }
  // The scene file's folder (empty for text scenes).
  std::string base_dir() const { return base_dir_; }
  const toml::table& table() const { return table_; }
  // Every key a getter or mark_used asked for, present or not.
  const std::set<std::string>& used() const { return used_; }
  // How an error names the key: "scene key 'k' (FILE line N)" when it came from the file.
  std::string where(const std::string& key) const;

private:
  const toml::node* find(const std::string& key) const;
  toml::table table_;
  std::string origin_;
  std::set<std::string> used_;
  std::set<std::string> overridden_;
  std::vector<std::pair<std::string, std::string>> repeated_;
  std::string base_dir_;
};

} // namespace cfddem
