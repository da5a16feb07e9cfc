// Dashpot coefficients of the linear spring-dashpot model from the restitution coefficient.
// docs/theory.md §2; Garg et al. 2012 (MFIX DEM), eq. for eta_n: the overlap ODE
// m_eff d'' + eta d' + k d = 0 ends at d = 0 after pi/omega_d, so e = exp(-pi zeta/sqrt(1-zeta^2)).
#pragma once

#include <cmath>
#include <numbers>

namespace cfddem::dem {

// zeta = |ln e| / sqrt(pi^2 + ln^2 e); e = 0 is critical damping (zeta = 1).
inline double damping_ratio(double e) {
  if (e <= 0.0) return 1.0;
  const double l = std::log(e);
  return -l / std::sqrt(std::numbers::pi * std::numbers::pi + l * l);
}

// eta_n = dashpot_coefficient(k, e) * sqrt(m_eff) = 2 zeta sqrt(k m_eff).
inline double dashpot_coefficient(double k, double e) { return 2.0 * damping_ratio(e) * std::sqrt(k); }

// Damped contact duration pi/omega_d for reduced mass m_eff (infinite at critical damping).
inline double contact_duration(double k, double e, double m_eff) {
  const double w0 = std::sqrt(k / m_eff);
  const double z = damping_ratio(e);
  return z >= 1.0 ? INFINITY : std::numbers::pi / (w0 * std::sqrt(1.0 - z * z));
}

// The closing speed of a head-on impact that a spring of stiffness k stops within the overlap
// delta, for reduced mass m_eff: 1/2 m_eff v^2 = 1/2 k delta^2 (the dashpot only lowers the
// overlap). A steady load it holds there is k delta.
inline double impact_speed_held(double k, double m_eff, double delta) {
  return delta * std::sqrt(k / m_eff);
}

} // namespace cfddem::dem
