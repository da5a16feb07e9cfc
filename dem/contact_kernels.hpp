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
#include "dem/explicit_scheme.hpp"
#include "dem/linear_spring_dashpot.hpp"

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

// Contact pass of an orb leaf batch over the rows act[a0, a1): each particle's force is the sum
// of its pair forces, partners nb[off[i], mid[i]) of its own leaf read live (x, v) and partners
// nb[mid[i], off[i + 1]) of other leaves (or ranks) read from their frozen copies (gx, gv);
// tracks the largest overlap ratio and the overlaps beyond m.max_overlap.
inline void leaf_contact_pass(std::uint32_t a0, std::uint32_t a1,
                              const std::uint32_t* __restrict act,
                              const std::uint32_t* __restrict off,
                              const std::uint32_t* __restrict mid,
                              const std::uint32_t* __restrict nb, const double* __restrict x,
                              const double* __restrict y, const double* __restrict z,
                              const double* __restrict vx, const double* __restrict vy,
                              const double* __restrict vz, const double* __restrict gx,
                              const double* __restrict gy, const double* __restrict gz,
                              const double* __restrict gvx, const double* __restrict gvy,
                              const double* __restrict gvz, const double* __restrict rad,
                              const double* __restrict mass, double* __restrict fx,
                              double* __restrict fy, double* __restrict fz,
                              const DomainGeometry& g, const StepModel& m, double& max_ratio,
                              std::int64_t& violations) {
  const double lim = m.max_overlap;
  for (std::uint32_t q = a0; q < a1; ++q) {
    const std::uint32_t i = act[q];
    const double xi = x[i], yi = y[i], zi = z[i];
    const double vxi = vx[i], vyi = vy[i], vzi = vz[i], ri = rad[i], mi = mass[i];
    double ax = 0.0, ay = 0.0, az = 0.0;
    auto partner = [&](std::uint32_t j, double xj, double yj, double zj, double vxj, double vyj,
                       double vzj) {
      const double delta = add_normal_contact(
          m, g.image(xj - xi, 0), g.image(yj - yi, 1), g.image(zj - zi, 2), ri, rad[j], mi,
          mass[j], vxi - vxj, vyi - vyj, vzi - vzj, ax, ay, az);
      if (delta <= 0.0) return;
      const double ratio = delta / std::min(ri, rad[j]);
      max_ratio = std::max(max_ratio, ratio);
      violations += ratio > lim;
    };
    for (std::uint32_t s = off[i]; s < mid[i]; ++s) {
      const std::uint32_t j = nb[s];
      partner(j, x[j], y[j], z[j], vx[j], vy[j], vz[j]);
    }
    for (std::uint32_t s = mid[i]; s < off[i + 1]; ++s) {
      const std::uint32_t j = nb[s];
      partner(j, gx[j], gy[j], gz[j], gvx[j], gvy[j], gvz[j]);
    }
    fx[i] = ax, fy[i] = ay, fz[i] = az;
  }
}

// Wall contacts of the particles [b, e) of a leaf batch (orb schemes): each adds its walls'
// normal forces to the force its row summed (a particle without a row has no pair force, so
// the wall force replaces what f held), and tracks the largest overlap ratio and the overlaps
// beyond `limit` radii.
inline void add_wall_forces(std::uint32_t b, std::uint32_t e, const std::uint32_t* off,
                            const double* x, const double* y, const double* z, const double* vx,
                            const double* vy, const double* vz, const double* rad,
                            const double* mass, double* fx, double* fy, double* fz,
                            const DomainGeometry& g, const NormalLaw& wall, double limit,
                            double& max_ratio, std::int64_t& violations) {
  for (std::uint32_t i = b; i < e; ++i) {
    const bool row = off[i + 1] > off[i];
    double f[3] = {row ? fx[i] : 0.0, row ? fy[i] : 0.0, row ? fz[i] : 0.0};
    const double pos[3] = {x[i], y[i], z[i]}, vel[3] = {vx[i], vy[i], vz[i]};
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a]) continue;
      for (int side = 0; side < 2; ++side) {
        const double sg = side ? 1.0 : -1.0;
        const double delta = side ? rad[i] - (g.hi[a] - pos[a]) : rad[i] - (pos[a] - g.lo[a]);
        if (delta <= 0.0) continue;
        f[a] -= sg * normal_force(wall, mass[i], delta, sg * vel[a]);
        max_ratio = std::max(max_ratio, delta / rad[i]);
        violations += delta > limit * rad[i];
      }
    }
    fx[i] = f[0], fy[i] = f[1], fz[i] = f[2];
  }
}

// The synchronised velocities v(n) = v(n-1/2) + a(n) h_prev of the particles [b, e) (a recorded
// step of the variable-step leapfrog), into sv.
template <bool External>
inline void synchronised_velocities(std::uint32_t b, std::uint32_t e, const double* vx,
                                    const double* vy, const double* vz, const double* fx,
                                    const double* fy, const double* fz, const double* fex,
                                    const double* fey, const double* fez, const double* im,
                                    const double* hp, const std::array<double, 3>& gravity,
                                    double* svx, double* svy, double* svz) {
  for (std::uint32_t i = b; i < e; ++i) {
    if constexpr (External) {
      svx[i] = vx[i] + ((fx[i] + fex[i]) * im[i] + gravity[0]) * hp[i];
      svy[i] = vy[i] + ((fy[i] + fey[i]) * im[i] + gravity[1]) * hp[i];
      svz[i] = vz[i] + ((fz[i] + fez[i]) * im[i] + gravity[2]) * hp[i];
    } else {
      svx[i] = vx[i] + (fx[i] * im[i] + gravity[0]) * hp[i];
      svy[i] = vy[i] + (fy[i] * im[i] + gravity[1]) * hp[i];
      svz[i] = vz[i] + (fz[i] * im[i] + gravity[2]) * hp[i];
    }
  }
}

} // namespace cfddem::dem
