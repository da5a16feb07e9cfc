#include "core/scene_config.hpp"

#include <algorithm>
#include <filesystem>
#include <sstream>

#include <fmt/format.h>

#include "core/error.hpp"

namespace cfddem {

namespace {

std::vector<std::string> split_key(const std::string& key) {
  std::vector<std::string> parts;
  std::string cur;
  for (char c : key) {
    if (c == '.') {
      parts.push_back(cur);
      cur.clear();
    } else {
      cur += c;
    }
  }
  parts.push_back(cur);
  return parts;
}

std::string type_name(const toml::node& n) {
  switch (n.type()) {
  case toml::node_type::string: return "a string";
  case toml::node_type::integer: return "an integer";
  case toml::node_type::floating_point: return "a number";
  case toml::node_type::boolean: return "a boolean";
  case toml::node_type::array: return "an array";
  case toml::node_type::table: return "a table";
  default: return "a date/time";
  }
}

std::string node_text(const toml::node& n) {
  std::ostringstream os;
  if (auto* s = n.as_string()) {
    os << '"' << s->get() << '"';
  } else if (auto* f = n.as_floating_point()) {
    os << fmt::format("{:.17g}", f->get());
  } else if (auto* a = n.as_array()) {
    os << '[';
    for (std::size_t i = 0; i < a->size(); ++i) os << (i ? ", " : "") << node_text(*a->get(i));
    os << ']';
  } else {
    n.visit([&](auto&& v) { os << v; });
  }
  return os.str();
}

void flatten_into(const toml::table& t, const std::string& prefix,
                  std::vector<std::pair<std::string, std::string>>& out) {
  for (auto&& [k, v] : t) {
    std::string key = prefix.empty() ? std::string(k.str()) : prefix + "." + std::string(k.str());
    if (auto* sub = v.as_table()) {
      flatten_into(*sub, key, out);
    } else {
      out.emplace_back(key, node_text(v));
    }
  }
}

} // namespace

SceneConfig SceneConfig::from_file(const std::string& path) {
  SceneConfig c;
  c.origin_ = path;
  c.base_dir_ = std::filesystem::path(path).parent_path().string();
  try {
    c.table_ = toml::parse_file(path);
  } catch (const toml::parse_error& e) {
    const auto& src = e.source();
    throw ConfigError(fmt::format("{} line {}, column {}", path, src.begin.line, src.begin.column),
                      std::string(e.description()));
  }
  return c;
}

SceneConfig SceneConfig::from_string(std::string_view text, const std::string& origin) {
  SceneConfig c;
  c.origin_ = origin;
  try {
    c.table_ = toml::parse(text, origin);
  } catch (const toml::parse_error& e) {
    const auto& src = e.source();
    throw ConfigError(fmt::format("{} line {}, column {}", origin, src.begin.line,
                                  src.begin.column),
                      std::string(e.description()));
  }
  return c;
}

void SceneConfig::apply_override(const std::string& assignment) {
  // Spaces around the '=' as a scene file allows them ("run.end_time = 0.1", quoted on the
  // command line), not part of the key or of a bare word.
  const auto trim = [](std::string_view v) {
    const auto first = v.find_first_not_of(" \t");
    return first == std::string_view::npos
               ? std::string()
               : std::string(v.substr(first, v.find_last_not_of(" \t") - first + 1));
  };
  const auto eq = assignment.find('=');
  const std::string key = eq == std::string::npos ? std::string() : trim(assignment.substr(0, eq));
  if (key.empty())
    throw ConfigError("command line",
                      fmt::format("override '{}' is not of the form key=value", assignment));
  const std::string value = trim(std::string_view(assignment).substr(eq + 1));
  auto parts = split_key(key);
  for (const auto& p : parts)
    if (p.empty())
      throw ConfigError("command line", fmt::format("override key '{}' has an empty part", key));

  toml::table parsed;
  bool is_toml = true;
  try {
    parsed = toml::parse("v = " + value);
  } catch (const toml::parse_error&) {
    is_toml = false;
  }
  toml::table* t = &table_;
  for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
    auto* node = t->get(parts[i]);
    if (!node) {
      t->insert_or_assign(parts[i], toml::table{});
      node = t->get(parts[i]);
    }
    t = node->as_table();
    if (!t)
      throw ConfigError(key, fmt::format("override goes through '{}', which is not a table",
                                         parts[i]));
  }
  if (!overridden_.insert(key).second) {
    const auto at = std::find_if(repeated_.begin(), repeated_.end(),
                                 [&](const auto& kv) { return kv.first == key; });
    if (at == repeated_.end())
      repeated_.emplace_back(key, value);
    else
      at->second = value;
  }
  if (is_toml) {
    t->insert_or_assign(parts.back(), *parsed.get("v"));
  } else {
    t->insert_or_assign(parts.back(), value);
  }
}

const toml::node* SceneConfig::find(const std::string& key) const {
  const toml::table* t = &table_;
  auto parts = split_key(key);
  for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
    auto* n = t->get(parts[i]);
    if (!n || !n->is_table()) return nullptr;
    t = n->as_table();
  }
  return t->get(parts.back());
}

std::string SceneConfig::where(const std::string& key) const {
  const toml::node* n = find(key);
  if (n && n->source().begin.line > 0)
    return fmt::format("scene key '{}' ({} line {})", key, origin_, n->source().begin.line);
  return fmt::format("scene key '{}'", key);
}

bool SceneConfig::has(const std::string& key) const { return find(key) != nullptr; }

bool SceneConfig::holds_string(const std::string& key) const {
  const toml::node* n = find(key);
  return n != nullptr && n->is_string();
}

void SceneConfig::mark_used(const std::string& key) { used_.insert(key); }

double SceneConfig::get_double(const std::string& key, double fallback) {
  return has(key) ? require_double(key) : (used_.insert(key), fallback);
}

double SceneConfig::require_double(const std::string& key) {
  used_.insert(key);
  const toml::node* n = find(key);
  if (!n) throw ConfigError(where(key), "is required but missing");
  if (auto* f = n->as_floating_point()) return f->get();
  if (auto* i = n->as_integer()) return static_cast<double>(i->get());
  throw ConfigError(where(key),
                    fmt::format("expected a number, got {} ({})", type_name(*n), node_text(*n)));
}

std::int64_t SceneConfig::get_int(const std::string& key, std::int64_t fallback) {
  used_.insert(key);
  const toml::node* n = find(key);
  if (!n) return fallback;
  if (auto* i = n->as_integer()) return i->get();
  if (auto* f = n->as_floating_point()) {
    const double v = f->get();
    if (v == static_cast<double>(static_cast<std::int64_t>(v))) return static_cast<std::int64_t>(v);
  }
  throw ConfigError(where(key),
                    fmt::format("expected an integer, got {} ({})", type_name(*n), node_text(*n)));
}

bool SceneConfig::get_bool(const std::string& key, bool fallback) {
  used_.insert(key);
  const toml::node* n = find(key);
  if (!n) return fallback;
  if (auto* b = n->as_boolean()) return b->get();
  throw ConfigError(where(key),
                    fmt::format("expected true or false, got {} ({})", type_name(*n), node_text(*n)));
}

std::string SceneConfig::get_string(const std::string& key, const std::string& fallback) {
  used_.insert(key);
  const toml::node* n = find(key);
  if (!n) return fallback;
  if (auto* s = n->as_string()) return s->get();
  throw ConfigError(where(key),
                    fmt::format("expected a string, got {} ({})", type_name(*n), node_text(*n)));
}

std::array<double, 3> SceneConfig::require_vec3(const std::string& key) {
  if (!has(key)) {
    used_.insert(key);
    throw ConfigError(where(key), "is required but missing");
  }
  return get_vec3(key, {0, 0, 0});
}

std::array<double, 3> SceneConfig::get_vec3(const std::string& key,
                                            std::array<double, 3> fallback) {
  used_.insert(key);
  const toml::node* n = find(key);
  if (!n) return fallback;
  const toml::array* a = n->as_array();
  if (!a || a->size() != 3)
    throw ConfigError(where(key), fmt::format("expected an array of 3 numbers [x, y, z], got {}",
                                              node_text(*n)));
  std::array<double, 3> out{};
  for (std::size_t i = 0; i < 3; ++i) {
    const toml::node* e = a->get(i);
    if (auto* f = e->as_floating_point()) {
      out[i] = f->get();
    } else if (auto* in = e->as_integer()) {
      out[i] = static_cast<double>(in->get());
    } else {
      throw ConfigError(where(key), fmt::format("element {} is {}, expected a number", i,
                                                type_name(*e)));
    }
  }
  return out;
}

std::array<bool, 3> SceneConfig::get_bool3(const std::string& key, std::array<bool, 3> fallback) {
  used_.insert(key);
  const toml::node* n = find(key);
  if (!n) return fallback;
  const toml::array* a = n->as_array();
  if (!a || a->size() != 3)
    throw ConfigError(where(key), fmt::format("expected an array of 3 booleans, got {}",
                                              node_text(*n)));
  std::array<bool, 3> out{};
  for (std::size_t i = 0; i < 3; ++i) {
    const auto* b = a->get(i)->as_boolean();
    if (!b)
      throw ConfigError(where(key), fmt::format("element {} is {}, expected true or false", i,
                                                type_name(*a->get(i))));
    out[i] = b->get();
  }
  return out;
}

void SceneConfig::check_all_used() const {
  std::vector<std::pair<std::string, std::string>> leaves;
  flatten_into(table_, "", leaves);
  for (const auto& [key, value] : leaves) {
    bool used = used_.count(key) > 0;
    // A consumed prefix (a whole sub-table marked used) covers its leaves.
    for (std::size_t p = key.find('.'); !used && p != std::string::npos; p = key.find('.', p + 1))
      used = used_.count(key.substr(0, p)) > 0;
    if (!used)
      throw ConfigError(where(key), "unknown key (check the spelling; `cfddem --help` and "
                                    "docs/keys.md list the keys)");
  }
}

std::vector<std::pair<std::string, std::string>> SceneConfig::flatten() const {
  std::vector<std::pair<std::string, std::string>> out;
  flatten_into(table_, "", out);
  std::sort(out.begin(), out.end());
  return out;
}

} // namespace cfddem
