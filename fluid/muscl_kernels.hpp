// Limited MUSCL reconstruction of an upwind edge state (van Leer 1979), used for advection of
// the face velocities. Scalar kernels without branches (both slopes and all three states are
// computed, then selected), so loops over them vectorize.
#pragma once

#include <algorithm>
#include <cmath>
#include <string_view>

namespace cfddem::fluid {

enum class Limiter { minmod, van_leer };

// Limited slope from the backward and forward differences dm, dp (TVD: zero at extrema).
template <Limiter L> [[nodiscard]] inline double limited_slope(double dm, double dp) {
  double s = 0.0;
  if constexpr (L == Limiter::minmod) {
    s = dm > 0.0 ? std::min(dm, dp) : std::max(dm, dp);
  } else {
    s = 2.0 * dm * dp / (dm + dp); // inf or NaN where dm = -dp: not selected below
  }
  return dm * dp <= 0.0 ? 0.0 : s;
}

[[nodiscard]] inline double limited_slope(double dm, double dp, Limiter limiter) {
  return limiter == Limiter::minmod ? limited_slope<Limiter::minmod>(dm, dp)
                                    : limited_slope<Limiter::van_leer>(dm, dp);
}

// State on the edge between qm and qp, upwinded by the advecting velocity a: the left state
// qm + slope_m/2 for a > 0, the right state qp - slope_p/2 for a < 0, their mean for a = 0.
template <Limiter L>
[[nodiscard]] inline double muscl_edge_state(double qmm, double qm, double qp, double qpp,
                                             double a) {
  const double dq = qp - qm;
  const double slope_m = limited_slope<L>(qm - qmm, dq);
  const double slope_p = limited_slope<L>(dq, qpp - qp);
  const double left = qm + 0.5 * slope_m;
  const double right = qp - 0.5 * slope_p;
  const double mean = 0.5 * (qm + 0.5 * slope_m + qp - 0.5 * slope_p);
  return a > 0.0 ? left : (a < 0.0 ? right : mean);
}

[[nodiscard]] inline double muscl_edge_state(double qmm, double qm, double qp, double qpp, double a,
                                             Limiter limiter) {
  return limiter == Limiter::minmod ? muscl_edge_state<Limiter::minmod>(qmm, qm, qp, qpp, a)
                                    : muscl_edge_state<Limiter::van_leer>(qmm, qm, qp, qpp, a);
}

} // namespace cfddem::fluid
