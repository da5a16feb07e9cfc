// A velocity inflow under a packed bed delivers the prescribed superficial velocity: the gas
// entering is pure (eps_g = 1 on the inflow plane, mac_grid.hpp), so the mass flux through the
// inflow face is rho_g U A, and once steady every horizontal plane of the column carries it.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include "fluid/gas_solver.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

constexpr double kRho = 1.0;
constexpr double kMu = 2e-5;

// Gas mass flux [kg/s] up through the y faces of plane j: rho sum eps_f v dx dz, eps_f the mean of
// the two cells across the face (the top face: the free board's cell and its zero-gradient
// ghost). Plane 0, the inflow face, is left out: what eps_g it has is the point in question.
double plane_flux(const MacGrid& grid, const GasSolver& solver, int j) {
  const GridField& eps = solver.volume_fraction();
  const GridField& v = solver.velocity()[1];
  double sum = 0.0;
  for (int k = 0; k < grid.cells(2); ++k) {
    for (int i = 0; i < grid.cells(0); ++i) {
      const double eps_below = eps(i, j - 1, k);
      const double eps_above = j < grid.cells(1) ? eps(i, j, k) : eps_below;
      sum += 0.5 * (eps_below + eps_above) * v(i, j, k);
    }
  }
  return kRho * sum * grid.spacing(0) * grid.spacing(2);
}

class PackedBedInflow : public ::testing::TestWithParam<bool> {};

TEST_P(PackedBedInflow, EveryPlaneCarriesTheInflowMassFlux) {
  // A 6 x 16 x 6 column of 0.1 mm cells with no-slip sides, 12 mm/s inflow at y_lo, pressure
  // outflow at y_hi, gravity along -y. A packed bed (eps_g 0.43 +- 0.04, drag beta = 1e6 N s/m^4,
  // particles at rest) fills the bottom 7 cell rows and touches the inflow face; pure gas above.
  const double inflow = 0.012;
  MacGridSpec spec = test::box_spec({6, 16, 6}, {6e-4, 1.6e-3, 6e-4}, BoundaryKind::wall);
  spec.bc[2] = test::bc_of(BoundaryKind::inflow);
  spec.bc[2].velocity = {0.0, inflow, 0.0};
  spec.bc[3] = test::bc_of(BoundaryKind::outflow);
  const MacGrid grid(spec);
  GasSolverSettings settings;
  settings.gas = {kRho, kMu, {0.0, -9.80665, 0.0}};
  settings.projection.tolerance = 1e-12;
  settings.implicit_viscosity = GetParam();
  settings.viscous_tolerance = 1e-12;
  settings.fixed_dt = 2e-5; // the explicit viscous limit is 4.2e-5 s (the gas starts at rest)
  GasSolver solver(grid, settings);
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> jitter(-0.04, 0.04);
  for (int k = 0; k < 6; ++k) {
    for (int j = 0; j < 7; ++j) {
      for (int i = 0; i < 6; ++i) {
        solver.volume_fraction()(i, j, k) = 0.43 + jitter(rng);
        solver.drag_coefficient()(i, j, k) = 1e6;
      }
    }
  }
  solver.reset_volume_fraction_history();
  // Steady: the bed is fixed, so the flow settles within a few viscous times of a cell
  // (dx^2 / nu = 0.5 ms); run 4 ms.
  double t = 0.0;
  while (t < 4e-3) {
    t += solver.step().dt;
  }
  const double area = grid.length(0) * grid.length(2);
  const double expected = kRho * inflow * area;
  // Continuity per cell holds to the projection's relative residual (1e-12) of a right-hand side
  // of order U / dx per cell; a plane's flux sums the residuals of the cells below it: at most
  // 576 cells x 1e-12 of rho U A, bounded here by 1e-9.
  const double tolerance = 1e-9 * expected;
  double worst = 0.0;
  for (int j = 1; j <= grid.cells(1); ++j) {
    const double flux = plane_flux(grid, solver, j);
    worst = std::max(worst, std::abs(flux / expected - 1.0));
    EXPECT_NEAR(flux, expected, tolerance)
        << "plane y = " << j << ": " << flux / expected << " of rho_g U A";
  }
  std::array<char, 32> text{};
  std::snprintf(text.data(), text.size(), "%.3g", worst);
  RecordProperty("worst_relative_plane_flux_error", text.data());
  // The bed's gas moves at the interstitial velocity: plane means of v in the bed exceed U by
  // about 1 / 0.43 (not U, which would mean only eps U A gets in).
  double mean_v = 0.0;
  for (int k = 0; k < 6; ++k) {
    for (int i = 0; i < 6; ++i) {
      mean_v += solver.velocity()[1](i, 3, k) / 36.0;
    }
  }
  EXPECT_GT(mean_v, 2.0 * inflow);
}

INSTANTIATE_TEST_SUITE_P(Viscosity, PackedBedInflow, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& param) {
                           return std::string(param.param ? "implicit" : "explicit");
                         });

} // namespace
} // namespace cfddem::fluid
