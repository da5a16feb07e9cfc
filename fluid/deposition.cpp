#include "fluid/deposition.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numbers>
#include <type_traits>
#include <vector>

#include <stdexcept>
#include <string>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <fmt/format.h>

#include "core/simd_level.hpp"
#include "core/usable_threads.hpp"
#include "fluid/diffusion_smoothing.hpp"
#include "fluid/trilinear_weights.hpp"

namespace cfddem::fluid {

namespace {
constexpr std::size_t kMaxDepositFields = 8;
// The widest kernel, in cells along an axis, that Deposition::plan stores.
constexpr int kMaxPlannedCells = 16;
// Whether a pass reads its kernels from `plan` (else it computes them).
bool from_plan(const TransferPlan* plan) {
  return plan != nullptr && plan->separable;
}
} // namespace

DepositionKernel parse_deposition_kernel(std::string_view name) {
  if (name == "trilinear") {
    return DepositionKernel::trilinear;
  }
  if (name == "dpvm_cube") {
    return DepositionKernel::dpvm_cube;
  }
  if (name == "dpvm_sphere") {
    return DepositionKernel::dpvm_sphere;
  }
  throw std::invalid_argument("unknown deposition kernel \"" + std::string(name) +
                              "\" (choose trilinear, dpvm_cube or dpvm_sphere)");
}

Deposition::Deposition(const MacGrid& grid, const DepositionSettings& settings, double max_radius,
                       const GridHalo* halo)
    : grid_(grid), settings_(settings), halo_(halo),
      sized_kernel_radius_(settings.width * max_radius) {
  if (grid.distributed() != (halo != nullptr)) {
    throw std::invalid_argument("deposition: a distributed grid needs its halo (and only it)");
  }
  if (grid.distributed() && settings.diffusion > 0.0) {
    throw std::invalid_argument("deposition diffusion is not distributed over ranks yet (D = 0)");
  }
  if (settings.kernel != DepositionKernel::trilinear && !(settings.width > 0.0)) {
    throw std::invalid_argument("deposition width must be positive (particle diameters)");
  }
  if (settings.diffusion < 0.0) {
    throw std::invalid_argument("deposition diffusion D must be >= 0 [m^2]");
  }
  weights_.resize(
      settings.kernel == DepositionKernel::trilinear ? 8 : kernel_cells(sized_kernel_radius_));
}

std::size_t Deposition::kernel_cells(double r) const {
  std::size_t cells = 1;
  for (int a = 0; a < 3; ++a) {
    cells *= static_cast<std::size_t>(dpvm_max_cells(r, grid_.spacing(a)));
  }
  return cells;
}

void Deposition::reserve_weights(double r, std::vector<double>& buf) const {
  if (r <= sized_kernel_radius_) {
    return; // the constructor sized weights_, and stencil() every buffer, for this kernel
  }
  const std::size_t needed = kernel_cells(r);
  if (needed > buf.size()) {
    buf.resize(needed); // a particle larger than max_radius: grow once
  }
}

int Deposition::fold(int axis, int i) const {
  if (grid_.distributed()) {
    return fold_in_box(axis, i);
  }
  const int n = grid_.cells(axis);
  if (i >= 0 && i < n) {
    return i; // inside: the common case, without the divisions below
  }
  if (grid_.periodic(axis)) {
    return ((i % n) + n) % n;
  }
  // Mirror about the wall as often as needed (kernels wider than the domain still conserve).
  const int period = 2 * n;
  int m = ((i % period) + period) % period;
  return m < n ? m : period - 1 - m;
}

// Global stencil index i to the box's local index: mirrored at walls (as above), kept on a
// periodic axis (the ghost's periodic image is the halo's business).
int Deposition::box_index(int axis, int i) const {
  const int n = grid_.global_cells()[axis];
  int g = i;
  if (!grid_.periodic(axis) && (i < 0 || i >= n)) {
    const int period = 2 * n;
    const int m = ((i % period) + period) % period;
    g = m < n ? m : period - 1 - m;
  }
  return g - grid_.box().lo[axis];
}

int Deposition::fold_in_box(int axis, int i) const {
  const int local = box_index(axis, i);
  const int g = local + grid_.box().lo[axis];
  if (local < -kGhostLayers || local > grid_.cells(axis) + kGhostLayers) {
    throw std::runtime_error(fmt::format(
        "deposition: a particle's kernel reaches cell {} along axis {}, beyond the {} ghost "
        "layers of the box of cells {}..{} (a particle outside its rank's box, or a kernel wider "
        "than {} cells: lower fluid.deposition_width or use coarser cells)",
        g, axis, kGhostLayers, grid_.box().lo[axis], grid_.box().hi[axis] - 1, kGhostLayers));
  }
  return local;
}

std::string Deposition::reach_problem(const ParticlePositions& p) {
  if (!grid_.distributed()) {
    return {};
  }
  for (std::size_t n = 0; n < p.radius.size(); ++n) {
    const CellStencil s = stencil({p.x[n], p.y[n], p.z[n]}, p.radius[n], weights_);
    for (int a = 0; a < 3; ++a) {
      for (int c = 0; c < s.size[a]; ++c) {
        const int local = box_index(a, s.lo[a] + c);
        if (local < -kGhostLayers || local > grid_.cells(a) + kGhostLayers) {
          return fmt::format(
              "deposition: the kernel of the particle at ({:.6g}, {:.6g}, {:.6g}) m reaches "
              "cell {} along axis {}, beyond the {} ghost layers of its rank's box of cells "
              "{}..{} (lower fluid.deposition_width, use coarser cells, or a smaller "
              "dem.neighbor_skin: owners are settled at neighbor rebuilds)",
              p.x[n], p.y[n], p.z[n], local + grid_.box().lo[a], a, kGhostLayers, grid_.box().lo[a],
              grid_.box().hi[a] - 1);
        }
      }
    }
  }
  return {};
}

CellStencil Deposition::stencil(const std::array<double, 3>& x, double radius,
                                std::vector<double>& buf) const {
  if (buf.size() < weights_.size()) {
    buf.resize(weights_.size());
  }
  const std::array<double, 3> origin = {grid_.origin(0), grid_.origin(1), grid_.origin(2)};
  const std::array<double, 3> dx = {grid_.spacing(0), grid_.spacing(1), grid_.spacing(2)};
  CellStencil s;
  switch (settings_.kernel) {
  case DepositionKernel::trilinear:
    s = trilinear_weights(x, origin, dx, std::span<double, 8>(buf.data(), 8));
    break;
  case DepositionKernel::dpvm_cube:
    reserve_weights(settings_.width * radius, buf);
    s = dpvm_weights(x, settings_.width * radius, origin, dx, DpvmShape::cube, buf);
    break;
  case DepositionKernel::dpvm_sphere:
    reserve_weights(settings_.width * radius, buf);
    s = dpvm_weights(x, settings_.width * radius, origin, dx, DpvmShape::sphere, buf,
                     settings_.sphere_samples);
    break;
  }
  return s;
}

void Deposition::onto_gas_cells(const CellStencil& s, double* weight) const {
  const auto& first = grid_.box().lo; // the stencil's indices are the grid's, not the box's
  double gas = 0.0;
  double solid = 0.0;
  std::size_t m = 0;
  for (int c = 0; c < s.size[2]; ++c) {
    for (int b = 0; b < s.size[1]; ++b) {
      for (int a = 0; a < s.size[0]; ++a, ++m) {
        const bool in_solid = grid_.solid_cell(s.lo[0] + a - first[0], s.lo[1] + b - first[1],
                                               s.lo[2] + c - first[2]);
        (in_solid ? solid : gas) += weight[m];
      }
    }
  }
  if (!(solid > 0.0) || !(gas > 0.0)) {
    return; // nothing in the wall, or nothing outside it (left as it is)
  }
  const double scale = (gas + solid) / gas;
  m = 0;
  for (int c = 0; c < s.size[2]; ++c) {
    for (int b = 0; b < s.size[1]; ++b) {
      for (int a = 0; a < s.size[0]; ++a, ++m) {
        const bool in_solid = grid_.solid_cell(s.lo[0] + a - first[0], s.lo[1] + b - first[1],
                                               s.lo[2] + c - first[2]);
        weight[m] = in_solid ? 0.0 : weight[m] * scale;
      }
    }
  }
}

template <class Visit>
void Deposition::for_each_weight(const std::array<double, 3>& x, double radius,
                                 std::vector<double>& buf, Visit&& visit, int k0, int k1) const {
  // The common trilinear kernel's 8 weights on the stack, the others' in buf.
  std::array<double, 8> w8{};
  const bool trilinear = settings_.kernel == DepositionKernel::trilinear;
  const CellStencil s =
      trilinear ? trilinear_weights(x, {grid_.origin(0), grid_.origin(1), grid_.origin(2)},
                                    {grid_.spacing(0), grid_.spacing(1), grid_.spacing(2)},
                                    std::span<double, 8>(w8))
                : stencil(x, radius, buf);
  double* const weight = trilinear ? w8.data() : buf.data();
  if (grid_.has_solid()) {
    onto_gas_cells(s, weight);
  }
  // The row's x indices, folded once per particle rather than once per cell (every row of the
  // kernel has the same ones); index(i, j, k) = index(0, j, k) + i.
  constexpr int kShortRow = 16;
  std::array<int, kShortRow> fx; // the first size[0] are set below
  const bool short_row = s.size[0] <= kShortRow;
  if (short_row) {
    for (int a = 0; a < s.size[0]; ++a) {
      fx[static_cast<std::size_t>(a)] = fold(0, s.lo[0] + a);
    }
  }
  const GridLayout& layout = grid_.layout();
  std::size_t m = 0; // weights are stored x fastest, as the loops run
  const auto plane_size = static_cast<std::size_t>(s.size[0]) * static_cast<std::size_t>(s.size[1]);
  for (int c = 0; c < s.size[2]; ++c) {
    const int k = fold(2, s.lo[2] + c);
    if (k < k0 || k >= k1) {
      m += plane_size; // another range's plane
      continue;
    }
    for (int b = 0; b < s.size[1]; ++b) {
      const int j = fold(1, s.lo[1] + b);
      const auto row = static_cast<std::ptrdiff_t>(layout.index(0, j, k));
      for (int a = 0; a < s.size[0]; ++a) {
        const double w = weight[m++];
        if (w != 0.0) {
          const int i = short_row ? fx[static_cast<std::size_t>(a)] : fold(0, s.lo[0] + a);
          if constexpr (std::is_invocable_v<Visit, std::size_t, double, int>) {
            visit(static_cast<std::size_t>(row + i), w, a); // the cell's place in its row
          } else {
            visit(static_cast<std::size_t>(row + i), w);
          }
        }
      }
    }
  }
}

template <int Cells, class Visit>
void Deposition::for_each_planned_weight(const TransferPlan& plan, std::size_t q, Visit&& visit,
                                         int k0, int k1) const {
  const std::size_t base = q * static_cast<std::size_t>(plan.stride);
  const double* wx = plan.factor.data() + base;
  const double* wy = wx + plan.slots[0];
  const double* wz = wy + plan.slots[1];
  const std::int32_t* ix = plan.index.data() + base;
  const std::int32_t* iy = ix + plan.slots[0];
  const std::int32_t* iz = iy + plan.slots[1];
  const std::uint8_t* n = plan.cells.data() + 3 * q;
  const int nx = Cells > 0 ? Cells : n[0];
  const int ny = Cells > 0 ? Cells : n[1];
  const int nz = Cells > 0 ? Cells : n[2];
  const GridLayout& layout = grid_.layout();
  for (int c = 0; c < nz; ++c) {
    const int k = iz[c];
    if (k < k0 || k >= k1) {
      continue;
    }
    for (int b = 0; b < ny; ++b) {
      const auto row = static_cast<std::ptrdiff_t>(layout.index(0, iy[b], k));
      for (int a = 0; a < nx; ++a) {
        // The kernel functions' product, (w_x w_y) w_z: the same weight bit for bit.
        const double w = wx[a] * wy[b] * wz[c];
        if (w != 0.0) {
          visit(static_cast<std::size_t>(row + ix[a]), w);
        }
      }
    }
  }
}

// Always inlined: the planned walk must inline into the pass's particle loop (else the visit
// lambda's captured sums leave the registers).
template <bool Planned, int Cells, class Visit>
[[gnu::always_inline]] inline void
Deposition::visit_kernel(const TransferPlan* plan, const ParticlePositions& p, std::size_t q,
                         std::vector<double>& buf, Visit&& visit, int k0, int k1) const {
  if constexpr (Planned) {
    for_each_planned_weight<Cells>(*plan, q, visit, k0, k1);
  } else {
    for_each_weight({p.x[q], p.y[q], p.z[q]}, p.radius[q], buf, visit, k0, k1);
  }
}

void Deposition::plan(const ParticlePositions& p, TransferPlan& out) const {
  const std::size_t n = p.radius.size();
  out.positions = p;
  out.count = n;
  // A round column moves the weights of solid cells onto gas cells (not a product of axis
  // factors), and the sphere's chords are not separable: those passes compute their kernels.
  out.separable = settings_.kernel != DepositionKernel::dpvm_sphere && !grid_.has_solid();
  const bool trilinear = settings_.kernel == DepositionKernel::trilinear;
  if (out.separable) {
    double r_max = 0.0;
    for (std::size_t q = 0; !trilinear && q < n; ++q) {
      r_max = std::max(r_max, p.radius[q]);
    }
    for (int a = 0; a < 3; ++a) {
      out.slots[a] = trilinear ? 2 : dpvm_max_cells(settings_.width * r_max, grid_.spacing(a));
      // A kernel more than 16 cells wide on an axis is computed pass by pass: its plan would
      // take kilobytes per particle, while its thousands of cells' sums, not its factors,
      // dominate each pass.
      out.separable = out.separable && out.slots[a] <= kMaxPlannedCells;
    }
  }
  out.fixed_cells = out.separable && trilinear ? 2 : 0;
  if (!out.separable) {
    out.slots = {}, out.stride = 0;
    out.cells.clear(), out.factor.clear(), out.index.clear();
    return;
  }
  out.stride = out.slots[0] + out.slots[1] + out.slots[2];
  out.cells.resize(3 * n);
  out.factor.resize(n * static_cast<std::size_t>(out.stride));
  out.index.resize(n * static_cast<std::size_t>(out.stride));
  const std::array<double, 3> origin = {grid_.origin(0), grid_.origin(1), grid_.origin(2)};
  const std::array<double, 3> dx = {grid_.spacing(0), grid_.spacing(1), grid_.spacing(2)};
  // Particles are independent: blocks of them as tasks (each writes only its own slots).
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, n, 1024), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t q = r.begin(); q != r.end(); ++q) {
          const double x[3] = {p.x[q], p.y[q], p.z[q]};
          std::size_t slot = q * static_cast<std::size_t>(out.stride);
          for (int a = 0; a < 3; ++a) {
            double* w = out.factor.data() + slot;
            std::int32_t* idx = out.index.data() + slot;
            int lo = 0;
            int cells = 2;
            if (trilinear) {
              double wt[2];
              lo = trilinear_axis(x[a], origin[a], dx[a], wt);
              w[0] = wt[0], w[1] = wt[1];
            } else {
              const double reach = settings_.width * p.radius[q];
              const std::array<int, 2> span = dpvm_axis_cells(x[a], reach, origin[a], dx[a]);
              lo = span[0], cells = span[1];
              if (cells > out.slots[a]) { // dpvm_max_cells bounds it: a broken bound, not input
                throw std::logic_error(fmt::format(
                    "Deposition::plan: a kernel covers {} cells along axis {}, the plan has {}",
                    cells, a, out.slots[a]));
              }
              for (int c = 0; c < cells; ++c) {
                w[c] = dpvm_cube_factor(x[a], reach, origin[a], dx[a], lo + c);
              }
            }
            for (int c = 0; c < cells; ++c) {
              idx[c] = fold(a, lo + c);
            }
            out.cells[3 * q + static_cast<std::size_t>(a)] = static_cast<std::uint8_t>(cells);
            slot += static_cast<std::size_t>(out.slots[a]);
          }
        }
      });
}

namespace {

// Calls f(n) with the field count as a compile-time constant for the counts the coupling uses
// (1: the solid fraction; 4: beta and beta v, or eps_g and u_g; 6: u_g and grad p), so the loops
// over the fields unroll; as a plain size_t otherwise. The same additions in the same order.
template <class F> void with_field_count(std::size_t nf, F&& f) {
  switch (nf) {
  case 1:
    return f(std::integral_constant<std::size_t, 1>{});
  case 4:
    return f(std::integral_constant<std::size_t, 4>{});
  case 6:
    return f(std::integral_constant<std::size_t, 6>{});
  default:
    return f(nf);
  }
}

// Calls f with the plan's fixed_cells as a compile-time constant: 2 (the trilinear kernel: the
// walk's loops unroll) or 0 (counts per particle).
template <class F> void with_fixed_cells(const TransferPlan& plan, F&& f) {
  if (plan.fixed_cells == 2) {
    return f(std::integral_constant<int, 2>{});
  }
  return f(std::integral_constant<int, 0>{});
}

// Calls f with from_plan(plan) as a compile-time constant: each pass's particle loop is then
// compiled once per kind of kernel, and the planned one inlines its kernel walk (a run-time
// choice per particle kept GCC from inlining, and the gathers' sums lived on the stack). f's
// second argument is the plan's fixed_cells as with_fixed_cells gives it (0 without a plan).
template <class F> void with_planned(const TransferPlan* plan, F&& f) {
  if (from_plan(plan)) {
    return with_fixed_cells(*plan, [&](auto fixed_cells) { f(std::true_type{}, fixed_cells); });
  }
  return f(std::false_type{}, std::integral_constant<int, 0>{});
}

// The wide kernels' gathers (dpvm: 4 to 6 cells along x) sum each field in five lanes, not in
// one running sum: a row's first four cells go to lanes 0-3, its further cells to lane 4, and the
// lanes are added in a fixed order at the end. One running sum is a chain of 125 dependent
// additions per field, which bounded the bed's gathers (3 cycles each); the lanes are four
// independent chains a row long, and the contiguous rows load as four-wide vectors. The
// arithmetic is fixed per cell (w = (w_x w_y) w_z, then lane += w v, no contraction), so the
// vector and scalar walks, the planned and computed kernels, every SIMD level and every rank
// count give the same bits. The trilinear kernel (two cells a row) keeps its one running sum.
constexpr int kGatherLanes = 5;
constexpr int gather_lane(int a) {
  return a < 4 ? a : 4;
}
inline double lanes_total(const std::array<double, kGatherLanes>& l) {
  return ((l[0] + l[1]) + (l[2] + l[3])) + l[4];
}
// Four doubles: one AVX2 register, or two SSE2 ones in the baseline build (the same operations).
using Lanes4 = double __attribute__((vector_size(32)));

// Whether a kernel's rows are 4 or 5 cells in consecutive memory (no wall or periodic fold along
// x): the planned passes take those as vectors.
inline bool consecutive_row(const std::int32_t* ix, int nx) {
  bool consecutive = nx == 4 || nx == 5;
  for (int a = 1; consecutive && a < nx; ++a) {
    consecutive = ix[a] == ix[0] + a;
  }
  return consecutive;
}

// Particle q's kernel in a plan: its factors and folded indices along x, y, z, and its cells.
struct PlannedKernel {
  const double *wx, *wy, *wz;
  const std::int32_t *ix, *iy, *iz;
  int nx, ny, nz;
};
inline PlannedKernel planned_kernel(const TransferPlan& plan, std::size_t q) {
  const std::size_t base = q * static_cast<std::size_t>(plan.stride);
  const double* wx = plan.factor.data() + base;
  const std::int32_t* ix = plan.index.data() + base;
  const std::uint8_t* n = plan.cells.data() + 3 * q;
  return {wx,
          wx + plan.slots[0],
          wx + plan.slots[0] + plan.slots[1],
          ix,
          ix + plan.slots[0],
          ix + plan.slots[0] + plan.slots[1],
          n[0],
          n[1],
          n[2]};
}

// Calls f with whether a consecutive row of nx (4 or 5) cells has a fifth, as a constant.
template <class F> [[gnu::always_inline]] inline void with_fifth(int nx, F&& f) {
  if (nx == 5) {
    f(std::true_type{});
  } else {
    f(std::false_type{});
  }
}

// Walks a kernel of consecutive rows (consecutive_row) on the k-planes [k0, k1) (every plane
// with AllPlanes), z then y: visit(row, w, w5) with row the index of the row's first cell, w its
// first four cells' weights and w5 its fifth's (Fifth), each (w_x w_y) w_z as the kernel
// functions make it.
template <bool Fifth, bool AllPlanes, class Visit>
[[gnu::always_inline]] inline void
walk_vector_rows(const PlannedKernel& k, const GridLayout& layout, int k0, int k1, Visit&& visit) {
  const Lanes4 wx4 = {k.wx[0], k.wx[1], k.wx[2], k.wx[3]};
  const double wx5 = Fifth ? k.wx[4] : 0.0;
  for (int c = 0; c < k.nz; ++c) {
    if (!AllPlanes && (k.iz[c] < k0 || k.iz[c] >= k1)) {
      continue;
    }
    for (int b = 0; b < k.ny; ++b) {
      const Lanes4 w = (wx4 * k.wy[b]) * k.wz[c];
      visit(layout.index(k.ix[0], k.iy[b], k.iz[c]), w, (wx5 * k.wy[b]) * k.wz[c]);
    }
  }
}

// Particle q's planned gather of n_f fields (fixed_cells 0) into sum[0, n_f), in lanes as above.
template <class FieldCount>
[[gnu::always_inline]] inline void
gather_planned_lanes(const TransferPlan& plan, const GridLayout& layout, std::size_t q,
                     const std::array<const double*, kMaxDepositFields>& in, FieldCount count,
                     std::array<double, kMaxDepositFields>& sum) {
  const std::size_t n_f = count;
  const PlannedKernel kernel = planned_kernel(plan, q);
  const auto [wx, wy, wz, ix, iy, iz, nx, ny, nz] = kernel;
  if (consecutive_row(ix, nx)) {
    with_fifth(nx, [&](auto fifth) CFDDEM_SIMD_BODY {
      std::array<Lanes4, kMaxDepositFields> acc{};
      std::array<double, kMaxDepositFields> tail{};
      walk_vector_rows<decltype(fifth)::value, true>(
          kernel, layout, 0, 0, [&](std::size_t row, const Lanes4& w, double w5) CFDDEM_SIMD_BODY {
            for (std::size_t f = 0; f < n_f; ++f) {
              Lanes4 v;
              std::memcpy(&v, in[f] + row, sizeof v);
              acc[f] += w * v;
              if constexpr (decltype(fifth)::value) {
                tail[f] += w5 * in[f][row + 4];
              }
            }
          });
      for (std::size_t f = 0; f < n_f; ++f) {
        sum[f] = ((acc[f][0] + acc[f][1]) + (acc[f][2] + acc[f][3])) + tail[f];
      }
    });
    return;
  }
  std::array<std::array<double, kGatherLanes>, kMaxDepositFields> lanes{};
  for (int c = 0; c < nz; ++c) {
    for (int b = 0; b < ny; ++b) {
      const std::size_t row = layout.index(0, iy[b], iz[c]);
      for (int a = 0; a < nx; ++a) {
        const double w = (wx[a] * wy[b]) * wz[c];
        const auto idx = static_cast<std::size_t>(static_cast<std::ptrdiff_t>(row) + ix[a]);
        for (std::size_t f = 0; f < n_f; ++f) {
          lanes[f][static_cast<std::size_t>(gather_lane(a))] += w * in[f][idx];
        }
      }
    }
  }
  for (std::size_t f = 0; f < n_f; ++f) {
    sum[f] = lanes_total(lanes[f]);
  }
}

// Particle q's planned deposit (fixed_cells 0) of vq[0, n_f) onto out, on the k-planes [k0, k1):
// out += w v cell by cell, as for_each_planned_weight's walk adds them, with consecutive rows of
// 4 or 5 cells as four-wide vectors and a fifth cell. Each cell's sum has the walk's bits: the
// vectors also add the walk's skipped weights of 0, and x + (+-0) is x for a sum that starts at +0
// (finite values).
template <class FieldCount>
[[gnu::always_inline]] inline void
scatter_planned_rows(const TransferPlan& plan, const GridLayout& layout, std::size_t q,
                     const std::array<double*, kMaxDepositFields>& out,
                     const std::array<double, kMaxDepositFields>& vq, FieldCount count, int k0,
                     int k1) {
  const std::size_t n_f = count;
  const PlannedKernel kernel = planned_kernel(plan, q);
  const auto [wx, wy, wz, ix, iy, iz, nx, ny, nz] = kernel;
  if (consecutive_row(ix, nx)) {
    with_fifth(nx, [&](auto fifth) CFDDEM_SIMD_BODY {
      walk_vector_rows<decltype(fifth)::value, false>(
          kernel, layout, k0, k1,
          [&](std::size_t row, const Lanes4& w, double w5) CFDDEM_SIMD_BODY {
            for (std::size_t f = 0; f < n_f; ++f) {
              Lanes4 o;
              std::memcpy(&o, out[f] + row, sizeof o);
              o += w * vq[f];
              std::memcpy(out[f] + row, &o, sizeof o);
              if constexpr (decltype(fifth)::value) {
                out[f][row + 4] += w5 * vq[f];
              }
            }
          });
    });
    return;
  }
  for (int c = 0; c < nz; ++c) {
    if (iz[c] < k0 || iz[c] >= k1) {
      continue;
    }
    for (int b = 0; b < ny; ++b) {
      const auto row = static_cast<std::ptrdiff_t>(layout.index(0, iy[b], iz[c]));
      for (int a = 0; a < nx; ++a) {
        const double w = (wx[a] * wy[b]) * wz[c];
        if (w != 0.0) {
          const auto idx = static_cast<std::size_t>(row + ix[a]);
          for (std::size_t f = 0; f < n_f; ++f) {
            out[f][idx] += w * vq[f];
          }
        }
      }
    }
  }
}

} // namespace

void Deposition::scatter(const TransferPlan* plan, const ParticlePositions& p, std::size_t count,
                         std::size_t nf, std::span<GridField* const> cells) {
  const double* v = values_.data();
  const auto threads = static_cast<std::size_t>(usable_threads());
  if (threads <= 1) {
    // One thread: the serial loop itself (the same sums, no kernel computed twice).
    std::array<double*, kMaxDepositFields> out{};
    for (std::size_t f = 0; f < nf; ++f) {
      out[f] = cells[f]->values().data();
    }
    with_planned(plan, [&](auto planned, auto fixed_cells) {
      with_field_count(nf, [&](auto count_of_fields) {
        const std::size_t n_f = count_of_fields;
        std::array<double, kMaxDepositFields> vq{};
        if constexpr (decltype(planned)::value && decltype(fixed_cells)::value == 0) {
          const GridLayout& layout = grid_.layout();
          at_simd_level(level_, [&]() CFDDEM_SIMD_BODY {
            for (std::size_t q = 0; q < count; ++q) {
              std::copy_n(v + q * n_f, n_f, vq.begin());
              scatter_planned_rows(*plan, layout, q, out, vq, count_of_fields,
                                   std::numeric_limits<int>::min(),
                                   std::numeric_limits<int>::max());
            }
          });
          return;
        }
        for (std::size_t q = 0; q < count; ++q) {
          std::copy_n(v + q * n_f, n_f, vq.begin());
          visit_kernel<decltype(planned)::value, decltype(fixed_cells)::value>(
              plan, p, q, weights_, [&](std::size_t idx, double w) {
                for (std::size_t f = 0; f < n_f; ++f) {
                  out[f][idx] += w * vq[f];
                }
              });
        }
      });
    });
  } else {
    scatter_by_planes(plan, p, count, nf, cells, threads);
  }
  if (halo_ != nullptr) {
    for (std::size_t f = 0; f < nf; ++f) {
      halo_->add_ghosts_to_owners(*cells[f], kCellCentred);
    }
  }
}

void Deposition::scatter_by_planes(const TransferPlan* plan, const ParticlePositions& p,
                                   std::size_t count, std::size_t nf,
                                   std::span<GridField* const> cells, std::size_t threads) {
  const double* v = values_.data();
  std::array<double*, kMaxDepositFields> out{};
  for (std::size_t f = 0; f < nf; ++f) {
    out[f] = cells[f]->values().data();
  }
  const double dz = grid_.spacing(2);
  const double z0 = grid_.origin(2);
  const int global_n = grid_.global_cells()[2];
  const int box_lo = grid_.box().lo[2];
  // With a plan, a particle's planes are its kernel's folded z indices. Without: each particle's
  // global k range that holds its kernel: the trilinear kernel's two cells, found as
  // trilinear_weights finds them (the same arithmetic, so exactly its cells); a dpvm kernel's
  // cells within its half-width, with a cell to spare.
  const bool planned = from_plan(plan);
  const bool trilinear = settings_.kernel == DepositionKernel::trilinear;
  if (!planned) {
    reach_.resize(count);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t q = r.begin(); q != r.end(); ++q) {
                          if (trilinear) {
                            const int i = static_cast<int>(trilinear_position(p.z[q], z0, dz)[1]);
                            reach_[q] = {i - 1, i};
                            continue;
                          }
                          const double reach = settings_.width * p.radius[q];
                          reach_[q] = {static_cast<int>(std::floor((p.z[q] - reach - z0) / dz)) - 1,
                                       static_cast<int>(std::floor((p.z[q] + reach - z0) / dz)) +
                                           1};
                        }
                      });
  }
  // The box's k-planes, ghosts included (a distributed box's deposits reach its ghost layers),
  // in one task a thread: a kernel spanning two tasks is computed by both (a dpvm kernel two
  // diameters wide spans about 7 planes), so fewer, larger tasks do less work twice.
  const int lo = -kGhostLayers;
  const int hi = grid_.cells(2) + kGhostLayers;
  const int tasks = static_cast<int>(threads);
  const int grain = std::max(4, (hi - lo + tasks) / tasks);
  tbb::parallel_for(
      tbb::blocked_range<int>(lo, hi + 1, grain),
      [&](const tbb::blocked_range<int>& r) {
        const int k0 = r.begin();
        const int k1 = r.end();
        std::vector<double> buf(planned ? 0 : weights_.size()); // a plan needs no weight buffer
        std::array<double, kMaxDepositFields> vq{};
        // Whether particle q's kernel has a cell in this task's planes.
        const auto touches = [&](std::size_t q) {
          if (planned) {
            const std::int32_t* kz = plan->index.data() +
                                     q * static_cast<std::size_t>(plan->stride) +
                                     static_cast<std::size_t>(plan->slots[0] + plan->slots[1]);
            for (int c = 0; c < plan->cells[3 * q + 2]; ++c) {
              if (kz[c] >= k0 && kz[c] < k1) {
                return true;
              }
            }
            return false;
          }
          const auto [first, last] = reach_[q];
          if (first >= 0 && last < global_n) {
            return first - box_lo < k1 && last - box_lo >= k0; // no wrap or mirror
          }
          for (int i = first; i <= last; ++i) {
            const int k = grid_.distributed() ? box_index(2, i) : fold(2, i);
            if (k >= k0 && k < k1) {
              return true;
            }
          }
          return false;
        };
        // Only the kernel's planes in this task's range [k0, k1) are visited.
        with_planned(plan, [&](auto kernel_planned, auto fixed_cells) {
          with_field_count(nf, [&](auto count_of_fields) {
            const std::size_t n_f = count_of_fields;
            if constexpr (decltype(kernel_planned)::value && decltype(fixed_cells)::value == 0) {
              const GridLayout& layout = grid_.layout();
              at_simd_level(level_, [&]() CFDDEM_SIMD_BODY {
                for (std::size_t q = 0; q < count; ++q) {
                  if (!touches(q)) {
                    continue;
                  }
                  std::copy_n(v + q * n_f, n_f, vq.begin());
                  scatter_planned_rows(*plan, layout, q, out, vq, count_of_fields, k0, k1);
                }
              });
              return;
            }
            for (std::size_t q = 0; q < count; ++q) {
              if (!touches(q)) {
                continue;
              }
              std::copy_n(v + q * n_f, n_f, vq.begin());
              visit_kernel<decltype(kernel_planned)::value, decltype(fixed_cells)::value>(
                  plan, p, q, buf,
                  [&](std::size_t idx, double w) {
                    for (std::size_t f = 0; f < n_f; ++f) {
                      out[f][idx] += w * vq[f];
                    }
                  },
                  k0, k1);
            }
          });
        });
      },
      tbb::simple_partitioner());
}

void Deposition::deposit(const ParticlePositions& p, std::span<const double> value,
                         GridField& cell) {
  const std::span<const double> values[1] = {value};
  GridField* const cells[1] = {&cell};
  deposit(p, values, cells);
}

void Deposition::deposit_solid_fraction(const ParticlePositions& p, GridField& eps_s) {
  solid_fraction_with(nullptr, p, eps_s);
}

void Deposition::deposit_solid_fraction(const TransferPlan& plan, GridField& eps_s) {
  solid_fraction_with(&plan, plan.positions, eps_s);
}

void Deposition::solid_fraction_with(const TransferPlan* plan, const ParticlePositions& p,
                                     GridField& eps_s) {
  const double inv_volume = 1.0 / grid_.cell_volume();
  const std::size_t n = p.radius.size();
  values_.resize(n);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t q = r.begin(); q != r.end(); ++q) {
                        const double rad = p.radius[q];
                        values_[q] = 4.0 / 3.0 * std::numbers::pi * rad * rad * rad * inv_volume;
                      }
                    });
  GridField* const cells[1] = {&eps_s};
  scatter(plan, p, n, 1, cells);
}

void Deposition::smooth(GridField& cell) const {
  if (settings_.diffusion > 0.0) {
    (void)smooth_implicit(grid_, settings_.diffusion, cell);
  }
}

void Deposition::interpolate(const ParticlePositions& p, const GridField& field,
                             std::span<double> out) {
  const GridField* const fields[1] = {&field};
  const std::span<double> outs[1] = {out};
  interpolate(p, fields, outs);
}

void Deposition::interpolate(const ParticlePositions& p, std::span<const GridField* const> fields,
                             std::span<const std::span<double>> outs) {
  interpolate_with(nullptr, p, fields, outs);
}

namespace {
// A plan's passes take as many values as it has particles.
void check_plan_count(const TransferPlan& plan, std::size_t n, const char* pass) {
  if (n != plan.count) {
    throw std::invalid_argument(fmt::format(
        "Deposition::{}: {} values per field for a plan of {} particles", pass, n, plan.count));
  }
}
} // namespace

void Deposition::interpolate(const TransferPlan& plan, std::span<const GridField* const> fields,
                             std::span<const std::span<double>> outs) {
  for (const std::span<double>& out : outs) {
    check_plan_count(plan, out.size(), "interpolate");
  }
  interpolate_with(&plan, plan.positions, fields, outs);
}

void Deposition::interpolate_with(const TransferPlan* plan, const ParticlePositions& p,
                                  std::span<const GridField* const> fields,
                                  std::span<const std::span<double>> outs) {
  const std::size_t nf = fields.size();
  if (outs.size() != nf) {
    throw std::invalid_argument("Deposition::interpolate: one output per field");
  }
  constexpr std::size_t kMaxFields = 8;
  if (nf > kMaxFields) {
    throw std::invalid_argument("Deposition::interpolate: at most 8 fields at once");
  }
  const std::size_t n = nf ? outs[0].size() : 0;
  // The fields' values, not their objects, in the inner loop (one load a term, not three).
  std::array<const double*, kMaxFields> value{};
  for (std::size_t f = 0; f < nf; ++f) {
    value[f] = fields[f]->values().data();
  }
  // Particles are independent (a gather): blocks of them are TBB tasks, each with its own
  // weight buffer; every particle's sums run in the same order whatever the thread count.
  // With a plan the kernel walk is for_each_planned_weight's alone, written out here: in a loop
  // of its own (not one shared with the computed kernels through visit_kernel, nor one compiled
  // into TBB's task body) GCC keeps the sums and the fields' pointers in registers; the shared
  // forms measured 115 M -> 145 M instructions over the bed's first 3 fluid steps.
  const bool planned = from_plan(plan);
  const bool trilinear = settings_.kernel == DepositionKernel::trilinear;
  const GridLayout& layout = grid_.layout();
  with_field_count(nf, [&](auto count_of_fields) {
    const std::size_t n_f = count_of_fields;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 512),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        const std::array<const double*, kMaxFields> in = value;
                        if (planned && plan->fixed_cells == 0) {
                          // The wide kernels' lanes, compiled for the CPU's vectors.
                          at_simd_level(level_, [&]() CFDDEM_SIMD_BODY {
                            for (std::size_t q = r.begin(); q != r.end(); ++q) {
                              std::array<double, kMaxFields> sum;
                              gather_planned_lanes(*plan, layout, q, in, count_of_fields, sum);
                              for (std::size_t f = 0; f < n_f; ++f) {
                                outs[f][q] = sum[f];
                              }
                            }
                          });
                          return;
                        }
                        if (planned) {
                          const auto gather = [&](auto fixed_cells) {
                            for (std::size_t q = r.begin(); q != r.end(); ++q) {
                              std::array<double, kMaxFields> sum{};
                              for_each_planned_weight<decltype(fixed_cells)::value>(
                                  *plan, q, [&](std::size_t idx, double w) {
                                    for (std::size_t f = 0; f < n_f; ++f) {
                                      sum[f] += w * in[f][idx];
                                    }
                                  });
                              for (std::size_t f = 0; f < n_f; ++f) {
                                outs[f][q] = sum[f];
                              }
                            }
                          };
                          with_fixed_cells(*plan, gather);
                          return;
                        }
                        std::vector<double> buf(weights_.size());
                        if (!trilinear) { // the lanes of gather_planned_lanes, cell by cell
                          for (std::size_t q = r.begin(); q != r.end(); ++q) {
                            std::array<std::array<double, kGatherLanes>, kMaxFields> lanes{};
                            for_each_weight({p.x[q], p.y[q], p.z[q]}, p.radius[q], buf,
                                            [&](std::size_t idx, double w, int a) {
                                              const auto l =
                                                  static_cast<std::size_t>(gather_lane(a));
                                              for (std::size_t f = 0; f < n_f; ++f) {
                                                lanes[f][l] += w * in[f][idx];
                                              }
                                            });
                            for (std::size_t f = 0; f < n_f; ++f) {
                              outs[f][q] = lanes_total(lanes[f]);
                            }
                          }
                          return;
                        }
                        for (std::size_t q = r.begin(); q != r.end(); ++q) {
                          std::array<double, kMaxFields> sum{};
                          for_each_weight({p.x[q], p.y[q], p.z[q]}, p.radius[q], buf,
                                          [&](std::size_t idx, double w) {
                                            for (std::size_t f = 0; f < n_f; ++f) {
                                              sum[f] += w * in[f][idx];
                                            }
                                          });
                          for (std::size_t f = 0; f < n_f; ++f) {
                            outs[f][q] = sum[f];
                          }
                        }
                      });
  });
}

void Deposition::deposit(const ParticlePositions& p,
                         std::span<const std::span<const double>> values,
                         std::span<GridField* const> cells) {
  deposit_with(nullptr, p, values, cells);
}

void Deposition::deposit(const TransferPlan& plan, std::span<const std::span<const double>> values,
                         std::span<GridField* const> cells) {
  for (const std::span<const double>& v : values) {
    check_plan_count(plan, v.size(), "deposit");
  }
  deposit_with(&plan, plan.positions, values, cells);
}

void Deposition::deposit_with(const TransferPlan* plan, const ParticlePositions& p,
                              std::span<const std::span<const double>> values,
                              std::span<GridField* const> cells) {
  const std::size_t nf = values.size();
  if (cells.size() != nf) {
    throw std::invalid_argument("Deposition::deposit: one cell field per value array");
  }
  if (nf > kMaxDepositFields) {
    throw std::invalid_argument("Deposition::deposit: at most 8 fields at once");
  }
  const double inv_volume = 1.0 / grid_.cell_volume();
  const std::size_t n = nf ? values[0].size() : 0;
  // Each particle's values per unit cell volume, computed once (as the additions use them).
  values_.resize(n * nf);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t q = r.begin(); q != r.end(); ++q) {
                        for (std::size_t f = 0; f < nf; ++f) {
                          values_[q * nf + f] = values[f][q] * inv_volume;
                        }
                      }
                    });
  scatter(plan, p, n, nf, cells);
}

} // namespace cfddem::fluid
