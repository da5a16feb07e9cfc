// Benchmarks of the gas solver on the paper's riser grid (32 x 50 x 32 cells, 0.2 mm, periodic,
// 2 Pa drop along y): the projection with hypre and with our multigrid side by side (full solve,
// V-cycle, smoother sweep, residual, in ns per cell), the momentum right-hand side and a full
// step.
#include <cmath>
#include <random>

#include <HYPRE_struct_ls.h>
#include <HYPRE_utilities.h>
#include <benchmark/benchmark.h>
#include <mpi.h>
#include <tbb/global_control.h>

#include "fluid/gas_solver.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/momentum_rhs.hpp"
#include "fluid/pressure_projection.hpp"

namespace cfddem::fluid {
namespace {

MacGridSpec riser_spec() {
  MacGridSpec spec;
  spec.cells = {32, 50, 32};
  spec.extent = {6.4e-3, 10e-3, 6.4e-3};
  for (BoundaryCondition& bc : spec.bc) {
    bc.kind = BoundaryKind::periodic;
  }
  spec.pressure_drop = {0.0, 2.0, 0.0};
  return spec;
}

// eps_g in [0.95, 1] (the riser's phi ~ 0.02 with clustering) and a drag field.
void fill_particle_fields(const MacGrid& grid, GridField& eps, GridField* beta, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int k = 0; k < grid.cells(2); ++k) {
    for (int j = 0; j < grid.cells(1); ++j) {
      for (int i = 0; i < grid.cells(0); ++i) {
        eps(i, j, k) = 0.95 + 0.05 * u(rng);
        if (beta != nullptr) {
          (*beta)(i, j, k) = 2e3 * u(rng); // ~ 40 particles' beta_i/V_cell at phi = 0.02
        }
      }
    }
  }
  fill_cell_ghosts(grid, eps, CellGhosts::zero_gradient);
}

void run_projection(benchmark::State& state, PoissonPreconditioner pc, bool new_matrix) {
  const MacGrid grid(riser_spec());
  ProjectionSettings settings;
  settings.tolerance = 1e-8;
  settings.preconditioner = pc;
  PressureProjection projection(grid, settings);
  std::array<GridField, 3> u = {grid.make_field(), grid.make_field(), grid.make_field()};
  const std::array<GridField, 3> mobility = {grid.make_field(1e-4), grid.make_field(1e-4),
                                             grid.make_field(1e-4)};
  GridField eps = grid.make_field();
  GridField source = grid.make_field();
  GridField phi = grid.make_field();
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> uni(-0.1, 0.1);
  unsigned seed = 0;
  fill_particle_fields(grid, eps, nullptr, seed);
  const double cells = 32.0 * 50.0 * 32.0;
  double iterations = 0.0;
  for (auto _ : state) {
    state.PauseTiming();
    for (auto& c : u) {
      for (double& v : c.values()) {
        v = uni(rng);
      }
    }
    fill_velocity_ghosts(grid, u);
    phi.fill(0.0);
    if (new_matrix) {
      fill_particle_fields(grid, eps, nullptr, ++seed);
    }
    state.ResumeTiming();
    const ProjectionReport report = projection.project(u, eps, mobility, source, phi);
    iterations += report.iterations;
  }
  state.counters["pcg_iterations"] =
      benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
  state.counters["cell_iterations_per_s"] =
      benchmark::Counter(cells * iterations, benchmark::Counter::kIsRate);
  state.counters["cells_per_s"] = benchmark::Counter(
      cells * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}

void BM_ProjectionRiserPfmg(benchmark::State& state) {
  run_projection(state, PoissonPreconditioner::pfmg, state.range(0) != 0);
}
BENCHMARK(BM_ProjectionRiserPfmg)
    ->ArgName("new_matrix")
    ->Arg(0)
    ->Arg(1)
    ->Unit(benchmark::kMillisecond);

void BM_ProjectionRiserSmg(benchmark::State& state) {
  run_projection(state, PoissonPreconditioner::smg, state.range(0) != 0);
}
BENCHMARK(BM_ProjectionRiserSmg)
    ->ArgName("new_matrix")
    ->Arg(0)
    ->Arg(1)
    ->Unit(benchmark::kMillisecond);

// Riser-like projection coefficients: eps_g in [0.95, 1] and the implicit-drag mobility
// dt / (rho + dt beta / eps) with beta up to 2e3 kg/m^3/s, new every step (as when coupled).
struct RiserSystem {
  MacGrid grid{riser_spec()};
  std::array<GridField, 3> u{grid.make_field(), grid.make_field(), grid.make_field()};
  std::array<GridField, 3> mobility{grid.make_field(), grid.make_field(), grid.make_field()};
  GridField eps = grid.make_field();
  GridField beta = grid.make_field();
  GridField source = grid.make_field();
  GridField phi = grid.make_field();
  std::mt19937_64 rng{1};

  void renew(unsigned seed) {
    const double dt = 1e-4;
    fill_particle_fields(grid, eps, &beta, seed);
    fill_cell_ghosts(grid, beta, CellGhosts::zero_gradient);
    const GridLayout& layout = grid.layout();
    for (int a = 0; a < 3; ++a) {
      const std::ptrdiff_t s = layout.stride(a);
      for (std::size_t f = static_cast<std::size_t>(s); f < layout.size(); ++f) {
        const double e = 0.5 * (eps[f] + eps[f - static_cast<std::size_t>(s)]);
        const double b = 0.5 * (beta[f] + beta[f - static_cast<std::size_t>(s)]);
        mobility[a][f] = e > 0.0 ? dt / (1.0 + dt * b / e) : dt;
      }
    }
    std::uniform_real_distribution<double> uni(-0.1, 0.1);
    for (auto& c : u) {
      for (double& v : c.values()) {
        v = uni(rng);
      }
    }
    fill_velocity_ghosts(grid, u);
    phi.fill(0.0);
  }
};

constexpr double kRiserCells = 32.0 * 50.0 * 32.0;

// A full projection at the scenes' default tolerance 1e-10: solver 0 = hypre (PCG + PFMG), 1 =
// multigrid (flexible CG + our V-cycle). ns_per_cell_iteration = time / (cells x iterations).
void BM_ProjectionRiserSolver(benchmark::State& state) {
  const tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                                    static_cast<std::size_t>(state.range(1)));
  RiserSystem sys;
  ProjectionSettings settings;
  settings.tolerance = 1e-10;
  settings.solver = state.range(0) == 0 ? PoissonSolver::hypre : PoissonSolver::multigrid;
  PressureProjection projection(sys.grid, settings);
  unsigned seed = 0;
  double iterations = 0.0;
  for (auto _ : state) {
    state.PauseTiming();
    sys.renew(++seed);
    state.ResumeTiming();
    iterations += projection.project(sys.u, sys.eps, sys.mobility, sys.source, sys.phi).iterations;
  }
  state.counters["pcg_iterations"] =
      benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
  state.counters["ns_per_cell"] =
      benchmark::Counter(1e-9 * kRiserCells * static_cast<double>(state.iterations()),
                         benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  state.counters["ns_per_cell_iteration"] = benchmark::Counter(
      1e-9 * kRiserCells * iterations, benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_ProjectionRiserSolver)
    ->ArgNames({"multigrid", "threads"})
    ->ArgsProduct({{0, 1}, {1, 2}})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

// The multigrid's kernels on the finest level of the riser system: kernel 0 = one V-cycle (the
// preconditioner, all levels), 1 = one red-black Gauss-Seidel sweep, 2 = one residual.
void BM_MultigridKernelRiser(benchmark::State& state) {
  const tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                                    static_cast<std::size_t>(state.range(1)));
  RiserSystem sys;
  ProjectionSettings settings;
  settings.tolerance = 1e-10;
  settings.solver = PoissonSolver::multigrid;
  PressureProjection projection(sys.grid, settings);
  sys.renew(1);
  (void)projection.project(sys.u, sys.eps, sys.mobility, sys.source, sys.phi);
  MultigridPoisson& mg = *projection.multigrid();
  const int64_t kernel = state.range(0);
  for (auto _ : state) {
    if (kernel == 0) {
      mg.benchmark_vcycle();
    } else if (kernel == 1) {
      mg.benchmark_sweep();
    } else {
      benchmark::DoNotOptimize(mg.benchmark_residual());
    }
  }
  state.counters["ns_per_cell"] =
      benchmark::Counter(1e-9 * kRiserCells * static_cast<double>(state.iterations()),
                         benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_MultigridKernelRiser)
    ->ArgNames({"kernel", "threads"})
    ->ArgsProduct({{0, 1, 2}, {1, 2}})
    ->UseRealTime()
    ->Unit(benchmark::kMicrosecond);

// hypre's counterparts on the same matrix (assembled here as the projection does for a periodic
// grid): kernel 0 = one PFMG V-cycle as PressureProjection configures it (symmetric red-black,
// 1 + 1 sweeps), 2 = one residual b - A x (HYPRE_StructMatrixMatvec). hypre 2.26 has no public
// single relaxation sweep of PFMG, so kernel 1 is not measured.
void BM_HypreKernelRiser(benchmark::State& state) {
  RiserSystem sys;
  sys.renew(1);
  const MacGrid& grid = sys.grid;
  const GridLayout& layout = grid.layout();
  std::array<HYPRE_Int, 3> lower = {0, 0, 0};
  std::array<HYPRE_Int, 3> upper = {31, 49, 31};
  std::array<HYPRE_Int, 3> periodic = {32, 50, 32};
  HYPRE_StructGrid hgrid = nullptr;
  HYPRE_StructStencil stencil = nullptr;
  HYPRE_StructMatrix A = nullptr;
  HYPRE_StructVector b = nullptr;
  HYPRE_StructVector x = nullptr;
  HYPRE_StructGridCreate(MPI_COMM_SELF, 3, &hgrid);
  HYPRE_StructGridSetExtents(hgrid, lower.data(), upper.data());
  HYPRE_StructGridSetPeriodic(hgrid, periodic.data());
  HYPRE_StructGridAssemble(hgrid);
  HYPRE_StructStencilCreate(3, 7, &stencil);
  std::array<std::array<HYPRE_Int, 3>, 7> offsets = {
      {{0, 0, 0}, {-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}}};
  for (int e = 0; e < 7; ++e) {
    HYPRE_StructStencilSetElement(stencil, e, offsets[static_cast<std::size_t>(e)].data());
  }
  HYPRE_StructMatrixCreate(MPI_COMM_SELF, hgrid, stencil, &A);
  HYPRE_StructMatrixInitialize(A);
  const std::size_t cells = 32 * 50 * 32;
  std::vector<double> values(7 * cells, 0.0);
  std::vector<double> rhs(cells);
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  std::size_t m = 0;
  for (int k = 0; k < 32; ++k) {
    for (int j = 0; j < 50; ++j) {
      for (int i = 0; i < 32; ++i, ++m) {
        const std::array<int, 3> cell = {i, j, k};
        for (int a = 0; a < 3; ++a) {
          const std::ptrdiff_t s = layout.stride(a);
          const double inv_dx2 = 1.0 / (grid.spacing(a) * grid.spacing(a));
          for (int side = 0; side < 2; ++side) {
            std::size_t f = layout.index(cell) + (side == 1 ? static_cast<std::size_t>(s) : 0);
            if (side == 1 && cell[a] == grid.cells(a) - 1) {
              f -= static_cast<std::size_t>(grid.cells(a) * s); // face n is face 0
            }
            const double e = 0.5 * (sys.eps[f] + sys.eps[f - static_cast<std::size_t>(s)]);
            const double coef = e * sys.mobility[a][f] * inv_dx2;
            values[7 * m] += coef;
            values[7 * m + 1 + static_cast<std::size_t>(2 * a + side)] = -coef;
          }
        }
        rhs[m] = uni(rng);
      }
    }
  }
  double mean = 0.0;
  for (const double r : rhs) {
    mean += r;
  }
  for (double& r : rhs) {
    r -= mean / static_cast<double>(cells);
  }
  std::array<HYPRE_Int, 7> entries = {0, 1, 2, 3, 4, 5, 6};
  HYPRE_StructMatrixSetBoxValues(A, lower.data(), upper.data(), 7, entries.data(), values.data());
  HYPRE_StructMatrixAssemble(A);
  HYPRE_StructVectorCreate(MPI_COMM_SELF, hgrid, &b);
  HYPRE_StructVectorInitialize(b);
  HYPRE_StructVectorSetBoxValues(b, lower.data(), upper.data(), rhs.data());
  HYPRE_StructVectorAssemble(b);
  HYPRE_StructVectorCreate(MPI_COMM_SELF, hgrid, &x);
  HYPRE_StructVectorInitialize(x);
  HYPRE_StructVectorAssemble(x);
  HYPRE_StructSolver pfmg = nullptr;
  HYPRE_StructPFMGCreate(MPI_COMM_SELF, &pfmg);
  HYPRE_StructPFMGSetMaxIter(pfmg, 1);
  HYPRE_StructPFMGSetTol(pfmg, 0.0);
  HYPRE_StructPFMGSetZeroGuess(pfmg);
  HYPRE_StructPFMGSetRelaxType(pfmg, 2);
  std::array<double, 3> dxyz = {grid.spacing(0), grid.spacing(1), grid.spacing(2)};
  HYPRE_StructPFMGSetDxyz(pfmg, dxyz.data());
  HYPRE_StructPFMGSetMaxLevels(pfmg, pfmg_max_levels(grid));
  HYPRE_StructPFMGSetNumPreRelax(pfmg, 1);
  HYPRE_StructPFMGSetNumPostRelax(pfmg, 1);
  HYPRE_StructPFMGSetup(pfmg, A, b, x);
  const int64_t kernel = state.range(0);
  for (auto _ : state) {
    if (kernel == 0) {
      HYPRE_StructPFMGSolve(pfmg, A, b, x);
    } else {
      HYPRE_StructMatrixMatvec(-1.0, A, x, 1.0, b);
    }
  }
  HYPRE_ClearAllErrors(); // one V-cycle does not reach a tolerance: not an error here
  state.counters["ns_per_cell"] =
      benchmark::Counter(1e-9 * kRiserCells * static_cast<double>(state.iterations()),
                         benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  HYPRE_StructPFMGDestroy(pfmg);
  HYPRE_StructVectorDestroy(x);
  HYPRE_StructVectorDestroy(b);
  HYPRE_StructMatrixDestroy(A);
  HYPRE_StructStencilDestroy(stencil);
  HYPRE_StructGridDestroy(hgrid);
}
BENCHMARK(BM_HypreKernelRiser)
    ->ArgName("kernel")
    ->Arg(0)
    ->Arg(2)
    ->UseRealTime()
    ->Unit(benchmark::kMicrosecond);

// The explicit momentum right-hand side alone (advection + viscous stress, three components).
void BM_MomentumRhsRiser(benchmark::State& state) {
  const MacGrid grid(riser_spec());
  const GasProperties gas{1.0, 2e-5, {0.0, -9.80665, 0.0}};
  std::array<GridField, 3> u = {grid.make_field(), grid.make_field(), grid.make_field()};
  std::array<GridField, 3> rhs = u;
  GridField eps = grid.make_field();
  fill_particle_fields(grid, eps, nullptr, 7);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> uni(-0.05, 0.05);
  for (auto& c : u) {
    for (double& v : c.values()) {
      v = uni(rng);
    }
  }
  fill_velocity_ghosts(grid, u);
  for (auto _ : state) {
    momentum_rhs(grid, gas, Limiter::van_leer, u, eps, {0.0, 0.0, 0.0}, rhs);
    benchmark::DoNotOptimize(rhs[0].values().data());
  }
  state.counters["cells_per_s"] = benchmark::Counter(
      32.0 * 50.0 * 32.0 * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_MomentumRhsRiser)->Unit(benchmark::kMillisecond);

// One full gas step (predictor-corrector: two momentum evaluations and two projections) at the
// paper's dt_f = 1e-4 s, with drag fields; eps changes every step as it does when coupled.
void gas_step_riser(benchmark::State& state, int time_order, double tolerance,
                    PoissonSolver poisson) {
  const MacGrid grid(riser_spec());
  GasSolverSettings settings;
  settings.gas = {1.0, 2e-5, {0.0, -9.80665, 0.0}};
  settings.projection.tolerance = tolerance;
  settings.projection.solver = poisson;
  settings.time_order = time_order;
  GasSolver solver(grid, settings);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> uni(-0.05, 0.05);
  for (auto& c : solver.velocity()) {
    for (double& v : c.values()) {
      v = uni(rng);
    }
  }
  unsigned seed = 0;
  fill_particle_fields(grid, solver.volume_fraction(), &solver.drag_coefficient(), seed);
  solver.reset_volume_fraction_history();
  double iterations = 0.0;
  for (auto _ : state) {
    state.PauseTiming();
    fill_particle_fields(grid, solver.volume_fraction(), &solver.drag_coefficient(), ++seed);
    state.ResumeTiming();
    iterations += solver.step(1e-4).projection_iterations;
  }
  state.counters["pcg_iterations"] =
      benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
  state.counters["cells_per_s"] = benchmark::Counter(
      32.0 * 50.0 * 32.0 * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
void BM_GasStepRiser(benchmark::State& state) {
  gas_step_riser(state, static_cast<int>(state.range(0)), 1e-8, PoissonSolver::automatic);
}
// A full gas step at the scenes' tolerance 1e-10 with each projection solver (0 = hypre, 1 =
// multigrid), side by side.
void BM_GasStepRiserSolver(benchmark::State& state) {
  const tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                                    static_cast<std::size_t>(state.range(1)));
  gas_step_riser(state, 2, 1e-10,
                 state.range(0) == 0 ? PoissonSolver::hypre : PoissonSolver::multigrid);
}
BENCHMARK(BM_GasStepRiserSolver)
    ->ArgNames({"multigrid", "threads"})
    ->ArgsProduct({{0, 1}, {1, 2}})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);
// The paper's fluidized bed: 1.6 x 10 x 1.6 mm in 32 x 50 x 32 cells (50 um across: smaller
// than a particle), no-slip sides, 1.5 cm/s inflow, pressure outflow, one step of dt_f = 1e-4 s
// with the viscosity implicit (explicitly this step would need 9 sub-steps).
void BM_GasStepFluidizedBedImplicitViscosity(benchmark::State& state) {
  MacGridSpec spec;
  spec.cells = {32, 50, 32};
  spec.extent = {1.6e-3, 10e-3, 1.6e-3};
  spec.bc[2].kind = BoundaryKind::inflow;
  spec.bc[2].velocity = {0.0, 0.015, 0.0};
  spec.bc[3].kind = BoundaryKind::outflow;
  const MacGrid grid(spec);
  GasSolverSettings settings;
  settings.gas = {1.0, 2e-5, {0.0, -9.80665, 0.0}};
  settings.projection.tolerance = 1e-8;
  settings.implicit_viscosity = true;
  settings.viscous_tolerance = 1e-8;
  GasSolver solver(grid, settings);
  unsigned seed = 0;
  fill_particle_fields(grid, solver.volume_fraction(), &solver.drag_coefficient(), seed);
  solver.reset_volume_fraction_history();
  double iterations = 0.0;
  double viscous = 0.0;
  for (auto _ : state) {
    state.PauseTiming();
    fill_particle_fields(grid, solver.volume_fraction(), &solver.drag_coefficient(), ++seed);
    state.ResumeTiming();
    const GasStepReport r = solver.step(1e-4);
    iterations += r.projection_iterations;
    viscous += r.viscous_iterations;
  }
  state.counters["pcg_iterations"] =
      benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
  state.counters["viscous_cg_iterations"] =
      benchmark::Counter(viscous, benchmark::Counter::kAvgIterations);
  state.counters["cells_per_s"] = benchmark::Counter(
      32.0 * 50.0 * 32.0 * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_GasStepFluidizedBedImplicitViscosity)->Unit(benchmark::kMillisecond);

BENCHMARK(BM_GasStepRiser)->ArgName("time_order")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

} // namespace
} // namespace cfddem::fluid

int main(int argc, char** argv) {
  MPI_Init(&argc, &argv);
  HYPRE_Init();
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) {
    return 1;
  }
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  HYPRE_Finalize();
  MPI_Finalize();
  return 0;
}
