// Scene configuration: overrides, typed getters, validation messages that name the key.
#include <gtest/gtest.h>

#include "core/error.hpp"
#include "core/scene.hpp"
#include "core/scene_config.hpp"

using namespace cfddem;

namespace {

const char* kMinimal = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.0e-3, 1.0e-3, 1.0e-3]
[particles]
count = 10
diameter = 100.0e-6
density = 1000.0
[dem]
spring_constant = 10.0
restitution = 0.8
[run]
end_time = 1.0e-3
)";

Scene load(std::initializer_list<std::string> overrides) {
  auto c = SceneConfig::from_string(kMinimal, "test.toml");
  for (const auto& o : overrides) c.apply_override(o);
  return read_scene(c, "test");
}

// The error message of loading with these overrides ("" if it loads).
std::string error_of(std::initializer_list<std::string> overrides) {
  try {
    load(overrides);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

} // namespace

TEST(SceneConfig, OverrideReplacesValueAsToml) {
  EXPECT_DOUBLE_EQ(load({"dem.restitution=0.9"}).dem.restitution, 0.9);
  EXPECT_EQ(load({"domain.periodic=[true, false, true]"}).domain.periodic[1], false);
  EXPECT_DOUBLE_EQ(load({"gravity=[0, -9.81, 0]"}).gravity[1], -9.81);
}

// A bare word that is not TOML is a string: dem.scheme=explicit and dem.scheme="explicit" agree.
TEST(SceneConfig, BareWordIsString) {
  EXPECT_EQ(load({"dem.scheme=explicit"}).dem.scheme, "explicit");
  EXPECT_EQ(load({"dem.scheme=\"explicit\""}).dem.scheme, "explicit");
  EXPECT_EQ(load({"name=myrun"}).name, "myrun");
}

// Spaces around '=' as a scene file writes them (one quoted argument on the command line): not
// part of the key ("unknown key 'run.end_time '") nor of a bare word; a key of spaces alone is
// no key.
TEST(SceneConfig, SpacesAroundTheEqualsSignAreNotPartOfKeyOrValue) {
  EXPECT_DOUBLE_EQ(load({"dem.restitution = 0.9"}).dem.restitution, 0.9);
  EXPECT_EQ(load({" dem.scheme =\torb "}).dem.scheme, "orb");
  EXPECT_EQ(load({"name = my run"}).name, "my run"); // inner spaces stay
  EXPECT_NE(error_of({" =5"}).find("not of the form key=value"), std::string::npos);
}

// A key set twice on the command line: the last value holds, and the key is listed once with it
// for the warning.
TEST(SceneConfig, RepeatedOverridesAreListedWithTheLastValue) {
  auto c = SceneConfig::from_string(kMinimal, "test.toml");
  for (const char* o :
       {"run.end_time=2e-3", "dem.restitution=0.5", "run.end_time = 3e-3", "run.end_time=4e-3"})
    c.apply_override(o);
  ASSERT_EQ(c.repeated_overrides().size(), 1U);
  EXPECT_EQ(c.repeated_overrides()[0].first, "run.end_time");
  EXPECT_EQ(c.repeated_overrides()[0].second, "4e-3");
  EXPECT_DOUBLE_EQ(read_scene(c, "test").run.end_time, 4e-3);
}

TEST(SceneConfig, DefaultsApplied) {
  const Scene s = load({});
  EXPECT_DOUBLE_EQ(s.dem.dt_factor, 0.02);
  EXPECT_EQ(s.dem.scheme, "explicit");
  EXPECT_EQ(s.domain.periodic[0], true);
  EXPECT_DOUBLE_EQ(s.gravity[1], 0.0);
  EXPECT_DOUBLE_EQ(s.dem.wall_restitution, 0.8);
}

TEST(SceneConfig, UnknownKeyNamed) {
  const std::string e = error_of({"dem.restitutoin=0.5"});
  EXPECT_NE(e.find("dem.restitutoin"), std::string::npos) << e;
  EXPECT_NE(e.find("unknown key"), std::string::npos) << e;
}

TEST(SceneConfig, WrongTypeNamed) {
  const std::string e = error_of({"dem.spring_constant=stiff"});
  EXPECT_NE(e.find("dem.spring_constant"), std::string::npos) << e;
  EXPECT_NE(e.find("expected a number"), std::string::npos) << e;
  EXPECT_NE(error_of({"domain.lo=[0, 0]"}).find("domain.lo"), std::string::npos);
  EXPECT_NE(error_of({"domain.periodic=[1, 0, 1]"}).find("domain.periodic"), std::string::npos);
}

TEST(SceneConfig, ImpossibleValuesNamed) {
  EXPECT_NE(error_of({"particles.diameter=-1e-4"}).find("particles.diameter"), std::string::npos);
  EXPECT_NE(error_of({"dem.restitution=1.5"}).find("dem.restitution"), std::string::npos);
  EXPECT_NE(error_of({"dem.restitution=-0.1"}).find("dem.restitution"), std::string::npos);
  EXPECT_NE(error_of({"dem.spring_constant=0"}).find("dem.spring_constant"), std::string::npos);
  EXPECT_NE(error_of({"dem.spring_constant=-3"}).find("must be > 0"), std::string::npos);
  EXPECT_NE(error_of({"domain.hi=[1e-3, -1e-3, 1e-3]"}).find("domain.hi"), std::string::npos);
  // A box smaller than a particle.
  EXPECT_NE(error_of({"particles.diameter=2e-3"}).find("particles.diameter"), std::string::npos);
  EXPECT_NE(error_of({"dem.scheme=warp"}).find("dem.scheme"), std::string::npos);
  EXPECT_NE(error_of({"run.end_time=0"}).find("run.end_time"), std::string::npos);
  EXPECT_NE(error_of({"dem.dt_factor=0"}).find("dem.dt_factor"), std::string::npos);
}

TEST(SceneConfig, MissingRequiredKeyNamed) {
  auto c = SceneConfig::from_string("[domain]\nlo = [0.0, 0.0, 0.0]\n", "t.toml");
  try {
    read_scene(c, "t");
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("domain.hi"), std::string::npos) << e.what();
  }
}

TEST(SceneConfig, SyntaxErrorGivesLineAndColumn) {
  try {
    SceneConfig::from_string("[dem]\nspring_constant = = 3\n", "broken.toml");
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("broken.toml line 2"), std::string::npos) << e.what();
  }
}

TEST(SceneConfig, FileAndGeneratorConflict) {
  EXPECT_NE(error_of({"particles.file=x.csv"}).find("cannot be combined"), std::string::npos);
}

// fluid.time_order: 2 (predictor-corrector) unless set; 1 or 2 only, listed when resolved.
TEST(SceneConfig, FluidTimeOrder) {
  const Scene s = load({"fluid.cells=[2,2,2]", "fluid.density=1.0", "fluid.viscosity=1e-5"});
  EXPECT_EQ(s.fluid.time_order, 2);
  const Scene euler = load(
      {"fluid.cells=[2,2,2]", "fluid.density=1.0", "fluid.viscosity=1e-5", "fluid.advection=\"mol\"",
       "fluid.time_order=1"});
  EXPECT_EQ(euler.fluid.time_order, 1);
  bool listed = false;
  for (const auto& [key, value] : describe_scene(euler)) {
    if (key == "fluid.time_order") {
      listed = true;
      EXPECT_EQ(value, "1");
    }
  }
  EXPECT_TRUE(listed);
  const std::string e = error_of(
      {"fluid.cells=[2,2,2]", "fluid.density=1.0", "fluid.viscosity=1e-5", "fluid.advection=\"mol\"",
       "fluid.time_order=3"});
  EXPECT_NE(e.find("fluid.time_order"), std::string::npos) << e;
}

// fluid.advection: Godunov at cfl 0.9 unless set; the method of lines at 0.4; Euler and Heun's
// settings refused with Godunov, naming the key.
TEST(SceneConfig, FluidAdvection) {
  const Scene s = load({"fluid.cells=[2,2,2]", "fluid.density=1.0", "fluid.viscosity=1e-5"});
  EXPECT_EQ(s.fluid.advection, "godunov");
  EXPECT_EQ(s.fluid.cfl, 0.9);
  const Scene mol = load({"fluid.cells=[2,2,2]", "fluid.density=1.0", "fluid.viscosity=1e-5",
                          "fluid.advection=\"mol\""});
  EXPECT_EQ(mol.fluid.cfl, 0.4);
  for (const char* key : {"fluid.time_order=1", "fluid.projections=2"}) {
    const std::string e =
        error_of({"fluid.cells=[2,2,2]", "fluid.density=1.0", "fluid.viscosity=1e-5", key});
    EXPECT_NE(e.find(std::string(key).substr(0, std::string(key).find('='))), std::string::npos)
        << e;
    EXPECT_NE(e.find("mol"), std::string::npos) << e;
  }
  EXPECT_NE(error_of({"fluid.cells=[2,2,2]", "fluid.density=1.0", "fluid.viscosity=1e-5",
                      "fluid.advection=\"rk4\""})
                .find("fluid.advection"),
            std::string::npos);
}
