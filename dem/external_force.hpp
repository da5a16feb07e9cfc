// A per-particle external force (the gas's drag and pressure force), held fixed over the particle
// sub-cycle (MFIX-Exa, docs/theory.md §2) and kept in the particle store's order: every scheme
// that permutes the store permutes it too. Empty means no external force.
#pragma once

#include <cstdint>
#include <span>
#include <stdexcept>
#include <utility>
#include <vector>

namespace cfddem::dem {

struct ExternalForce {
  std::vector<double> x, y, z; // [N], one per particle, or empty

  bool active() const { return !x.empty(); }

  // One value per particle (n of them); empty spans remove the force.
  void set(std::span<const double> fx, std::span<const double> fy, std::span<const double> fz,
           std::size_t n) {
    if (fx.empty()) {
      x.clear(), y.clear(), z.clear();
      return;
    }
    if (fx.size() != n || fy.size() != n || fz.size() != n)
      throw std::invalid_argument("set_external_force: one value per particle expected");
    x.assign(fx.begin(), fx.end());
    y.assign(fy.begin(), fy.end());
    z.assign(fz.begin(), fz.end());
  }

  // Follow a permutation of the store (new index k = old index order[k]); reuses one buffer.
  void permute(std::span<const std::uint32_t> order) {
    if (!active()) return;
    for (auto* v : {&x, &y, &z}) {
      scratch_.resize(order.size());
      for (std::size_t k = 0; k < order.size(); ++k) scratch_[k] = (*v)[order[k]];
      v->swap(scratch_);
    }
  }

  void swap(std::size_t a, std::size_t b) {
    if (!active()) return;
    std::swap(x[a], x[b]), std::swap(y[a], y[b]), std::swap(z[a], z[b]);
  }

private:
  std::vector<double> scratch_;
};

// At a fluid-step boundary a new gas force replaces the one held over the last sub-cycle. A
// particle's velocity is half its last step h behind (v(t - h)), and its next kick pays that
// half together with its own first half, at the force then held. Settling the owed half with
// the old force first, v += (F_old - F_new) h / m, makes every particle take each fluid step's
// force over exactly that fluid step, the interval over which the gas gives it up, so the
// momentum they exchange balances at every fluid-step boundary instead of the particles running
// ahead by h F. The sub-iterated schemes' h is half a sub-iteration for a free particle, where
// this matters (a small riser's total momentum was off by dt_sp/2 x the gas force, 0.4% of its
// growth at dt_sp = dt_f / 10); the explicit schemes' h is dt/2 and they keep the plain
// replacement. The first n particles of the spans; an empty old or new force counts as zero.
inline void settle_owed_half_kick(std::span<double> vx, std::span<double> vy, std::span<double> vz,
                                  std::span<const double> inv_mass, std::span<const double> h,
                                  std::span<const double> ox, std::span<const double> oy,
                                  std::span<const double> oz, std::span<const double> nx,
                                  std::span<const double> ny, std::span<const double> nz) {
  const std::size_t n = h.size();
  const bool has_old = !ox.empty(), has_new = !nx.empty();
  for (std::size_t i = 0; i < n; ++i) {
    const double k = inv_mass[i] * h[i];
    const double dx = (has_old ? ox[i] : 0.0) - (has_new ? nx[i] : 0.0);
    const double dy = (has_old ? oy[i] : 0.0) - (has_new ? ny[i] : 0.0);
    const double dz = (has_old ? oz[i] : 0.0) - (has_new ? nz[i] : 0.0);
    vx[i] += dx * k, vy[i] += dy * k, vz[i] += dz * k;
  }
}

} // namespace cfddem::dem
