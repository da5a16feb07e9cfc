// Limited MUSCL reconstruction of an upwind edge state (van Leer 1979), used for advection of
// the face velocities. Scalar kernels.
#pragma once

#include <algorithm>
#include <cmath>
#include <string_view>

namespace cfddem::fluid {

enum class Limiter { minmod, van_leer };

// Limited slope from the backward and forward differences dm, dp (TVD: zero at extrema).
[[nodiscard]] inline double limited_slope(double dm, double dp, Limiter limiter) {
  if (dm * dp <= 0.0) {
    return 0.0;
  }
  if (limiter == Limiter::minmod) {
    return dm > 0.0 ? std::min(dm, dp) : std::max(dm, dp);
  }
  return 2.0 * dm * dp / (dm + dp);
}

// State on the edge between qm and qp, upwinded by the advecting velocity a: the left state
// qm + slope_m/2 for a > 0, the right state qp - slope_p/2 for a < 0, their mean for a = 0.
[[nodiscard]] inline double muscl_edge_state(double qmm, double qm, double qp, double qpp, double a,
                                             Limiter limiter) {
  const double dq = qp - qm;
  if (a > 0.0) {
    return qm + 0.5 * limited_slope(qm - qmm, dq, limiter);
  }
  if (a < 0.0) {
    return qp - 0.5 * limited_slope(dq, qpp - qp, limiter);
  }
  return 0.5 * (qm + 0.5 * limited_slope(qm - qmm, dq, limiter) + qp -
                0.5 * limited_slope(dq, qpp - qp, limiter));
}

} // namespace cfddem::fluid
