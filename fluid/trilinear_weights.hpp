// Trilinear weights of a particle over the 2x2x2 cell-centred stencil (MFIX-Exa's default
// deposition_scheme; docs/theory.md §7). Kernel: no allocation.
#pragma once

#include <array>
#include <cmath>
#include <span>

#include "fluid/cell_stencil.hpp"

namespace cfddem::fluid {

// xh = (x_p - x_lo)/dx + 1/2, i = floor(xh): cells i-1 and i, w_hi = xh - i (docs/theory.md §7).
[[nodiscard]] inline CellStencil trilinear_weights(const std::array<double, 3>& x,
                                                   const std::array<double, 3>& origin,
                                                   const std::array<double, 3>& dx,
                                                   std::span<double, 8> weights) {
  CellStencil s;
  std::array<std::array<double, 2>, 3> w{};
  for (int a = 0; a < 3; ++a) {
    const double xh = (x[a] - origin[a]) / dx[a] + 0.5;
    const double i = std::floor(xh);
    s.lo[a] = static_cast<int>(i) - 1;
    s.size[a] = 2;
    w[a][1] = xh - i;
    w[a][0] = 1.0 - w[a][1];
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
