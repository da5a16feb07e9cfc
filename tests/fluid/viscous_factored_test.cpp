// The implicit viscosity's factored step (ImplicitViscosity::step_factored): on a grid whose other
// two axes are single periodic cells the factors are the operator itself, so the step is the
// exact solve; on 3-D grids it differs from the exact solve by no more than the factorization's
// norm bound; and its sweeps give the same bits on 1 and 2 threads.
#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "core/simd_level.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/implicit_viscosity.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

// A bed: walls along x, inflow below and outflow above, periodic along z.
MacGridSpec bed_box() {
  MacGridSpec bed = test::box_spec({9, 14, 7}, {4.5e-4, 2.8e-3, 3.5e-4}, BoundaryKind::wall);
  test::set_axis(bed, 2, BoundaryKind::periodic);
  bed.bc[2].kind = BoundaryKind::inflow;
  bed.bc[2].velocity = {0.0, 0.015, 0.0};
  bed.bc[3].kind = BoundaryKind::outflow;
  return bed;
}

// A system for component comp: diag in [0.5, 1.5], rhs in [-0.5, 0.5], a first guess with its
// ghosts filled.
struct System {
  GridField diag, rhs, guess;
};
System random_system(const MacGrid& grid, int comp, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  System s{grid.make_field(), grid.make_field(), grid.make_field()};
  for (std::size_t p = 0; p < s.diag.values().size(); ++p) {
    s.diag[p] = 0.5 + uni(rng);
    s.rhs[p] = uni(rng) - 0.5;
  }
  std::array<GridField, 3> u = {grid.make_field(), grid.make_field(), grid.make_field()};
  for (GridField& f : u) {
    for (double& v : f.values()) {
      v = 0.1 * (uni(rng) - 0.5);
    }
  }
  fill_velocity_ghosts(grid, u);
  s.guess = u[static_cast<std::size_t>(comp)];
  return s;
}

// One factored step of component comp's system s from its first guess, the line solves' copy
// for `level`.
GridField factored_step(const MacGrid& grid, int comp, double c, const GridField& eps,
                        const System& s, SimdLevel level = simd_level()) {
  GridField u = s.guess;
  ImplicitViscosity factored(grid);
  factored.use_simd_level(level);
  factored.step_factored(comp, c, eps, s.diag, s.rhs, u);
  return u;
}

// f(grid, eps, comp, system) for each component's random system (random_system, from `seed`) on
// a bed box (walls, inflow, outflow, a periodic axis) and a periodic box (every line cyclic).
template <class F> void for_bed_and_periodic_systems(std::uint64_t seed, F&& f) {
  for (const MacGridSpec& spec :
       {bed_box(), test::box_spec({10, 12, 6}, {5e-4, 2.4e-3, 3e-4}, BoundaryKind::periodic)}) {
    const MacGrid grid(spec);
    std::mt19937_64 rng(seed);
    const GridField eps = test::random_gas_fraction(grid, rng);
    for (int comp = 0; comp < 3; ++comp) {
      SCOPED_TRACE("component " + std::to_string(comp));
      f(grid, eps, comp, random_system(grid, comp, rng));
    }
  }
}

// max |a - b| and max |b - c| over the points where the solve's unknowns lie (everything the
// step writes; the other points are equal in all three).
std::array<double, 2> max_differences(const GridField& a, const GridField& b, const GridField& c) {
  std::array<double, 2> m{};
  for (std::size_t p = 0; p < a.values().size(); ++p) {
    m[0] = std::max(m[0], std::abs(a[p] - b[p]));
    m[1] = std::max(m[1], std::abs(b[p] - c[p]));
  }
  return m;
}

// Every kind of line end along the line axis: walls (the normal component's wall faces known,
// the tangential ones' ghosts reflected), inflow below and outflow above, and periodic (a cyclic
// line); the other two axes one periodic cell each, so their operators vanish.
std::vector<MacGridSpec> line_grids(int axis) {
  std::vector<MacGridSpec> specs;
  std::array<int, 3> cells = {1, 1, 1};
  cells[static_cast<std::size_t>(axis)] = 13;
  std::array<double, 3> extent = {5e-5, 5e-5, 5e-5};
  extent[static_cast<std::size_t>(axis)] = 13 * 5e-5;
  for (int kind = 0; kind < 3; ++kind) {
    MacGridSpec spec = test::box_spec(cells, extent, BoundaryKind::periodic);
    const auto a = static_cast<std::size_t>(axis);
    if (kind == 0) {
      test::set_axis(spec, a, BoundaryKind::wall);
    } else if (kind == 1) {
      spec.bc[2 * a].kind = BoundaryKind::inflow;
      spec.bc[2 * a].velocity[a] = 0.015;
      spec.bc[2 * a + 1].kind = BoundaryKind::outflow;
    }
    specs.push_back(spec);
  }
  return specs;
}

TEST(ViscousFactoredStep, OnOneAxisItIsTheExactSolve) {
  for (int axis = 0; axis < 3; ++axis) {
    int g = 0;
    for (const MacGridSpec& spec : line_grids(axis)) {
      SCOPED_TRACE("lines along " + std::to_string(axis) + ", ends " + std::to_string(g++));
      const MacGrid grid(spec);
      std::mt19937_64 rng(7 + static_cast<unsigned>(axis));
      const GridField eps = test::random_gas_fraction(grid, rng);
      // c / dx^2 = 4: far from dominant rows, where a factored step of a 3-D operator would err
      // most; here it must still be exact.
      const double c = 4.0 * 2.5e-9;
      for (int comp = 0; comp < 3; ++comp) {
        SCOPED_TRACE("component " + std::to_string(comp));
        const System s = random_system(grid, comp, rng);
        ImplicitViscosity exact(grid);
        GridField u_exact = s.guess;
        const ViscousSolveReport solved =
            exact.solve(comp, c, eps, s.diag, s.rhs, u_exact, 1e-14, 2000);
        ASSERT_TRUE(solved.converged);
        ImplicitViscosity factored(grid);
        GridField u = s.guess;
        const ViscousSolveReport step = factored.step_factored(comp, c, eps, s.diag, s.rhs, u);
        EXPECT_TRUE(step.factored);
        double scale = 0.0;
        for (const double v : u_exact.values()) {
          scale = std::max(scale, std::abs(v));
        }
        ASSERT_GT(scale, 0.0);
        const std::array<double, 2> d = max_differences(u, u_exact, u_exact);
        EXPECT_LT(d[0], 1e-11 * scale);
      }
    }
  }
}

// The factored step solves M delta = r with D^-1 M = (I + D^-1 c N_x)(I + D^-1 c N_y)(I + D^-1 c
// N_z), where the exact solve has D^-1 A = I + sum D^-1 c N_b. Each factor is a row-diagonally
// dominant M-matrix with a unit margin, so |(D^-1 M)^-1|_inf <= 1, and |D^-1 c N_b|_inf <= 2
// alpha_b with alpha_b = max over rows of c (k_lo + k_hi) / D. Hence
// |delta - delta_exact|_inf <= E |delta_exact|_inf, E = 4 (a_x a_y + a_x a_z + a_y a_z) +
// 8 a_x a_y a_z.
TEST(ViscousFactoredStep, ErrsNoMoreThanTheFactorizationBound) {
  std::vector<MacGridSpec> specs;
  const MacGridSpec bed = bed_box();
  specs.push_back(bed);
  specs.push_back(
      test::box_spec({10, 12, 6}, {5e-4, 2.4e-3, 3e-4}, BoundaryKind::periodic)); // all cyclic
  for (std::size_t g = 0; g < specs.size(); ++g) {
    SCOPED_TRACE("grid " + std::to_string(g));
    const MacGrid grid(specs[g]);
    std::mt19937_64 rng(11 + g);
    const GridField eps = test::random_gas_fraction(grid, rng);
    const double c = 0.02 * 2.5e-9;
    for (int comp = 0; comp < 3; ++comp) {
      SCOPED_TRACE("component " + std::to_string(comp));
      const System s = random_system(grid, comp, rng);
      // k <= max eps / dx_b^2 on every face (eps <= 1, the inflow's too); D >= 0.5.
      std::array<double, 3> alpha{};
      for (int b = 0; b < 3; ++b) {
        alpha[static_cast<std::size_t>(b)] = c * 2.0 / (grid.spacing(b) * grid.spacing(b)) / 0.5;
      }
      const double bound = 4.0 * (alpha[0] * alpha[1] + alpha[0] * alpha[2] + alpha[1] * alpha[2]) +
                           8.0 * alpha[0] * alpha[1] * alpha[2];
      ASSERT_LT(bound, 0.5); // a bound that says something
      ImplicitViscosity exact(grid);
      GridField u_exact = s.guess;
      ASSERT_TRUE(exact.solve(comp, c, eps, s.diag, s.rhs, u_exact, 1e-14, 2000).converged);
      const GridField u = factored_step(grid, comp, c, eps, s);
      // |u - u_exact| against |u_exact - guess| = |delta_exact|.
      const std::array<double, 2> d = max_differences(u, u_exact, s.guess);
      ASSERT_GT(d[1], 0.0);
      EXPECT_LE(d[0], bound * d[1]) << "bound " << bound;
      // And the factorization does change the answer (the test could not pass by solving
      // exactly with the wrong operator's ends: the 1-D test pins those).
      EXPECT_GT(d[0], 0.0);
    }
  }
}

// The line solves' copies for x86-64-v3 and -v4 (the ones this CPU runs) give the baseline's bits
// on a bed box (walls, inflow, outflow, a periodic axis) and a periodic box (every line cyclic).
TEST(ViscousFactoredStep, EveryInstructionSetGivesTheBaselineBits) {
  const SimdLevel cpu = cpu_simd_level();
  const double c = 2.0 * 2.5e-9;
  for_bed_and_periodic_systems(
      17, [&](const MacGrid& grid, const GridField& eps, int comp, const System& s) {
        const GridField base = factored_step(grid, comp, c, eps, s, SimdLevel::x86_64);
        for (int l = 1; l <= static_cast<int>(cpu); ++l) {
          const auto level = static_cast<SimdLevel>(l);
          SCOPED_TRACE(std::string(simd_level_name(level)));
          EXPECT_TRUE(test::same_bits(factored_step(grid, comp, c, eps, s, level), base));
        }
      });
}

TEST(ViscousFactoredStep, OneAndTwoThreadsGiveTheSameBits) {
  MacGridSpec spec = test::box_spec({12, 9, 11}, {6e-4, 4.5e-4, 5.5e-4}, BoundaryKind::wall);
  test::set_axis(spec, 0, BoundaryKind::periodic);
  const MacGrid grid(spec);
  std::mt19937_64 rng(5);
  const GridField eps = test::random_gas_fraction(grid, rng);
  const double c = 0.5 * 2.5e-9;
  for (int comp = 0; comp < 3; ++comp) {
    SCOPED_TRACE("component " + std::to_string(comp));
    const System s = random_system(grid, comp, rng);
    std::array<GridField, 2> u;
    for (int t = 0; t < 2; ++t) {
      const tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                                        static_cast<std::size_t>(t + 1));
      u[static_cast<std::size_t>(t)] = factored_step(grid, comp, c, eps, s);
    }
    EXPECT_TRUE(test::same_bits(u[0], u[1]));
    EXPECT_FALSE(test::same_bits(u[0], s.guess));
  }
}

// Given rhs - A u itself (rhs_is_residual: the gas solver makes it from its L(u^n), as here),
// the step is the one that makes the residual from rhs: on the bed box and a periodic box, each
// component, to round-off of the step's change. Told that rhs is the residual while it is not,
// the step moves u by rhs's solution instead, far from it.
TEST(ViscousFactoredStep, TakesTheResidualGivenAsTheOneItWouldMake) {
  const double c = 0.5 * 2.5e-9;
  for_bed_and_periodic_systems(
      31, [&](const MacGrid& grid, const GridField& eps, int comp, const System& s) {
        ImplicitViscosity viscosity(grid);
        // rhs - A u = rhs - diag u + c div(eps grad u), the divergence from the Laplacian the gas
        // solver keeps (mu = rho = 1: div(eps grad u) / eps_f, eps_f the face's mean) as it does.
        GridField lap = grid.make_field();
        viscosity.laplacian(comp, 1.0, 1.0, eps, s.guess, lap);
        GridField residual = grid.make_field();
        const auto sa = static_cast<std::size_t>(grid.layout().stride(comp));
        for (std::size_t p = sa; p < lap.values().size(); ++p) {
          const double eps_f = 0.5 * (eps[p] + eps[p - sa]);
          residual[p] = s.rhs[p] - s.diag[p] * s.guess[p] + c * (lap[p] * eps_f);
        }
        GridField made = s.guess;
        GridField given = s.guess;
        GridField misread = s.guess;
        viscosity.step_factored(comp, c, eps, s.diag, s.rhs, made);
        viscosity.step_factored(comp, c, eps, s.diag, residual, given, true);
        viscosity.step_factored(comp, c, eps, s.diag, s.rhs, misread, true);
        const auto [apart, change] = max_differences(given, made, s.guess);
        EXPECT_GT(change, 0.0);
        EXPECT_LE(apart, 1e-12 * change);
        EXPECT_GT(max_differences(misread, made, s.guess)[0], 0.1 * change);
      });
}

// declare_eps (the gas solver's word that eps_g stays put for a step) gives the bits of the
// coefficients made from a compared copy, for the factored step and for the solve, and takes a
// changed field at its next declaration: run against a declaration that did not remake the
// coefficients, the second half fails.
TEST(ImplicitViscosityDeclaredEps, GivesTheComparedBitsAndFollowsEachDeclaration) {
  const MacGrid grid(bed_box());
  std::mt19937_64 rng(23);
  GridField eps = test::random_gas_fraction(grid, rng);
  const double c = 2.0 * 2.5e-9;
  ImplicitViscosity declared(grid);
  ImplicitViscosity compared(grid);
  for (int round = 0; round < 2; ++round) {
    SCOPED_TRACE("declaration " + std::to_string(round + 1));
    if (round == 1) {
      const GridField changed = test::random_gas_fraction(grid, rng);
      std::copy(changed.values().begin(), changed.values().end(), eps.values().begin());
    }
    declared.declare_eps(eps);
    for (int comp = 0; comp < 3; ++comp) {
      SCOPED_TRACE("component " + std::to_string(comp));
      const System s = random_system(grid, comp, rng);
      std::array<GridField, 2> step = {s.guess, s.guess};
      declared.step_factored(comp, c, eps, s.diag, s.rhs, step[0]);
      compared.step_factored(comp, c, eps, s.diag, s.rhs, step[1]);
      EXPECT_TRUE(test::same_bits(step[0], step[1]));
      std::array<GridField, 2> solved = {s.guess, s.guess};
      declared.solve(comp, c, eps, s.diag, s.rhs, solved[0], 1e-10, 1000);
      compared.solve(comp, c, eps, s.diag, s.rhs, solved[1], 1e-10, 1000);
      EXPECT_TRUE(test::same_bits(solved[0], solved[1]));
    }
  }
}

} // namespace
} // namespace cfddem::fluid
