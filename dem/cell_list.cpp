#include "dem/cell_list.hpp"

#include <cmath>

namespace cfddem::dem {

CellGrid make_cell_grid(const DomainGeometry& g, double cutoff, std::size_t particles,
                        double per_particle) {
  CellGrid c;
  double cell = cutoff;
  const double volume = g.length[0] * g.length[1] * g.length[2];
  const double target = per_particle * static_cast<double>(particles) + 64.0;
  if (volume / (cell * cell * cell) > target)
    cell = std::cbrt(volume / target);
  for (int a = 0; a < 3; ++a) {
    c.n[a] = std::max(1, static_cast<int>(std::floor(g.length[a] / cell)));
    c.inv[a] = c.n[a] / g.length[a];
  }
  return c;
}

template <bool Wrap>
void CellList::bin(const DomainGeometry& g, const CellGrid& grid, const double* x, const double* y,
                   const double* z, std::size_t n) {
  g_ = g, grid_ = grid;
  const std::size_t ncell = grid.count();
  cell_of_.resize(n);
  start_.assign(ncell + 1, 0);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t c =
        cell_index(coord<Wrap>(x[i], 0), coord<Wrap>(y[i], 1), coord<Wrap>(z[i], 2));
    cell_of_[i] = static_cast<std::uint32_t>(c);
    ++start_[c + 1];
  }
  for (std::size_t c = 0; c < ncell; ++c)
    start_[c + 1] += start_[c];
  items_.resize(n);
  fill_.assign(start_.begin(), start_.end() - 1);
  for (std::size_t i = 0; i < n; ++i)
    items_[fill_[cell_of_[i]]++] = static_cast<std::uint32_t>(i);
}

template void CellList::bin<false>(const DomainGeometry&, const CellGrid&, const double*,
                                   const double*, const double*, std::size_t);
template void CellList::bin<true>(const DomainGeometry&, const CellGrid&, const double*,
                                  const double*, const double*, std::size_t);

} // namespace cfddem::dem
