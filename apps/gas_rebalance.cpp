#include "apps/gas_rebalance.hpp"

#include <algorithm>
#include <cmath>

#include "fluid/gas_boxes.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::apps {

namespace {

// Sum of this rank's cell weights w (its box, x fastest) over the cells of `box`, per slab along
// `axis` (box.cells(axis) values; zero where the boxes do not meet).
std::vector<double> own_slabs(const CellBox& own, const std::vector<double>& w, const CellBox& box,
                              int axis) {
  std::vector<double> out(static_cast<std::size_t>(box.cells(axis)), 0.0);
  std::array<int, 3> lo{}, hi{};
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::max(own.lo[a], box.lo[a]);
    hi[a] = std::min(own.hi[a], box.hi[a]);
    if (hi[a] <= lo[a]) return out;
  }
  const std::array<int, 3> n = own.cells();
  for (int k = lo[2]; k < hi[2]; ++k)
    for (int j = lo[1]; j < hi[1]; ++j)
      for (int i = lo[0]; i < hi[0]; ++i) {
        const std::array<int, 3> g = {i, j, k};
        const auto c = static_cast<std::size_t>((i - own.lo[0]) +
                                                n[0] * ((j - own.lo[1]) + n[1] * (k - own.lo[2])));
        out[static_cast<std::size_t>(g[axis] - box.lo[axis])] += w[c];
      }
  return out;
}

// max / mean of the boxes' loads, from every rank's part of them.
double imbalance(const CellBox& own, const std::vector<double>& w, const std::vector<CellBox>& boxes,
                 const Communicator& comm) {
  std::vector<double> load(boxes.size(), 0.0);
  for (std::size_t b = 0; b < boxes.size(); ++b) {
    for (const double v : own_slabs(own, w, boxes[b], 0)) load[b] += v;
  }
  comm.sum(load);
  double total = 0.0, worst = 0.0;
  for (const double v : load) total += v, worst = std::max(worst, v);
  return total > 0.0 ? worst / (total / static_cast<double>(boxes.size())) : 1.0;
}

} // namespace

GasBalance balance_gas_boxes(const GasCoupling& gas, std::span<const double> x,
                             std::span<const double> y, std::span<const double> z,
                             std::span<const double> steps, double cell_weight,
                             const Communicator& comm) {
  const fluid::MacGrid& grid = gas.solver().grid();
  const CellBox own = grid.box();
  const std::array<int, 3> n = own.cells();
  std::vector<double> w(static_cast<std::size_t>(own.count()), cell_weight);
  const std::span<const double> pos[3] = {x, y, z};
  for (std::size_t p = 0; p < x.size(); ++p) {
    // The particle's cell, clamped into this box (a particle in the ghost reach counts for the
    // nearest owned cell).
    std::array<int, 3> c{};
    for (int a = 0; a < 3; ++a) {
      const double s = (pos[a][p] - grid.origin(a)) / grid.spacing(a);
      const int g = std::isfinite(s) ? static_cast<int>(std::floor(s)) : own.lo[a];
      c[a] = std::clamp(g, own.lo[a], own.hi[a] - 1) - own.lo[a];
    }
    w[static_cast<std::size_t>(c[0] + n[0] * (c[1] + n[1] * c[2]))] += steps[p];
  }
  GasBalance out;
  const SlabWeights slabs = [&](const CellBox& box, int axis) {
    std::vector<double> v = own_slabs(own, w, box, axis);
    comm.sum(v);
    return v;
  };
  out.boxes = fluid::gas_cell_boxes(grid.spec(), comm.size(), slabs);
  out.imbalance_before = imbalance(own, w, gas.boxes(), comm);
  out.imbalance_after = imbalance(own, w, out.boxes, comm);
  return out;
}

} // namespace cfddem::apps
