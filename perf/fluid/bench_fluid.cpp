// Benchmarks of the gas solver on the paper's riser grid (32 x 50 x 32 cells, 0.2 mm, periodic,
// 2 Pa drop along y): the hypre projection (cells x PCG iterations per second) and a full step;
// the parts of a fluid step in nanoseconds per cell (momentum right-hand side, deposition,
// interpolation) on 1 and 2 TBB threads (argument `threads`).
#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <span>
#include <vector>

#include <HYPRE_utilities.h>
#include <benchmark/benchmark.h>
#include <mpi.h>
#include <tbb/global_control.h>

#include "fluid/deposition.hpp"
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

constexpr double kRiserCells = 32.0 * 50.0 * 32.0;

// Seconds per iteration divided by `cells`, in ns (Google Benchmark inverts the rate; wall time
// where the benchmark uses real time, as the threaded ones do).
benchmark::Counter ns_per(double cells) {
  return benchmark::Counter(cells * 1e-9, benchmark::Counter::kIsIterationInvariantRate |
                                              benchmark::Counter::kInvert);
}

std::size_t threads_of(const benchmark::State& state, int arg) {
  return static_cast<std::size_t>(state.range(arg));
}

// The explicit momentum right-hand side alone (advection + viscous stress, three components).
void BM_MomentumRhsRiser(benchmark::State& state) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads_of(state, 0));
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
  MomentumWorkspace work; // as the solver: allocated once
  for (auto _ : state) {
    momentum_rhs(grid, gas, Limiter::van_leer, u, eps, {0.0, 0.0, 0.0}, rhs, work);
    benchmark::DoNotOptimize(rhs[0].values().data());
  }
  state.counters["cells_per_s"] = benchmark::Counter(
      kRiserCells * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["ns_per_cell"] = ns_per(kRiserCells);
}
BENCHMARK(BM_MomentumRhsRiser)
    ->ArgName("threads")
    ->Arg(1)
    ->Arg(2)
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

// One full gas step (predictor-corrector: two momentum evaluations and two projections) at the
// paper's dt_f = 1e-4 s, with drag fields; eps changes every step as it does when coupled.
void BM_GasStepRiser(benchmark::State& state) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads_of(state, 1));
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
