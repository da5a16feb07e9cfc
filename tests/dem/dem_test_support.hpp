// Shared set-up for DEM tests: a scene from TOML text, particles placed by hand, and a runner
// that steps the explicit scheme and returns synchronised states.
#pragma once

#include <cstring>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include <gtest/gtest.h>

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

// Two columns equal bit for bit. Empty columns (no rotation fields) have a null data(): memcmp
// must not see them (UBSan).
inline bool same_bits(const std::vector<double>& a, const std::vector<double>& b) {
  return a.size() == b.size() &&
         (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0);
}

// Two stores' ids, positions, velocities and spins, bit for bit (`label` names the case).
inline void expect_same_state(const ParticleStore& a, const ParticleStore& b,
                              const std::string& label) {
  EXPECT_EQ(a.id, b.id) << label;
  EXPECT_TRUE(same_bits(a.x, b.x) && same_bits(a.y, b.y) && same_bits(a.z, b.z)) << label;
  EXPECT_TRUE(same_bits(a.vx, b.vx) && same_bits(a.vy, b.vy) && same_bits(a.vz, b.vz)) << label;
  EXPECT_TRUE(same_bits(a.wx, b.wx) && same_bits(a.wy, b.wy) && same_bits(a.wz, b.wz)) << label;
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
