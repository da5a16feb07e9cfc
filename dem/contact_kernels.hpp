// Per-pair and per-particle arithmetic shared by the explicit and orb schemes, so both take the
// same floating-point path: the normal contact force of a pair (equal masses skip the divide and
// the square root of m_eff) and the leapfrog kick-drift of one particle. Inline scalars: no
// allocation, no threads; the callers' loops keep their own layout and vectorize as before.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

#include "dem/domain_geometry.hpp"
#include "dem/linear_spring_dashpot.hpp"
#include "dem/step_model.hpp"

namespace cfddem::dem {

// Reduced mass of a pair (a constant when every particle has the same mass).
inline double contact_meff(const StepModel& m, double mi, double mj) {
  return m.uniform_mass ? m.uniform_meff : mi * mj / (mi + mj);
}

// F_n = k delta + eta_n v_n (docs/theory.md §2), with eta_n precomputed for equal masses.
inline double contact_normal_force(const StepModel& m, double meff, double delta, double vn) {
  return m.uniform_mass ? m.pair.k * delta + m.uniform_eta * vn
                        : normal_force(m.pair, meff, delta, vn);
}

// Frictionless contact of particle i with a partner at separation (dx, dy, dz) = x_j - x_i (the
// minimum image), radii ri, rj, masses mi, mj, relative velocity (dvx, dvy, dvz) = v_i - v_j:
// when they overlap, adds the normal force on i to (ax, ay, az) and returns the overlap; returns
// 0 when they are apart. The orb and islands schemes' pair (the explicit scheme's contact pass
// takes the same steps, with friction).
inline double add_normal_contact(const StepModel& m, double dx, double dy, double dz, double ri,
                                 double rj, double mi, double mj, double dvx, double dvy,
                                 double dvz, double& ax, double& ay, double& az) {
  const double r2 = dx * dx + dy * dy + dz * dz;
  const double rs = ri + rj;
  if (r2 >= rs * rs) return 0.0;
  const double dist = std::sqrt(r2);
  const double inv = 1.0 / dist;
  const double nx = dx * inv, ny = dy * inv, nz = dz * inv;
  const double delta = rs - dist;
  const double vn = dvx * nx + dvy * ny + dvz * nz;
  const double fn = contact_normal_force(m, contact_meff(m, mi, mj), delta, vn);
  ax -= fn * nx, ay -= fn * ny, az -= fn * nz;
  return delta;
}

// v += f (1/m) s + g s, x += v dt: the kick over s (s = dt for a constant step) and the drift
// over dt. `gs` is g * s, hoisted by the caller. Returns nothing: the caller keeps the values.
inline void kick_drift(double& x, double& v, double f, double ims, double gs, double dt) {
  v = v + f * ims + gs;
  x = x + v * dt;
}

} // namespace cfddem::dem
