#include "fluid/ghost_fill.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace cfddem::fluid {

namespace {

// Calls line(base) for every line of the padded index space along `axis`; base is the linear
// index of the point with index 0 along axis. A line's ghosts are filled from points of the
// same line only, so lines are independent TBB tasks (by blocks of the outer index): the
// result does not depend on the thread count.
template <class Line> void for_each_line(const GridLayout& layout, int axis, Line&& line) {
  const int b = (axis + 1) % 3;
  const int c = (axis + 2) % 3;
  const auto& n = layout.cells();
  tbb::parallel_for(tbb::blocked_range<int>(-kGhostLayers, n[c] + kGhostLayers + 1),
                    [&](const tbb::blocked_range<int>& r) {
                      for (int jc = r.begin(); jc != r.end(); ++jc) {
                        for (int jb = -kGhostLayers; jb <= n[b] + kGhostLayers; ++jb) {
                          std::array<int, 3> idx{};
                          idx[b] = jb;
                          idx[c] = jc;
                          line(layout.index(idx));
                        }
                      }
                    });
}

int wrap(int i, int n) {
  return ((i % n) + n) % n;
}

// Even/odd mirror of a cell index about the low (high) face, clamped to the interior.
int mirror_lo(int g, int n) {
  return wrap(-1 - g, 2 * n) < n ? wrap(-1 - g, 2 * n) : n - 1;
}
int mirror_hi(int g, int n) {
  const int m = 2 * n - 1 - g;
  return m >= 0 ? m : 0;
}

} // namespace

void fill_cell_ghosts(const MacGrid& grid, GridField& q, CellGhosts mode) {
  const GridLayout& layout = grid.layout();
  for (int a = 0; a < 3; ++a) {
    const int n = grid.cells(a);
    const std::ptrdiff_t s = layout.stride(a);
    const BoundaryCondition& lo = grid.bc(a, 0);
    const BoundaryCondition& hi = grid.bc(a, 1);
    const bool periodic = grid.periodic(a);
    const bool fill_lo = !grid.exchanged(a, 0);
    const bool fill_hi = !grid.exchanged(a, 1);
    if (!fill_lo && !fill_hi) {
      continue;
    }
    for_each_line(layout, a, [&](std::size_t base) {
      const auto at = [&](int i) -> double& { return q[base + static_cast<std::size_t>(i * s)]; };
      for (int g = 1; fill_lo && g <= kGhostLayers; ++g) {
        if (periodic) {
          at(-g) = at(wrap(-g, n));
          continue;
        }
        const double inner = at(mirror_lo(-g, n));
        at(-g) = (mode == CellGhosts::pressure && lo.kind == BoundaryKind::outflow)
                     ? 2.0 * lo.pressure - inner
                     : inner;
      }
      for (int g = 0; fill_hi && g <= kGhostLayers; ++g) {
        if (periodic) {
          at(n + g) = at(wrap(n + g, n));
          continue;
        }
        const double inner = at(mirror_hi(n + g, n));
        at(n + g) = (mode == CellGhosts::pressure && hi.kind == BoundaryKind::outflow)
                        ? 2.0 * hi.pressure - inner
                        : inner;
      }
    });
  }
}

void fill_velocity_ghosts(const MacGrid& grid, int comp, GridField& f) {
  const GridLayout& layout = grid.layout();
  {
    for (int a = 0; a < 3; ++a) {
      const int n = grid.cells(a);
      const std::ptrdiff_t s = layout.stride(a);
      const bool periodic = grid.periodic(a);
      const std::array<bool, 2> fill = {!grid.exchanged(a, 0), !grid.exchanged(a, 1)};
      if (!fill[0] && !fill[1]) {
        continue;
      }
      for_each_line(layout, a, [&](std::size_t base) {
        const auto at = [&](int i) -> double& { return f[base + static_cast<std::size_t>(i * s)]; };
        if (a == comp) {
          // Normal component on its own axis: faces 0..n.
          if (periodic) {
            for (int g = 1; g <= kGhostLayers; ++g) {
              at(-g) = at(wrap(-g, n));
            }
            for (int g = 0; g <= kGhostLayers; ++g) {
              at(n + g) = at(wrap(n + g, n));
            }
            return;
          }
          for (int side = 0; side < 2; ++side) {
            if (!fill[side]) {
              continue;
            }
            const BoundaryCondition& bc = grid.bc(a, side);
            const int face = side == 0 ? 0 : n;
            const int out = side == 0 ? -1 : 1;
            if (bc.kind == BoundaryKind::outflow) {
              for (int g = 1; g <= kGhostLayers; ++g) {
                at(face + out * g) = at(face);
              }
              continue;
            }
            const double vb = bc.kind == BoundaryKind::inflow ? bc.velocity[comp] : 0.0;
            at(face) = vb;
            for (int g = 1; g <= kGhostLayers; ++g) {
              const int inner = face - out * g;
              at(face + out * g) = 2.0 * vb - at(inner >= 0 && inner <= n ? inner : face);
            }
          }
          return;
        }
        // Tangential component: cells 0..n-1 along this axis.
        for (int side = 0; side < 2; ++side) {
          if (!fill[side]) {
            continue;
          }
          const BoundaryCondition& bc = grid.bc(a, side);
          for (int g = 1; g <= kGhostLayers; ++g) {
            const int ghost = side == 0 ? -g : n - 1 + g;
            if (periodic) {
              at(ghost) = at(wrap(ghost, n));
              continue;
            }
            const double inner = at(side == 0 ? mirror_lo(ghost, n) : mirror_hi(ghost, n));
            switch (bc.kind) {
            case BoundaryKind::outflow:
              at(ghost) = inner;
              break;
            case BoundaryKind::inflow:
              at(ghost) = 2.0 * bc.velocity[comp] - inner;
              break;
            default:
              at(ghost) = -inner;
              break;
            }
          }
        }
      });
    }
  }
}

void fill_velocity_ghosts(const MacGrid& grid, std::array<GridField, 3>& u) {
  for (int comp = 0; comp < 3; ++comp) {
    fill_velocity_ghosts(grid, comp, u[comp]);
  }
}

} // namespace cfddem::fluid
