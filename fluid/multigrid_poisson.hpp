// Geometric multigrid for the cell-centred, variable-coefficient Poisson problem of the pressure
// projection, -div(K grad phi) = b on a box of cells, used as the preconditioner of a flexible
// conjugate-gradient solve (docs/multigrid.md). The operator is given by its face coefficients
// K_f / h^2 (no assembled stencil); each boundary side is Neumann (wall, inflow), homogeneous
// Dirichlet on the face (outflow: the caller moves p_out into b) or periodic.
//
// Levels coarsen by 2 along every axis that has at least 4 cells and is among the finest of those
// that can coarsen (semi-coarsening). An odd axis coarsens to (n + 1) / 2 cells, the last with
// one child, where its high side is Neumann (one grid only); otherwise by 3 where 3 divides it
// (periodic 135 -> 45 -> 15 -> 5), else it keeps its cells. A level
// whose finest axis is markedly finer than the others relaxes whole lines along it; the coarsest
// level is solved directly (dense Cholesky) when small, else by conjugate gradients. Every loop
// over a level runs over z-planes (TBB) and every reduction is summed plane by plane in plane
// order, so results are bitwise independent of the thread count. Over MPI ranks (the second
// constructor) each rank holds its box of the fine levels, exchanging face ghosts after every pass,
// and a coarse level is gathered onto rank 0 (docs/multigrid.md, "On R ranks").
#pragma once

#include <array>
#include <limits>
#include <memory>
#include <span>
#include <vector>

#include "core/cell_box.hpp"
#include "core/communicator.hpp"
#include "core/huge_page_allocator.hpp"
#include "core/simd_level.hpp"
#include "fluid/grid_field.hpp"

namespace cfddem::fluid {

// dirichlet: zero on the boundary face, half a spacing beyond the last cell centre (a cell-centred
// unknown: ghost -x). dirichlet_node: zero one spacing beyond the last unknown (a staggered
// velocity next to its known wall face).
enum class PoissonSide { neumann, dirichlet, periodic, dirichlet_node };

struct MultigridSettings {
  int pre_sweeps = 2;  // red-black Gauss-Seidel sweeps before the coarse correction
  int post_sweeps = 2; // black-red sweeps after it (the adjoint: the V-cycle stays symmetric)
  int max_direct_cells = 256; // coarsest level solved by dense Cholesky up to this many cells
  // Over-relaxation of the point-relaxed levels' red-black passes: each cell moves omega times
  // its Gauss-Seidel correction, x += omega (x_GS - x). 1 is Gauss-Seidel (the default); any
  // omega in (0, 2) keeps each colour step A-self-adjoint and convergent, so the V-cycle (the
  // post-smoothing in the reverse colour order) stays a symmetric positive definite
  // preconditioner. Over-relaxed red-black smoothing damps the Poisson operator's oscillatory
  // modes faster than plain Gauss-Seidel (Yavneh, SIAM J. Sci. Comput. 17 (1996) 180). Line
  // relaxation is not weighted, nor a level with an odd periodic axis (its seam pairs cells of
  // one colour: docs/multigrid.md, "Over-relaxation").
  double relaxation_weight = 1.0;
  // Point-relaxed levels run each red-black (black-red) pair of passes as one sweep over the
  // planes (bitwise the same result, about half the memory traffic); false: pass by pass.
  bool fuse_colour_pairs = true;
  // Distributed: a level of at most this many cells (all ranks together) is gathered onto rank 0
  // rather than coarsened further over the ranks.
  int gather_cells = 4096;
  // Rows may be empty (a round column's solid cells, fluid/solid_mask.hpp): the levels count
  // their non-empty rows at every set-up (on R ranks one more sum per level) and the singular
  // problem's means and shifts skip the empty ones. false: every row has a diagonal, nothing
  // is counted.
  bool empty_rows = false;
};

class MultigridExchange;

struct MultigridReport {
  int iterations = 0;
  double relative_residual = 0.0; // ||b - A x|| / ||b||, recomputed from x at the end
  bool converged = false;
  // Stopped short of the tolerance before the iteration cap: a restart from the true residual
  // made no progress (round-off holds the residual there).
  bool stalled = false;
};

class MultigridPoisson {
public:
  // cells, spacing: the finest grid; sides[a][side]: a periodic axis is periodic on both sides.
  MultigridPoisson(std::array<int, 3> cells, std::array<double, 3> spacing,
                   std::array<std::array<PoissonSide, 2>, 3> sides,
                   MultigridSettings settings = {});
  // Distributed: this rank holds boxes[comm.rank()] of a grid of `cells` cells (every rank
  // passes the same boxes, which tile the grid); vectors, coefficients and the levels' cells are
  // the box's. Levels coarsen over the ranks while every box divides by the ratio, with point
  // relaxation and a face-ghost exchange after every pass; the first level that would need line
  // relaxation, cannot coarsen so, or has at most settings.gather_cells cells is gathered onto
  // rank 0, which runs one V-cycle of a one-grid hierarchy of it (the constructor above) and
  // scatters the correction back. The constructor, set_coefficients and solve are then
  // collective over comm.
  MultigridPoisson(std::array<int, 3> cells, std::array<double, 3> spacing,
                   std::array<std::array<PoissonSide, 2>, 3> sides, std::vector<CellBox> boxes,
                   const Communicator& comm, MultigridSettings settings = {});
  ~MultigridPoisson();
  // Cells of the coarsest level the one-grid hierarchy of such a grid reaches (the grid's own
  // count when no axis coarsens: odd or short axes keep their cells). Above max_direct_cells it
  // is solved by conjugate gradients at every V-cycle.
  static std::size_t coarsest_cells(std::array<int, 3> cells, std::array<double, 3> spacing,
                                    std::array<std::array<PoissonSide, 2>, 3> sides,
                                    MultigridSettings settings = {});
  // The axes whose levels halve an odd count unevenly, (n + 1) / 2 with one child in the last
  // coarse cell: those whose high side is Neumann (wall, inflow). A distributed grid's boxes
  // should cut such an axis on powers of two (fluid/gas_boxes.hpp).
  static std::array<bool, 3> halves_unevenly(std::array<std::array<PoissonSide, 2>, 3> sides);
  MultigridPoisson(const MultigridPoisson&) = delete;
  MultigridPoisson& operator=(const MultigridPoisson&) = delete;

  // coef[a] at layout index (i, j, k) is the coefficient K / h_a^2 of the low a-face of cell
  // (i, j, k), faces 0..n_a (layout: GridLayout(cells)). Read on interior faces, on Dirichlet
  // faces, and on face 0 of a periodic axis (face n_a is face 0); Neumann faces are not read.
  // mass (optional, same layout): a non-negative term added to the diagonal (a Helmholtz
  // operator mass - div(K grad)); coarse levels average it over the children.
  // Builds the coarse levels' coefficients and factors the coarsest level.
  void set_coefficients(const std::array<GridField, 3>& coef, const GridField* mass = nullptr);

  // Solves A x = b (cells in i-fastest order) from the first guess x, until the relative residual
  // 2-norm is at most tolerance. Without a Dirichlet side A is singular: b must sum to zero (up
  // to rounding; its mean is removed) and x is returned with mean zero. Likewise with a mass
  // term: then A is definite and nothing is removed.
  MultigridReport solve(std::span<const double> b, std::span<double> x, double tolerance,
                        int max_iterations);

  [[nodiscard]] int levels() const;
  // Distributed: this rank's box of the level (the last one is the gathered level).
  [[nodiscard]] std::array<int, 3> level_cells(int level) const;
  // The axis a level relaxes lines along (-1: point relaxation).
  [[nodiscard]] int line_axis(int level) const;
  [[nodiscard]] bool singular() const { return singular_; }
  // Distributed: the global cells of the level gathered onto rank 0 (the last level); its
  // hierarchy's levels (0 except on rank 0). One grid: {0, 0, 0} and 0.
  [[nodiscard]] std::array<int, 3> gathered_cells() const { return gathered_cells_; }
  [[nodiscard]] int gathered_levels() const;

  // The finest level's kernels on the state the last solve left, for benchmarks: one V-cycle
  // (the preconditioner), one red-black sweep, one residual with its norm.
  void benchmark_vcycle();
  void benchmark_sweep();
  double benchmark_residual();
  // The instruction set of the row kernels (fluid/multigrid_rows.hpp), simd_level() unless set:
  // for tests and side-by-side measurements (every level gives the same bits).
  void use_simd_level(SimdLevel level);

  struct Level; // one grid of the hierarchy (multigrid_poisson.cpp)

private:
  void vcycle(int level, double* b, double* x, const double* shift);
  void coarsest_solve(const double* b, double* x); // b: the coarsest level's own vector
  void factor_coarsest();
  // After level 0's coefficients: the diagonal, the coarse levels and the coarsest solve's set-up.
  void finish_coefficients();
  // Distributed: the last level's b onto rank 0, one V-cycle of gathered_ there, x back.
  void gathered_solve(const double* b, double* x);
  // Distributed: the last level's coefficients onto rank 0 into gathered_'s finest level.
  void gather_coefficients();
  // Sums over the ranks (identity on one grid).
  void all_sum(std::span<double> v) const;
  double all_sum(double v) const;
  // z = V-cycle(r). Singular: r's mean is removed first (r_sum: r's interior sum if known, else
  // NaN), and z's mean is returned for the caller to remove (0 otherwise).
  double precondition(double* r, double* z,
                      double r_sum = std::numeric_limits<double>::quiet_NaN());

  MultigridSettings settings_;
  std::array<std::array<PoissonSide, 2>, 3> sides_{};
  bool has_dirichlet_ = false;
  bool singular_ = true;
  std::vector<Level> levels_;
  // Outer flexible CG's vectors on the finest level's padded layout.
  HugePageVector<double> x_, b_, r_, r_old_, z_, p_, q_;
  // Coarsest level: dense Cholesky factor (row-major lower triangle) or empty (CG).
  std::vector<double> cholesky_;
  std::vector<double> dense_rhs_;
  std::vector<double> cg_r_, cg_p_, cg_q_, cg_z_;
  // Distributed: one exchange per level (levels_[l].exchange points into it), the one-grid
  // hierarchy of the gathered last level (rank 0 only) and the gather's buffers.
  std::vector<std::unique_ptr<MultigridExchange>> exchanges_;
  std::unique_ptr<MultigridPoisson> gathered_;
  std::array<int, 3> gathered_cells_{};
  std::vector<double> mine_, all_;
};

} // namespace cfddem::fluid
