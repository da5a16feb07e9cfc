// Beetstra-van der Hoef-Kuipers (2007) drag, as MFIX-Exa coded it in 2018 (docs/theory.md §4).
// Kernels on scalars: no allocation, no I/O.
#pragma once

#include <cmath>
#include <numbers>

namespace cfddem::fluid {

// Dimensionless drag F(phi, Re) of BVK 2007 (AIChE J. 53:489, eq. 7 with the Re-correction of
// eq. 9), with Re = eps rho_g d U / mu_g (superficial). Re = 0 gives the Stokes-limit value
// 10 phi/eps^2 + eps^2 (1 + 1.5 sqrt(phi)); MFIX returns beta = 0 there, which only differs
// when U = 0, where the force is zero either way.
[[nodiscard]] inline double bvk_dimensionless_drag(double phi, double re) {
  const double eps = 1.0 - phi;
  double f = 10.0 * phi / (eps * eps) + eps * eps * (1.0 + 1.5 * std::sqrt(phi));
  if (re > 0.0) {
    f += 0.413 * re / (24.0 * eps * eps) *
         (1.0 / eps + 3.0 * eps * phi + 8.4 * std::pow(re, -0.343)) /
         (1.0 + std::pow(10.0, 3.0 * phi) * std::pow(re, -(1.0 + 4.0 * phi) / 2.0));
  }
  return f;
}

// beta_i [N s/m] of one particle: beta_i = 3 pi mu_g d eps F (docs/theory.md §4, BVK).
[[nodiscard]] inline double bvk_beta(double eps_g, double d, double slip, double rho_g,
                                     double mu_g) {
  const double re = eps_g * rho_g * d * slip / mu_g;
  return 3.0 * std::numbers::pi * mu_g * d * eps_g * bvk_dimensionless_drag(1.0 - eps_g, re);
}

} // namespace cfddem::fluid
