#include "dem/granular_diagnostics.hpp"

#include <cmath>

namespace cfddem::dem {

GranularState measure(const ParticleSpans& p) {
  GranularState s;
  const std::size_t n = p.x.size();
  if (n == 0) return s;
  double sx = 0, sy = 0, sz = 0, ux = 0, uy = 0, uz = 0, speed = 0, ke = 0;
  for (std::size_t i = 0; i < n; ++i) {
    sx += p.x[i], sy += p.y[i], sz += p.z[i];
    ux += p.vx[i], uy += p.vy[i], uz += p.vz[i];
    const double v2 = p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
    speed += std::sqrt(v2);
    ke += 0.5 * p.mass[i] * v2;
    s.momentum[0] += p.mass[i] * p.vx[i];
    s.momentum[1] += p.mass[i] * p.vy[i];
    s.momentum[2] += p.mass[i] * p.vz[i];
  }
  const double inv = 1.0 / static_cast<double>(n);
  s.mean_position = {sx * inv, sy * inv, sz * inv};
  s.mean_velocity = {ux * inv, uy * inv, uz * inv};
  double fluct = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double dx = p.vx[i] - s.mean_velocity[0], dy = p.vy[i] - s.mean_velocity[1],
                 dz = p.vz[i] - s.mean_velocity[2];
    fluct += dx * dx + dy * dy + dz * dz;
  }
  s.granular_temperature = fluct * inv / 3.0;
  s.kinetic_energy = ke;
  s.mean_speed = speed * inv;
  return s;
}

} // namespace cfddem::dem
