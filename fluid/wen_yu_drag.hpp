// Wen & Yu (1966) drag as MFIX codes it (docs/theory.md §4). Scalar kernel.
#pragma once

#include <cmath>
#include <numbers>

namespace cfddem::fluid {

// beta_i [N s/m] = V_p (3/4) C_d rho_g eps U eps^-2.65 / d with C_d = 24/Re (1 + 0.15 Re^0.687)
// for Re = eps rho_g d U / mu_g < 1000, else 0.44. Below Re = 1000 the 24/Re is multiplied out
// (24 rho_g eps U / Re = 24 mu_g / d) so that U = 0 gives the finite Stokes limit.
[[nodiscard]] inline double wen_yu_beta(double eps_g, double d, double slip, double rho_g,
                                        double mu_g) {
  const double volume = std::numbers::pi * d * d * d / 6.0;
  const double re = eps_g * rho_g * d * slip / mu_g;
  const double swarm = std::pow(eps_g, -2.65);
  if (re < 1000.0) {
    return volume * 18.0 * mu_g / (d * d) * (1.0 + 0.15 * std::pow(re, 0.687)) * swarm;
  }
  return volume * 0.75 * 0.44 * rho_g * eps_g * slip / d * swarm;
}

} // namespace cfddem::fluid
