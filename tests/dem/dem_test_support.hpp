// Shared set-up for DEM tests: a scene from TOML text, particles placed by hand, and a runner
// that steps the explicit scheme and returns synchronised states.
#pragma once

#include <span>
#include <string>
#include <type_traits>

#include "core/initial_conditions.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "core/scene_config.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/granular_diagnostics.hpp"

namespace cfddem::demtest {

// Scene from TOML text (plus overrides); validates exactly as `cfddem run` does.
inline Scene scene_from(const std::string& toml, std::span<const std::string> overrides) {
  auto cfg = SceneConfig::from_string(toml, "test scene");
  for (const auto& o : overrides) cfg.apply_override(o);
  return read_scene(cfg, "test");
}
inline Scene scene_from(const std::string& toml, std::initializer_list<std::string> overrides = {}) {
  return scene_from(toml, std::span<const std::string>(overrides.begin(), overrides.size()));
}

// Two particles of the paper (d = 100 um, rho = 1000) in a periodic 1 mm box, no gravity.
inline const char* kPairScene = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.0e-3, 1.0e-3, 1.0e-3]
periodic = [true, true, true]
[particles]
count = 0
diameter = 100.0e-6
density = 1000.0
[dem]
spring_constant = 10.0
restitution = 0.8
[run]
end_time = 1.0e-3
)";

inline dem::GranularState measure_now(const ParticleStore& p) {
  return dem::measure({p.x, p.y, p.z, p.vx, p.vy, p.vz, p.mass});
}

// `steps` steps of the explicit scheme (recording every 50th, as a run's output would) or
// sub-iterations of orb and islands.
template <class Scheme> void advance(Scheme& scheme, int steps) {
  for (int k = 0; k < steps; ++k) {
    if constexpr (std::is_same_v<Scheme, dem::ExplicitScheme>)
      scheme.step(k % 50 == 0);
    else
      scheme.subiterate();
  }
}

} // namespace cfddem::demtest
