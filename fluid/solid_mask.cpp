#include "fluid/solid_mask.hpp"

#include <algorithm>
#include <cstddef>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "fluid/box_loops.hpp"

namespace cfddem::fluid {

SolidMask::SolidMask(const MacGrid& grid) : active_(grid.has_solid()) {
  if (!active_) {
    return;
  }
  const GridLayout& layout = grid.layout();
  const auto& n = grid.cells();
  constexpr int g = kGhostLayers;
  const std::array<int, 3> lo = {-g, -g, -g};
  const std::array<int, 3> hi = {n[0] + g, n[1] + g, n[2] + g}; // every padded index
  // A ghost cell beyond a face of the domain takes the status of the cell inside it: its
  // velocities are the boundary condition's (the walls' mirror images), which must stay.
  const auto& first = grid.box().lo;
  const auto& global = grid.global_cells();
  const auto inside = [&](int a, int local) {
    const int at = std::clamp(first[a] + local, 0, global[a] - 1);
    return at - first[a];
  };
  cells_ = grid.make_field(0.0);
  for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int j, int k) {
    for (int i = lo[0]; i <= hi[0]; ++i) {
      const bool solid = grid.solid_cell(inside(0, i), inside(1, j), inside(2, k));
      cells_[static_cast<std::size_t>(row + i - lo[0])] = solid ? 0.0 : 1.0;
    }
  });
  for (int a = 0; a < 3; ++a) {
    faces_[a] = cells_; // the lowest padded face has no low cell: its own cell decides
    wall_[a] = grid.make_field(0.0);
    const std::ptrdiff_t s = layout.stride(a);
    std::array<int, 3> from = lo;
    from[a] = lo[a] + 1;
    for_box(layout, from, hi, [&](std::ptrdiff_t p) {
      const auto f = static_cast<std::size_t>(p);
      faces_[a][f] = cells_[f] * cells_[f - static_cast<std::size_t>(s)];
    });
  }
  // The wall's shear: an open a-face's neighbour along a tangential axis b that is closed (a
  // solid cell beside it). Neighbours beyond the domain's faces along b are left to the box's
  // boundary conditions, whose ghost layers already mirror the velocity.
  for (int a = 0; a < 3; ++a) {
    std::array<int, 3> top = {n[0] - 1, n[1] - 1, n[2] - 1};
    top[a] = n[a];
    normal_[a] = grid.make_field(0.0);
    for (int b = 0; b < 3; ++b) {
      if (b == a) {
        // Along its own axis a closed neighbour lies in the domain whenever the face is open
        // (the face between a gas and a solid cell).
        const auto sa = static_cast<std::size_t>(layout.stride(a));
        const double inv_h2 = 1.0 / (grid.spacing(a) * grid.spacing(a));
        for_box(layout, {0, 0, 0}, top, [&](std::ptrdiff_t p) {
          const auto f = static_cast<std::size_t>(p);
          if (faces_[a][f] != 0.0) {
            normal_[a][f] = inv_h2 * ((faces_[a][f - sa] == 0.0 ? 1.0 : 0.0) +
                                      (faces_[a][f + sa] == 0.0 ? 1.0 : 0.0));
          }
        });
        continue;
      }
      const auto sb = static_cast<std::size_t>(layout.stride(b));
      const double inv_h2 = 1.0 / (grid.spacing(b) * grid.spacing(b));
      for_box_rows(layout, {0, 0, 0}, top, [&](std::ptrdiff_t row, int j, int k) {
        const std::array<int, 2> at = {j, k};
        for (int i = 0; i <= top[0]; ++i) {
          const auto f = static_cast<std::size_t>(row + i);
          if (faces_[a][f] == 0.0) {
            continue;
          }
          const int mine = b == 0 ? i : at[static_cast<std::size_t>(b - 1)];
          const int global_index = first[b] + mine;
          double add = 0.0;
          if (global_index > 0 && faces_[a][f - sb] == 0.0) {
            add += inv_h2;
          }
          if (global_index < global[b] - 1 && faces_[a][f + sb] == 0.0) {
            add += inv_h2;
          }
          wall_[a][f] += add;
        }
      });
    }
  }
}

namespace {

// v *= mask over every index, blocks as TBB tasks (an elementwise product is exact in any order).
void multiply(GridField& v, const GridField& mask) {
  const std::span<double> x = v.values();
  const std::span<const double> m = mask.values();
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, x.size(), 16384),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t i = r.begin(); i != r.end(); ++i) {
                        x[i] *= m[i];
                      }
                    });
}

} // namespace

void SolidMask::close(std::array<GridField, 3>& u) const {
  if (!active_) {
    return;
  }
  for (int a = 0; a < 3; ++a) {
    multiply(u[a], faces_[a]);
  }
}

void SolidMask::clear_solid(GridField& v) const {
  if (active_) {
    multiply(v, cells_);
  }
}

} // namespace cfddem::fluid
