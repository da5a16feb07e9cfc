// The tangential force of a wall at rest on a particle, shared by the planar walls
// (dem/friction_kernels.hpp) and a cylindrical column's curved wall (dem/cylinder_wall.hpp):
// walls keep no spring history, so the force is the dashpot capped by the Coulomb limit
// (MFIX-Exa's sliding friction, docs/theory.md §2.3). Inline scalars: no allocation, no threads.
#pragma once

#include <cmath>

#include "dem/linear_spring_dashpot.hpp"

namespace cfddem::dem {

// Velocity of the contact point x_i + r_i n of a particle of radius ri, velocity vel and spin
// w against a wall with outward unit normal n: v_i + w_i x (r_i n), into rv.
inline void wall_contact_velocity(double ri, const double n[3], const double vel[3],
                                  const double w[3], double rv[3]) {
  rv[0] = vel[0] + ri * (w[1] * n[2] - w[2] * n[1]);
  rv[1] = vel[1] + ri * (w[2] * n[0] - w[0] * n[2]);
  rv[2] = vel[2] + ri * (w[0] * n[1] - w[1] * n[0]);
}

// The wall's tangential force for the slip vt (in the tangent plane of n) under the normal force
// fn, on a particle of mass mi and radius ri: added to f, its torque r_i n x F_t to tq.
inline void add_wall_tangential(const TangentialLaw& law, double mi, double ri, double fn,
                                const double n[3], const double vt[3], double f[3], double tq[3]) {
  double xi[3] = {0, 0, 0}, ft[3];
  tangential_force(law, mi, 0.0, std::abs(fn), n, vt, xi, ft);
  for (int b = 0; b < 3; ++b)
    f[b] += ft[b];
  tq[0] += ri * (n[1] * ft[2] - n[2] * ft[1]);
  tq[1] += ri * (n[2] * ft[0] - n[0] * ft[2]);
  tq[2] += ri * (n[0] * ft[1] - n[1] * ft[0]);
}

} // namespace cfddem::dem
