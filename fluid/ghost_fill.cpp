#include "fluid/ghost_fill.hpp"

#include <algorithm>
#include <cstddef>
#include <span>
#include <stdexcept>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace cfddem::fluid {

namespace {

// Even/odd mirror of a cell index about the low (high) face, clamped to the interior.
int mirror_lo(int g, int n) {
  return wrap_index(-1 - g, 2 * n) < n ? wrap_index(-1 - g, 2 * n) : n - 1;
}
int mirror_hi(int g, int n) {
  const int m = 2 * n - 1 - g;
  return m >= 0 ? m : 0;
}

} // namespace

// What a plane map writes from the source value x.
enum class MapKind {
  copy,    // x
  negate,  // -x (a wall's tangential ghost)
  reflect, // c - x (c = 2 v_b or 2 p_out: the mean of ghost and image is the boundary value)
  set      // c (a wall's or inflow's own face)
};

// f at index dst along `axis` = op(f at index src), over the whole padded plane: every line along
// the axis, the other axes' ghosts included. A ghost (or boundary face) takes its value from a
// point of its own line only.
struct PlaneMap {
  int axis = 0;
  int dst = 0;
  int src = 0;
  MapKind kind = MapKind::copy;
  double c = 0.0;
};

// A fill is a few plane maps per axis, in the order the line-by-line rule visits them. At most
// 1 + kGhostLayers maps per side of an axis.
struct FillPlan {
  std::array<PlaneMap, 6 * (1 + kGhostLayers)> maps{};
  int count = 0;
  void add(int axis, int dst, int src, MapKind kind = MapKind::copy, double c = 0.0) {
    if (static_cast<std::size_t>(count) == maps.size()) {
      throw std::logic_error("ghost fill: more plane maps than a fill can have");
    }
    maps[static_cast<std::size_t>(count++)] = {axis, dst, src, kind, c};
  }
  [[nodiscard]] std::span<const PlaneMap> all() const {
    return {maps.data(), static_cast<std::size_t>(count)};
  }
};

namespace {

// Applies map m to len points of its source plane from `first`, `stride` apart, each written to
// its image `shift` further on, in the destination plane. The kind is chosen once per call.
inline void apply(const PlaneMap& m, double* v, std::ptrdiff_t first, std::ptrdiff_t len,
                  std::ptrdiff_t shift, std::ptrdiff_t stride = 1) {
  double* out = v + first + shift;
  const double* in = v + first;
  switch (m.kind) {
  case MapKind::copy:
    if (stride == 1) {
      std::copy_n(in, len, out);
      break;
    }
    for (std::ptrdiff_t q = 0; q < len; ++q) {
      out[q * stride] = in[q * stride];
    }
    break;
  case MapKind::negate:
    for (std::ptrdiff_t q = 0; q < len; ++q) {
      out[q * stride] = -in[q * stride];
    }
    break;
  case MapKind::reflect:
    for (std::ptrdiff_t q = 0; q < len; ++q) {
      out[q * stride] = m.c - in[q * stride];
    }
    break;
  case MapKind::set:
    for (std::ptrdiff_t q = 0; q < len; ++q) {
      out[q * stride] = m.c;
    }
    break;
  }
}

// Padded extent of the layout along an axis.
std::ptrdiff_t extent(const GridLayout& layout, int a) {
  return layout.cells()[a] + 1 + 2 * kGhostLayers;
}

// The maps along x and y of the padded z-plane kp: a point's x and y maps read and write points
// of its own z-plane only, so the planes are independent.
void apply_xy(const GridLayout& layout, const FillPlan& plan, double* v, std::ptrdiff_t kp) {
  const std::ptrdiff_t sy = layout.stride(1);
  const std::ptrdiff_t sz = layout.stride(2);
  const std::ptrdiff_t ny = extent(layout, 1);
  for (const PlaneMap& m : plan.all()) {
    const std::ptrdiff_t shift = static_cast<std::ptrdiff_t>(m.dst - m.src) * layout.stride(m.axis);
    if (m.axis == 0) {
      // One point per row of the plane.
      apply(m, v, kp * sz + (m.src + kGhostLayers), ny, shift, sy);
    } else if (m.axis == 1) {
      // One row of the plane.
      apply(m, v, kp * sz + (m.src + kGhostLayers) * sy, sy, shift);
    }
  }
}

// The maps along z of the padded row jp (of every z-plane): likewise independent rows.
void apply_z(const GridLayout& layout, const FillPlan& plan, double* v, std::ptrdiff_t jp) {
  const std::ptrdiff_t sy = layout.stride(1);
  const std::ptrdiff_t sz = layout.stride(2);
  for (const PlaneMap& m : plan.all()) {
    if (m.axis == 2) {
      apply(m, v, (m.src + kGhostLayers) * sz + jp * sy, sy,
            static_cast<std::ptrdiff_t>(m.dst - m.src) * sz);
    }
  }
}

// Below this many points a fill runs on the calling thread (a task costs more than it does).
constexpr std::size_t kParallelPoints = 32768;

// Runs the plans on their fields: the x and y maps plane by plane, then the z maps row by row
// (they read the x and y ghosts just made). Each point is written by one map of one task, from
// values no other task writes meanwhile, so the result is the serial fill's on any thread count.
void run_plans(const GridLayout& layout, std::span<const FillPlan> plans,
               std::span<GridField* const> fields) {
  const auto nf = static_cast<std::ptrdiff_t>(plans.size());
  const std::ptrdiff_t nz = extent(layout, 2);
  const std::ptrdiff_t ny = extent(layout, 1);
  const auto xy = [&](std::ptrdiff_t t) {
    apply_xy(layout, plans[static_cast<std::size_t>(t / nz)],
             fields[static_cast<std::size_t>(t / nz)]->values().data(), t % nz);
  };
  const auto z = [&](std::ptrdiff_t t) {
    apply_z(layout, plans[static_cast<std::size_t>(t / ny)],
            fields[static_cast<std::size_t>(t / ny)]->values().data(), t % ny);
  };
  // Each loop's tasks on the calling thread alone below kParallelPoints.
  const bool serial = layout.size() * plans.size() < kParallelPoints;
  const auto each = [serial](std::ptrdiff_t n, const auto& task) {
    if (serial) {
      for (std::ptrdiff_t t = 0; t < n; ++t) {
        task(t);
      }
      return;
    }
    tbb::parallel_for(tbb::blocked_range<std::ptrdiff_t>(0, n),
                      [&](const tbb::blocked_range<std::ptrdiff_t>& r) {
                        for (std::ptrdiff_t t = r.begin(); t != r.end(); ++t) {
                          task(t);
                        }
                      });
  };
  each(nf * nz, xy);
  each(nf * ny, z);
}

// Every line along an axis takes its ghosts from the same positions, so the positions (the
// wraps and mirrors, with their divisions) are found once per axis, not once per line.
FillPlan cell_plan(const MacGrid& grid, CellGhosts mode) {
  FillPlan plan;
  for (int a = 0; a < 3; ++a) {
    const int n = grid.cells(a);
    const BoundaryCondition& lo = grid.bc(a, 0);
    const BoundaryCondition& hi = grid.bc(a, 1);
    const bool periodic = grid.periodic(a);
    const bool fill_lo = !grid.exchanged(a, 0);
    const bool fill_hi = !grid.exchanged(a, 1);
    // Source of ghost -g (g = 1..G) and of ghost n + g (g = 0..G).
    std::array<int, kGhostLayers + 1> lo_src{}, hi_src{};
    for (int g = 0; g <= kGhostLayers; ++g) {
      lo_src[g] = periodic ? wrap_index(-g, n) : mirror_lo(-g, n);
      hi_src[g] = periodic ? wrap_index(n + g, n) : mirror_hi(n + g, n);
    }
    const bool lo_reflects =
        !periodic && mode == CellGhosts::pressure && lo.kind == BoundaryKind::outflow;
    const bool hi_reflects =
        !periodic && mode == CellGhosts::pressure && hi.kind == BoundaryKind::outflow;
    for (int g = 1; fill_lo && g <= kGhostLayers; ++g) {
      if (lo_reflects) {
        plan.add(a, -g, lo_src[g], MapKind::reflect, 2.0 * lo.pressure);
      } else {
        plan.add(a, -g, lo_src[g]);
      }
    }
    for (int g = 0; fill_hi && g <= kGhostLayers; ++g) {
      if (hi_reflects) {
        plan.add(a, n + g, hi_src[g], MapKind::reflect, 2.0 * hi.pressure);
      } else {
        plan.add(a, n + g, hi_src[g]);
      }
    }
  }
  return plan;
}

FillPlan velocity_plan(const MacGrid& grid, int comp) {
  FillPlan plan;
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
            plan.add(a, -g, wrap_index(-g, n));
          }
          for (int g = 0; side == 1 && g <= kGhostLayers; ++g) {
            plan.add(a, n + g, wrap_index(n + g, n));
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
            plan.add(a, face + out * g, face);
          }
          continue;
        }
        const double vb = bc.kind == BoundaryKind::inflow ? bc.velocity[comp] : 0.0;
        plan.add(a, face, face, MapKind::set, vb);
        for (int g = 1; g <= kGhostLayers; ++g) {
          const int inner = face - out * g;
          plan.add(a, face + out * g, inner >= 0 && inner <= n ? inner : face, MapKind::reflect,
                   2.0 * vb);
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
        const int src = periodic    ? wrap_index(ghost, n)
                        : side == 0 ? mirror_lo(ghost, n)
                                    : mirror_hi(ghost, n);
        if (periodic || bc.kind == BoundaryKind::outflow) {
          plan.add(a, ghost, src);
        } else if (bc.kind == BoundaryKind::inflow) {
          plan.add(a, ghost, src, MapKind::reflect, 2.0 * bc.velocity[comp]);
        } else {
          plan.add(a, ghost, src, MapKind::negate);
        }
      }
    }
  }
  return plan;
}

} // namespace

void fill_cell_ghosts(const MacGrid& grid, GridField& q, CellGhosts mode) {
  const FillPlan plans[1] = {cell_plan(grid, mode)};
  GridField* const fields[1] = {&q};
  run_plans(grid.layout(), plans, fields);
}

void fill_velocity_ghosts(const MacGrid& grid, std::array<GridField, 3>& u) {
  const FillPlan plans[3] = {velocity_plan(grid, 0), velocity_plan(grid, 1),
                             velocity_plan(grid, 2)};
  GridField* const fields[3] = {&u[0], &u[1], &u[2]};
  run_plans(grid.layout(), plans, fields);
}

void fill_velocity_ghosts(const MacGrid& grid, int comp, GridField& f) {
  const FillPlan plans[1] = {velocity_plan(grid, comp)};
  GridField* const fields[1] = {&f};
  run_plans(grid.layout(), plans, fields);
}

PlaneGhostFill::PlaneGhostFill(const MacGrid& grid, int comp)
    : layout_(grid.layout()), plan_(std::make_unique<const FillPlan>(velocity_plan(grid, comp))) {}

PlaneGhostFill::~PlaneGhostFill() = default;

void PlaneGhostFill::fill_plane(GridField& f, int k) const {
  apply_xy(layout_, *plan_, f.values().data(), static_cast<std::ptrdiff_t>(k) + kGhostLayers);
}

void PlaneGhostFill::fill_z(GridField& f) const {
  const std::ptrdiff_t ny = extent(layout_, 1);
  for (std::ptrdiff_t jp = 0; jp < ny; ++jp) {
    apply_z(layout_, *plan_, f.values().data(), jp);
  }
}

} // namespace cfddem::fluid
