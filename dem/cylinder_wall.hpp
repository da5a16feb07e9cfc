// The curved wall of a cylindrical column (domain.shape = "cylinder"): a particle's gap to it and
// its contact law, which is the planar walls' law (docs/theory.md §2.4) with the radial normal
// (§11). Inline scalars: no allocation, no threads.
#pragma once

#include <cmath>

#include "dem/domain_geometry.hpp"
#include "dem/linear_spring_dashpot.hpp"
#include "dem/wall_friction.hpp"

namespace cfddem::dem {

// A point's offset (du, dw) from the column's axis across it, and its distance rho to the axis.
struct RadialOffset {
  double du, dw, rho;
};
inline RadialOffset radial_offset(const DomainGeometry& g, const double pos[3]) {
  const double du = pos[g.u] - g.centre_u, dw = pos[g.w] - g.centre_w;
  return {du, dw, std::sqrt(du * du + dw * dw)};
}

// The gap R - rho - r between a particle of radius r at pos and the curved wall (negative: the
// overlap delta = rho + r - R, §11).
inline double cylinder_gap(const DomainGeometry& g, const double pos[3], double r) {
  return g.radius - radial_offset(g, pos).rho - r;
}
inline double cylinder_gap(const DomainGeometry& g, double x, double y, double z, double r) {
  const double pos[3] = {x, y, z};
  return cylinder_gap(g, pos, r);
}

// The tangential force of a wall with outward unit normal n pressing on a particle of radius ri,
// mass mi, velocity vel and spin w with the normal force fn: added to f, its torque to tq
// (dem/wall_friction.hpp), for the slip v_t of the contact point in the tangent plane of n.
inline void add_wall_friction_along(const TangentialLaw& law, double mi, double ri, double fn,
                                    const double n[3], const double vel[3], const double w[3],
                                    double f[3], double tq[3]) {
  double rv[3];
  wall_contact_velocity(ri, n, vel, w, rv);
  const double rvn = rv[0] * n[0] + rv[1] * n[1] + rv[2] * n[2];
  const double vt[3] = {rv[0] - rvn * n[0], rv[1] - rvn * n[1], rv[2] - rvn * n[2]};
  add_wall_tangential(law, mi, ri, fn, n, vt, f, tq);
}

// The curved wall acting on one particle at pos with velocity vel and radius ri (§11): when it
// overlaps by delta = rho + r_i - R > 0, the normal spring-dashpot of the planar walls with the
// outward radial normal n = (pos - axis)_perp / rho, F = -(k_w delta + eta_w v.n) n, added to f,
// and with Friction the wall's tangential force and torque (add_wall_friction_along). mass(),
// spin(double w[3]) and overlap(delta) as add_wall_contacts (dem/friction_kernels.hpp), called
// only in contact. rho > 0 whenever delta > 0: the parser keeps R above every radius.
template <bool Friction, class Mass, class Spin, class Overlap>
[[gnu::always_inline]] inline void
add_cylinder_contact(const DomainGeometry& g, const NormalLaw& wall,
                     [[maybe_unused]] const TangentialLaw& wall_t, const double pos[3],
                     const double vel[3], double ri, Mass&& mass, [[maybe_unused]] Spin&& spin,
                     double f[3], [[maybe_unused]] double tq[3], Overlap&& overlap) {
  const RadialOffset o = radial_offset(g, pos);
  const double delta = o.rho + ri - g.radius;
  if (!(delta > 0.0) || !(o.rho > 0.0))
    return;
  const double inv = 1.0 / o.rho;
  double n[3] = {0.0, 0.0, 0.0};
  n[g.u] = o.du * inv, n[g.w] = o.dw * inv;
  const double mi = mass();
  const double fn = normal_force(wall, mi, delta, vel[g.u] * n[g.u] + vel[g.w] * n[g.w]);
  f[g.u] -= fn * n[g.u], f[g.w] -= fn * n[g.w];
  overlap(delta);
  if constexpr (Friction) {
    double w[3];
    spin(w);
    add_wall_friction_along(wall_t, mi, ri, fn, n, vel, w, f, tq);
  }
}

} // namespace cfddem::dem
