#include "fluid/ghost_fill.hpp"

#include <algorithm>

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

// f at index dst along axis a = f at index src, over the whole padded plane: every line along a,
// the other axes' ghosts included, as for_each_line visits them. A periodic axis's ghosts are
// such copies; whole planes are contiguous runs of memory (rows for the middle axis, single
// values only for the first), where the line-by-line fill pays its loop for every value.
void copy_plane(const GridLayout& layout, int a, int dst, int src, GridField& f) {
  double* v = f.values().data();
  const std::ptrdiff_t s = layout.stride(a);
  const std::ptrdiff_t period = s * (layout.cells()[a] + 1 + 2 * kGhostLayers);
  const auto total = static_cast<std::ptrdiff_t>(layout.size());
  const std::ptrdiff_t shift = static_cast<std::ptrdiff_t>(dst - src) * s;
  for (std::ptrdiff_t run = (src + kGhostLayers) * s; run < total; run += period) {
    std::copy_n(v + run, s, v + run + shift);
  }
}

} // namespace

// Every line along an axis takes its ghosts from the same positions, so the positions (the
// wraps and mirrors, with their divisions) are found once per axis, not once per line.
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
    if (periodic && fill_lo && fill_hi) {
      for (int g = 1; g <= kGhostLayers; ++g) {
        copy_plane(layout, a, -g, wrap(-g, n), q);
      }
      for (int g = 0; g <= kGhostLayers; ++g) {
        copy_plane(layout, a, n + g, wrap(n + g, n), q);
      }
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
    for_each_line(layout, a, [&](std::size_t base) {
      const auto at = [&](int i) -> double& { return q[base + static_cast<std::size_t>(i * s)]; };
      for (int g = 1; fill_lo && g <= kGhostLayers; ++g) {
        const double inner = at(lo_src[g]);
        at(-g) = lo_reflects ? 2.0 * lo.pressure - inner : inner;
      }
      for (int g = 0; fill_hi && g <= kGhostLayers; ++g) {
        const double inner = at(hi_src[g]);
        at(n + g) = hi_reflects ? 2.0 * hi.pressure - inner : inner;
      }
    });
  }
}

void fill_velocity_ghosts(const MacGrid& grid, int comp, GridField& f) {
  const GridLayout& layout = grid.layout();
  for (int a = 0; a < 3; ++a) {
    const int n = grid.cells(a);
    const std::ptrdiff_t s = layout.stride(a);
    const bool periodic = grid.periodic(a);
    const std::array<bool, 2> fill = {!grid.exchanged(a, 0), !grid.exchanged(a, 1)};
    if (!fill[0] && !fill[1]) {
      continue;
    }
    if (a == comp) {
      // Normal component on its own axis: faces 0..n.
      if (periodic && fill[0] && fill[1]) {
        for (int g = 1; g <= kGhostLayers; ++g) {
          copy_plane(layout, a, -g, wrap(-g, n), f);
        }
        for (int g = 0; g <= kGhostLayers; ++g) {
          copy_plane(layout, a, n + g, wrap(n + g, n), f);
        }
        continue;
      }
      if (periodic) {
        std::array<int, kGhostLayers + 1> lo_src{}, hi_src{};
        for (int g = 0; g <= kGhostLayers; ++g) {
          lo_src[g] = wrap(-g, n);
          hi_src[g] = wrap(n + g, n);
        }
        for_each_line(layout, a, [&](std::size_t base) {
          const auto at = [&](int i) -> double& {
            return f[base + static_cast<std::size_t>(i * s)];
          };
          for (int g = 1; g <= kGhostLayers; ++g) {
            at(-g) = at(lo_src[g]);
          }
          for (int g = 0; g <= kGhostLayers; ++g) {
            at(n + g) = at(hi_src[g]);
          }
        });
        continue;
      }
      for_each_line(layout, a, [&](std::size_t base) {
        const auto at = [&](int i) -> double& { return f[base + static_cast<std::size_t>(i * s)]; };
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
      });
      continue;
    }
    // Tangential component: cells 0..n-1 along this axis; ghost g of a side and its source.
    if (periodic && fill[0] && fill[1]) {
      for (int side = 0; side < 2; ++side) {
        for (int g = 1; g <= kGhostLayers; ++g) {
          const int ghost = side == 0 ? -g : n - 1 + g;
          copy_plane(layout, a, ghost, wrap(ghost, n), f);
        }
      }
      continue;
    }
    std::array<std::array<int, kGhostLayers + 1>, 2> ghost{}, src{};
    // 0: copy (periodic, outflow), 1: -inner (wall), 2: 2 v_b - inner (inflow).
    std::array<int, 2> rule{0, 0};
    std::array<double, 2> twice_vb{0.0, 0.0};
    for (int side = 0; side < 2; ++side) {
      const BoundaryCondition& bc = grid.bc(a, side);
      for (int g = 1; g <= kGhostLayers; ++g) {
        ghost[side][g] = side == 0 ? -g : n - 1 + g;
        src[side][g] = periodic    ? wrap(ghost[side][g], n)
                       : side == 0 ? mirror_lo(ghost[side][g], n)
                                   : mirror_hi(ghost[side][g], n);
      }
      if (!periodic && bc.kind == BoundaryKind::inflow) {
        rule[side] = 2;
        twice_vb[side] = 2.0 * bc.velocity[comp];
      } else if (!periodic && bc.kind != BoundaryKind::outflow) {
        rule[side] = 1;
      }
    }
    for_each_line(layout, a, [&](std::size_t base) {
      const auto at = [&](int i) -> double& { return f[base + static_cast<std::size_t>(i * s)]; };
      for (int side = 0; side < 2; ++side) {
        if (!fill[side]) {
          continue;
        }
        for (int g = 1; g <= kGhostLayers; ++g) {
          const double inner = at(src[side][g]);
          at(ghost[side][g]) = rule[side] == 0   ? inner
                               : rule[side] == 1 ? -inner
                                                 : twice_vb[side] - inner;
        }
      }
    });
  }
}

void fill_velocity_ghosts(const MacGrid& grid, std::array<GridField, 3>& u) {
  for (int comp = 0; comp < 3; ++comp) {
    fill_velocity_ghosts(grid, comp, u[comp]);
  }
}

} // namespace cfddem::fluid
