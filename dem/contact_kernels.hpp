// Per-pair and per-particle arithmetic shared by the explicit and orb schemes, so both take the
// same floating-point path: the normal contact force of a pair (equal masses skip the divide and
// the square root of m_eff) and the leapfrog kick-drift of one particle. Inline scalars: no
// allocation, no threads; the callers' loops keep their own layout and vectorize as before.
#pragma once

#include "dem/explicit_scheme.hpp"
#include "dem/linear_spring_dashpot.hpp"

namespace cfddem::dem {

// Reduced mass of a pair (a constant when every particle has the same mass).
inline double contact_meff(const StepModel& m, double mi, double mj) {
  return m.uniform_mass ? m.uniform_meff : mi * mj / (mi + mj);
}

// F_n = k delta + eta_n v_n (physics.md §2), with eta_n precomputed for equal masses.
inline double contact_normal_force(const StepModel& m, double meff, double delta, double vn) {
  return m.uniform_mass ? m.pair.k * delta + m.uniform_eta * vn
                        : normal_force(m.pair, meff, delta, vn);
}

// v += f (1/m) s + g s, x += v dt: the kick over s (s = dt for a constant step) and the drift
// over dt. `gs` is g * s, hoisted by the caller. Returns nothing: the caller keeps the values.
inline void kick_drift(double& x, double& v, double f, double ims, double gs, double dt) {
  v = v + f * ims + gs;
  x = x + v * dt;
}

} // namespace cfddem::dem
