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
  const double* x = v.x;
  const double* y = v.y;
  const double* z = v.z;
  const double* bound = v.bound;
  const double* radius = v.radius;
  // A local copy of the geometry: through the reference it would be reloaded for every entry
  // (the stores to the histogram could alias it).
  const DomainGeometry geo = g;
  const bool walls = !(geo.periodic[0] && geo.periodic[1] && geo.periodic[2]);
  for (std::size_t i = 0; i < v.n; ++i) {
    const double si = bound[i], ri = radius[i], xi = x[i], yi = y[i], zi = z[i];
    double tau = std::numeric_limits<double>::infinity();
    for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
      const std::uint32_t j = nb[k];
      const double dx = geo.image(x[j] - xi, 0), dy = geo.image(y[j] - yi, 1),
                   dz = geo.image(z[j] - zi, 2);
      const double d2 = dx * dx + dy * dy + dz * dz;
      // Pairs that cannot link even over D: no sqrt.
      if (!islands::may_touch(d2, si, bound[j], ri, radius[j], D, margin))
        continue;
      const double gap = std::sqrt(d2) - ri - radius[j] - margin;
      tau = std::min(tau, islands::closing_time(gap, si + bound[j]));
    }
    if (walls) {
      const double pos[3] = {xi, yi, zi};
      for (int a = 0; a < 3; ++a)
        if (!geo.periodic[a])
          tau =
              std::min(tau, islands::closing_time(
                                islands::wall_gap(pos[a], geo.lo[a], geo.hi[a], ri) - margin, si));
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

Choice choose(std::span<const double> hist, double N, double D, double dt_fine, Rho rho,
              std::int64_t m_lo, std::int64_t m_hi, std::int64_t m_prev, int lo_reason,
              double entries, double pairs, bool prev_global) {
  m_lo = std::clamp<std::int64_t>(m_lo, 1, m_hi);
  // busy[m] = sum over c >= m of hist[c].
  std::vector<double> busy(static_cast<std::size_t>(m_hi) + 2, 0.0);
  for (std::int64_t m = m_hi; m >= 1; --m)
    busy[static_cast<std::size_t>(m)] =
        busy[static_cast<std::size_t>(m) + 1] + hist[static_cast<std::size_t>(m)];
  const double overhead = kPerParticle * N + kPerEntry * entries;
  auto K_of = [&](std::int64_t m) {
    return static_cast<double>(fine_steps(D / static_cast<double>(m), dt_fine).K);
  };
  // Every particle on the fine steps: through the explicit scheme's passes where the global mode
  // is a candidate (pairs >= 0), else at the islands' price.
  const double global_step =
      pairs >= 0.0 ? (kGlobalPerStep + kGlobalPerPair * pairs) / kGlobalRate : kPerFineStep;
  // The nominal model (every member on every step after its lead): an upper bound of the
  // islands' work, against which the global mode is weighed.
  auto nominal = [&](std::int64_t m) {
    const double fine = std::min(N, rho.nominal * busy[static_cast<std::size_t>(m)]);
    return static_cast<double>(m) * (overhead + kPerFineStep * fine * K_of(m));
  };
  // The folded model: kFreeSteps per member, the contact steps (the same at every length) left
  // out; past kSwitchMargin kGlobalFraction of the particles a sub-iteration is priced as one
  // that steps everyone.
  const double cliff = kSwitchMargin * kGlobalFraction * N;
  const bool measured_past = rho.at > 0 && rho.measured > cliff;
  auto members_of = [&](std::int64_t m) {
    double b = rho.members * busy[static_cast<std::size_t>(m)];
    if (measured_past)
      b = m <= rho.at
              ? N
              : std::max(b, rho.measured * static_cast<double>(rho.at) / static_cast<double>(m));
    return std::min(N, b);
  };
  auto cost = [&](std::int64_t m) {
    const double members = members_of(m);
    const double mm = static_cast<double>(m);
    if (members > cliff)
      return mm * (overhead + global_step * N * K_of(m));
    return mm * (overhead + kPerFineStep * kFreeSteps * members);
  };
  Choice c;
  c.m_lo = m_lo, c.m_hi = m_hi, c.rho = rho.members;
  double best = std::numeric_limits<double>::infinity();
  double nominal_best = std::numeric_limits<double>::infinity();
  std::int64_t free_best = 1;
  double free_cost = std::numeric_limits<double>::infinity();
  for (std::int64_t m = 1; m <= m_hi; ++m) {
    const double q = cost(m);
    if (q < free_cost)
      free_cost = q, free_best = m;
    if (m >= m_lo && q < best)
      best = q, c.m = m;
    if (m >= m_lo)
      nominal_best = std::min(nominal_best, nominal(m));
  }
  c.reason = free_best < m_lo ? lo_reason : c.m == m_hi && m_hi > 1 ? kFine : kMinCost;
  // The global mode: every particle on the fine step for the whole interval, taken where it
  // costs less than the islands' nominal work at its best (the fold saves nothing in a dense
  // gas, where some contact acts in every island at every step).
  const double global_cost =
      pairs >= 0.0 ? K_of(1) * N * global_step : std::numeric_limits<double>::infinity();
  const bool global = global_cost < nominal_best;
  // Hysteresis: the previous m (or mode) is kept unless the best saves kMinGain of its modelled
  // cost (the fine count of a dilute scene is small and noisy; a change for less is not worth a
  // row). Each comparison within one model.
  const std::int64_t prev = std::clamp<std::int64_t>(m_prev, m_lo, m_hi);
  const bool prev_kept = prev_global || prev == m_prev;
  if (prev_global)
    c.cost_ratio = global ? 1.0 : nominal_best / global_cost;
  else if (global)
    c.cost_ratio = global_cost / nominal(prev);
  else
    c.cost_ratio = cost(prev) > 0.0 ? best / cost(prev) : 1.0; // no particles: nothing to gain
  if (global)
    c.m = 1, c.global = true, c.reason = kGlobal;
  if (c.cost_ratio > 1.0 - kMinGain && prev_kept) {
    c.m = prev_global ? 1 : prev, c.global = prev_global, c.cost_ratio = 1.0;
    c.reason = kKept;
  }
  c.busy_estimate = c.global ? N : members_of(c.m);
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

std::int64_t subiterations_over(double A, double dt_sp, double dt_fine) {
  const std::int64_t hi = most_subiterations(A, dt_fine);
  if (!(dt_sp > 0.0))
    return hi;
  const double m = std::ceil(A / dt_sp * (1 - 1e-12));
  return std::clamp<std::int64_t>(m < static_cast<double>(hi) ? static_cast<std::int64_t>(m) : hi,
                                  1, hi);
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
