// The implicit viscosity's Chebyshev rows (fluid/implicit_viscosity_chebyshev.cpp): a regular
// row computes its face coefficients from eps instead of reading the stored ones, and the rows
// carry copies for x86-64-v3 and -v4. Every copy this CPU can run, with either coefficient source,
// must give bitwise the baseline's solution with the stored coefficients, on grids whose rows
// touch walls, inflow planes (along y and along x, where only a row's ends lie in the plane),
// outflow faces and periodic axes.
#include <array>
#include <cstdio>
#include <random>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "core/simd_level.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/implicit_viscosity.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

std::array<MacGridSpec, 3> row_test_grids() {
  // A bed: walls along x, inflow below and outflow above, periodic along z.
  MacGridSpec bed = test::box_spec({9, 14, 7}, {4.5e-4, 2.8e-3, 3.5e-4}, BoundaryKind::wall);
  test::set_axis(bed, 2, BoundaryKind::periodic);
  bed.bc[2].kind = BoundaryKind::inflow;
  bed.bc[2].velocity = {0.0, 0.015, 0.0};
  bed.bc[3].kind = BoundaryKind::outflow;
  // Gas entering along x: a row's first and last points lie in the inflow and outflow planes.
  MacGridSpec along_x = test::box_spec({11, 6, 5}, {5.5e-4, 3e-4, 2.5e-4}, BoundaryKind::wall);
  along_x.bc[0].kind = BoundaryKind::inflow;
  along_x.bc[0].velocity = {0.02, 0.0, 0.0};
  along_x.bc[1].kind = BoundaryKind::outflow;
  return {bed, along_x, test::box_spec({10, 12, 6}, {5e-4, 2.4e-3, 3e-4}, BoundaryKind::periodic)};
}

TEST(ViscousChebyshevRows, EveryCopyAndCoefficientSourceMatchesTheStoredBaselineBitwise) {
  const SimdLevel cpu = cpu_simd_level();
  std::printf("this CPU runs the copies up to %s\n", std::string(simd_level_name(cpu)).c_str());
  const std::array<MacGridSpec, 3> specs = row_test_grids();
  for (std::size_t g = 0; g < specs.size(); ++g) {
    SCOPED_TRACE("grid " + std::to_string(g));
    const MacGrid grid(specs[g]);
    std::mt19937_64 rng(41);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    const GridField eps = test::random_gas_fraction(grid, rng);
    // c / dx^2 ~ 0.1 of the mass term: the rows are dominant, the solve is the Chebyshev one.
    const double c = 0.1 * 2.5e-9;
    for (int comp = 0; comp < 3; ++comp) {
      SCOPED_TRACE("component " + std::to_string(comp));
      GridField diag = grid.make_field();
      GridField rhs = grid.make_field();
      for (std::size_t p = 0; p < diag.values().size(); ++p) {
        diag[p] = 0.5 + uni(rng);
        rhs[p] = uni(rng) - 0.5;
      }
      std::array<GridField, 3> start = {grid.make_field(), grid.make_field(), grid.make_field()};
      for (GridField& f : start) {
        for (double& v : f.values()) {
          v = 0.1 * (uni(rng) - 0.5); // a first guess with ghosts of its own
        }
      }
      fill_velocity_ghosts(grid, start);
      const auto solve = [&](SimdLevel level, CoefficientSource source, GridField& u) {
        ImplicitViscosity viscosity(grid);
        viscosity.use_simd_level(level);
        viscosity.use_coefficient_source(source);
        u = start[static_cast<std::size_t>(comp)];
        return viscosity.solve(comp, c, eps, diag, rhs, u, 1e-12, 500);
      };
      GridField base;
      const ViscousSolveReport reference =
          solve(SimdLevel::x86_64, CoefficientSource::stored, base);
      ASSERT_TRUE(reference.chebyshev) << "dominance " << reference.dominance;
      ASSERT_TRUE(reference.converged);
      EXPECT_EQ(reference.rows_from_eps, 0);
      EXPECT_GT(reference.iterations, 5);
      for (int l = 0; l <= static_cast<int>(cpu); ++l) {
        const auto level = static_cast<SimdLevel>(l);
        for (const CoefficientSource source :
             {CoefficientSource::from_eps, CoefficientSource::stored,
              CoefficientSource::stored_inverse, CoefficientSource::automatic}) {
          SCOPED_TRACE(std::string(simd_level_name(level)) + ", source " +
                       std::to_string(static_cast<int>(source)));
          const bool stored = source != CoefficientSource::from_eps;
          GridField u;
          const ViscousSolveReport report = solve(level, source, u);
          EXPECT_EQ(report.iterations, reference.iterations);
          EXPECT_EQ(report.relative_residual, reference.relative_residual);
          EXPECT_TRUE(test::same_bits(u, base));
          if (!stored && level != SimdLevel::x86_64) {
            // Most rows are regular: the bed's x and z components lose the rows beside the
            // inflow plane; the along-x grid's y and z components lose every row (its ends lie
            // in the inflow and outflow planes).
            if (g == 1 && comp != 0) {
              EXPECT_EQ(report.rows_from_eps, 0);
            } else {
              EXPECT_GT(report.rows_from_eps, 0);
            }
          } else {
            EXPECT_EQ(report.rows_from_eps, 0);
          }
        }
      }
    }
  }
}

// Two iterations per sweep (the default on one grid) against one: the same iterations, residual
// and solution bit for bit, whichever iteration of a pair the tolerance stops at, when the
// iteration limit cuts the Chebyshev solve short (CG finishes), on 1 to 3 threads (one chunk of
// planes per task, whose end planes take their second iteration after the sweep), on the row
// grids and on a walled box with a periodic axis and a tall z (several chunks, z-walls).
TEST(ViscousChebyshevRows, PairedIterationsGiveTheSingleIterationsBits) {
  std::vector<MacGridSpec> specs;
  for (const MacGridSpec& spec : row_test_grids()) {
    specs.push_back(spec);
  }
  MacGridSpec tall = test::box_spec({8, 6, 29}, {4e-4, 3e-4, 1.45e-3}, BoundaryKind::wall);
  test::set_axis(tall, 0, BoundaryKind::periodic);
  specs.push_back(tall);
  for (std::size_t g = 0; g < specs.size(); ++g) {
    SCOPED_TRACE("grid " + std::to_string(g));
    const MacGrid grid(specs[g]);
    std::mt19937_64 rng(43);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    const GridField eps = test::random_gas_fraction(grid, rng);
    const double c = 0.15 * 2.5e-9; // dominance about 0.5: a dozen iterations and more
    for (int comp = 0; comp < 3; ++comp) {
      SCOPED_TRACE("component " + std::to_string(comp));
      GridField diag = grid.make_field();
      GridField rhs = grid.make_field();
      GridField start = grid.make_field();
      for (std::size_t p = 0; p < diag.values().size(); ++p) {
        diag[p] = 0.5 + uni(rng);
        rhs[p] = uni(rng) - 0.5;
        start[p] = 0.1 * (uni(rng) - 0.5);
      }
      fill_velocity_ghosts(grid, comp, start);
      const auto solve = [&](bool paired, double tolerance, int max_iterations, GridField& u) {
        ImplicitViscosity viscosity(grid);
        viscosity.use_paired_iterations(paired);
        u = start;
        return viscosity.solve(comp, c, eps, diag, rhs, u, tolerance, max_iterations);
      };
      std::set<int> parities;
      // Tolerances a third of a decade apart stop at both iterations of a pair; the last two
      // cut the Chebyshev solve after an odd and an even count, and CG (multigrid-preconditioned)
      // finishes.
      std::vector<std::pair<double, int>> cases;
      for (double tolerance = 1e-4; tolerance > 1e-11; tolerance /= 2.0) {
        cases.emplace_back(tolerance, 500);
      }
      cases.emplace_back(1e-12, 11);
      cases.emplace_back(1e-12, 12);
      for (const auto& [tolerance, max_iterations] : cases) {
        SCOPED_TRACE("tolerance " + std::to_string(tolerance) + ", at most " +
                     std::to_string(max_iterations));
        GridField single;
        const ViscousSolveReport reference = solve(false, tolerance, max_iterations, single);
        ASSERT_GT(reference.dominance, 0.0);
        ASSERT_LE(reference.dominance, kChebyshevMaxDominance);
        if (max_iterations == 500) {
          ASSERT_TRUE(reference.chebyshev && reference.converged);
          parities.insert(reference.iterations % 2);
        } else {
          ASSERT_GT(reference.iterations, max_iterations); // Chebyshev's, then CG's
        }
        for (const int threads : {1, 2, 3}) {
          SCOPED_TRACE(std::to_string(threads) + " threads");
          const tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                                          static_cast<std::size_t>(threads));
          GridField paired;
          const ViscousSolveReport report = solve(true, tolerance, max_iterations, paired);
          EXPECT_EQ(report.iterations, reference.iterations);
          EXPECT_EQ(report.chebyshev, reference.chebyshev);
          EXPECT_EQ(report.relative_residual, reference.relative_residual);
          EXPECT_TRUE(test::same_bits(paired, single));
        }
      }
      EXPECT_EQ(parities.size(), 2U) << "the tolerances should stop at both iterations of a pair";
    }
  }
}

// The automatic source: fields that stay in the caches read the stored inverse diagonal; larger
// ones compute it, from eps at x86-64-v4 only; a forced source holds at every size (from eps
// falls back to the stored arrays at baseline x86-64, which has no eps rows).
TEST(ViscousChebyshevRows, TheAutomaticSourceFollowsTheFieldsSizeAndLevel) {
  using enum CoefficientSource;
  constexpr std::size_t big = kChebyshevCachedFieldBytes;
  constexpr std::size_t small = kChebyshevCachedFieldBytes - 1;
  for (const SimdLevel level : {SimdLevel::x86_64, SimdLevel::x86_64_v3, SimdLevel::x86_64_v4}) {
    EXPECT_EQ(chebyshev_row_source(automatic, level, small), stored_inverse);
    for (const std::size_t bytes : {small, big}) {
      EXPECT_EQ(chebyshev_row_source(stored, level, bytes), stored);
      EXPECT_EQ(chebyshev_row_source(stored_inverse, level, bytes), stored_inverse);
      EXPECT_EQ(chebyshev_row_source(from_eps, level, bytes),
                level == SimdLevel::x86_64 ? stored : from_eps);
    }
  }
  EXPECT_EQ(chebyshev_row_source(automatic, SimdLevel::x86_64, big), stored);
  EXPECT_EQ(chebyshev_row_source(automatic, SimdLevel::x86_64_v3, big), stored);
  EXPECT_EQ(chebyshev_row_source(automatic, SimdLevel::x86_64_v4, big), from_eps);
  // The small bed's fields (32 x 50 x 32 cells with ghosts) stay in the caches, the 1e5 bed's
  // (101 x 50 x 101) do not.
  const auto field_bytes = [](std::array<int, 3> cells) {
    return GridLayout(cells).size() * sizeof(double);
  };
  EXPECT_LT(field_bytes({32, 50, 32}), kChebyshevCachedFieldBytes);
  EXPECT_GE(field_bytes({101, 50, 101}), kChebyshevCachedFieldBytes);
}

} // namespace
} // namespace cfddem::fluid
