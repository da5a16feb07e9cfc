// Small MAC grids shared by the fluid tests.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <numbers>
#include <random>

#include "fluid/ghost_fill.hpp"
#include "fluid/grid_field.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::fluid::test {

// A bed's range of gas fractions, uniform in [0.4, 1], every cell different, ghosts filled
// (zero gradient).
template <class Rng> GridField random_gas_fraction(const MacGrid& grid, Rng& rng) {
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  GridField eps = grid.make_field();
  for (double& e : eps.values()) {
    e = 0.4 + 0.6 * uni(rng);
  }
  fill_cell_ghosts(grid, eps, CellGhosts::zero_gradient);
  return eps;
}

// The two fields hold the same doubles bit for bit, ghosts included.
inline bool same_bits(const GridField& a, const GridField& b) {
  return a.values().size() == b.values().size() &&
         std::memcmp(a.values().data(), b.values().data(), a.values().size() * sizeof(double)) == 0;
}

// The 2-norm over the interior cells of div(eps u) + d(eps)/dt: what the projection drives to
// zero.
inline double constraint_residual_norm(const MacGrid& grid, const GridField& div,
                                       const GridField& source) {
  double s = 0.0;
  for (int k = 0; k < grid.cells(2); ++k) {
    for (int j = 0; j < grid.cells(1); ++j) {
      for (int i = 0; i < grid.cells(0); ++i) {
        const double r = div(i, j, k) + source(i, j, k);
        s += r * r;
      }
    }
  }
  return std::sqrt(s);
}

// f at the cells (centring < 0) or the faces normal to axis `centring` of the grid's box, from
// a function of position: the interior index range 0..n (faces 0..n along their axis).
template <class F> void set_field(const MacGrid& g, GridField& f, int centring, F&& fn) {
  std::array<int, 3> hi = g.cells();
  if (centring >= 0) {
    hi[static_cast<std::size_t>(centring)] += 1;
  }
  for (int k = 0; k < hi[2]; ++k) {
    for (int j = 0; j < hi[1]; ++j) {
      for (int i = 0; i < hi[0]; ++i) {
        const std::array<int, 3> l = {i, j, k};
        std::array<double, 3> x{};
        for (int a = 0; a < 3; ++a) {
          const auto s = static_cast<std::size_t>(a);
          x[s] = a == centring ? g.face_position(a, l[s]) : g.cell_centre(a, l[s]);
        }
        f(i, j, k) = fn(x[0], x[1], x[2]);
      }
    }
  }
}

inline BoundaryCondition bc_of(BoundaryKind kind) {
  BoundaryCondition bc;
  bc.kind = kind;
  return bc;
}

// A box with the given cells and lengths and every face of one kind.
inline MacGridSpec box_spec(std::array<int, 3> cells, std::array<double, 3> extent,
                            BoundaryKind kind) {
  MacGridSpec spec;
  spec.cells = cells;
  spec.extent = extent;
  spec.bc.fill(bc_of(kind));
  return spec;
}

inline void set_axis(MacGridSpec& spec, std::size_t axis, BoundaryKind kind) {
  spec.bc[2 * axis] = bc_of(kind);
  spec.bc[2 * axis + 1] = bc_of(kind);
}

// The 2-D Taylor-Green vortex u = U sin(kx) cos(ky), v = -U cos(kx) sin(ky), k = 2 pi / L_x, on
// the x and y faces of the first z layer of a periodic box (ghosts not filled).
inline void set_taylor_green(const MacGrid& grid, std::array<GridField, 3>& u, double amplitude) {
  const double k = 2.0 * std::numbers::pi / grid.length(0);
  const int nx = grid.cells(0);
  const int ny = grid.cells(1);
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i <= nx; ++i) {
      u[0](i, j, 0) =
          amplitude * std::sin(k * grid.face_position(0, i)) * std::cos(k * grid.cell_centre(1, j));
    }
  }
  for (int j = 0; j <= ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      u[1](i, j, 0) = -amplitude * std::cos(k * grid.cell_centre(0, i)) *
                      std::sin(k * grid.face_position(1, j));
    }
  }
}

} // namespace cfddem::fluid::test
