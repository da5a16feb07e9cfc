// Benchmarks of the gas solver on the paper's riser grid (32 x 50 x 32 cells, 0.2 mm, periodic,
// 2 Pa drop along y): the hypre projection (cells x PCG iterations per second) and a full step.
#include <cmath>
#include <random>

#include <HYPRE_utilities.h>
#include <benchmark/benchmark.h>
#include <mpi.h>

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
void BM_GasStepRiser(benchmark::State& state) {
  const MacGrid grid(riser_spec());
  GasSolverSettings settings;
  settings.gas = {1.0, 2e-5, {0.0, -9.80665, 0.0}};
  settings.projection.tolerance = 1e-8;
  settings.time_order = static_cast<int>(state.range(0));
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
