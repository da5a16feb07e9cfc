// Benchmarks of the gas solver on the paper's riser grid (32 x 50 x 32 cells, 0.2 mm, periodic,
// 2 Pa drop along y): the projection with hypre and with our multigrid side by side (full solve,
// V-cycle, smoother sweep, residual, in ns per cell), a full step, and the parts of a fluid step
// in nanoseconds per cell (momentum right-hand side, deposition, interpolation) on 1 and 2 TBB
// threads (argument `threads`).
#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <span>
#include <vector>

#include <HYPRE_struct_ls.h>
#include <HYPRE_utilities.h>
#include <_hypre_struct_ls.h> // hypre_RedBlackGS: PFMG's smoother, for kernel 1
#include <benchmark/benchmark.h>
#include <mpi.h>
#include <tbb/global_control.h>

#include "core/mpi_start.hpp"
#include "core/simd_level.hpp"
#include "fluid/deposition.hpp"
#include "fluid/gas_solver.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/implicit_viscosity.hpp"
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
  settings.solver = PoissonSolver::hypre; // these measure hypre's preconditioners
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

// Setting up a projection on the riser grid (solver 0 = hypre: its grid, matrix and vectors; 1 =
// the multigrid: its hierarchy only, no hypre object). A GasSolver pays this once.
void BM_ProjectionSetupRiser(benchmark::State& state) {
  const MacGrid grid(riser_spec());
  ProjectionSettings settings;
  settings.solver = state.range(0) == 0 ? PoissonSolver::hypre : PoissonSolver::multigrid;
  for (auto _ : state) {
    PressureProjection projection(grid, settings);
    benchmark::DoNotOptimize(projection.holds_hypre_objects());
  }
}
BENCHMARK(BM_ProjectionSetupRiser)
    ->ArgName("multigrid")
    ->Arg(0)
    ->Arg(1)
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
// 1 + 1 sweeps), 1 = one red-black Gauss-Seidel sweep (hypre_RedBlackGS, the smoother PFMG's
// relax type 2 runs; hypre's internal API, no public one exists), 2 = one residual b - A x
// (HYPRE_StructMatrixMatvec).
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
  void* rbgs = hypre_RedBlackGSCreate(MPI_COMM_SELF);
  hypre_RedBlackGSSetMaxIter(rbgs, 1);
  hypre_RedBlackGSSetTol(rbgs, 0.0);
  hypre_RedBlackGSSetStartRed(rbgs);
  auto* hA = reinterpret_cast<hypre_StructMatrix*>(A);
  auto* hb = reinterpret_cast<hypre_StructVector*>(b);
  auto* hx = reinterpret_cast<hypre_StructVector*>(x);
  hypre_RedBlackGSSetup(rbgs, hA, hb, hx);
  const int64_t kernel = state.range(0);
  for (auto _ : state) {
    if (kernel == 0) {
      HYPRE_StructPFMGSolve(pfmg, A, b, x);
    } else if (kernel == 1) {
      hypre_RedBlackGS(rbgs, hA, hb, hx);
    } else {
      HYPRE_StructMatrixMatvec(-1.0, A, x, 1.0, b);
    }
  }
  hypre_RedBlackGSDestroy(rbgs);
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
    ->Arg(1)
    ->Arg(2)
    ->UseRealTime()
    ->Unit(benchmark::kMicrosecond);

// Seconds per iteration divided by `cells`, in ns (Google Benchmark inverts the rate; wall time
// where the benchmark uses real time, as the threaded ones do).
benchmark::Counter ns_per(double cells) {
  return benchmark::Counter(cells * 1e-9, benchmark::Counter::kIsIterationInvariantRate |
                                              benchmark::Counter::kInvert);
}

std::size_t threads_of(const benchmark::State& state, int arg) {
  return static_cast<std::size_t>(state.range(arg));
}

// The implicit viscosity's Helmholtz solve of one component on the fluidized bed's grid (32 x 50
// x 32 cells of 50 um, walls, inflow below, outflow above), c = theta dt mu at dt = 1e-4 s:
// multigrid 0 = Jacobi CG (the distributed path), 1 = multigrid-preconditioned CG; tolerance
// 1e-10 (GasSolverSettings::viscous_tolerance). Component 1 (the inflow axis).
void BM_ViscousSolveBed(benchmark::State& state) {
  const tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 1);
  MacGridSpec spec;
  spec.cells = {32, 50, 32};
  spec.extent = {1.6e-3, 2.5e-3, 1.6e-3};
  spec.bc[2].kind = BoundaryKind::inflow;
  spec.bc[2].velocity = {0.0, 0.015, 0.0};
  spec.bc[3].kind = BoundaryKind::outflow;
  const MacGrid grid(spec);
  GridField eps = grid.make_field();
  GridField beta = grid.make_field();
  fill_particle_fields(grid, eps, &beta, 3);
  GridField diag = grid.make_field();
  GridField rhs = grid.make_field();
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> uni(-0.01, 0.01);
  const double dt = 1e-4;
  for (std::size_t p = 0; p < diag.values().size(); ++p) {
    diag[p] = eps[p] * (1.0 + dt * beta[p] / std::max(eps[p], 0.1)); // eps_f rho (1 + k beta)
    rhs[p] = diag[p] * (0.015 + uni(rng));
  }
  std::array<GridField, 3> u = {grid.make_field(), grid.make_field(), grid.make_field()};
  ImplicitViscosity viscosity(grid);
  viscosity.declare_eps(eps); // as the gas solver declares its eps_g: no compare per call
  viscosity.use_multigrid(state.range(0) != 0);
  const int comp = 1;
  double iterations = 0.0;
  for (auto _ : state) {
    state.PauseTiming();
    u[comp].fill(0.0);
    fill_velocity_ghosts(grid, u);
    state.ResumeTiming();
    iterations +=
        viscosity.solve(comp, 0.5 * dt * 2e-5, eps, diag, rhs, u[comp], 1e-10, 1000).iterations;
  }
  state.counters["cg_iterations"] =
      benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
}
BENCHMARK(BM_ViscousSolveBed)->ArgName("multigrid")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// A fluidized bed's viscous system, as BM_ViscousChebyshevBed and BM_ViscousFactoredBed take it:
// `cells` x 50 x `cells` cells of 50 x 200 x 50 um, walls, inflow below, outflow above, eps in
// [0.55, 0.6], each component's diagonal eps_f rho (1 + k beta_f) and right-hand side.
struct BedViscousSystem {
  explicit BedViscousSystem(int n) : grid(spec_of(n)), eps(grid.make_field()) {
    std::mt19937_64 rng(4);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    for (double& e : eps.values()) {
      e = 0.55 + 0.05 * uni(rng);
    }
    fill_cell_ghosts(grid, eps, CellGhosts::zero_gradient);
    for (int a = 0; a < 3; ++a) {
      diag[static_cast<std::size_t>(a)] = grid.make_field();
      rhs[static_cast<std::size_t>(a)] = grid.make_field();
      u[static_cast<std::size_t>(a)] = grid.make_field();
      for (std::size_t p = 0; p < eps.values().size(); ++p) {
        diag[a][p] = eps[p] * kRho * (1.0 + kDt * 3e4 * uni(rng));
        rhs[a][p] = diag[a][p] * ((a == 1 ? 0.3 : 0.0) + 0.05 * (uni(rng) - 0.5));
      }
    }
  }
  static MacGridSpec spec_of(int n) {
    MacGridSpec spec;
    spec.cells = {n, 50, n};
    spec.extent = {n * 50e-6, 50 * 200e-6, n * 50e-6};
    spec.bc[2].kind = BoundaryKind::inflow;
    spec.bc[2].velocity = {0.0, 0.015, 0.0};
    spec.bc[3].kind = BoundaryKind::outflow;
    return spec;
  }
  // Every component's velocity back to zero, its ghosts filled (outside the timing).
  void reset_velocity() {
    for (GridField& f : u) {
      f.fill(0.0);
    }
    fill_velocity_ghosts(grid, u);
  }
  static constexpr double kRho = 1.2;
  static constexpr double kDt = 1e-4;
  static constexpr double kC = 0.5 * kDt * 1.8e-5; // theta dt mu
  MacGrid grid;
  GridField eps;
  std::array<GridField, 3> diag, rhs, u;
};

// The implicit viscosity's Chebyshev solves of the three components on a fluidized bed's grid
// (`cells` x 50 x `cells` cells of 50 x 200 x 50 um: 32 is scenes/fluidized_bed.toml's, 101 the
// 1e5 bed's, whose fields no longer fit the caches; 48, 64 and 80 frame chebyshev_row_source's
// threshold, 64's fields just below it; walls, inflow below, outflow above), eps in
// [0.55, 0.6], c = theta dt mu at dt = 1e-4 s, tolerance 1e-10, from a zero first guess. Its rows
// at the instruction set `simd`, their face coefficients from eps (stored 0) or read from the
// stored arrays (stored 1; 2 also the stored inverse diagonal), one iteration per sweep (paired
// 0) or two (1); a level the CPU lacks is skipped. Counter ns_per_iteration: per unknown and
// iteration.
void BM_ViscousChebyshevBed(benchmark::State& state) {
  const auto level = static_cast<SimdLevel>(state.range(1));
  if (level > cpu_simd_level()) {
    state.SkipWithError("the CPU has no such instruction set");
    return;
  }
  const tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 1);
  BedViscousSystem bed(static_cast<int>(state.range(0)));
  ImplicitViscosity viscosity(bed.grid);
  viscosity.declare_eps(bed.eps); // as the gas solver declares its eps_g: no compare per call
  viscosity.use_simd_level(level);
  constexpr std::array<CoefficientSource, 3> sources = {
      CoefficientSource::from_eps, CoefficientSource::stored, CoefficientSource::stored_inverse};
  viscosity.use_coefficient_source(sources.at(static_cast<std::size_t>(state.range(2))));
  viscosity.use_paired_iterations(state.range(3) != 0);
  double iterations = 0.0;
  for (auto _ : state) {
    state.PauseTiming();
    bed.reset_velocity();
    state.ResumeTiming();
    for (std::size_t a = 0; a < 3; ++a) {
      const ViscousSolveReport r =
          viscosity.solve(static_cast<int>(a), BedViscousSystem::kC, bed.eps, bed.diag[a],
                          bed.rhs[a], bed.u[a], 1e-10, 1000);
      if (!r.chebyshev) {
        state.SkipWithError("the solve did not take the Chebyshev iteration");
        return;
      }
      iterations += r.iterations;
    }
  }
  const int n = static_cast<int>(state.range(0));
  state.counters["iterations"] = benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
  const double unknowns = static_cast<double>(n) * 50.0 * n;
  state.counters["ns_per_iteration"] = benchmark::Counter(
      iterations * unknowns * 1e-9, benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_ViscousChebyshevBed)
    ->ArgNames({"cells", "simd", "stored", "paired"})
    ->ArgsProduct({{32, 48, 64, 80, 101}, {0, 1, 2}, {0, 1, 2}, {0, 1}})
    ->Unit(benchmark::kMillisecond);

// The factored viscous step (ImplicitViscosity::step_factored) of the three components on the
// bed's system above (`cells` 32: scenes/fluidized_bed.toml's grid, 101: the 1e5 bed's), its
// line solves at the instruction set `simd`, from u = 0 with the ghosts filled. The end closures
// are found at the first step (outside the timing). Counter ns_per_unknown: per unknown of the
// three components and step.
void BM_ViscousFactoredBed(benchmark::State& state) {
  const auto level = static_cast<SimdLevel>(state.range(1));
  if (level > cpu_simd_level()) {
    state.SkipWithError("the CPU has no such instruction set");
    return;
  }
  const tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                                    static_cast<std::size_t>(state.range(2)));
  BedViscousSystem bed(static_cast<int>(state.range(0)));
  ImplicitViscosity viscosity(bed.grid);
  viscosity.declare_eps(bed.eps); // as the gas solver declares its eps_g: no compare per call
  viscosity.use_simd_level(level);
  const auto step_all = [&] {
    for (std::size_t a = 0; a < 3; ++a) {
      (void)viscosity.step_factored(static_cast<int>(a), BedViscousSystem::kC, bed.eps, bed.diag[a],
                                    bed.rhs[a], bed.u[a]);
    }
  };
  bed.reset_velocity();
  step_all();
  for (auto _ : state) {
    state.PauseTiming();
    bed.reset_velocity();
    state.ResumeTiming();
    step_all();
  }
  const int n = static_cast<int>(state.range(0));
  state.counters["ns_per_unknown"] = ns_per(3.0 * n * 50.0 * n);
}
BENCHMARK(BM_ViscousFactoredBed)
    ->ArgNames({"cells", "simd", "threads"})
    ->ArgsProduct({{32, 101}, {0, 1, 2}, {1, 2}})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

// The momentum right-hand side alone (advection + viscous stress, three components): the method
// of lines' (godunov 0) or the Godunov step's with its edge prediction (1), its row loops at the
// instruction set level `simd` (0 x86-64, 1 x86-64-v3, 2 x86-64-v4; a level the CPU lacks is
// skipped). --benchmark_enable_random_interleaving compares the levels on one machine state.
void BM_MomentumRhsRiser(benchmark::State& state) {
  const auto level = static_cast<SimdLevel>(state.range(1));
  if (level > cpu_simd_level()) {
    state.SkipWithError("the CPU has no such instruction set");
    return;
  }
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads_of(state, 2));
  const MacGrid grid(riser_spec());
  const GasProperties gas{1.0, 2e-5, {0.0, -9.80665, 0.0}};
  std::array<GridField, 3> u = {grid.make_field(), grid.make_field(), grid.make_field()};
  std::array<GridField, 3> rhs = u;
  std::array<GridField, 3> gain = u;
  std::array<GridField, 3> push = u;
  GridField eps = grid.make_field();
  GridField pressure = grid.make_field();
  fill_particle_fields(grid, eps, nullptr, 7);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> uni(-0.05, 0.05);
  for (auto& c : u) {
    for (double& v : c.values()) {
      v = uni(rng);
    }
  }
  for (auto& c : gain) {
    std::fill(c.values().begin(), c.values().end(), 1.0); // no drag
  }
  fill_velocity_ghosts(grid, u);
  EdgePrediction pred;
  pred.dt = 1e-4;
  pred.pressure = &pressure;
  pred.drag_gain = &gain;
  pred.drag_push = &push;
  MomentumWorkspace work; // as the solver: allocated once
  const bool godunov = state.range(0) == 1;
  for (auto _ : state) {
    if (godunov) {
      godunov_momentum_rhs(grid, gas, Limiter::van_leer, u, eps, {0.0, 0.0, 0.0}, pred, rhs, work,
                           false, level);
    } else {
      momentum_rhs(grid, gas, Limiter::van_leer, u, eps, {0.0, 0.0, 0.0}, rhs, work, false,
                   level);
    }
    benchmark::DoNotOptimize(rhs[0].values().data());
  }
  state.counters["cells_per_s"] = benchmark::Counter(
      kRiserCells * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["ns_per_cell"] = ns_per(kRiserCells);
}
BENCHMARK(BM_MomentumRhsRiser)
    ->ArgNames({"godunov", "simd", "threads"})
    ->ArgsProduct({{0, 1}, {0, 1, 2}, {1, 2}})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

// Particles as the coupling sees them: the riser (14,000 of 100 um, uniform in its 6 x 10 x 6 mm,
// trilinear) or the paper's bed (10,000 in the bottom 4.8 mm of 1.6 x 10 x 1.6 mm, 50 um cells,
// dpvm cube two diameters wide).
struct BenchParticles {
  MacGridSpec spec;
  DepositionSettings settings;
  std::vector<double> x, y, z, r;
  [[nodiscard]] ParticlePositions view() const { return {x, y, z, r}; }
};

BenchParticles bench_particles(bool bed) {
  BenchParticles b;
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::array<double, 3> region{};
  std::size_t count = 0;
  if (bed) {
    b.spec.cells = {32, 50, 32};
    b.spec.extent = {1.6e-3, 10e-3, 1.6e-3};
    b.spec.bc[2].kind = BoundaryKind::inflow;
    b.spec.bc[2].velocity = {0.0, 0.015, 0.0};
    b.spec.bc[3].kind = BoundaryKind::outflow;
    b.settings.kernel = DepositionKernel::dpvm_cube;
    region = {1.6e-3, 4.8e-3, 1.6e-3};
    count = 10000;
  } else {
    b.spec = riser_spec();
    b.spec.extent = {6e-3, 10e-3, 6e-3};
    region = b.spec.extent;
    count = 14000;
  }
  // Sorted by cell (z slowest), as the particle store keeps them (re-sorted at neighbor builds).
  std::vector<std::array<double, 3>> at(count);
  for (auto& p : at) {
    p = {region[0] * uni(rng), region[1] * uni(rng), region[2] * uni(rng)};
  }
  const auto cell = [&](const std::array<double, 3>& p) {
    std::array<int, 3> c{};
    for (int a = 0; a < 3; ++a) {
      c[a] = static_cast<int>(p[a] / b.spec.extent[a] * b.spec.cells[a]);
    }
    return std::array<int, 3>{c[2], c[1], c[0]};
  };
  std::sort(at.begin(), at.end(), [&](const auto& p, const auto& q) { return cell(p) < cell(q); });
  for (const auto& p : at) {
    b.x.push_back(p[0]);
    b.y.push_back(p[1]);
    b.z.push_back(p[2]);
    b.r.push_back(5e-5);
  }
  return b;
}

void set_particle_counters(benchmark::State& state, const BenchParticles& b) {
  state.counters["ns_per_cell"] = ns_per(b.spec.cells[0] * b.spec.cells[1] * b.spec.cells[2]);
  state.counters["ns_per_particle"] = ns_per(static_cast<double>(b.x.size()));
}

// What the coupling deposits per fluid step: the solid fraction, then beta and beta v (4 fields).
void BM_Deposition(benchmark::State& state) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads_of(state, 1));
  const BenchParticles b = bench_particles(state.range(0) != 0);
  const MacGrid grid(b.spec);
  Deposition deposition(grid, b.settings, 5e-5);
  GridField eps_s = grid.make_field();
  std::array<GridField, 4> cells = {grid.make_field(), grid.make_field(), grid.make_field(),
                                    grid.make_field()};
  std::vector<double> beta(b.x.size(), 1e-6);
  const std::span<const double> values[4] = {beta, b.x, b.y, b.z};
  GridField* out[4] = {&cells[0], &cells[1], &cells[2], &cells[3]};
  for (auto _ : state) {
    eps_s.fill(0.0);
    for (GridField& c : cells) {
      c.fill(0.0);
    }
    deposition.deposit_solid_fraction(b.view(), eps_s);
    deposition.deposit(b.view(), values, out);
    benchmark::DoNotOptimize(eps_s.values().data());
  }
  set_particle_counters(state, b);
}

// Riser (bed 0) and bed (bed 1), each on 1 and 2 threads.
void particle_args(benchmark::internal::Benchmark* bench) {
  bench->ArgNames({"bed", "threads"})
      ->Args({0, 1})
      ->Args({0, 2})
      ->Args({1, 1})
      ->Args({1, 2})
      ->UseRealTime()
      ->Unit(benchmark::kMillisecond);
}
BENCHMARK(BM_Deposition)->Apply(particle_args);

// What the coupling interpolates per fluid step: eps_g and the three cell-centred velocities.
void BM_Interpolation(benchmark::State& state) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads_of(state, 1));
  const BenchParticles b = bench_particles(state.range(0) != 0);
  const MacGrid grid(b.spec);
  Deposition deposition(grid, b.settings, 5e-5);
  std::array<GridField, 4> fields = {grid.make_field(0.9), grid.make_field(0.1),
                                     grid.make_field(0.2), grid.make_field(0.3)};
  std::array<std::vector<double>, 4> outs;
  for (auto& o : outs) {
    o.resize(b.x.size());
  }
  const GridField* in[4] = {&fields[0], &fields[1], &fields[2], &fields[3]};
  const std::span<double> out[4] = {outs[0], outs[1], outs[2], outs[3]};
  for (auto _ : state) {
    deposition.interpolate(b.view(), in, out);
    benchmark::DoNotOptimize(outs[0].data());
  }
  set_particle_counters(state, b);
}
BENCHMARK(BM_Interpolation)->Apply(particle_args);

// The transfers of one coupled fluid step, from one plan (fluid/transfer_plan.hpp) as
// GasCoupling makes them: pass 0 all of them; 1 the plan alone; 2 the solid fraction; 3 eps_g
// and u_g at the particles (4 fields); 4 beta and beta v to the cells (4 fields); 5 u_g and
// grad p at the particles (6 fields).
void BM_PlannedTransfers(benchmark::State& state) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads_of(state, 2));
  const BenchParticles b = bench_particles(state.range(0) != 0);
  const auto pass = state.range(1);
  const MacGrid grid(b.spec);
  Deposition deposition(grid, b.settings, 5e-5);
  TransferPlan plan;
  deposition.plan(b.view(), plan);
  const std::size_t n = b.x.size();
  GridField eps_s = grid.make_field();
  std::array<GridField, 6> in = {grid.make_field(0.9), grid.make_field(0.1), grid.make_field(0.2),
                                 grid.make_field(0.3), grid.make_field(0.4), grid.make_field(0.5)};
  std::array<GridField, 4> drag = {grid.make_field(), grid.make_field(), grid.make_field(),
                                   grid.make_field()};
  std::array<std::vector<double>, 6> at;
  for (auto& o : at) {
    o.resize(n);
  }
  std::vector<double> beta(n, 1e-6);
  const std::span<const double> values[4] = {beta, b.x, b.y, b.z};
  GridField* const cells[4] = {&drag[0], &drag[1], &drag[2], &drag[3]};
  const GridField* const four[4] = {&in[0], &in[1], &in[2], &in[3]};
  const GridField* const six[6] = {&in[0], &in[1], &in[2], &in[3], &in[4], &in[5]};
  const std::span<double> out4[4] = {at[0], at[1], at[2], at[3]};
  const std::span<double> out6[6] = {at[0], at[1], at[2], at[3], at[4], at[5]};
  for (auto _ : state) {
    if (pass == 0 || pass == 1) {
      deposition.plan(b.view(), plan);
    }
    if (pass == 0 || pass == 2) {
      eps_s.fill(0.0);
      deposition.deposit_solid_fraction(plan, eps_s);
    }
    if (pass == 0 || pass == 3) {
      deposition.interpolate(plan, four, out4);
    }
    if (pass == 0 || pass == 4) {
      for (GridField& c : drag) {
        c.fill(0.0);
      }
      deposition.deposit(plan, values, cells);
    }
    if (pass == 0 || pass == 5) {
      deposition.interpolate(plan, six, out6);
    }
    benchmark::DoNotOptimize(at[0].data());
    benchmark::DoNotOptimize(drag[0].values().data());
  }
  set_particle_counters(state, b);
}
BENCHMARK(BM_PlannedTransfers)
    ->ArgNames({"bed", "pass", "threads"})
    ->ArgsProduct({{0, 1}, {0, 1, 2, 3, 4, 5}, {1, 2}})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

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
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads_of(state, 1));
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

BENCHMARK(BM_GasStepRiser)
    ->ArgNames({"time_order", "threads"})
    ->Args({1, 1})
    ->Args({2, 1})
    ->Args({2, 2})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

} // namespace
} // namespace cfddem::fluid

int main(int argc, char** argv) {
  cfddem::init_mpi(&argc, &argv, MPI_THREAD_SINGLE);
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
