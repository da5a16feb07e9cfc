#include "fluid/pressure_projection.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>

#include <HYPRE_struct_ls.h>
#include <fmt/format.h>
#include <mpi.h>

#include "core/communicator_mpi.hpp"
#include "fluid/box_loops.hpp"

namespace cfddem::fluid {

namespace {
// Cells whose longest side is at most this many times their shortest are not named as the cause
// of a stalled projection (the bed's 4:1 cells converge).
constexpr double kNearCubes = 10.0;
} // namespace

struct PressureProjection::Hypre {
  HYPRE_StructGrid grid = nullptr;
  HYPRE_StructStencil stencil = nullptr;
  HYPRE_StructMatrix matrix = nullptr;
  HYPRE_StructVector b = nullptr;
  HYPRE_StructVector x = nullptr;
  HYPRE_StructSolver solver = nullptr;
  HYPRE_StructSolver precond = nullptr;
  PoissonPreconditioner precond_kind = PoissonPreconditioner::pfmg;
  MPI_Comm comm = MPI_COMM_SELF;
  bool solver_ready = false;
  std::array<HYPRE_Int, 3> lower{};
  std::array<HYPRE_Int, 3> upper{};

  void destroy_solver() {
    if (solver != nullptr) {
      HYPRE_StructPCGDestroy(solver);
      solver = nullptr;
    }
    if (precond != nullptr) {
      if (precond_kind == PoissonPreconditioner::pfmg) {
        HYPRE_StructPFMGDestroy(precond);
      } else {
        HYPRE_StructSMGDestroy(precond);
      }
      precond = nullptr;
    }
    solver_ready = false;
  }
};

int smg_blocking_axis(const MacGrid& grid) {
  const std::array<int, 3> size = grid.global_cells();
  for (int a = 0; a < 3; ++a) {
    if (grid.periodic(a) && size[a] > 1 && size[a] % 2 == 1) {
      return a;
    }
  }
  return -1;
}

std::array<std::array<PoissonSide, 2>, 3> poisson_sides(const MacGridSpec& spec) {
  std::array<std::array<PoissonSide, 2>, 3> sides{};
  for (int a = 0; a < 3; ++a) {
    for (int side = 0; side < 2; ++side) {
      const BoundaryKind kind = spec.bc[static_cast<std::size_t>(2 * a + side)].kind;
      sides[a][side] = kind == BoundaryKind::periodic  ? PoissonSide::periodic
                       : kind == BoundaryKind::outflow ? PoissonSide::dirichlet
                                                       : PoissonSide::neumann;
    }
  }
  return sides;
}

PoissonSolver auto_solver(const MacGrid& grid) {
  std::array<double, 3> spacing{};
  for (int a = 0; a < 3; ++a) {
    spacing[a] = grid.spacing(a);
  }
  // Over R ranks the levels coarsen as one grid's while the boxes divide (their cuts fall on the
  // granules of the grid's ratios, core/cell_box.hpp), and uneven halving included; a level
  // that stops dividing is gathered and coarsened on as one grid: the one-grid hierarchy judges.
  const std::array<std::array<PoissonSide, 2>, 3> sides = poisson_sides(grid.spec());
  const bool large_coarsest =
      MultigridPoisson::coarsest_cells(grid.global_cells(), spacing, sides) > kAutoCoarsestCells;
  return large_coarsest && pfmg_coarsest_cells(grid) <= kAutoCoarsestCells
             ? PoissonSolver::hypre
             : PoissonSolver::multigrid;
}

namespace {

constexpr int kStencilSize = 7; // centre, -x, +x, -y, +y, -z, +z

} // namespace

namespace {

// PFMG levels that keep every periodic axis at two or more cells. PFMG semicoarsens by 2 along
// the axis of smallest dxyz (ties: lowest axis) and itself stops at an odd period; a period of
// one cell couples a cell to itself, where red/black relaxation is wrong (PCG then stalls or
// breaks down: seen on 4-cell periodic axes and on the riser grid). Mirrors the coarsening
// loop of hypre 2.26's pfmg_setup.c with dxyz set explicitly.
struct PfmgHierarchy {
  int levels = 1;
  std::size_t coarsest_cells = 0;
};

PfmgHierarchy pfmg_hierarchy(const MacGrid& grid) {
  std::array<int, 3> size = grid.global_cells();
  std::array<double, 3> dxyz = {grid.spacing(0), grid.spacing(1), grid.spacing(2)};
  int levels = 1;
  for (;;) {
    int dir = -1;
    for (int d = 0; d < 3; ++d) {
      if (size[d] > 1 && (dir < 0 || dxyz[d] < dxyz[dir])) {
        dir = d;
      }
    }
    if (dir < 0) {
      break;
    }
    if (grid.periodic(dir) && (size[dir] % 2 == 1 || size[dir] == 2)) {
      break;
    }
    size[dir] = (size[dir] + 1) / 2;
    dxyz[dir] *= 2.0;
    ++levels;
  }
  return {levels, static_cast<std::size_t>(size[0]) * static_cast<std::size_t>(size[1]) *
                      static_cast<std::size_t>(size[2])};
}

} // namespace

int pfmg_max_levels(const MacGrid& grid) {
  return pfmg_hierarchy(grid).levels;
}

std::size_t pfmg_coarsest_cells(const MacGrid& grid) {
  return pfmg_hierarchy(grid).coarsest_cells;
}

namespace {

double face_eps(const GridField& eps, std::size_t c, std::ptrdiff_t s) {
  return 0.5 * (eps[c] + eps[c - static_cast<std::size_t>(s)]);
}

} // namespace

void flux_divergence(const MacGrid& grid, const std::array<GridField, 3>& u, const GridField& eps,
                     GridField& div) {
  const GridLayout& layout = grid.layout();
  const auto& n = grid.cells();
  // A cell next to a velocity-inflow face takes that face's flux at eps_g = 1 (mac_grid.hpp:
  // kInflowVolumeFraction), so the prescribed velocity is the superficial one; averaging the
  // cell with its zero-gradient ghost would deliver only eps_g(cell) times it.
  std::array<std::array<bool, 2>, 3> inflow{};
  for (int a = 0; a < 3; ++a) {
    inflow[a] = {grid.inflow_face(a, 0), grid.inflow_face(a, 1)};
  }
  // Rows of cells as TBB tasks: each cell is written once, from values this loop does not write.
  // Along a row the y and z faces' inflow flags are constant; the x faces' apply at the row's
  // ends only, which are recomputed with them after the (vectorizable) row loop.
  const std::array<double, 3> h = {grid.spacing(0), grid.spacing(1), grid.spacing(2)};
  const std::array<std::ptrdiff_t, 3> st = {layout.stride(0), layout.stride(1), layout.stride(2)};
  const double* __restrict e = eps.values().data();
  const double* __restrict u0 = u[0].values().data();
  const double* __restrict u1 = u[1].values().data();
  const double* __restrict u2 = u[2].values().data();
  double* __restrict out = div.values().data();
  for_box_rows(layout, {0, 0, 0}, {n[0] - 1, n[1] - 1, n[2] - 1},
               [&](std::ptrdiff_t row, int j, int k) {
                 const bool lo1 = j == 0 && inflow[1][0];
                 const bool hi1 = j == n[1] - 1 && inflow[1][1];
                 const bool lo2 = k == 0 && inflow[2][0];
                 const bool hi2 = k == n[2] - 1 && inflow[2][1];
                 const std::ptrdiff_t s1 = st[1];
                 const std::ptrdiff_t s2 = st[2];
                 // The divergence of cell c, the x faces' volume fractions given: terms x, y, z in
                 // order.
                 const auto cell = [&](std::ptrdiff_t c, double elo0, double ehi0) {
                   const double elo1 = lo1 ? kInflowVolumeFraction : 0.5 * (e[c] + e[c - s1]);
                   const double ehi1 = hi1 ? kInflowVolumeFraction : 0.5 * (e[c + s1] + e[c]);
                   const double elo2 = lo2 ? kInflowVolumeFraction : 0.5 * (e[c] + e[c - s2]);
                   const double ehi2 = hi2 ? kInflowVolumeFraction : 0.5 * (e[c + s2] + e[c]);
                   double sum = 0.0;
                   sum += (ehi0 * u0[c + 1] - elo0 * u0[c]) / h[0];
                   sum += (ehi1 * u1[c + s1] - elo1 * u1[c]) / h[1];
                   sum += (ehi2 * u2[c + s2] - elo2 * u2[c]) / h[2];
                   return sum;
                 };
                 for (std::ptrdiff_t c = row; c < row + n[0]; ++c) {
                   out[c] = cell(c, 0.5 * (e[c] + e[c - 1]), 0.5 * (e[c + 1] + e[c]));
                 }
                 if (inflow[0][0] || inflow[0][1]) {
                   for (const std::ptrdiff_t c : {row, row + n[0] - 1}) {
                     const bool lo0 = c == row && inflow[0][0];
                     const bool hi0 = c == row + n[0] - 1 && inflow[0][1];
                     out[c] = cell(c, lo0 ? kInflowVolumeFraction : 0.5 * (e[c] + e[c - 1]),
                                   hi0 ? kInflowVolumeFraction : 0.5 * (e[c + 1] + e[c]));
                   }
                 }
               });
}

PressureProjection::PressureProjection(const MacGrid& grid, const ProjectionSettings& settings,
                                       const GridHalo* halo)
    : grid_(grid), settings_(settings), halo_(halo) {
  if (!(settings.tolerance > 0.0) || settings.max_iterations < 1) {
    throw std::invalid_argument("projection tolerance must be > 0 and max_iterations >= 1");
  }
  const auto& n = grid.cells();
  const auto& global = grid.global_cells();
  if (const int a = smg_blocking_axis(grid);
      a >= 0 && settings.preconditioner == PoissonPreconditioner::smg &&
      settings.solver == PoissonSolver::hypre) { // "auto" never picks hypre on such a grid
    throw std::invalid_argument(fmt::format(
        "fluid.preconditioner = \"smg\" cannot run on this grid: periodic axis {} has {} cells, "
        "an odd count, where hypre 2.26's SMG set-up fails; use \"pfmg\" or an even count",
        "xyz"[a], global[a]));
  }
  for (int a = 0; a < 3; ++a) {
    owns_first_cell_ = owns_first_cell_ && grid.box().lo[a] == 0;
  }
  global_cells_ = static_cast<double>(global[0]) * global[1] * global[2];
  const std::size_t cells = static_cast<std::size_t>(n[0]) * n[1] * n[2];
  rhs_.resize(cells);
  solution_.resize(cells);
  div_ = grid.make_field();
  if (grid.has_solid() && settings.solver == PoissonSolver::hypre) {
    throw std::invalid_argument(
        "fluid.solver = \"hypre\" does not take solid cells (domain.shape = \"cylinder\"): its "
        "rows are assembled for a full box; use \"multigrid\" or \"auto\"");
  }
  // Solid cells leave empty rows, which the multigrid skips (multigrid_poisson.hpp): "auto"
  // takes it for a grid with a column.
  const PoissonSolver solver = grid.has_solid()                            ? PoissonSolver::multigrid
                               : settings.solver == PoissonSolver::automatic ? auto_solver(grid)
                                                                            : settings.solver;
  const bool multigrid = solver == PoissonSolver::multigrid;
  if (multigrid) {
    // Only the multigrid's own hierarchy: no hypre grid, matrix, vectors or solver are created
    // (their set-up time and memory would be spent for nothing).
    const std::array<std::array<PoissonSide, 2>, 3> sides = poisson_sides(grid.spec());
    std::array<double, 3> spacing{};
    for (int a = 0; a < 3; ++a) {
      spacing[a] = grid.spacing(a);
    }
    MultigridSettings mg_settings;
    mg_settings.empty_rows = grid.has_solid(); // a column's solid cells
    mg_settings.relaxation_weight = kProjectionRelaxationWeight;
    if (halo == nullptr) {
      mg_ = std::make_unique<MultigridPoisson>(n, spacing, sides, mg_settings);
    } else {
      // Each rank its box; halos at every level, the coarse level gathered onto rank 0.
      mg_ = std::make_unique<MultigridPoisson>(global, spacing, sides, halo->boxes(), halo->comm(),
                                               mg_settings);
    }
    face_coef_ = {grid.make_field(), grid.make_field(), grid.make_field()};
    return;
  }
  hypre_ = new Hypre;
  Hypre& h = *hypre_;
  std::array<HYPRE_Int, 3> periodic{};
  for (int a = 0; a < 3; ++a) {
    h.lower[a] = grid.box().lo[a];
    h.upper[a] = grid.box().hi[a] - 1;
    // A single periodic cell couples only to itself (no flux): leave the axis non-periodic.
    periodic[a] = (grid.periodic(a) && global[a] > 1) ? global[a] : 0;
  }
  // Distributed: hypre talks on its own duplicate of the ranks' communicator, so its messages
  // can never match those of other traffic in flight meanwhile (the particles' ghost forward
  // posted before a gas step, MPI-3.1 §3.5: matching is by source, tag and communicator).
  if (halo != nullptr) {
    MPI_Comm_dup(mpi_comm(halo->comm()), &h.comm);
  }
  const MPI_Comm comm = h.comm;
  HYPRE_StructGridCreate(comm, 3, &h.grid);
  HYPRE_StructGridSetExtents(h.grid, h.lower.data(), h.upper.data());
  HYPRE_StructGridSetPeriodic(h.grid, periodic.data());
  HYPRE_StructGridAssemble(h.grid);
  HYPRE_StructStencilCreate(3, kStencilSize, &h.stencil);
  std::array<std::array<HYPRE_Int, 3>, kStencilSize> offsets = {
      {{0, 0, 0}, {-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}}};
  for (int e = 0; e < kStencilSize; ++e) {
    HYPRE_StructStencilSetElement(h.stencil, e, offsets[e].data());
  }
  HYPRE_StructMatrixCreate(comm, h.grid, h.stencil, &h.matrix);
  HYPRE_StructMatrixInitialize(h.matrix);
  HYPRE_StructVectorCreate(comm, h.grid, &h.b);
  HYPRE_StructVectorInitialize(h.b);
  HYPRE_StructVectorCreate(comm, h.grid, &h.x);
  HYPRE_StructVectorInitialize(h.x);
  guess_.resize(cells);
  x_ = grid.make_field();
}

PressureProjection::~PressureProjection() {
  if (hypre_ == nullptr) {
    return;
  }
  hypre_->destroy_solver();
  HYPRE_StructVectorDestroy(hypre_->x);
  HYPRE_StructVectorDestroy(hypre_->b);
  HYPRE_StructMatrixDestroy(hypre_->matrix);
  HYPRE_StructStencilDestroy(hypre_->stencil);
  HYPRE_StructGridDestroy(hypre_->grid);
  if (hypre_->comm != MPI_COMM_SELF) {
    MPI_Comm_free(&hypre_->comm);
  }
  delete hypre_;
}

void PressureProjection::assemble(const std::vector<double>& stencil_values) {
  Hypre& h = *hypre_;
  std::array<HYPRE_Int, kStencilSize> entries = {0, 1, 2, 3, 4, 5, 6};
  HYPRE_StructMatrixSetBoxValues(h.matrix, h.lower.data(), h.upper.data(), kStencilSize,
                                 entries.data(), const_cast<double*>(stencil_values.data()));
  HYPRE_StructMatrixAssemble(h.matrix);
  h.destroy_solver();
}

// Relative residual ||b - A x|| / ||b|| of the unpinned closed-box system (no periodic axis: a
// neighbour outside the grid has a zero coefficient), from the assembled stencil rows; a
// neighbour across an internal face of a distributed grid is read from x's exchanged ghosts.
double PressureProjection::closed_box_residual(const std::vector<double>& x) {
  const auto& n = grid_.cells();
  const GridLayout& layout = grid_.layout();
  std::size_t m = 0;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        x_(i, j, k) = x[m++];
      }
    }
  }
  if (halo_ != nullptr) {
    halo_->fill(x_, kCellCentred);
  }
  std::array<double, 2> sums{}; // |r|^2, |b|^2
  m = 0;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i, ++m) {
        const double* row = &stencil_values_[m * kStencilSize];
        const int cell[3] = {i, j, k};
        const std::size_t c = layout.index(i, j, k);
        // The pin doubled the diagonal of the global first cell.
        double ax = (m == 0 && owns_first_cell_ ? 0.5 : 1.0) * row[0] * x[m];
        for (int a = 0; a < 3; ++a) {
          const auto s = static_cast<std::size_t>(layout.stride(a));
          if (cell[a] > 0 || grid_.exchanged(a, 0)) {
            ax += row[1 + 2 * a] * x_[c - s];
          }
          if (cell[a] < n[a] - 1 || grid_.exchanged(a, 1)) {
            ax += row[2 + 2 * a] * x_[c + s];
          }
        }
        sums[0] += (rhs_[m] - ax) * (rhs_[m] - ax);
        sums[1] += rhs_[m] * rhs_[m];
      }
    }
  }
  if (halo_ != nullptr) {
    halo_->sum(sums);
  }
  return sums[1] > 0.0 ? std::sqrt(sums[0] / sums[1]) : std::sqrt(sums[0]);
}

bool PressureProjection::solve(PoissonPreconditioner pc, std::vector<double>& x,
                               ProjectionReport& report, double tolerance) {
  Hypre& h = *hypre_;
  if (!(tolerance > 0.0)) {
    tolerance = settings_.tolerance;
  }
  if (!h.solver_ready || h.precond_kind != pc) {
    h.destroy_solver();
    h.precond_kind = pc;
    HYPRE_StructPCGCreate(h.comm, &h.solver);
    HYPRE_StructPCGSetTol(h.solver, settings_.tolerance);
    HYPRE_StructPCGSetMaxIter(h.solver, settings_.max_iterations);
    HYPRE_StructPCGSetTwoNorm(h.solver, 1);
    HYPRE_StructPCGSetRelChange(h.solver, 0);
    HYPRE_StructPCGSetLogging(h.solver, 1);
    if (pc == PoissonPreconditioner::pfmg) {
      HYPRE_StructPFMGCreate(h.comm, &h.precond);
      HYPRE_StructPFMGSetMaxIter(h.precond, 1);
      HYPRE_StructPFMGSetTol(h.precond, 0.0);
      HYPRE_StructPFMGSetZeroGuess(h.precond);
      // Symmetric red/black Gauss-Seidel (hypre then builds non-Galerkin coarse operators).
      HYPRE_StructPFMGSetRelaxType(h.precond, 2);
      std::array<double, 3> dxyz = {grid_.spacing(0), grid_.spacing(1), grid_.spacing(2)};
      HYPRE_StructPFMGSetDxyz(h.precond, dxyz.data());
      HYPRE_StructPFMGSetMaxLevels(h.precond, pfmg_max_levels(grid_));
      HYPRE_StructPFMGSetNumPreRelax(h.precond, 1);
      HYPRE_StructPFMGSetNumPostRelax(h.precond, 1);
      HYPRE_StructPCGSetPrecond(h.solver, HYPRE_StructPFMGSolve, HYPRE_StructPFMGSetup, h.precond);
    } else {
      HYPRE_StructSMGCreate(h.comm, &h.precond);
      HYPRE_StructSMGSetMemoryUse(h.precond, 0);
      HYPRE_StructSMGSetMaxIter(h.precond, 1);
      HYPRE_StructSMGSetTol(h.precond, 0.0);
      HYPRE_StructSMGSetZeroGuess(h.precond);
      HYPRE_StructSMGSetNumPreRelax(h.precond, 1);
      HYPRE_StructSMGSetNumPostRelax(h.precond, 1);
      HYPRE_StructPCGSetPrecond(h.solver, HYPRE_StructSMGSolve, HYPRE_StructSMGSetup, h.precond);
    }
    HYPRE_StructPCGSetup(h.solver, h.matrix, h.b, h.x);
    h.solver_ready = true;
  }
  HYPRE_StructPCGSetTol(h.solver, tolerance);
  HYPRE_StructVectorSetBoxValues(h.x, h.lower.data(), h.upper.data(), x.data());
  HYPRE_StructVectorAssemble(h.x);
  HYPRE_StructPCGSolve(h.solver, h.matrix, h.b, h.x);
  HYPRE_ClearAllErrors(); // non-convergence is judged from the residual below
  HYPRE_Int iterations = 0;
  double residual = 0.0;
  HYPRE_StructPCGGetNumIterations(h.solver, &iterations);
  HYPRE_StructPCGGetFinalRelativeResidualNorm(h.solver, &residual);
  report.iterations += iterations;
  report.relative_residual = residual;
  if (!(residual <= tolerance)) {
    return false;
  }
  HYPRE_StructVectorGetBoxValues(h.x, h.lower.data(), h.upper.data(), x.data());
  return true;
}

ProjectionReport PressureProjection::project(std::array<GridField, 3>& u, const GridField& eps,
                                             const std::array<GridField, 3>& mobility,
                                             const GridField& source, GridField& phi) {
  flux_divergence(grid_, u, eps, div_);
  ProjectionReport report;
  if (mg_) {
    solve_with_multigrid(eps, mobility, source, phi, report);
  } else {
    solve_with_hypre(eps, mobility, source, phi, report);
  }
  correct(u, mobility, phi);
  return report;
}

// The same system as the hypre rows below, given to the multigrid as face coefficients: K_f =
// eps_f m_f / h^2 on every face (a periodic axis's face n is its face 0; wall and inflow faces
// carry no flux and are not read), the outflow faces' p_out moved into the right-hand side.
void PressureProjection::solve_with_multigrid(const GridField& eps,
                                              const std::array<GridField, 3>& mobility,
                                              const GridField& source, const GridField& phi,
                                              ProjectionReport& report) {
  const GridLayout& layout = grid_.layout();
  const auto& n = grid_.cells();
  // The hierarchy (coarse coefficients, line factors, coarsest Cholesky) is rebuilt only when a
  // face coefficient changed: the corrector of a gas step projects with the predictor's eps and
  // mobility, so its set-up would repeat the predictor's bit for bit (hypre's path likewise
  // keeps its set-up while the matrix is unchanged). Rows are TBB tasks; each marks its plane.
  changed_planes_.assign(static_cast<std::size_t>(n[2]) + 1, 0);
  for (int a = 0; a < 3; ++a) {
    const std::ptrdiff_t s = layout.stride(a);
    const double inv_dx2 = 1.0 / (grid_.spacing(a) * grid_.spacing(a));
    std::array<int, 3> hi = {n[0] - 1, n[1] - 1, n[2] - 1};
    hi[a] = n[a]; // faces 0..n along a
    for_box_rows(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t row, int, int k) {
      bool changed = false;
      for (std::ptrdiff_t p = row; p <= row + hi[0]; ++p) {
        const auto f = static_cast<std::size_t>(p);
        const double coef = face_eps(eps, f, s) * mobility[a][f] * inv_dx2;
        changed |= coef != face_coef_[a][f]; // no short circuit: the row vectorizes
        face_coef_[a][f] = coef;
      }
      if (changed) {
        changed_planes_[static_cast<std::size_t>(k)] = 1; // only this plane's rows write it
      }
    });
  }
  bool changed = !mg_ready_ || std::find(changed_planes_.begin(), changed_planes_.end(), 1) !=
                                   changed_planes_.end();
  if (halo_ != nullptr) {
    // The set-up is collective: every rank rebuilds if any box's coefficients changed.
    changed = halo_->max(changed ? 1.0 : 0.0) > 0.0;
  }
  if (changed) {
    mg_->set_coefficients(face_coef_);
    mg_ready_ = true;
    ++mg_setups_;
  }
  // Cell (i, j, k) is entry m = i + n0 (j + n1 k) of the solver's vectors; rows are TBB tasks.
  // An outflow face's 2 K_f p_out (ghost 2 p_out - phi) is added after the row's -(div + source),
  // axis by axis: on the x sides to the row's end cells, on the y and z sides to whole rows.
  for_box_rows(
      layout, {0, 0, 0}, {n[0] - 1, n[1] - 1, n[2] - 1}, [&](std::ptrdiff_t row, int j, int k) {
        const std::size_t m = static_cast<std::size_t>(n[0]) *
                              (static_cast<std::size_t>(j) +
                               static_cast<std::size_t>(n[1]) * static_cast<std::size_t>(k));
        const auto c0 = static_cast<std::size_t>(row);
        double* __restrict out = rhs_.data() + m;
        for (int i = 0; i < n[0]; ++i) {
          const std::size_t c = c0 + static_cast<std::size_t>(i);
          out[i] = -(div_[c] + source[c]);
          solution_[m + static_cast<std::size_t>(i)] = phi[c];
        }
        const std::array<int, 3> at = {0, j, k};
        for (int a = 0; a < 3; ++a) {
          for (int side = 0; side < 2; ++side) {
            const BoundaryCondition& bc = grid_.bc(a, side);
            if (bc.kind != BoundaryKind::outflow || grid_.exchanged(a, side)) {
              continue; // a side shared with another box is no outflow face
            }
            const int edge = side == 0 ? 0 : n[a] - 1;
            const std::size_t up = side == 0 ? 0 : static_cast<std::size_t>(layout.stride(a));
            const double* coef = face_coef_[a].values().data();
            if (a == 0) {
              const auto i = static_cast<std::size_t>(edge);
              out[i] += 2.0 * coef[c0 + i + up] * bc.pressure;
            } else if (at[a] == edge) {
              for (int i = 0; i < n[0]; ++i) {
                const std::size_t f = c0 + static_cast<std::size_t>(i) + up;
                out[i] += 2.0 * coef[f] * bc.pressure;
              }
            }
          }
        }
      });
  const MultigridReport mr =
      mg_->solve(rhs_, solution_, settings_.tolerance, settings_.max_iterations);
  report.iterations = mr.iterations;
  report.relative_residual = mr.relative_residual;
  if (!std::isfinite(mr.relative_residual)) {
    // Every box took the same norms: each looks at its own cells, and all name the first such
    // cell of the whole grid.
    std::int64_t key = 0;
    std::string message = not_finite_input(eps, mobility, source, key);
    if (halo_ != nullptr)
      message = halo_->comm().agree_on_error(key, message);
    throw std::runtime_error(
        message.empty() ? "pressure projection: the multigrid's residual is not finite, though "
                          "its equation's values and their squares are"
                        : message);
  }
  if (!mr.converged) {
    // Stalled (MultigridReport): round-off bounds the residual above the tolerance. Cells far
    // from cubes raise that floor (the operator's rows mix 1/dx^2 of very different sizes):
    // [1000, 1, 1] on the bed's column, 6250:1, stalled at 7.6e-10.
    double longest = 0.0;
    double shortest = std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a) {
      longest = std::max(longest, grid_.spacing(a));
      shortest = std::min(shortest, grid_.spacing(a));
    }
    // So does a wide span of the face coefficients eps_f m_f / dx^2: the mobility m_f falls
    // where the drag is strong against the gas's inertia (hcs_gas with rho_g = 1e-9 stalled at
    // 1.8e-10 on cubic cells). Only cells far from cubes are named as the cause.
    // Over every box (the solve, and so its stall, is collective).
    std::array<double, 2> span = {-std::numeric_limits<double>::infinity(), 0.0}; // -min, max
    for (int a = 0; a < 3; ++a)
      for (const double k : face_coef_[a].values())
        if (k > 0.0 && std::isfinite(k))
          span = {std::max(span[0], -k), std::max(span[1], k)};
    if (halo_ != nullptr)
      halo_->comm().max(span);
    const double kmin = -span[0], kmax = span[1];
    const double aspect = longest / shortest;
    throw std::runtime_error(fmt::format(
        "pressure projection: multigrid-preconditioned CG {} relative residual {:g} after {} "
        "iterations (tolerance {:g}){}",
        mr.stalled ? "stopped making progress at" : "reached", mr.relative_residual, mr.iterations,
        settings_.tolerance,
        mr.stalled
            ? fmt::format(": round-off holds the residual above the tolerance (the cells' longest "
                          "side is {:.3g}x their shortest, the face coefficients eps_g x "
                          "mobility / dx^2 span {:.3g}x; {})",
                          aspect, kmax > 0.0 ? kmax / kmin : 1.0,
                          aspect > kNearCubes
                              ? "cells nearer cubes, or a looser fluid.tolerance, lower that floor"
                              : "a looser fluid.tolerance lowers that floor")
            : std::string()));
  }
}

// Why the multigrid's residual is not finite: this box's first cell (x fastest) whose right-hand
// side, or face coefficient, is not finite or squares beyond double precision, with the terms
// that made it, in the whole grid's indices; `key` its index in the whole grid (x fastest). An
// empty message when the box has none. A velocity of 1e300 m/s or an outflow pressure of 1e300
// Pa read "reached relative residual -nan after 0 iterations".
std::string PressureProjection::not_finite_input(const GridField& eps,
                                                 const std::array<GridField, 3>& mobility,
                                                 const GridField& source, std::int64_t& key) const {
  const GridLayout& layout = grid_.layout();
  const auto& n = grid_.cells();
  const auto& lo = grid_.box().lo;
  const auto& whole = grid_.global_cells();
  for (int k = 0; k < n[2]; ++k)
    for (int j = 0; j < n[1]; ++j)
      for (int i = 0; i < n[0]; ++i) {
        const std::size_t m = static_cast<std::size_t>(i) +
                              static_cast<std::size_t>(n[0]) *
                                  (static_cast<std::size_t>(j) +
                                   static_cast<std::size_t>(n[1]) * static_cast<std::size_t>(k));
        const auto c = static_cast<std::size_t>(layout.index(i, j, k));
        // Finite squares: the solver's norms and dot products square its values.
        const auto held = [](double x) { return std::isfinite(x * x); };
        bool faces = true;
        for (int a = 0; a < 3; ++a)
          faces = faces && held(face_coef_[a][c]) &&
                  held(face_coef_[a][c + static_cast<std::size_t>(layout.stride(a))]);
        if (held(rhs_[m]) && faces)
          continue;
        std::string outflow;
        for (int a = 0; a < 3; ++a)
          for (int side = 0; side < 2; ++side) {
            const BoundaryCondition& bc = grid_.bc(a, side);
            const int at = a == 0 ? i : a == 1 ? j : k;
            if (bc.kind == BoundaryKind::outflow && !grid_.exchanged(a, side) &&
                at == (side == 0 ? 0 : n[a] - 1))
              outflow = fmt::format(", next to an outflow face at {:g} Pa (fluid.outflow_pressure)",
                                    bc.pressure);
          }
        const std::array<std::int64_t, 3> g = {lo[0] + i, lo[1] + j, lo[2] + k};
        key = g[0] + whole[0] * (g[1] + static_cast<std::int64_t>(whole[1]) * g[2]);
        return fmt::format(
            "pressure projection: its equation overflows at gas cell ({}, {}, {}) (right-hand "
            "side {:g}: velocity divergence {:g}, continuity source {:g}{}; eps_g {:g}, face "
            "mobilities {:g} {:g} {:g}): a value not finite, or whose square double precision "
            "cannot hold",
            g[0], g[1], g[2], rhs_[m], div_[c], source[c], outflow, eps[c], mobility[0][c],
            mobility[1][c], mobility[2][c]);
      }
  return {};
}

void PressureProjection::solve_with_hypre(const GridField& eps,
                                          const std::array<GridField, 3>& mobility,
                                          const GridField& source, const GridField& phi,
                                          ProjectionReport& report) {
  const GridLayout& layout = grid_.layout();
  const auto& n = grid_.cells();
  std::vector<double>& values = next_values_;
  values.assign(rhs_.size() * kStencilSize, 0.0);
  const GridField& div = div_;
  const bool singular = !grid_.has_outflow();
  const bool pinned = singular && settings_.preconditioner == PoissonPreconditioner::pfmg &&
                      !grid_.periodic(0) && !grid_.periodic(1) && !grid_.periodic(2);
  const auto& global = grid_.global_cells();

  std::size_t m = 0;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i, ++m) {
        const std::array<int, 3> cell = {i, j, k};
        const std::size_t c = layout.index(cell);
        double* row = &values[m * kStencilSize];
        double rhs = -(div[c] + source[c]);
        for (int a = 0; a < 3; ++a) {
          const std::ptrdiff_t s = layout.stride(a);
          const double inv_dx2 = 1.0 / (grid_.spacing(a) * grid_.spacing(a));
          for (int side = 0; side < 2; ++side) {
            const bool edge = side == 0 ? cell[a] == 0 : cell[a] == n[a] - 1;
            // A face shared with another box (or a periodic image) couples like an interior
            // one: its coefficient is computed from the same exchanged values on both sides.
            const bool exchanged = edge && grid_.exchanged(a, side) && global[a] > 1;
            const bool boundary = edge && !grid_.exchanged(a, side);
            std::size_t f = side == 0 ? c : c + static_cast<std::size_t>(s);
            if (boundary && side == 1 && grid_.periodic(a)) {
              f -= static_cast<std::size_t>(n[a] * s); // face n is face 0: one coefficient
            }
            const double coef = face_eps(eps, f, s) * mobility[a][f] * inv_dx2;
            if (!edge || exchanged) {
              row[0] += coef;
              row[1 + 2 * a + side] = -coef;
              continue;
            }
            if (!boundary) {
              continue; // a one-cell periodic axis of a distributed grid: no flux
            }
            const BoundaryCondition& bc = grid_.bc(a, side);
            if (bc.kind == BoundaryKind::periodic && n[a] > 1) {
              row[0] += coef;
              row[1 + 2 * a + side] = -coef;
            } else if (bc.kind == BoundaryKind::outflow) {
              // phi = p_out on the face: ghost 2 p_out - phi (docs/theory.md §5 outflow).
              row[0] += 2.0 * coef;
              rhs += 2.0 * coef * bc.pressure;
            }
          }
        }
        if (pinned && m == 0 && owns_first_cell_) {
          // Pin the first cell (phi = 0 there): A + d e0 e0^T is definite, and with a
          // compatible right-hand side (zero sum, below) its exact solution solves the
          // singular system (summing all rows gives d phi_0 = 0). In a closed box PFMG's coarse
          // levels are otherwise singular and PCG stalls.
          row[0] *= 2.0;
        }
        rhs_[m] = rhs;
        solution_[m] = phi[c];
      }
    }
  }
  if (singular) {
    // Only gradients of phi are defined: make the right-hand side compatible (zero sum).
    double mean = 0.0;
    for (const double r : rhs_) {
      mean += r;
    }
    mean = global_sum(mean) / global_cells_;
    for (double& r : rhs_) {
      r -= mean;
    }
  }
  bool changed = values != stencil_values_;
  if (halo_ != nullptr) {
    // Assembly and solver set-up are collective: every rank re-assembles if any matrix changed.
    changed = halo_->max(changed ? 1.0 : 0.0) > 0.0;
  }
  if (changed) {
    std::swap(stencil_values_, values);
    assemble(stencil_values_);
  }
  Hypre& h = *hypre_;
  HYPRE_StructVectorSetBoxValues(h.b, h.lower.data(), h.upper.data(), rhs_.data());
  HYPRE_StructVectorAssemble(h.b);

  guess_ = solution_;
  if (!solve(settings_.preconditioner, solution_, report)) {
    if (settings_.preconditioner == PoissonPreconditioner::smg) {
      throw std::runtime_error(fmt::format(
          "pressure projection: PCG/SMG reached relative residual {:g} after {} iterations "
          "(tolerance {:g})",
          report.relative_residual, report.iterations, settings_.tolerance));
    }
    if (const int a = smg_blocking_axis(grid_); a >= 0) {
      // Calling SMG here would abort the whole run inside hypre: say what went wrong instead.
      throw std::runtime_error(fmt::format(
          "pressure projection: PCG/PFMG reached relative residual {:g} after {} iterations "
          "(tolerance {:g}, fluid.max_iterations = {}). PFMG coarsens this {} x {} x {} grid to "
          "{} level(s) only (it stops at the first odd periodic count), and the SMG fallback "
          "cannot run: periodic axis {} has an odd cell count ({}). Give periodic axes cell "
          "counts divisible by a power of two, raise fluid.max_iterations, or use "
          "fluid.solver = \"multigrid\"",
          report.relative_residual, report.iterations, settings_.tolerance,
          settings_.max_iterations, grid_.global_cells()[0], grid_.global_cells()[1],
          grid_.global_cells()[2], pfmg_max_levels(grid_), "xyz"[a], grid_.global_cells()[a]));
    }
    solution_ = guess_;
    report.used_fallback = true;
    if (!solve(PoissonPreconditioner::smg, solution_, report)) {
      throw std::runtime_error(
          fmt::format("pressure projection: neither PCG/PFMG nor PCG/SMG reached tolerance {:g} "
                      "(relative residual {:g} after {} iterations)",
                      settings_.tolerance, report.relative_residual, report.iterations));
    }
  }
  if (pinned) {
    // The solver's residual is the pinned system's; the constraint is the singular system's,
    // which differs in the pinned row by d phi_0 (phi_0 -> 0 only as the solve converges).
    // Tighten until the singular system's residual meets the tolerance too.
    for (int tries = 1; tries <= 4; ++tries) {
      const double rel = closed_box_residual(solution_);
      if (rel <= settings_.tolerance) {
        break;
      }
      if (tries == 4 || !solve(PoissonPreconditioner::pfmg, solution_, report,
                               settings_.tolerance * std::pow(0.1, tries))) {
        throw std::runtime_error(fmt::format(
            "pressure projection: the pinned closed-box system left a relative residual {:g} "
            "(tolerance {:g})",
            rel, settings_.tolerance));
      }
    }
  }
}

void PressureProjection::correct(std::array<GridField, 3>& u,
                                 const std::array<GridField, 3>& mobility, GridField& phi) {
  const GridLayout& layout = grid_.layout();
  const auto& n = grid_.cells();
  if (!grid_.has_outflow()) {
    double mean = 0.0;
    for (const double x : solution_) {
      mean += x;
    }
    mean = global_sum(mean) / global_cells_;
    for (double& x : solution_) {
      x -= mean;
    }
  }
  for_box_rows(
      layout, {0, 0, 0}, {n[0] - 1, n[1] - 1, n[2] - 1}, [&](std::ptrdiff_t row, int j, int k) {
        const std::size_t m = static_cast<std::size_t>(n[0]) *
                              (static_cast<std::size_t>(j) +
                               static_cast<std::size_t>(n[1]) * static_cast<std::size_t>(k));
        std::copy_n(solution_.begin() + static_cast<std::ptrdiff_t>(m), n[0],
                    phi.values().begin() + row);
      });
  if (halo_ != nullptr) {
    halo_->fill(phi, kCellCentred); // the correction of the box's edge faces reads them
  }

  // u = u* - m_f grad phi on every face whose velocity is not prescribed; rows of faces are TBB
  // tasks (each face written once, from phi and its own value).
  for (int a = 0; a < 3; ++a) {
    const std::ptrdiff_t s = layout.stride(a);
    const double inv_dx = 1.0 / grid_.spacing(a);
    std::array<int, 3> hi = {n[0] - 1, n[1] - 1, n[2] - 1};
    hi[a] = n[a]; // faces 0..n along a
    const bool open_lo = grid_.exchanged(a, 0);
    const bool open_hi = grid_.exchanged(a, 1);
    // Faces between two cells of the box (or an exchanged side): grad = (phi_c - phi_below) / h.
    const auto interior = [&](std::size_t f) {
      const std::size_t below = f - static_cast<std::size_t>(s);
      u[a][f] -= mobility[a][f] * ((phi[f] - phi[below]) * inv_dx);
    };
    // A face on the box's boundary along a (face index 0 or n).
    const auto boundary = [&](std::size_t f, std::array<int, 3> face) {
      const std::size_t below = f - static_cast<std::size_t>(s);
      const int side = face[a] == 0 ? 0 : 1;
      const BoundaryCondition& bc = grid_.bc(a, side);
      double grad = 0.0;
      if (bc.kind == BoundaryKind::periodic) {
        if (side == 1) {
          return; // face n is face 0, set below
        }
        face[a] = n[a] - 1;
        grad = (phi[f] - phi(face[0], face[1], face[2])) * inv_dx;
      } else if (bc.kind == BoundaryKind::outflow) {
        grad = side == 0 ? 2.0 * (phi[f] - bc.pressure) * inv_dx
                         : 2.0 * (bc.pressure - phi[below]) * inv_dx;
      } else {
        return; // wall or inflow: prescribed
      }
      u[a][f] -= mobility[a][f] * grad;
    };
    for_box_rows(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t row, int j, int k) {
      const auto f0 = static_cast<std::size_t>(row);
      if (a != 0) {
        const int at = a == 1 ? j : k; // the row's face index along a
        if ((at > 0 || open_lo) && (at < n[a] || open_hi)) {
          for (int i = 0; i <= hi[0]; ++i) {
            interior(f0 + static_cast<std::size_t>(i));
          }
        } else {
          for (int i = 0; i <= hi[0]; ++i) {
            boundary(f0 + static_cast<std::size_t>(i), {i, j, k});
          }
        }
        return;
      }
      // Along x the row's first and last faces may lie on the boundary.
      if (!open_lo) {
        boundary(f0, {0, j, k});
      }
      for (int i = open_lo ? 0 : 1; i <= (open_hi ? n[0] : n[0] - 1); ++i) {
        interior(f0 + static_cast<std::size_t>(i));
      }
      if (!open_hi) {
        boundary(f0 + static_cast<std::size_t>(n[0]), {n[0], j, k});
      }
    });
    if (grid_.periodic(a) && !grid_.distributed()) {
      // Face n is face 0.
      std::array<int, 3> hi_other = {n[0] - 1, n[1] - 1, n[2] - 1};
      hi_other[a] = 0;
      const std::size_t period = static_cast<std::size_t>(n[a]) * static_cast<std::size_t>(s);
      for_box(layout, {0, 0, 0}, hi_other, [&](std::ptrdiff_t p) {
        const auto f = static_cast<std::size_t>(p);
        u[a][f + period] = u[a][f];
      });
    }
  }
}

} // namespace cfddem::fluid
