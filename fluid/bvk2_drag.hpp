// Tang et al. (2015) drag, "BVK2" in MFIX-Exa since 2019 (docs/theory.md §4). Scalar kernels.
#pragma once

#include <cmath>
#include <numbers>

namespace cfddem::fluid {

// F(phi, Re) of Tang, Peters, Kuipers, Kriebitzsch & van der Hoef (AIChE J. 61:688, 2015,
// eq. 24), Re = eps rho_g d U / mu_g (superficial).
[[nodiscard]] inline double bvk2_dimensionless_drag(double phi, double re) {
  const double eps = 1.0 - phi;
  const double eps4 = eps * eps * eps * eps;
  double f = 10.0 * phi / (eps * eps) + eps * eps * (1.0 + 1.5 * std::sqrt(phi));
  if (re > 0.0) {
    f += re * (0.11 * phi * (1.0 + phi) - 0.00456 / eps4 +
               (0.169 * eps + 0.0644 / eps4) * std::pow(re, -0.343));
  }
  return f;
}

// beta_i [N s/m] = 3 pi mu_g d eps F, as for BVK.
[[nodiscard]] inline double bvk2_beta(double eps_g, double d, double slip, double rho_g,
                                      double mu_g) {
  const double re = eps_g * rho_g * d * slip / mu_g;
  return 3.0 * std::numbers::pi * mu_g * d * eps_g * bvk2_dimensionless_drag(1.0 - eps_g, re);
}

} // namespace cfddem::fluid
