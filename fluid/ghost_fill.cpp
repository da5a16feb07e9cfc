#include "fluid/ghost_fill.hpp"

#include <algorithm>

namespace cfddem::fluid {

namespace {

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

// f at index dst along axis a = op(f at index src), over the whole padded plane: every line along
// a, the other axes' ghosts included. A ghost (or boundary face) takes its value from a point of
// its own line only, so a fill is a few such plane maps per axis, done in the order the
// line-by-line rule would visit them. Planes are contiguous runs of memory (rows for the middle
// axis; single values only for the first), and a map is exact in any order.
template <class Op>
void map_plane(const GridLayout& layout, int a, int dst, int src, GridField& f, Op&& op) {
  double* v = f.values().data();
  const std::ptrdiff_t s = layout.stride(a);
  const std::ptrdiff_t period = s * (layout.cells()[a] + 1 + 2 * kGhostLayers);
  const auto total = static_cast<std::ptrdiff_t>(layout.size());
  const std::ptrdiff_t shift = static_cast<std::ptrdiff_t>(dst - src) * s;
  for (std::ptrdiff_t run = (src + kGhostLayers) * s; run < total; run += period) {
    for (std::ptrdiff_t m = run; m < run + s; ++m) {
      v[m + shift] = op(v[m]);
    }
  }
}

void copy_plane(const GridLayout& layout, int a, int dst, int src, GridField& f) {
  map_plane(layout, a, dst, src, f, [](double x) { return x; });
}

} // namespace

// Every line along an axis takes its ghosts from the same positions, so the positions (the
// wraps and mirrors, with their divisions) are found once per axis, not once per line.
void fill_cell_ghosts(const MacGrid& grid, GridField& q, CellGhosts mode) {
  const GridLayout& layout = grid.layout();
  for (int a = 0; a < 3; ++a) {
    const int n = grid.cells(a);
    const BoundaryCondition& lo = grid.bc(a, 0);
    const BoundaryCondition& hi = grid.bc(a, 1);
    const bool periodic = grid.periodic(a);
    const bool fill_lo = !grid.exchanged(a, 0);
    const bool fill_hi = !grid.exchanged(a, 1);
    if (!fill_lo && !fill_hi) {
      continue;
    }
    // Source of ghost -g (g = 1..G) and of ghost n + g (g = 0..G).
    std::array<int, kGhostLayers + 1> lo_src{}, hi_src{};
    for (int g = 0; g <= kGhostLayers; ++g) {
      lo_src[g] = periodic ? wrap(-g, n) : mirror_lo(-g, n);
      hi_src[g] = periodic ? wrap(n + g, n) : mirror_hi(n + g, n);
    }
    const bool lo_reflects =
        !periodic && mode == CellGhosts::pressure && lo.kind == BoundaryKind::outflow;
    const bool hi_reflects =
        !periodic && mode == CellGhosts::pressure && hi.kind == BoundaryKind::outflow;
    for (int g = 1; fill_lo && g <= kGhostLayers; ++g) {
      if (lo_reflects) {
        map_plane(layout, a, -g, lo_src[g], q,
                  [p = lo.pressure](double inner) { return 2.0 * p - inner; });
      } else {
        copy_plane(layout, a, -g, lo_src[g], q);
      }
    }
    for (int g = 0; fill_hi && g <= kGhostLayers; ++g) {
      if (hi_reflects) {
        map_plane(layout, a, n + g, hi_src[g], q,
                  [p = hi.pressure](double inner) { return 2.0 * p - inner; });
      } else {
        copy_plane(layout, a, n + g, hi_src[g], q);
      }
    }
  }
}

void fill_velocity_ghosts(const MacGrid& grid, int comp, GridField& f) {
  const GridLayout& layout = grid.layout();
  for (int a = 0; a < 3; ++a) {
    const int n = grid.cells(a);
    const bool periodic = grid.periodic(a);
    const std::array<bool, 2> fill = {!grid.exchanged(a, 0), !grid.exchanged(a, 1)};
    if (!fill[0] && !fill[1]) {
      continue;
    }
    if (a == comp) {
      // Normal component on its own axis: faces 0..n. A periodic axis takes both sides' planes
      // from their periodic images (also where one side is exchanged); a wall's or inflow's face
      // holds its value and the ghosts reflect about it; an outflow's ghosts copy its face.
      for (int side = 0; side < 2; ++side) {
        if (periodic) {
          for (int g = 1; side == 0 && g <= kGhostLayers; ++g) {
            copy_plane(layout, a, -g, wrap(-g, n), f);
          }
          for (int g = 0; side == 1 && g <= kGhostLayers; ++g) {
            copy_plane(layout, a, n + g, wrap(n + g, n), f);
          }
          continue;
        }
        if (!fill[side]) {
          continue;
        }
        const BoundaryCondition& bc = grid.bc(a, side);
        const int face = side == 0 ? 0 : n;
        const int out = side == 0 ? -1 : 1;
        if (bc.kind == BoundaryKind::outflow) {
          for (int g = 1; g <= kGhostLayers; ++g) {
            copy_plane(layout, a, face + out * g, face, f);
          }
          continue;
        }
        const double vb = bc.kind == BoundaryKind::inflow ? bc.velocity[comp] : 0.0;
        map_plane(layout, a, face, face, f, [vb](double) { return vb; });
        for (int g = 1; g <= kGhostLayers; ++g) {
          const int inner = face - out * g;
          map_plane(layout, a, face + out * g, inner >= 0 && inner <= n ? inner : face, f,
                    [vb](double x) { return 2.0 * vb - x; });
        }
      }
      continue;
    }
    // Tangential component: cells 0..n-1 along this axis. Ghost g of a side is its periodic image
    // or the mirrored cell: copied (periodic, outflow), negated (wall) or 2 v_b - x (inflow).
    for (int side = 0; side < 2; ++side) {
      if (!fill[side]) {
        continue;
      }
      const BoundaryCondition& bc = grid.bc(a, side);
      for (int g = 1; g <= kGhostLayers; ++g) {
        const int ghost = side == 0 ? -g : n - 1 + g;
        const int src = periodic    ? wrap(ghost, n)
                        : side == 0 ? mirror_lo(ghost, n)
                                    : mirror_hi(ghost, n);
        if (periodic || bc.kind == BoundaryKind::outflow) {
          copy_plane(layout, a, ghost, src, f);
        } else if (bc.kind == BoundaryKind::inflow) {
          map_plane(layout, a, ghost, src, f,
                    [w = 2.0 * bc.velocity[comp]](double x) { return w - x; });
        } else {
          map_plane(layout, a, ghost, src, f, [](double x) { return -x; });
        }
      }
    }
  }
}

void fill_velocity_ghosts(const MacGrid& grid, std::array<GridField, 3>& u) {
  for (int comp = 0; comp < 3; ++comp) {
    fill_velocity_ghosts(grid, comp, u[comp]);
  }
}

} // namespace cfddem::fluid
