// Projection of face velocities onto the model-A constraint div(eps u) = -d(eps)/dt
// (docs/theory.md §5): the variable-coefficient Poisson equation
//   div(eps_f m_f grad phi) = div(eps_f u*) + d(eps)/dt,   u = u* - m_f grad phi,
// solved either by our geometric multigrid inside flexible CG (fluid/multigrid_poisson.hpp) or
// with hypre's Struct interface, PCG preconditioned with PFMG (SMG as fallback).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "fluid/grid_field.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/mac_grid.hpp"
#include "fluid/multigrid_poisson.hpp"

namespace cfddem::fluid {

// automatic: auto_solver() below (the multigrid, unless its hierarchy ends on a large grid that
// hypre's PFMG coarsens).
enum class PoissonSolver { automatic, multigrid, hypre };

// PFMG (semicoarsening, pointwise relaxation) is the default. SMG (plane relaxation) is more
// robust for strong anisotropy but, in hypre 2.26, fails to converge when a periodic axis has
// an odd number of cells (tests: PressureProjection); PFMG handles any period, slower when the
// period is not 2^m times a small number.
enum class PoissonPreconditioner { pfmg, smg };

struct ProjectionSettings {
  double tolerance = 1e-10; // PCG relative residual, 2-norm
  int max_iterations = 200;
  PoissonPreconditioner preconditioner = PoissonPreconditioner::pfmg; // hypre's
  PoissonSolver solver = PoissonSolver::automatic;
};

struct ProjectionReport {
  int iterations = 0;
  double relative_residual = 0.0;
  bool used_fallback = false; // PFMG did not converge and SMG was used
};

// The PFMG levels the hypre path uses on this grid (every periodic axis keeps >= 2 cells).
[[nodiscard]] int pfmg_max_levels(const MacGrid& grid);
// The cells of PFMG's coarsest grid at those levels.
[[nodiscard]] std::size_t pfmg_coarsest_cells(const MacGrid& grid);

// The first periodic axis (global count > 1) with an odd cell count, or -1. hypre 2.26's SMG
// set-up fails there (on R ranks with MPI_ERR_TRUNCATE inside its interpolation assembly), so
// SMG is neither offered nor used as the fallback on such a grid.
[[nodiscard]] int smg_blocking_axis(const MacGrid& grid);

// What fluid.solver = "auto" picks for this grid (global counts, on any rank count): the
// multigrid (fewer instructions than hypre on the riser grid, on one grid and on R ranks:
// docs/multigrid.md, docs/performance_history.md), except where its hierarchy cannot coarsen below
// kAutoCoarsestCells (odd or short axes: its coarsest level is then solved by CG at every
// V-cycle) while PFMG's own coarsening gets to at most kAutoCoarsestCells (it stops at an odd
// period, on any level: the riser at 1e6, 270 x 50 x 270 periodic, halves x and z once to 135
// in both, where PFMG needed 117 PCG iterations per fluid step on 16 ranks and the multigrid
// 14). Measured on the bed at 1e5 particles, 101 x 50 x 101 cells, walls on x and z: coarsest
// level 255,025 cells, fluid phase 6.81 s with the multigrid against 1.70 s with hypre per fluid
// step; the riser at 85 x 50 x 86, periodic: 1.21 s against 2.40 s (docs/performance_history.md).
inline constexpr std::size_t kAutoCoarsestCells = 32768;
[[nodiscard]] PoissonSolver auto_solver(const MacGrid& grid);

// The weight of the projection's red-black smoothing (MultigridSettings::relaxation_weight):
// over-relaxed Gauss-Seidel, which saves PCG iterations on the risers (measured over the first
// 5 ms, PCG iterations at weight 1, 1.05, 1.08, 1.1, 1.12: the riser 349, 309, 306, 305, 305;
// riser_gravity 313, 298, 288, 286, 286; hcs_gas 351 then 350; the fluidized bed's first 2 ms
// 182 at 1, 181 at 1.1, 182 at 1.15, 183 at 1.2, 196 at 1.3; the riser's 2 ms 143 at 1, 141 at
// 1.2, 164 at 1.3, 189 at 1.4): flat from 1.05 to 1.15, a loss from 1.2, so the middle of the
// flat stretch (docs/multigrid.md, "Over-relaxation").
inline constexpr double kProjectionRelaxationWeight = 1.1;

// The grid's boundary kinds as the multigrid's sides: walls and inflow carry no correction flux
// (Neumann), an outflow face holds phi (Dirichlet), periodic stays periodic.
[[nodiscard]] std::array<std::array<PoissonSide, 2>, 3> poisson_sides(const MacGridSpec& spec);

// div(eps_f u) per interior cell [1/s]; eps ghosts must be filled. eps_f is the mean of the two
// cells, except on a velocity-inflow face: kInflowVolumeFraction (the incoming gas's).
void flux_divergence(const MacGrid& grid, const std::array<GridField, 3>& u, const GridField& eps,
                     GridField& div);

// With hypre: holds its grid, matrix and solver; the solver set-up is reused while the matrix
// is unchanged. Undistributed (halo == nullptr): hypre objects on MPI_COMM_SELF. Distributed: on
// the halo's communicator, each rank's box in global indices, the periodic axes by
// HYPRE_StructGridSetPeriodic; collective. MPI must be initialised. The multigrid keeps its own
// hierarchy (distributed: over the halo's boxes, collective): with it no hypre object is ever
// created.
class PressureProjection {
public:
  // halo: the grid's halo when grid is one box of a distributed grid (kept by the caller).
  PressureProjection(const MacGrid& grid, const ProjectionSettings& settings,
                     const GridHalo* halo = nullptr);
  ~PressureProjection();
  PressureProjection(const PressureProjection&) = delete;
  PressureProjection& operator=(const PressureProjection&) = delete;

  // mobility[a] = m_f on the a-faces (dt/(rho_g + dt beta_f/eps_f) for the implicit-drag
  // predictor). source = d(eps)/dt per cell. phi: in, first guess; out, solution with phi =
  // p_out on outflow faces (mean zero when no face fixes the level). Preconditions: ghosts of
  // eps filled; u satisfies its boundary conditions. Corrects every face that is not prescribed
  // (interior, periodic and outflow faces); the caller refills velocity ghosts. Distributed:
  // phi's ghosts are exchanged (the correction of the box's edge faces reads them) and face n
  // of an exchanged side is corrected like its owner's face 0, bitwise.
  // Throws std::runtime_error when neither preconditioner reaches the tolerance.
  ProjectionReport project(std::array<GridField, 3>& u, const GridField& eps,
                           const std::array<GridField, 3>& mobility, const GridField& source,
                           GridField& phi);

  [[nodiscard]] const ProjectionSettings& settings() const { return settings_; }
  // The solver in use (automatic resolved).
  [[nodiscard]] PoissonSolver solver() const {
    return mg_ ? PoissonSolver::multigrid : PoissonSolver::hypre;
  }
  // Whether hypre's grid, matrix and vectors exist (only when hypre solves).
  [[nodiscard]] bool holds_hypre_objects() const { return hypre_ != nullptr; }
  // The multigrid (nullptr when hypre solves), e.g. for benchmarks of its kernels.
  [[nodiscard]] MultigridPoisson* multigrid() { return mg_.get(); }
  [[nodiscard]] const MultigridPoisson* multigrid() const { return mg_.get(); }
  // How many times the multigrid's hierarchy was built (once per new set of face coefficients).
  [[nodiscard]] long long multigrid_setups() const { return mg_setups_; }

private:
  struct Hypre;
  // The message for a multigrid residual that is not finite, and its cell's key (the .cpp).
  [[nodiscard]] std::string not_finite_input(const GridField& eps,
                                             const std::array<GridField, 3>& mobility,
                                             const GridField& source, std::int64_t& key) const;
  // The projection's right-hand side into rhs_ and the solve into solution_: hypre (stencil rows
  // assembled) or the multigrid (face coefficients).
  void solve_with_hypre(const GridField& eps, const std::array<GridField, 3>& mobility,
                        const GridField& source, const GridField& phi, ProjectionReport& report);
  void solve_with_multigrid(const GridField& eps, const std::array<GridField, 3>& mobility,
                            const GridField& source, const GridField& phi,
                            ProjectionReport& report);
  // phi from solution_ (mean zero when singular), then u -= m_f grad phi.
  void correct(std::array<GridField, 3>& u, const std::array<GridField, 3>& mobility,
               GridField& phi);
  void assemble(const std::vector<double>& stencil_values);
  // tolerance <= 0: the settings' tolerance.
  bool solve(PoissonPreconditioner pc, std::vector<double>& x, ProjectionReport& report,
             double tolerance = 0.0);
  double closed_box_residual(const std::vector<double>& x);
  [[nodiscard]] double global_sum(double v) const { return halo_ ? halo_->sum(v) : v; }

  MacGrid grid_;
  ProjectionSettings settings_;
  const GridHalo* halo_ = nullptr;
  double global_cells_ = 0.0;
  bool owns_first_cell_ = true; // global cell (0, 0, 0), the closed box's pinned cell
  Hypre* hypre_ = nullptr;
  std::vector<double> stencil_values_; // 7 per cell: centre, -x, +x, -y, +y, -z, +z
  std::vector<double> next_values_;
  std::vector<double> rhs_;
  std::vector<double> solution_;
  std::vector<double> guess_;
  GridField div_;
  GridField x_; // closed_box_residual's iterate with ghosts
  std::unique_ptr<MultigridPoisson> mg_;
  std::array<GridField, 3> face_coef_; // the multigrid's eps_f m_f / h^2
  std::vector<char> changed_planes_;   // per z-plane: a face coefficient changed
  bool mg_ready_ = false;              // the hierarchy holds face_coef_'s coefficients
  long long mg_setups_ = 0;
};

} // namespace cfddem::fluid
