#include "dem/granular_diagnostics.hpp"

#include <array>
#include <cmath>

namespace cfddem::dem {

GranularState measure(const ParticleSpans& p) {
  GranularState s;
  const std::size_t n = p.x.size();
  if (n == 0) return s;
  double sx = 0, sy = 0, sz = 0, ux = 0, uy = 0, uz = 0, speed = 0, ke = 0, mass = 0;
  for (std::size_t i = 0; i < n; ++i) {
    mass += p.mass[i];
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
  s.mass = mass;
  s.mean_speed = speed * inv;
  return s;
}

GranularState measure(const ParticleSpans& p, const Communicator& comm) {
  const std::size_t n = p.x.size();
  // count, sum x (3), sum v (3), sum |v|, KE, momentum (3), mass
  std::array<double, 13> q{};
  q[0] = static_cast<double>(n);
  for (std::size_t i = 0; i < n; ++i) {
    q[1] += p.x[i], q[2] += p.y[i], q[3] += p.z[i];
    q[4] += p.vx[i], q[5] += p.vy[i], q[6] += p.vz[i];
    const double v2 = p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
    q[7] += std::sqrt(v2);
    q[8] += 0.5 * p.mass[i] * v2;
    q[9] += p.mass[i] * p.vx[i], q[10] += p.mass[i] * p.vy[i], q[11] += p.mass[i] * p.vz[i];
    q[12] += p.mass[i];
  }
  comm.sum(q);
  GranularState s;
  if (q[0] == 0.0) return s;
  const double inv = 1.0 / q[0];
  s.mean_position = {q[1] * inv, q[2] * inv, q[3] * inv};
  s.mean_velocity = {q[4] * inv, q[5] * inv, q[6] * inv};
  s.mean_speed = q[7] * inv;
  s.kinetic_energy = q[8];
  s.momentum = {q[9], q[10], q[11]};
  s.mass = q[12];
  double fluct = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const double dx = p.vx[i] - s.mean_velocity[0], dy = p.vy[i] - s.mean_velocity[1],
                 dz = p.vz[i] - s.mean_velocity[2];
    fluct += dx * dx + dy * dy + dz * dz;
  }
  comm.sum(std::span<double>(&fluct, 1));
  s.granular_temperature = fluct * inv / 3.0;
  return s;
}

} // namespace cfddem::dem
