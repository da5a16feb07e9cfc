// The scene keys, once: per key its name, type, unit, allowed values, default and meaning. The
// parser (core/scene.cpp) takes its defaults, ranges and choices from this table and refuses any
// key that is not in it; `cfddem --help`, `cfddem keys` and docs/keys.md are printed from it
// (core/scene_keys_doc.cpp).
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <variant>

namespace cfddem {

enum class KeyType { String, Integer, Number, Bool, Vec3, Bool3, Int3 };

// Where a key is listed (docs/keys.md's sections, in this order).
enum class KeySection { DomainParticles, Contacts, Partition, RunOutput, Fluid };

// The closed or open interval a number (or each element of a vector) must lie in.
struct KeyRange {
  double lo = -std::numeric_limits<double>::infinity();
  double hi = std::numeric_limits<double>::infinity();
  bool lo_open = false, hi_open = false;
  bool bounded() const { return std::isfinite(lo) || std::isfinite(hi); }
  // False for NaN and for an infinity even where the bound is infinite.
  bool contains(double v) const {
    return std::isfinite(v) && (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
  }
};

// A default the parser applies when the key is absent.
struct KeyDefault {
  enum class Kind {
    Required, // no default: the scene is refused without it (`text`: when, "" = always)
    Value,    // `value`; `text`: how the docs show it ("" = the value itself)
    SameAs,   // the resolved value of the key named in `text`
    Derived,  // computed by the parser from other keys; `text` says how
  };
  using Value = std::variant<std::monostate, double, std::int64_t, bool, std::string_view,
                             std::array<double, 3>, std::array<bool, 3>>;
  Kind kind = Kind::Required;
  Value value;
  std::string_view text;
};

struct SceneKey {
  std::string_view name;
  KeyType type;
  KeySection section;
  std::string_view unit{};                     // SI unit ("" = none)
  KeyRange range{};                            // numbers: allowed interval (unbounded = any)
  std::span<const std::string_view> choices{}; // strings: the accepted words (empty = any)
  KeyDefault fallback;
  std::string_view meaning; // Markdown, one line
};

// Every key, in the order `cfddem check`, `--help` and docs/keys.md list them.
std::span<const SceneKey> scene_keys();
// The table entry of `name`, or nullptr.
const SceneKey* find_scene_key(std::string_view name);
// Why `name` is not a key, with the nearest key when one is close ("did you mean ...").
std::string unknown_key_hint(std::string_view name);

// A value as TOML text: numbers with 17 significant digits, as `cfddem check` prints them, or
// (shortest) the shortest decimal that reads back exactly, as the docs show them.
std::string toml_text(const KeyDefault::Value& v, bool shortest = false);
// "> 0", "[0, 1]", "0..20" (integers), or "" when unbounded.
std::string range_text(const SceneKey& key);
// "must be > 0", "must be in [0, 1]": what a value outside the key's range is told.
std::string must_be(const SceneKey& key);

// The keys a restart may change; every other key must be as the checkpoint's scene had it. An
// entry ending in ".*" covers the keys it prefixes. The run's name, its end and outputs, and the
// gas drive (so that a bed settled with the gas at rest can be fluidized from its checkpoint).
// apps/checkpoint.cpp applies this rule and docs/keys.md prints it: the one list.
std::span<const std::string_view> restart_free_keys();
bool restart_may_change(std::string_view key);
// "`name`, `run.*`, ... and `fluid.bc.*`" (markdown) or without the backquotes.
std::string restart_free_keys_text(bool markdown);

} // namespace cfddem
