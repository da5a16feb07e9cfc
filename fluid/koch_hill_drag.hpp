// Koch-Hill drag (Hill, Koch & Ladd 2001; Benyahia et al. 2006 blend) exactly as MFIX codes it,
// with the 17.14 phi coefficient and the jump at phi = 0.01 (docs/theory.md §4). Scalar kernels.
#pragma once

#include <cmath>
#include <numbers>

namespace cfddem::fluid {

// The pieces of the Koch-Hill fit at one solids fraction (MFIX des/drag_gs_des names F_0..F_3).
struct KochHillCoefficients {
  double f0, f1, f2, f3;
};

[[nodiscard]] inline KochHillCoefficients koch_hill_coefficients(double phi) {
  const double eps = 1.0 - phi;
  const double dense = 10.0 * phi / (eps * eps * eps);
  // phi ln(phi) -> 0 as phi -> 0; written out so that phi = 0 gives 0, not NaN.
  const double phi_ln_phi = phi > 0.0 ? phi * std::log(phi) : 0.0;
  const double w = phi > 0.0 ? std::exp(-10.0 * (0.4 - phi) / phi) : 0.0;
  const double root = 1.0 + 3.0 * std::sqrt(phi / 2.0) + 135.0 / 64.0 * phi_ln_phi;
  KochHillCoefficients c{};
  // F0, F2: MFIX's 17.14 (CFDEMcoupling writes Hill-Koch-Ladd's 16.14); docs/theory.md §4.
  if (phi < 0.4) {
    c.f0 = (1.0 - w) * (root + 17.14 * phi) /
               (1.0 + 0.681 * phi - 8.48 * phi * phi + 8.16 * phi * phi * phi) +
           w * dense;
    c.f2 = (1.0 - w) * (root + 17.89 * phi) /
               (1.0 + 0.681 * phi - 11.03 * phi * phi + 15.41 * phi * phi * phi) +
           w * dense;
  } else {
    c.f0 = dense;
    c.f2 = dense;
  }
  // MFIX leaves F1 undefined for phi <= 0.01, where it is never used.
  c.f1 = phi <= 0.1 ? (phi > 0.0 ? std::sqrt(2.0 / phi) / 40.0 : 0.0)
                    : 0.11 + 5.1e-4 * std::exp(11.6 * phi);
  // eps^5 by multiplication, as Fortran evaluates an integer power (MFIX's (ONE-PHIS)**5): std::pow
  // cost each particle of the bed about 25 ns per fluid step (perf).
  const double eps2 = eps * eps;
  c.f3 =
      phi < 0.0953 ? 0.9351 * phi + 0.03667 : 0.0673 + 0.212 * phi + 0.0232 / (eps2 * eps2 * eps);
  return c;
}

// Dimensionless drag F(phi, Re_KH), Re_KH = eps rho_g (d/2) U / mu_g (radius based).
[[nodiscard]] inline double koch_hill_dimensionless_drag(double phi, double re_kh) {
  const KochHillCoefficients c = koch_hill_coefficients(phi);
  if (phi <= 0.01) {
    const double re_t1 = (c.f2 - 1.0) / (3.0 / 8.0 - c.f3);
    if (re_kh <= re_t1) {
      return 1.0 + 3.0 / 8.0 * re_kh;
    }
  } else {
    const double re_t2 =
        (c.f3 + std::sqrt(c.f3 * c.f3 - 4.0 * c.f1 * (c.f0 - c.f2))) / (2.0 * c.f1);
    if (re_kh <= re_t2) {
      return c.f0 + c.f1 * re_kh * re_kh;
    }
  }
  return c.f2 + c.f3 * re_kh;
}

// beta_i [N s/m] = 3 pi mu_g d eps^2 F (eps squared: Koch-Hill's F normalises the total fluid
// force; MFIX F_STOKES = 18 mu eps^2/d^2 times V_p).
[[nodiscard]] inline double koch_hill_beta(double eps_g, double d, double slip, double rho_g,
                                           double mu_g) {
  const double re_kh = 0.5 * eps_g * rho_g * d * slip / mu_g;
  return 3.0 * std::numbers::pi * mu_g * d * eps_g * eps_g *
         koch_hill_dimensionless_drag(1.0 - eps_g, re_kh);
}

} // namespace cfddem::fluid
