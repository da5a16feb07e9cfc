// Small MAC grids shared by the fluid tests.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <numbers>

#include "fluid/grid_field.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::fluid::test {

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
