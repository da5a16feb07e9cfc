// Trilinear weights of a particle over the 2x2x2 cell-centred stencil (MFIX-Exa's default
// deposition_scheme; docs/theory.md §7). Kernel: no allocation.
#pragma once

#include <array>
#include <cmath>
#include <span>

#include "fluid/cell_stencil.hpp"

namespace cfddem::fluid {

// Along one axis: xh = (x_p - x_lo)/dx + 1/2 and floor(xh); the stencil's cells are
// floor(xh) - 1 and floor(xh).
[[nodiscard]] inline std::array<double, 2> trilinear_position(double x, double origin, double dx) {
  const double xh = (x - origin) / dx + 0.5;
  return {xh, std::floor(xh)};
}

// Along one axis: the first of the stencil's two cells, with its weight w[0] and the other's w[1]
// (the 3-D weights are the products w_x w_y w_z, x fastest).
[[nodiscard]] inline int trilinear_axis(double x, double origin, double dx, double (&w)[2]) {
  const auto [xh, i] = trilinear_position(x, origin, dx);
  w[1] = xh - i;
  w[0] = 1.0 - w[1];
  return static_cast<int>(i) - 1;
}

// xh = (x_p - x_lo)/dx + 1/2, i = floor(xh): cells i-1 and i, w_hi = xh - i (docs/theory.md §7).
[[nodiscard]] inline CellStencil trilinear_weights(const std::array<double, 3>& x,
                                                   const std::array<double, 3>& origin,
                                                   const std::array<double, 3>& dx,
                                                   std::span<double, 8> weights) {
  CellStencil s;
  double w[3][2];
  for (int a = 0; a < 3; ++a) {
    s.lo[a] = trilinear_axis(x[a], origin[a], dx[a], w[a]);
    s.size[a] = 2;
  }
  std::size_t m = 0; // x fastest
  for (int c = 0; c < 2; ++c) {
    for (int b = 0; b < 2; ++b) {
      for (int a = 0; a < 2; ++a) {
        weights[m++] = w[0][a] * w[1][b] * w[2][c];
      }
    }
  }
  return s;
}

} // namespace cfddem::fluid
