// The frictional contact of one pair and of one wall, and the planar walls' contact law
// (docs/theory.md §2: the normal spring-dashpot plus the tangential spring with history and the
// Coulomb limit), for the orb and islands schemes' leaf and island kernels. The arithmetic is the
// explicit scheme's contact pass and wall pass (dem/verlet_passes.hpp) step for step, in the same
// order, so that a sub-iterated scheme stepping at the explicit dt takes the explicit
// floating-point path. Inline scalars: no allocation, no threads.
#pragma once

#include <cmath>

#include "dem/contact_kernels.hpp"
#include "dem/cylinder_wall.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/linear_spring_dashpot.hpp"
#include "dem/wall_friction.hpp"

namespace cfddem::dem {

// Contact of particle i with a partner at separation (dx, dy, dz) = x_j - x_i (minimum image),
// radii ri, rj, masses mi, mj, relative velocity dv = v_i - v_j, spins wi, wj, over a step dt.
// h: the tangential history of this (i, j) entry (i's record), updated; zeroed when the pair is
// apart. When they overlap, adds the force on i to a and the torque on i to tq and returns the
// overlap; returns 0 when apart.
inline double add_frictional_contact(const StepModel& m, double dx, double dy, double dz, double ri,
                                     double rj, double mi, double mj, double dvx, double dvy,
                                     double dvz, const double wi[3], const double wj[3], double dt,
                                     double h[3], double a[3], double tq[3]) {
  const double r2 = dx * dx + dy * dy + dz * dz;
  const double rs = ri + rj;
  if (r2 >= rs * rs) {
    h[0] = h[1] = h[2] = 0.0;
    return 0.0;
  }
  const double dist = std::sqrt(r2);
  const double inv = 1.0 / dist;
  const double nx = dx * inv, ny = dy * inv, nz = dz * inv;
  const double delta = rs - dist;
  const double vn = dvx * nx + dvy * ny + dvz * nz;
  const double meff = contact_meff(m, mi, mj);
  const double fn = contact_normal_force(m, meff, delta, vn);
  a[0] -= fn * nx, a[1] -= fn * ny, a[2] -= fn * nz;
  // Contact-point relative velocity: v_i - v_j + (r_i w_i + r_j w_j) x n.
  const double sx = ri * wi[0] + rj * wj[0];
  const double sy = ri * wi[1] + rj * wj[1];
  const double sz = ri * wi[2] + rj * wj[2];
  const double rvx = dvx + (sy * nz - sz * ny), rvy = dvy + (sz * nx - sx * nz),
               rvz = dvz + (sx * ny - sy * nx);
  const double rvn = rvx * nx + rvy * ny + rvz * nz;
  const double nvec[3] = {nx, ny, nz};
  const double vt[3] = {rvx - rvn * nx, rvy - rvn * ny, rvz - rvn * nz};
  double ft[3];
  tangential_force(m.pair_t, meff, dt, std::abs(fn), nvec, vt, h, ft);
  a[0] += ft[0], a[1] += ft[1], a[2] += ft[2];
  // Torque on i: (r_i n) x F_t.
  tq[0] += ri * (ny * ft[2] - nz * ft[1]);
  tq[1] += ri * (nz * ft[0] - nx * ft[2]);
  tq[2] += ri * (nx * ft[1] - ny * ft[0]);
  return delta;
}

// The tangential force of a wall with outward normal s e_a (s = -1 at lo, +1 at hi) pressing on
// a particle of radius ri, mass mi, velocity vel and spin w with the normal force fn: added to f,
// its torque to tq. Walls keep no history: a dashpot capped by the Coulomb limit (MFIX-Exa's
// sliding friction, docs/theory.md §2).
inline void add_wall_friction(const TangentialLaw& law, double mi, double ri, double fn, int a,
                              double s, const double vel[3], const double w[3], double f[3],
                              double tq[3]) {
  double nvec[3] = {0, 0, 0};
  nvec[a] = s;
  // Slip of the contact point (the wall is at rest), its normal part read off axis a.
  double rv[3];
  wall_contact_velocity(ri, nvec, vel, w, rv);
  const double rvn = rv[a] * s;
  const double vt[3] = {rv[0] - rvn * nvec[0], rv[1] - rvn * nvec[1], rv[2] - rvn * nvec[2]};
  add_wall_tangential(law, mi, ri, fn, nvec, vt, f, tq);
}

// The planar walls at lo and hi of every non-periodic axis acting on one particle at pos with
// velocity vel and radius ri (docs/theory.md §2): each wall it overlaps by delta > 0 adds the
// normal spring-dashpot force -s fn e_a (outward normal s e_a: s = -1 at lo, +1 at hi) to f, and
// with Friction the wall's tangential force and torque (add_wall_friction) to f and tq. The
// explicit update and the islands contact kernel call it; what differs between them is how a
// particle's mass and spin are read and how an overlap is counted, so those come in as callables
// (mass() -> double, spin(double w[3]), overlap(delta)), called only for a wall in contact and
// inlined at compile time. (The orb leaf kernels keep their own loops: through this helper their
// frictional wall pass measured 37% more instructions.) With Cylinder the column's curved wall
// replaces the planar walls across its axis (where the column touches the box, both would act
// on one contact) and acts after the planar walls along it (add_cylinder_contact); callers
// choose it once per pass, from DomainGeometry::cylinder, so the box's path is unchanged.
template <bool Friction, bool Cylinder = false, class Mass, class Spin, class Overlap>
[[gnu::always_inline]] inline void
add_wall_contacts(const DomainGeometry& g, const NormalLaw& wall,
                  [[maybe_unused]] const TangentialLaw& wall_t, const double pos[3],
                  const double vel[3], double ri, Mass&& mass, [[maybe_unused]] Spin&& spin,
                  double f[3], [[maybe_unused]] double tq[3], Overlap&& overlap) {
  for (int a = 0; a < 3; ++a) {
    if (g.periodic[a] || (Cylinder && a != g.axis))
      continue;
    for (int side = 0; side < 2; ++side) {
      const double s = side ? 1.0 : -1.0;
      const double delta = side ? ri - (g.hi[a] - pos[a]) : ri - (pos[a] - g.lo[a]);
      if (delta <= 0.0)
        continue;
      const double mi = mass();
      const double fn = normal_force(wall, mi, delta, s * vel[a]);
      f[a] -= s * fn;
      overlap(delta);
      if constexpr (Friction) {
        double w[3];
        spin(w);
        add_wall_friction(wall_t, mi, ri, fn, a, s, vel, w, f, tq);
      }
    }
  }
  if constexpr (Cylinder)
    add_cylinder_contact<Friction>(g, wall, wall_t, pos, vel, ri, mass, spin, f, tq, overlap);
}

} // namespace cfddem::dem
