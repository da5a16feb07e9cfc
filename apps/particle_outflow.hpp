// Particles leaving through the gas's outflow faces (fluid.bc.<face> = "outflow" with
// particles.outflow = "remove", docs/keys.md; docs/theory.md §12). The particle side keeps its
// walls on those faces, and a particle is taken out of the run at the start of the fluid step in
// which its surface would reach the face on its current velocity:
//     hi face on axis a:  x_a + r + max(v_a, 0) dt_f >= hi_a,
//     lo face:            x_a - r + min(v_a, 0) dt_f <= lo_a,
// so that it leaves before the wall could push it back. The rule takes a particle up to one fluid
// step of flight and one radius early: a particle that would cross the face during the step, or
// rests against it, leaves; one that turns back within the step might have stayed. The loop
// (apps/run_loop.hpp) removes them through the scheme's saved state (dem/state_edit.hpp),
// on each rank its own, and counts their mass in diagnostics.csv's mass_out.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "core/particle_store.hpp"
#include "core/scene.hpp"

namespace cfddem::apps {

// The six faces (x_lo, x_hi, y_lo, y_hi, z_lo, z_hi) particles leave through.
struct OutflowFaces {
  std::array<bool, 6> open{};
  std::array<double, 3> lo{}, hi{};
  bool any() const {
    return std::ranges::any_of(open, [](bool b) { return b; });
  }
};

inline OutflowFaces outflow_faces(const Scene& scene) {
  OutflowFaces f;
  f.lo = scene.domain.lo, f.hi = scene.domain.hi;
  if (!scene.fluid.enabled || scene.particles.outflow != "remove")
    return f;
  for (std::size_t k = 0; k < 6; ++k)
    f.open[k] = scene.fluid.bc[k] == "outflow";
  return f;
}

// The particles among [0, owned) that leave in the fluid step of length dt_f, in increasing
// index order.
inline std::vector<std::uint32_t> leaving_particles(const ParticleStore& p, std::size_t owned,
                                                    const OutflowFaces& f, double dt_f) {
  std::vector<std::uint32_t> out;
  if (!f.any())
    return out;
  const std::vector<double>* x[3] = {&p.x, &p.y, &p.z};
  const std::vector<double>* v[3] = {&p.vx, &p.vy, &p.vz};
  for (std::size_t i = 0; i < owned; ++i) {
    bool leaves = false;
    for (std::size_t a = 0; a < 3; ++a) {
      const double q = (*x[a])[i], u = (*v[a])[i], r = p.radius[i];
      leaves = leaves || (f.open[2 * a] && q - r + std::min(u, 0.0) * dt_f <= f.lo[a]) ||
               (f.open[2 * a + 1] && q + r + std::max(u, 0.0) * dt_f >= f.hi[a]);
    }
    if (leaves)
      out.push_back(static_cast<std::uint32_t>(i));
  }
  return out;
}

// The complement of `leaving` (increasing) in [0, n).
inline std::vector<std::uint32_t> staying_particles(std::size_t n,
                                                    const std::vector<std::uint32_t>& leaving) {
  std::vector<std::uint32_t> kept;
  kept.reserve(n - leaving.size());
  std::size_t k = 0;
  for (std::uint32_t i = 0; i < n; ++i) {
    if (k < leaving.size() && leaving[k] == i)
      ++k;
    else
      kept.push_back(i);
  }
  return kept;
}

} // namespace cfddem::apps
