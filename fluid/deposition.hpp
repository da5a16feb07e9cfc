// Particle <-> cell transfer with one kernel (trilinear or dpvm): deposit per-particle values to
// cells and interpolate cell fields to particles with the same weights, so exchanged momentum
// is conserved (docs/theory.md §5, §7). The loop layer above the weight kernels.
#pragma once

#include <array>
#include <limits>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/simd_level.hpp"
#include "fluid/dpvm_weights.hpp"
#include "fluid/grid_field.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/mac_grid.hpp"
#include "fluid/transfer_plan.hpp"

namespace cfddem::fluid {

enum class DepositionKernel { trilinear, dpvm_cube, dpvm_sphere };

// Throws std::invalid_argument naming the value ("trilinear", "dpvm_cube", "dpvm_sphere").
[[nodiscard]] DepositionKernel parse_deposition_kernel(std::string_view name);

struct DepositionSettings {
  DepositionKernel kernel = DepositionKernel::trilinear;
  // dpvm: kernel width in particle diameters, 2 r* = s d_p, i.e. r* = s r_p.
  double width = 2.0;
  int sphere_samples = 16;
  // Optional implicit smoothing (I - D lap) q_new = q_old of deposited fields; D [m^2], 0 = off.
  double diffusion = 0.0;
};

// Distributed (grid is one box, halo its grid's halo): each rank passes the particles it owns
// (centres in its box); their stencils fold back at the domain faces the box touches, reach
// into the ghost layers across internal and periodic faces, and deposits there are added into
// the owners' cells (GridHalo::add_ghosts_to_owners). A stencil must end within the ghost
// layers (std::runtime_error otherwise). Weights are computed in the global frame, so a
// particle's weights are bitwise those of the one-grid run.
class Deposition {
public:
  // max_radius sizes the weight buffer (larger particles grow it on first use). Throws
  // std::invalid_argument for smoothing on a distributed grid (not distributed yet).
  Deposition(const MacGrid& grid, const DepositionSettings& settings, double max_radius,
             const GridHalo* halo = nullptr);

  // cell += sum_p value_p W_p(cell) / V_cell over interior cells (a density: value per m^3).
  // Stencil cells outside the grid wrap on periodic axes and fold back (mirror) at other
  // boundaries, so the total sum_cells cell V_cell = sum_p value_p is conserved. Distributed:
  // collective (the ghosts' deposits go to their owners; ghosts are left at zero).
  void deposit(const ParticlePositions& p, std::span<const double> value, GridField& cell);
  // Solid volume fraction eps_s of the particles (sphere volumes; not smoothed).
  void deposit_solid_fraction(const ParticlePositions& p, GridField& eps_s);
  // Applies the optional implicit diffusion (settings().diffusion > 0) to a deposited field;
  // conserves its cell sum. No-op when diffusion = 0.
  void smooth(GridField& cell) const;
  // out_p = sum_cells W_p(cell) field(cell), with the same wrap/fold as deposit. Distributed:
  // the field's exchanged ghosts must be filled (GridHalo::fill).
  void interpolate(const ParticlePositions& p, const GridField& field, std::span<double> out);

  // Several fields at once: the weights of each particle are computed once for all of them
  // (they cost more than the sums: a dpvm kernel samples the sphere). Each output is bit for
  // bit what the one-field call gives (same weights, same order). Distributed as above.
  void interpolate(const ParticlePositions& p, std::span<const GridField* const> fields,
                   std::span<const std::span<double>> outs);
  void deposit(const ParticlePositions& p, std::span<const std::span<const double>> values,
               std::span<GridField* const> cells);

  // The particles' kernels, once for several passes at the same positions (fluid/transfer_plan.hpp;
  // `out`'s arrays are reused). The passes below that take the plan give bitwise what the ones
  // taking the positions give. The plan holds spans of the positions, which must not change
  // while it is used, and belongs to this Deposition (its grid). Distributed: the positions must
  // have passed reach_problem.
  void plan(const ParticlePositions& p, TransferPlan& out) const;
  void deposit_solid_fraction(const TransferPlan& plan, GridField& eps_s);
  void interpolate(const TransferPlan& plan, std::span<const GridField* const> fields,
                   std::span<const std::span<double>> outs);
  void deposit(const TransferPlan& plan, std::span<const std::span<const double>> values,
               std::span<GridField* const> cells);

  // Distributed: the first of the particles whose stencil leaves the box's ghost layers, as a
  // message (empty: all fit; always empty on an undistributed grid). Not collective: a caller
  // agrees on it over the ranks before the collective deposit.
  [[nodiscard]] std::string reach_problem(const ParticlePositions& p);

  [[nodiscard]] const DepositionSettings& settings() const { return settings_; }

  // The instruction set of the wide kernels' row loops (core/simd_level.hpp), simd_level() unless
  // set: every level gives the same bits, which a test checks against the baseline's.
  void use_simd_level(SimdLevel level) { level_ = level; }

private:
  // A particle's kernel: its cells, with the weights in `buf` (grown for large particles), so
  // concurrent callers pass their own buffers.
  CellStencil stencil(const std::array<double, 3>& x, double radius,
                      std::vector<double>& buf) const;
  [[nodiscard]] int box_index(int axis, int i) const;
  // Visits the cells of a particle's kernel with their weights; only those on the k-planes [k0,
  // k1).
  template <class Visit>
  void for_each_weight(const std::array<double, 3>& x, double radius, std::vector<double>& buf,
                       Visit&& visit, int k0 = std::numeric_limits<int>::min(),
                       int k1 = std::numeric_limits<int>::max()) const;
  // Visits the cells of particle q's kernel from the plan's axis factors (plan.separable), in
  // for_each_weight's order with its weights; only those on the k-planes [k0, k1). Cells: the
  // plan's fixed_cells (2: the loops' counts are constants, the walk unrolls), 0: per particle.
  template <int Cells, class Visit>
  void for_each_planned_weight(const TransferPlan& plan, std::size_t q, Visit&& visit,
                               int k0 = std::numeric_limits<int>::min(),
                               int k1 = std::numeric_limits<int>::max()) const;
  // Particle q's kernel on the k-planes [k0, k1): from the plan (Planned: plan->separable, with
  // Cells its fixed_cells) or computed from p with buf. Planned and Cells are compile-time
  // choices (with_planned in the passes).
  template <bool Planned, int Cells, class Visit>
  void visit_kernel(const TransferPlan* plan, const ParticlePositions& p, std::size_t q,
                    std::vector<double>& buf, Visit&& visit,
                    int k0 = std::numeric_limits<int>::min(),
                    int k1 = std::numeric_limits<int>::max()) const;
  // The passes, with the kernels from `plan` (null: computed from p).
  void interpolate_with(const TransferPlan* plan, const ParticlePositions& p,
                        std::span<const GridField* const> fields,
                        std::span<const std::span<double>> outs);
  void deposit_with(const TransferPlan* plan, const ParticlePositions& p,
                    std::span<const std::span<const double>> values,
                    std::span<GridField* const> cells);
  void solid_fraction_with(const TransferPlan* plan, const ParticlePositions& p, GridField& eps_s);
  // In a round column (docs/theory.md §13): the weights of the kernel's solid cells moved onto
  // its gas cells in proportion to theirs, so a particle beside the wall deposits all its volume
  // and drag where the gas is, and interpolates from gas cells only. Cells beyond the domain's
  // faces count as solid by their position (outside the column). A kernel without gas cells
  // keeps its weights.
  void onto_gas_cells(const CellStencil& s, double* weight) const;
  [[nodiscard]] int fold(int axis, int i) const;
  [[nodiscard]] int fold_in_box(int axis, int i) const;
  // Grows buf to a dpvm kernel of this radius (no-op up to the one weights_ was sized for).
  void reserve_weights(double kernel_radius, std::vector<double>& buf) const;
  // Most cells a dpvm kernel of this radius covers (dpvm_max_cells along each axis).
  [[nodiscard]] std::size_t kernel_cells(double kernel_radius) const;
  // cells[f][idx] += W_q(idx) values_[q nf + f] for every particle q, f < nf, in the serial
  // order (particles in turn, each one's kernel cells in turn) at every cell. With TBB threads
  // (scatter_by_planes) each task owns a range of k-planes and goes through the particles in
  // order, adding only into its planes (a particle whose kernel spans two tasks' planes has its
  // weights computed by both): every cell gets its additions in the serial order, so the sums
  // are the serial ones whatever the thread count. On one thread the serial loop runs itself.
  void scatter(const TransferPlan* plan, const ParticlePositions& p, std::size_t count,
               std::size_t nf, std::span<GridField* const> cells);
  void scatter_by_planes(const TransferPlan* plan, const ParticlePositions& p, std::size_t count,
                         std::size_t nf, std::span<GridField* const> cells, std::size_t threads);

  MacGrid grid_;
  DepositionSettings settings_;
  const GridHalo* halo_ = nullptr;
  SimdLevel level_ = simd_level();
  // The kernel radius weights_ was sized for (width x max_radius): a kernel no larger fits it.
  double sized_kernel_radius_ = 0.0;
  std::vector<double> weights_;
  std::vector<double> values_;            // per particle and field, per unit cell volume
  std::vector<std::array<int, 2>> reach_; // per particle: global k range of its kernel
};

} // namespace cfddem::fluid
