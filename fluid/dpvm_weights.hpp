// Divided-particle-volume weights: the fraction of a cube or sphere of radius r* = s r_p around
// the particle lying in each cell, over as many cells as it covers (docs/theory.md §7; unlike
// MFIX-Exa's dpvm, r* is not capped at dx/2, so cells smaller than a particle work). Kernels.
#pragma once

#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <span>

#include "fluid/cell_stencil.hpp"

namespace cfddem::fluid {

enum class DpvmShape { cube, sphere };

// Most cells a kernel of radius r covers along an axis of spacing dx: ceil(2r/dx) + 1 in exact
// arithmetic, one more for rounding. dpvm_weights floors x/dx - r/dx and x/dx + r/dx apart, and
// x/dx + r/dx may round up onto an integer while x/dx - r/dx stays below one: in
// scenes/cylinder_bed.toml a particle on the column's axis, x = 0.8 mm less an ulp, with dx = r =
// 0.1 mm, covered four cells, not three, and wrote past the buffer before this slot was added.
[[nodiscard]] inline int dpvm_max_cells(double r, double dx) {
  return static_cast<int>(std::ceil(2.0 * r / dx)) + 2;
}

namespace detail {
// Length of [c - h, c + h] inside [x0, x0 + dx].
[[nodiscard]] inline double interval_overlap(double c, double h, double x0, double dx) {
  return std::max(0.0, std::min(c + h, x0 + dx) - std::max(c - h, x0));
}
} // namespace detail

// The cube kernel's factor along one axis for cell `cell` (origin + cell dx is its low face): the
// kernel's share of its length in the cell, overlap / (2r). A cell's weight is w_x w_y w_z.
[[nodiscard]] inline double dpvm_cube_factor(double x, double r, double origin, double dx,
                                             int cell) {
  return detail::interval_overlap(x, r, origin + cell * dx, dx) / (2 * r);
}

// The kernel's cells along one axis: lo and count, as dpvm_weights takes them.
[[nodiscard]] inline std::array<int, 2> dpvm_axis_cells(double x, double r, double origin,
                                                        double dx) {
  const double rel = (x - origin) / dx;
  const int first = static_cast<int>(std::floor(rel - r / dx));
  const int last = static_cast<int>(std::floor(rel + r / dx));
  return {first, last - first + 1};
}

// Stencil and weights (sum 1) of the kernel of radius r centred at x. weights must hold at least
// prod_a dpvm_max_cells(r, dx[a]) values. Sphere: exact along x, midpoint rule with
// `samples` x `samples` chords over (y, z); normalised by the sampled volume, so the weights
// still sum to 1 exactly.
[[nodiscard]] inline CellStencil dpvm_weights(const std::array<double, 3>& x, double r,
                                              const std::array<double, 3>& origin,
                                              const std::array<double, 3>& dx, DpvmShape shape,
                                              std::span<double> weights, int samples = 16) {
  CellStencil s;
  for (int a = 0; a < 3; ++a) {
    const std::array<int, 2> cells = dpvm_axis_cells(x[a], r, origin[a], dx[a]);
    s.lo[a] = cells[0];
    s.size[a] = cells[1];
  }
  assert(static_cast<std::size_t>(s.count()) <= weights.size());
  const std::span<double> w = weights.first(static_cast<std::size_t>(s.count()));
  if (shape == DpvmShape::cube) {
    // Separable: the cube's overlap with a cell is a product of 1-D overlaps, wx * wy * wz
    // (x fastest). The x factors are computed once, into the first row, and every row is
    // filled from them, the first row last (it holds them until then).
    const auto n0 = static_cast<std::size_t>(s.size[0]);
    for (std::size_t a = 0; a < n0; ++a) {
      w[a] = dpvm_cube_factor(x[0], r, origin[0], dx[0], s.lo[0] + static_cast<int>(a));
    }
    // The y factors once (a short kernel's, on the stack), not once per z layer.
    const auto y_factor = [&](int b) {
      return dpvm_cube_factor(x[1], r, origin[1], dx[1], s.lo[1] + b);
    };
    constexpr int kShort = 16;
    std::array<double, kShort> wys;
    const bool short_y = s.size[1] <= kShort;
    for (int b = 0; short_y && b < s.size[1]; ++b) {
      wys[static_cast<std::size_t>(b)] = y_factor(b);
    }
    for (int c = s.size[2] - 1; c >= 0; --c) {
      const double wz = dpvm_cube_factor(x[2], r, origin[2], dx[2], s.lo[2] + c);
      for (int b = s.size[1] - 1; b >= 0; --b) {
        const double wy = short_y ? wys[static_cast<std::size_t>(b)] : y_factor(b);
        double* row =
            w.data() + n0 * (static_cast<std::size_t>(b) +
                             static_cast<std::size_t>(s.size[1]) * static_cast<std::size_t>(c));
        for (std::size_t a = 0; a < n0; ++a) {
          row[a] = w[a] * wy * wz;
        }
      }
    }
    return s;
  }
  std::fill(w.begin(), w.end(), 0.0);
  double total = 0.0;
  const double h = 2.0 * r / samples;
  for (int q = 0; q < samples; ++q) {
    const double dz = -r + (q + 0.5) * h;
    for (int p = 0; p < samples; ++p) {
      const double dy = -r + (p + 0.5) * h;
      const double half2 = r * r - dy * dy - dz * dz;
      if (half2 <= 0.0) {
        continue;
      }
      const double half = std::sqrt(half2);
      const double yc = x[1] + dy;
      const double zc = x[2] + dz;
      const int b = std::clamp(static_cast<int>(std::floor((yc - origin[1]) / dx[1])) - s.lo[1], 0,
                               s.size[1] - 1);
      const int c = std::clamp(static_cast<int>(std::floor((zc - origin[2]) / dx[2])) - s.lo[2], 0,
                               s.size[2] - 1);
      const std::size_t row = static_cast<std::size_t>(s.size[0]) *
                              (static_cast<std::size_t>(b) +
                               static_cast<std::size_t>(s.size[1]) * static_cast<std::size_t>(c));
      for (int a = 0; a < s.size[0]; ++a) {
        const double len =
            detail::interval_overlap(x[0], half, origin[0] + (s.lo[0] + a) * dx[0], dx[0]);
        w[row + static_cast<std::size_t>(a)] += len;
        total += len;
      }
    }
  }
  for (double& v : w) {
    v /= total;
  }
  return s;
}

} // namespace cfddem::fluid
