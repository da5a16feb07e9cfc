// The key table (core/scene_keys.cpp) against the parser that reads it and the docs printed from
// it: the parser reads every key of the table and no other, applies the table's defaults, refuses
// exactly the values outside the table's ranges and words, and docs/keys.md is what the table
// prints.
#include <cmath>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "core/error.hpp"
#include "core/scene.hpp"
#include "core/scene_config.hpp"
#include "core/scene_keys.hpp"
#include "core/scene_keys_doc.hpp"

using namespace cfddem;

namespace {

using Lines = std::vector<std::pair<std::string, std::string>>;

// The required keys only, a gas included: every other key takes its default.
const Lines kRequired = {
    {"domain.lo", "[0.0, 0.0, 0.0]"}, {"domain.hi", "[1.0e-3, 1.0e-3, 1.0e-3]"},
    {"particles.diameter", "1.0e-4"}, {"particles.density", "1000.0"},
    {"dem.spring_constant", "10.0"},  {"dem.restitution", "0.8"},
    {"run.end_time", "1.0e-3"},       {"fluid.cells", "[2, 2, 2]"},
    {"fluid.density", "1.0"},         {"fluid.viscosity", "1.0e-5"}};

Lines with(const Lines& lines, const std::string& key, const std::string& value) {
  Lines out = lines;
  for (auto& [k, v] : out)
    if (k == key)
      v = value;
  return out;
}

// Diameters from a distribution instead of one size.
const Lines kNormal = with(kRequired, "particles.diameter",
                           "{ distribution = \"normal\", mean = 1.0e-4, std = 1.0e-5, min = "
                           "8.0e-5, max = 1.2e-4 }");
const Lines kUniform = with(kRequired, "particles.diameter",
                            "{ distribution = \"uniform\", min = 8.0e-5, max = 1.2e-4 }");

// Particles from a file: no generator keys, no gas.
Lines file_scene() {
  Lines lines;
  for (const auto& line : kRequired)
    if (line.first.rfind("particles.", 0) != 0 && line.first.rfind("fluid.", 0) != 0)
      lines.push_back(line);
  lines.emplace_back("particles.file", "\"particles.csv\"");
  return lines;
}

// An inviscid gas (fluid.viscosity = 0, the key's bound) takes only a drag law that is finite at
// mu = 0 (core/scene.cpp).
const Lines kWenYu = [] {
  Lines lines = kRequired;
  lines.emplace_back("fluid.drag", "\"wen_yu\"");
  return lines;
}();

// A cylindrical column (domain.shape = "cylinder"): particles only, its cross axes walled.
const Lines kCylinder = [] {
  Lines lines;
  for (const auto& line : kRequired)
    if (line.first.rfind("fluid.", 0) != 0)
      lines.push_back(line);
  lines.emplace_back("domain.shape", "\"cylinder\"");
  lines.emplace_back("domain.periodic", "[false, true, false]");
  return lines;
}();

// An inlet (its keys are refused without one).
const Lines kInlet = [] {
  Lines lines = kRequired;
  lines.emplace_back("inlet.mass_rate", "1.0e-6");
  lines.emplace_back("inlet.region_lo", "[0.0, 0.0, 0.0]");
  lines.emplace_back("inlet.region_hi", "[1.0e-3, 2.0e-4, 1.0e-3]");
  return lines;
}();

// An inlet with a size distribution of its own (the inlet.diameter.* keys).
const Lines kInletNormal = [] {
  Lines lines = kInlet;
  lines.emplace_back("inlet.diameter", "{ distribution = \"normal\", mean = 1.0e-4, std = 1.0e-5, "
                                       "min = 8.0e-5, max = 1.2e-4 }");
  return lines;
}();
const Lines kInletUniform = [] {
  Lines lines = kInlet;
  lines.emplace_back("inlet.diameter", "{ distribution = \"uniform\", min = 8.0e-5, max = 1.2e-4 }");
  return lines;
}();

// The scene a key's value is tried in: the distribution's keys need a distribution.
// The method of lines, whose keys the Godunov step (the default) refuses.
const Lines kMethodOfLines = [] {
  Lines lines = kRequired;
  lines.emplace_back("fluid.advection", "\"mol\"");
  return lines;
}();

const Lines& scene_for(const std::string& key, std::string_view value) {
  if (key == "fluid.viscosity")
    return kWenYu;
  if (key == "fluid.time_order" || key == "fluid.projections")
    return kMethodOfLines;
  if (key.rfind("domain.shape", 0) == 0 || key.rfind("domain.cylinder_", 0) == 0)
    return kCylinder;
  if (key.rfind("inlet.diameter.", 0) == 0)
    return value == "uniform" ? kInletUniform : kInletNormal;
  if (key.rfind("inlet.", 0) == 0)
    return kInlet;
  if (key.rfind("particles.diameter.", 0) != 0)
    return kRequired;
  return value == "uniform" ? kUniform : kNormal;
}

std::string toml(const Lines& lines) {
  std::string text;
  for (const auto& [k, v] : lines)
    text += fmt::format("{} = {}\n", k, v);
  return text;
}

struct Parsed {
  Scene scene;
  std::set<std::string> used;
};

Parsed parse(const Lines& lines, const std::vector<std::string>& overrides = {}) {
  auto c = SceneConfig::from_string(toml(lines), "keys.toml");
  for (const auto& o : overrides)
    c.apply_override(o);
  Parsed p{read_scene(c, "keys"), {}};
  p.used = c.used();
  return p;
}

// The ConfigError message, or "" when the scene loads.
std::string error_of(const Lines& lines, const std::vector<std::string>& overrides = {}) {
  try {
    parse(lines, overrides);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

std::map<std::string, std::string> described(const Scene& s) {
  std::map<std::string, std::string> m;
  for (const auto& [k, v] : describe_scene(s))
    m[k] = v;
  return m;
}

std::string number_toml(double v) {
  return fmt::format("{:.17g}", v);
}

// A value of the key's type with every element v, as TOML (fluid.cells: [v, 2, 2], so that the
// total stays small).
std::string value_toml(const SceneKey& k, double v) {
  switch (k.type) {
  case KeyType::Integer:
    return fmt::format("{}", static_cast<long long>(v));
  case KeyType::Int3:
    return fmt::format("[{}, 2, 2]", static_cast<long long>(v));
  case KeyType::Vec3:
    return fmt::format("[{0}, {0}, {0}]", number_toml(v));
  default:
    return number_toml(v);
  }
}

bool whole(const SceneKey& k) {
  return k.type == KeyType::Integer || k.type == KeyType::Int3;
}

// The nearest value below (above) a closed bound: the next double, or the next integer.
double just_below(const SceneKey& k, double bound) {
  return whole(k) ? bound - 1 : std::nextafter(bound, -INFINITY);
}
double just_above(const SceneKey& k, double bound) {
  return whole(k) ? bound + 1 : std::nextafter(bound, INFINITY);
}

std::string read_file(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

} // namespace

TEST(SceneKeys, TableIsConsistent) {
  std::set<std::string_view> names;
  for (const SceneKey& k : scene_keys()) {
    EXPECT_TRUE(names.insert(k.name).second) << "listed twice: " << k.name;
    EXPECT_FALSE(k.meaning.empty()) << k.name;
    EXPECT_TRUE(k.choices.empty() || k.type == KeyType::String) << k.name;
    EXPECT_TRUE(!k.range.bounded() || k.type == KeyType::Number || k.type == KeyType::Vec3 ||
                whole(k))
        << k.name;
    const KeyDefault& d = k.fallback;
    if (d.kind == KeyDefault::Kind::SameAs) {
      const SceneKey* other = find_scene_key(d.text);
      ASSERT_NE(other, nullptr) << k.name << " defaults to an unknown key " << d.text;
      EXPECT_EQ(other->type, k.type) << k.name;
    }
    if (d.kind != KeyDefault::Kind::Value) {
      EXPECT_TRUE(std::holds_alternative<std::monostate>(d.value)) << k.name;
      continue;
    }
    // A default the parser applies must be of the key's type and allowed by the key itself.
    switch (k.type) {
    case KeyType::Number: {
      const double* v = std::get_if<double>(&d.value);
      ASSERT_NE(v, nullptr) << k.name;
      EXPECT_TRUE(!k.range.bounded() || k.range.contains(*v)) << k.name;
      break;
    }
    case KeyType::Integer: {
      const std::int64_t* v = std::get_if<std::int64_t>(&d.value);
      ASSERT_NE(v, nullptr) << k.name;
      EXPECT_TRUE(!k.range.bounded() || k.range.contains(static_cast<double>(*v))) << k.name;
      break;
    }
    case KeyType::String: {
      const std::string_view* v = std::get_if<std::string_view>(&d.value);
      ASSERT_NE(v, nullptr) << k.name;
      EXPECT_TRUE(k.choices.empty() ||
                  std::find(k.choices.begin(), k.choices.end(), *v) != k.choices.end())
          << k.name;
      break;
    }
    case KeyType::Bool:
      EXPECT_TRUE(std::holds_alternative<bool>(d.value)) << k.name;
      break;
    case KeyType::Vec3: {
      const auto* v = std::get_if<std::array<double, 3>>(&d.value);
      ASSERT_NE(v, nullptr) << k.name;
      for (double x : *v)
        EXPECT_TRUE(!k.range.bounded() || k.range.contains(x)) << k.name;
      break;
    }
    case KeyType::Bool3:
      EXPECT_TRUE((std::holds_alternative<std::array<bool, 3>>(d.value))) << k.name;
      break;
    case KeyType::Int3:
      ADD_FAILURE() << k.name << ": no Int3 default is supported";
      break;
    }
  }
}

// Every key the parser reads is in the table, and every key of the table is read by the parser
// (the generator and gas keys in one scene, a diameter distribution in another, particles.file
// in a third).
TEST(SceneKeys, ParserReadsExactlyTheTable) {
  std::set<std::string> read;
  for (const Lines& scene : {kRequired, kNormal, file_scene(), kInletNormal}) {
    const std::set<std::string> used = parse(scene).used;
    read.insert(used.begin(), used.end());
  }

  std::set<std::string> table;
  for (const SceneKey& k : scene_keys())
    table.insert(std::string(k.name));
  for (const std::string& k : read)
    EXPECT_TRUE(table.count(k)) << "read but not in the table: " << k;
  for (const std::string& k : table)
    EXPECT_TRUE(read.count(k)) << "in the table, never read: " << k;
  EXPECT_EQ(table.size(), scene_keys().size());
}

// A scene of required keys only: every key with a default in the table resolves to it, as
// `cfddem check` prints it; a SameAs default takes the other key's value; the derived ones are
// computed as the table says.
TEST(SceneKeys, DefaultsAreTheOnesTheParserApplies) {
  const auto resolved = described(parse(kRequired).scene);
  int compared = 0;
  // domain.shape and the cylinder's keys are listed for a cylinder only (core/scene.cpp).
  const auto cylinder = described(parse(kCylinder).scene);
  const auto inlet = described(parse(kInlet).scene);
  for (const SceneKey& k : scene_keys()) {
    if (k.fallback.kind != KeyDefault::Kind::Value || k.name == "particles.file")
      continue;
    if (k.name == "domain.cylinder_axis") {
      EXPECT_EQ(cylinder.at(std::string(k.name)), toml_text(k.fallback.value)) << k.name;
      continue;
    }
    if (k.name == "domain.shape") {
      EXPECT_FALSE(resolved.count(std::string(k.name))) << "a box lists " << k.name;
      continue;
    }
    // The inlet's keys are listed with an inlet only (kInlet sets its mass rate).
    if (k.name.starts_with("inlet.")) {
      EXPECT_FALSE(resolved.count(std::string(k.name))) << "no inlet, yet it lists " << k.name;
      if (k.name != "inlet.mass_rate") {
        EXPECT_EQ(inlet.at(std::string(k.name)), toml_text(k.fallback.value)) << k.name;
      }
      continue;
    }
    ASSERT_TRUE(resolved.count(std::string(k.name))) << "cfddem check omits " << k.name;
    EXPECT_EQ(resolved.at(std::string(k.name)), toml_text(k.fallback.value)) << k.name;
    ++compared;
  }
  EXPECT_GT(compared, 40);
  EXPECT_EQ(parse(kRequired).scene.particles.file, "");

  // Other keys' values that differ from their own defaults, so that "same as" is seen.
  const auto same = described(
      parse(kRequired, {"dem.friction=0.3", "dem.spring_constant=12.5", "dem.restitution=0.65"})
          .scene);
  for (const SceneKey& k : scene_keys()) {
    if (k.fallback.kind != KeyDefault::Kind::SameAs)
      continue;
    EXPECT_EQ(same.at(std::string(k.name)), same.at(std::string(k.fallback.text))) << k.name;
  }
  EXPECT_EQ(same.at("dem.wall_friction"), "0.29999999999999999");

  // The derived defaults, as the table describes them.
  const Scene s = parse(kRequired, {"domain.periodic=[true, false, true]"}).scene;
  EXPECT_EQ(s.name, "keys"); // the default name passed in (the scene file's stem)
  EXPECT_EQ(s.output.interval, s.run.end_time / 100.0);
  EXPECT_EQ(s.particles.region_lo, s.domain.lo);
  EXPECT_EQ(s.particles.region_hi, s.domain.hi);
  EXPECT_EQ(s.dem.neighbor_skin, -1.0); // resolved later from the diameters
  EXPECT_EQ(described(s).at("dem.neighbor_skin"), "\"auto\"");
  const std::array<std::string, 6> bc = {"periodic", "periodic", "wall",
                                         "wall",     "periodic", "periodic"};
  EXPECT_EQ(s.fluid.bc, bc);
}

// The member initializers of Scene (core/scene.hpp), which code that builds a Scene by hand
// gets, are the table's defaults too.
TEST(SceneKeys, SceneMemberDefaultsAreTheTables) {
  Scene s;
  s.fluid.enabled = true; // lists the gas keys
  const auto members = described(s);
  int compared = 0;
  for (const SceneKey& k : scene_keys()) {
    if (k.fallback.kind != KeyDefault::Kind::Value || !members.count(std::string(k.name)))
      continue;
    EXPECT_EQ(members.at(std::string(k.name)), toml_text(k.fallback.value)) << k.name;
    ++compared;
  }
  EXPECT_GT(compared, 40);
}

TEST(SceneKeys, RequiredKeysAreRequired) {
  for (const auto& [key, value] : kRequired) {
    const SceneKey* k = find_scene_key(key);
    ASSERT_NE(k, nullptr) << key;
    EXPECT_EQ(k->fallback.kind, KeyDefault::Kind::Required) << key;
    Lines without;
    for (const auto& line : kRequired)
      if (line.first != key)
        without.push_back(line);
    const std::string e = error_of(without);
    EXPECT_NE(e.find(fmt::format("'{}'", key)), std::string::npos) << key << ": " << e;
    EXPECT_NE(e.find("required"), std::string::npos) << key << ": " << e;
  }
  // A key the table calls required without a condition is in the scene above.
  for (const SceneKey& k : scene_keys())
    if (k.fallback.kind == KeyDefault::Kind::Required && k.fallback.text.empty()) {
      EXPECT_TRUE(std::any_of(kRequired.begin(), kRequired.end(), [&](const auto& line) {
        return line.first == k.name;
      })) << k.name;
    }
  // A distribution's conditions: mean and std for normal (not uniform), min and max for both.
  const auto distribution_error = [](const std::string& table) {
    return error_of(with(kRequired, "particles.diameter", table));
  };
  EXPECT_NE(
      distribution_error("{ distribution = \"normal\", std = 1e-5, min = 8e-5, max = 1.2e-4 }")
          .find("'particles.diameter.mean': is required but missing"),
      std::string::npos);
  EXPECT_NE(
      distribution_error("{ distribution = \"lognormal\", mean = 1e-4, min = 8e-5, max = 1.2e-4 }")
          .find("'particles.diameter.std': is required but missing"),
      std::string::npos);
  EXPECT_NE(distribution_error("{ distribution = \"uniform\", max = 1.2e-4 }")
                .find("'particles.diameter.min': is required but missing"),
            std::string::npos);
  EXPECT_NE(
      distribution_error("{ distribution = \"uniform\", std = 1e-5, min = 8e-5, max = 1.2e-4 }")
          .find("'particles.diameter.std': a uniform distribution takes only min and max"),
      std::string::npos);
}

// Each finite bound of each range is where the parser draws the line: the next value outside is
// refused with the key named, a closed bound itself is accepted.
TEST(SceneKeys, RangesAreTheParsersRanges) {
  int bounds = 0;
  for (const SceneKey& k : scene_keys()) {
    if (!k.range.bounded())
      continue;
    const std::string name(k.name);
    const auto refused = [&](double v) {
      const std::string e =
          error_of(scene_for(name, ""), {fmt::format("{}={}", name, value_toml(k, v))});
      EXPECT_NE(e.find(fmt::format("'{}'", name)), std::string::npos)
          << name << " = " << value_toml(k, v) << ": " << e;
    };
    const auto accepted = [&](double v) {
      EXPECT_EQ(error_of(scene_for(name, ""), {fmt::format("{}={}", name, value_toml(k, v))}), "")
          << name << " = " << value_toml(k, v);
    };
    // A closed bound is accepted and the next value past it refused; an open bound is refused.
    const auto line = [&](double bound, bool open, double past) {
      if (!std::isfinite(bound))
        return;
      ++bounds;
      refused(open ? bound : past);
      if (!open)
        accepted(bound);
    };
    line(k.range.lo, k.range.lo_open, just_below(k, k.range.lo));
    line(k.range.hi, k.range.hi_open, just_above(k, k.range.hi));
  }
  EXPECT_GT(bounds, 40);
  // The message says what the range is.
  EXPECT_NE(error_of(kRequired, {"dem.restitution=1.5"}).find("must be in [0, 1], got 1.5"),
            std::string::npos);
  EXPECT_NE(error_of(kRequired, {"fluid.cell_size=[1e-4, -1, 0]"})
                .find("must be >= 0 on every axis, got [0.0001, -1, 0]"),
            std::string::npos);
}

// Every listed word is accepted, any other refused with the list.
TEST(SceneKeys, ChoicesAreTheParsersChoices) {
  for (const SceneKey& k : scene_keys()) {
    if (k.choices.empty())
      continue;
    const std::string name(k.name);
    for (std::string_view c : k.choices) {
      // A gas boundary must agree with the domain: periodic exactly on periodic axes.
      const std::string periodic = c == "periodic" ? "true" : "false";
      EXPECT_EQ(
          error_of(scene_for(name, c), {fmt::format("{}={}", name, c),
                                        fmt::format("domain.periodic=[{0}, {0}, {0}]", periodic)}),
          "")
          << name << " = " << c;
    }
    const std::string e = error_of(scene_for(name, ""), {name + "=no_such_word"});
    EXPECT_NE(e.find(fmt::format("'{}'", name)), std::string::npos) << e;
    EXPECT_NE(e.find(fmt::format("\"{}\"", k.choices.back())), std::string::npos) << e;
  }
}

// fluid.implicit_viscosity: not given, "auto" (chosen per fluid step); true and false fix it;
// any other word is refused naming the key and the choices.
TEST(SceneKeys, ImplicitViscosityTakesAutoTrueOrFalse) {
  const Scene plain = parse(kRequired).scene;
  EXPECT_TRUE(plain.fluid.implicit_viscosity_auto);
  EXPECT_FALSE(plain.fluid.implicit_viscosity);
  const Scene given_auto = parse(kRequired, {"fluid.implicit_viscosity=\"auto\""}).scene;
  EXPECT_TRUE(given_auto.fluid.implicit_viscosity_auto);
  EXPECT_EQ(described(given_auto).at("fluid.implicit_viscosity"), "\"auto\"");
  for (const bool on : {true, false}) {
    const Scene fixed = parse(kRequired, {fmt::format("fluid.implicit_viscosity={}", on)}).scene;
    EXPECT_FALSE(fixed.fluid.implicit_viscosity_auto);
    EXPECT_EQ(fixed.fluid.implicit_viscosity, on);
    EXPECT_EQ(described(fixed).at("fluid.implicit_viscosity"), on ? "true" : "false");
  }
  const std::string e = error_of(kRequired, {"fluid.implicit_viscosity=\"sometimes\""});
  EXPECT_NE(e.find("'fluid.implicit_viscosity'"), std::string::npos) << e;
  EXPECT_NE(e.find("\"auto\""), std::string::npos) << e;
}

TEST(SceneKeys, UnknownKeyNamedWithTheNearest) {
  const auto unknown = [](const std::string& override) { return error_of(kRequired, {override}); };
  const std::string swapped = unknown("dem.restitutoin=0.5");
  EXPECT_NE(swapped.find("'dem.restitutoin'"), std::string::npos) << swapped;
  EXPECT_NE(swapped.find("unknown key (did you mean 'dem.restitution'?"), std::string::npos)
      << swapped;
  // The right name in the wrong section.
  EXPECT_NE(unknown("particles.restitution=0.5").find("did you mean 'dem.restitution'"),
            std::string::npos);
  const std::string far = unknown("dem.no_such_key=1");
  EXPECT_NE(far.find("unknown key (check the spelling"), std::string::npos) << far;
  EXPECT_EQ(far.find("did you mean"), std::string::npos) << far;
  // A misspelt required key is named as unknown, not reported as the required one missing.
  Lines misspelt = kRequired;
  misspelt[4].first = "dem.sprign_constant";
  const std::string e = error_of(misspelt);
  EXPECT_NE(e.find("'dem.sprign_constant' (keys.toml line 5): unknown key (did you mean "
                   "'dem.spring_constant'?"),
            std::string::npos)
      << e;
  // A section given a value.
  EXPECT_NE(error_of({{"dem", "3"}}).find("'dem' is a table of keys"), std::string::npos);
}

// `cfddem check` lists every key the scene uses, in the table's order; the scenes together use
// every key.
TEST(SceneKeys, CheckListsTheKeysInTableOrder) {
  std::map<std::string, std::size_t> position;
  for (const SceneKey& k : scene_keys())
    position[std::string(k.name)] = position.size();
  std::set<std::string> listed;
  for (const Lines& scene : {kRequired, kNormal, kUniform, file_scene(), kCylinder, kInlet,
                             kInletNormal, kInletUniform}) {
    std::vector<std::size_t> order;
    for (const auto& [k, v] : describe_scene(parse(scene).scene)) {
      ASSERT_TRUE(position.count(k)) << "cfddem check lists " << k << ", not in the table";
      EXPECT_TRUE(order.empty() || position[k] > order.back()) << k << " is out of table order";
      order.push_back(position[k]);
      listed.insert(k);
    }
  }
  EXPECT_EQ(listed.size(), scene_keys().size());
}

TEST(SceneKeys, HelpAndKeysListEveryKey) {
  const std::string help = keys_help_text(), text = keys_text();
  for (const SceneKey& k : scene_keys()) {
    EXPECT_NE(help.find(fmt::format("  {} ", k.name)), std::string::npos) << k.name;
    EXPECT_NE(text.find(fmt::format("  {}  (", k.name)), std::string::npos) << k.name;
  }
  for (const std::string_view line :
       {"  dem.scheme                      string, \"explicit\", \"orb\", \"islands\"; default: "
        "\"explicit\"\n",
        "  dem.restitution                 number, [0, 1]; required\n",
        "  dem.wall_friction               number, >= 0; default: dem.friction\n"})
    EXPECT_NE(help.find(line), std::string::npos) << line << "\n" << help;
}

// docs/keys.md is the table as `cfddem keys --markdown` prints it: it cannot go stale.
TEST(SceneKeys, DocsKeysMdIsGeneratedFromTheTable) {
  const std::string path = std::string(CFDDEM_SOURCE_DIR) + "/docs/keys.md";
  const std::string docs = read_file(path), generated = keys_markdown();
  if (docs == generated)
    return;
  std::istringstream a(docs), b(generated);
  std::string la, lb;
  int line = 1;
  while (std::getline(a, la) && std::getline(b, lb) && la == lb)
    ++line;
  ADD_FAILURE() << path << " differs from the key table at line " << line << ":\n  file:  " << la
                << "\n  table: " << lb << "\nRegenerate it: cmake --build build --target docs_keys";
}

// The keys a restart may change are one list: the rule the restart applies (apps/checkpoint.cpp)
// and what docs/keys.md prints. A ".*" entry covers its section's keys, any other one key.
TEST(SceneKeys, RestartMayChangeTheRunAndTheGasDriveOnly) {
  for (const std::string_view k : {"name", "run.end_time", "output.interval", "fluid.velocity",
                                   "fluid.inflow_velocity", "fluid.bc.y_lo"})
    EXPECT_TRUE(restart_may_change(k)) << k;
  for (const std::string_view k : {"names", "runs.end_time", "fluid.density", "fluid.velocity_x",
                                   "fluid.bc", "dem.restitution", "particles.count"})
    EXPECT_FALSE(restart_may_change(k)) << k;
  // Every entry is a key of the table or a section of them.
  for (const std::string_view k : restart_free_keys()) {
    bool known = false;
    for (const SceneKey& key : scene_keys())
      known = known ||
              (k.ends_with(".*") ? key.name.starts_with(k.substr(0, k.size() - 1)) : key.name == k);
    EXPECT_TRUE(known) << k;
  }
  EXPECT_NE(keys_markdown().find("A restart may change only\n" + restart_free_keys_text(true)),
            std::string::npos);
}
