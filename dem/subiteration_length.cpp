#include "dem/subiteration_length.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "dem/islands_kernels.hpp"
#include "dem/scheme_support.hpp"

namespace cfddem::dem::length {

namespace {

// The candidates m in [1, m_hi] with m < D / tau (tau: a first-contact time).
std::int64_t fine_candidates(double tau, double D, std::int64_t m_hi) {
  if (!(tau > 0.0))
    return m_hi; // in contact now (or a NaN the fault check reports): fine at every length
  const double q = D / tau;
  if (!(q < static_cast<double>(m_hi) + 1.0))
    return m_hi;
  // m < q for m = 1 .. ceil(q) - 1.
  return std::max<std::int64_t>(0, static_cast<std::int64_t>(std::ceil(q)) - 1);
}

} // namespace

void first_contact_histogram(const RowsView& v, const DomainGeometry& g, double margin, double D,
                             std::int64_t m_hi, std::span<std::int64_t> hist) {
  const std::uint32_t* off = v.offsets.data();
  const std::uint32_t* nb = v.neighbors.data();
  for (std::size_t i = 0; i < v.n; ++i) {
    const double si = v.bound[i], ri = v.radius[i];
    double tau = std::numeric_limits<double>::infinity();
    for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
      const std::uint32_t j = nb[k];
      const double dx = g.image(v.x[j] - v.x[i], 0), dy = g.image(v.y[j] - v.y[i], 1),
                   dz = g.image(v.z[j] - v.z[i], 2);
      const double d2 = dx * dx + dy * dy + dz * dz;
      // Pairs that cannot link even over D: no sqrt.
      if (!islands::may_touch(d2, si, v.bound[j], ri, v.radius[j], D, margin))
        continue;
      const double gap = std::sqrt(d2) - ri - v.radius[j] - margin;
      tau = std::min(tau, islands::closing_time(gap, si + v.bound[j]));
    }
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a])
        continue;
      const double pos = a == 0 ? v.x[i] : a == 1 ? v.y[i] : v.z[i];
      tau = std::min(
          tau, islands::closing_time(islands::wall_gap(pos, g.lo[a], g.hi[a], ri) - margin, si));
    }
    const std::int64_t c = fine_candidates(tau, D, m_hi);
    if (c > 0)
      ++hist[static_cast<std::size_t>(c)];
  }
}

const char* reason_text(int r) {
  switch (r) {
  case kStart:
    return "start: the first interval takes dem.nsubit's default count";
  case kMinCost:
    return "least modelled cost per interval";
  case kSkin:
    return "least cost within the skin bound (longer sub-iterations would outrun the list)";
  case kGas:
    return "least cost within the gas force's change bound";
  case kFine:
    return "least cost at the fine step (dt_sp = fine dt)";
  case kKept:
    return "kept: no other count saves 10% of the modelled cost";
  case kGlobal:
    return "global mode: every particle on the fine step costs less than any islands' count";
  default:
    return "?";
  }
}

Choice choose(std::span<const double> hist, double N, double D, double dt_fine, double rho,
              std::int64_t m_lo, std::int64_t m_hi, std::int64_t m_prev, int lo_reason,
              double entries, double pairs, bool prev_global) {
  m_lo = std::clamp<std::int64_t>(m_lo, 1, m_hi);
  // busy[m] = sum over c >= m of hist[c].
  std::vector<double> busy(static_cast<std::size_t>(m_hi) + 2, 0.0);
  for (std::int64_t m = m_hi; m >= 1; --m)
    busy[static_cast<std::size_t>(m)] =
        busy[static_cast<std::size_t>(m) + 1] + hist[static_cast<std::size_t>(m)];
  auto cost = [&](std::int64_t m) {
    const double dt = D / static_cast<double>(m);
    const double fine = std::min(N, rho * busy[static_cast<std::size_t>(m)]);
    const auto K = static_cast<double>(fine_steps(dt, dt_fine).K);
    return static_cast<double>(m) *
           (kPerParticle * N + kPerEntry * entries + kPerFineStep * fine * K);
  };
  Choice c;
  c.m_lo = m_lo, c.m_hi = m_hi, c.rho = rho;
  double best = std::numeric_limits<double>::infinity();
  std::int64_t free_best = 1;
  double free_cost = std::numeric_limits<double>::infinity();
  for (std::int64_t m = 1; m <= m_hi; ++m) {
    const double q = cost(m);
    if (q < free_cost)
      free_cost = q, free_best = m;
    if (m >= m_lo && q < best)
      best = q, c.m = m;
  }
  c.reason = free_best < m_lo ? lo_reason : c.m == m_hi && m_hi > 1 ? kFine : kMinCost;
  // The global mode: every particle on the fine step for the whole interval.
  const double global_cost = pairs >= 0.0
                                 ? static_cast<double>(fine_steps(D, dt_fine).K) * N *
                                       (kGlobalPerStep + kGlobalPerPair * pairs) / kGlobalRate
                                 : std::numeric_limits<double>::infinity();
  if (global_cost < best) {
    best = global_cost;
    c.m = 1, c.global = true, c.reason = kGlobal;
  }
  // Hysteresis: the previous m (or mode) is kept unless the best saves kMinGain of its modelled
  // cost (the fine count of a dilute scene is small and noisy; a change for less is not worth a
  // row).
  const std::int64_t prev = std::clamp<std::int64_t>(m_prev, m_lo, m_hi);
  const bool prev_kept = prev_global || prev == m_prev;
  const double prev_cost = prev_global ? global_cost : cost(prev);
  c.cost_ratio = prev_cost > 0.0 ? best / prev_cost : 1.0; // no particles: nothing to gain
  if (c.cost_ratio > 1.0 - kMinGain && prev_kept) {
    c.m = prev_global ? 1 : prev, c.global = prev_global, c.cost_ratio = 1.0;
    c.reason = kKept;
  }
  c.busy_estimate = c.global ? N : std::min(N, rho * busy[static_cast<std::size_t>(c.m)]);
  return c;
}

double row_entries(double N, double V, double r, double s) {
  if (!(V > 0.0))
    return 0.0;
  const double c = 2.0 * r + s;
  return N * N / V * (4.0 / 3.0) * std::numbers::pi * c * c * c;
}

std::int64_t most_subiterations(double D, double dt_fine) {
  if (!(dt_fine > 0.0) || !(D > dt_fine))
    return 1;
  return std::max<std::int64_t>(1,
                                static_cast<std::int64_t>(std::floor(D / dt_fine * (1 + 1e-12))));
}

std::int64_t fewest_for_skin(double D, double s_max, double skin) {
  if (!(s_max > 0.0) || !(skin > 0.0))
    return 1;
  const double q = 4.0 * s_max * D / skin;
  if (!(q < 1e15))
    return std::numeric_limits<std::int64_t>::max() / 4;
  return std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil(q)));
}

std::int64_t fewest_for_gas(double dA, double a_ref) {
  if (!(dA > 0.0))
    return 1;
  if (!(a_ref > 0.0))
    return std::numeric_limits<std::int64_t>::max() / 4;
  const double q = dA / (kGasChangeBound * a_ref);
  if (!(q < 1e15))
    return std::numeric_limits<std::int64_t>::max() / 4;
  return std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil(q)));
}

} // namespace cfddem::dem::length
