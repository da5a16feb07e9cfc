// A per-particle external force (the gas's drag and pressure force), held fixed over the particle
// sub-cycle (MFIX-Exa, physics.md §2) and kept in the particle store's order: every scheme that
// permutes the store permutes it too. Empty means no external force.
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

} // namespace cfddem::dem
