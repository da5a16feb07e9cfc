// The threaded gas step (momentum right-hand side, ghost fills, drag and mobility loops) and the
// threaded deposition and interpolation give bitwise the same fields on 1 and 2 TBB threads.
#include <array>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "core/simd_level.hpp"
#include "fluid/deposition.hpp"
#include "fluid/gas_solver.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

using test::same_bits;

// A packed column: no-slip sides, inflow with a tangential part, outflow, gravity, a non-uniform
// bed with drag towards moving particles; or the riser's periodic box with a pressure drop.
MacGridSpec column_spec(bool periodic) {
  if (periodic) {
    MacGridSpec spec = test::box_spec({9, 12, 7}, {9e-4, 1.2e-3, 7e-4}, BoundaryKind::periodic);
    spec.pressure_drop[1] = 2e-2;
    return spec;
  }
  MacGridSpec spec = test::box_spec({7, 12, 6}, {7e-4, 1.2e-3, 6e-4}, BoundaryKind::wall);
  spec.bc[2] = test::bc_of(BoundaryKind::inflow);
  spec.bc[2].velocity = {0.002, 0.012, 0.0};
  spec.bc[3] = test::bc_of(BoundaryKind::outflow);
  return spec;
}

// Four coupled-like steps on `threads` threads: eps_g, drag and its velocity change each step.
GasSolver::State run_steps(bool periodic, bool implicit, int order, int threads,
                           bool cylinder = false, SimdLevel level = SimdLevel::x86_64) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(threads));
  MacGridSpec spec = column_spec(periodic);
  if (cylinder) { // a round column (fluid/solid_mask.hpp) inside the walled one
    spec.cylinder_axis = 1;
    spec.cylinder_radius = 2.9e-4;
  }
  const MacGrid grid(spec);
  GasSolverSettings settings;
  settings.gas = {1.0, 2e-5, {0.0, periodic ? 0.0 : -9.80665, 0.0}};
  settings.projection.tolerance = 1e-10;
  settings.implicit_viscosity = implicit;
  settings.time_order = order;
  GasSolver solver(grid, settings);
  solver.use_simd_level(level);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (auto& c : solver.velocity()) {
    for (double& v : c.values()) {
      v = 0.01 * (uni(rng) - 0.5);
    }
  }
  for (int s = 0; s < 4; ++s) {
    const auto& n = grid.cells();
    for (int k = 0; k < n[2]; ++k) {
      for (int j = 0; j < n[1]; ++j) {
        for (int i = 0; i < n[0]; ++i) {
          solver.volume_fraction()(i, j, k) = j < 6 ? 0.45 + 0.1 * uni(rng) : 0.9 + 0.1 * uni(rng);
          solver.drag_coefficient()(i, j, k) = 1e5 * uni(rng);
          solver.drag_velocity_sum(1)(i, j, k) = 1e3 * (uni(rng) - 0.5);
        }
      }
    }
    if (s == 0) {
      solver.reset_volume_fraction_history();
    }
    (void)solver.step(1.5e-5);
  }
  return solver.save_state();
}

TEST(GasStepThreads, OneAndTwoThreadsGiveBitwiseEqualFields) {
  for (const bool periodic : {false, true}) {
    for (const bool implicit : {false, true}) {
      for (const int order : {1, 2}) {
        SCOPED_TRACE(std::string(periodic ? "periodic" : "column") +
                     (implicit ? ", implicit" : ", explicit") + ", order " + std::to_string(order));
        const GasSolver::State one = run_steps(periodic, implicit, order, 1);
        const GasSolver::State two = run_steps(periodic, implicit, order, 2);
        for (int a = 0; a < 3; ++a) {
          EXPECT_EQ(one.velocity[a], two.velocity[a]) << "velocity component " << a;
        }
        EXPECT_EQ(one.pressure, two.pressure);
      }
    }
  }
  for (const bool implicit : {false, true}) { // a round column
    for (const int order : {1, 2}) {
      SCOPED_TRACE(std::string("cylinder, ") + (implicit ? "implicit" : "explicit") + ", order " +
                   std::to_string(order));
      const GasSolver::State one = run_steps(false, implicit, order, 1, true);
      const GasSolver::State two = run_steps(false, implicit, order, 2, true);
      for (int a = 0; a < 3; ++a) {
        EXPECT_EQ(one.velocity[a], two.velocity[a]) << "velocity component " << a;
      }
      EXPECT_EQ(one.pressure, two.pressure);
    }
  }
}

// The step's row kernels at every instruction set this CPU runs (core/simd_level.hpp: the drag's
// face factors, the momentum rows, the Chebyshev rows, the multigrid's rows) give the baseline
// copies' fields bit for bit: walled column and periodic box, explicit and implicit viscosity,
// time orders 1 and 2.
TEST(GasStepCopies, EveryInstructionSetGivesTheBaselineFieldsBitwise) {
  for (const SimdLevel level : {SimdLevel::x86_64_v3, SimdLevel::x86_64_v4}) {
    if (level > cpu_simd_level()) {
      continue;
    }
    for (const bool periodic : {false, true}) {
      for (const bool implicit : {false, true}) {
        for (const int order : {1, 2}) {
          SCOPED_TRACE(
              std::string(simd_level_name(level)) + (periodic ? ", periodic" : ", column") +
              (implicit ? ", implicit" : ", explicit") + ", order " + std::to_string(order));
          const GasSolver::State base = run_steps(periodic, implicit, order, 1);
          const GasSolver::State copy = run_steps(periodic, implicit, order, 1, false, level);
          for (int a = 0; a < 3; ++a) {
            EXPECT_EQ(base.velocity[a], copy.velocity[a]) << "velocity component " << a;
          }
          EXPECT_EQ(base.pressure, copy.pressure);
        }
      }
    }
  }
}

// Particles of a bed against walls (kernels folded at the walls) and across a periodic axis.
struct Cloud {
  std::vector<double> x, y, z, r;
  [[nodiscard]] ParticlePositions view() const { return {x, y, z, r}; }
};

TEST(DepositionThreads, OneAndTwoThreadsGiveBitwiseEqualFields) {
  MacGridSpec spec = test::box_spec({8, 20, 8}, {8e-4, 2e-3, 8e-4}, BoundaryKind::wall);
  test::set_axis(spec, 2, BoundaryKind::periodic);
  const MacGrid grid(spec);
  Cloud cloud;
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (int q = 0; q < 3000; ++q) { // more than one 256-particle block per thread
    cloud.x.push_back(8e-4 * uni(rng));
    cloud.y.push_back(2e-3 * uni(rng) * uni(rng)); // denser at the bottom
    cloud.z.push_back(8e-4 * uni(rng));
    cloud.r.push_back(4e-5 + 2e-5 * uni(rng));
  }
  std::vector<double> value(cloud.x.size());
  for (double& v : value) {
    v = uni(rng) - 0.3;
  }
  GridField field = grid.make_field();
  for (double& v : field.values()) {
    v = uni(rng);
  }
  for (const DepositionKernel kernel :
       {DepositionKernel::trilinear, DepositionKernel::dpvm_cube, DepositionKernel::dpvm_sphere}) {
    SCOPED_TRACE(static_cast<int>(kernel));
    DepositionSettings settings;
    settings.kernel = kernel;
    std::array<GridField, 2> eps_s = {grid.make_field(), grid.make_field()};
    std::array<GridField, 2> deposited = {grid.make_field(), grid.make_field()};
    std::array<std::vector<double>, 2> gathered;
    for (const int threads : {1, 2}) {
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                                static_cast<std::size_t>(threads));
      Deposition deposition(grid, settings, 6e-5);
      deposition.deposit_solid_fraction(cloud.view(), eps_s[threads - 1]);
      const std::span<const double> values[2] = {value, cloud.r};
      GridField* cells[2] = {&deposited[threads - 1], &eps_s[threads - 1]};
      deposition.deposit(cloud.view(), values, cells);
      gathered[threads - 1].resize(cloud.x.size());
      deposition.interpolate(cloud.view(), field, gathered[threads - 1]);
    }
    EXPECT_TRUE(same_bits(eps_s[0], eps_s[1]));
    EXPECT_TRUE(same_bits(deposited[0], deposited[1]));
    EXPECT_EQ(gathered[0], gathered[1]);
  }
}

} // namespace
} // namespace cfddem::fluid
