// The gas in a round column (domain.shape = "cylinder", fluid/solid_mask.hpp, docs/theory.md
// §13): laminar pipe flow against Hagen-Poiseuille at two resolutions, no gas through the
// staircase wall, and the projection's empty rows.
#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

#include "fluid/gas_solver.hpp"
#include "fluid/pressure_projection.hpp"
#include "fluid/solid_mask.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

using test::box_spec;
using test::set_axis;

constexpr double kRho = 1.0;
constexpr double kMu = 2e-5;
constexpr double kRadius = 5e-4;

// A pipe of radius R along z (periodic, driven by a pressure drop) in a box of n x n cells
// across, its walls on x and y.
MacGridSpec pipe_spec(int n) {
  const double width = 2.0 * kRadius;
  MacGridSpec spec = box_spec({n, n, 2}, {width, width, 2.0 * width / n}, BoundaryKind::periodic);
  set_axis(spec, 0, BoundaryKind::wall);
  set_axis(spec, 1, BoundaryKind::wall);
  spec.pressure_drop[2] = 1e-3 * spec.extent[2]; // G = 1e-3 Pa/m
  spec.cylinder_axis = 2;
  spec.cylinder_radius = kRadius;
  return spec;
}

struct PipeResult {
  double centre_error = 0.0; // relative, at the four cells around the axis
  double flow_error = 0.0;   // the volume flow's, relative to pi G R^4 / (8 mu)
  double closed_speed = 0.0; // max |u| on a closed face
  double divergence = 0.0;   // max |div u| h / u_centre over the gas cells
};

// Runs the pipe from rest until the slowest mode (Bessel root 2.405) has decayed by e^-16.
PipeResult pipe_flow(int n, bool implicit_viscosity) {
  const MacGrid grid(pipe_spec(n));
  GasSolverSettings settings;
  settings.gas = {kRho, kMu, {0.0, 0.0, 0.0}};
  settings.cfl = 0.45;
  settings.implicit_viscosity = implicit_viscosity;
  GasSolver solver(grid, settings);
  const double g = 1e-3;
  const double nu = kMu / kRho;
  const double t_end = 16.0 * kRadius * kRadius / (2.405 * 2.405 * nu);
  const double h = grid.spacing(0), hz = grid.spacing(2);
  const double dt = 0.45 / (2.0 * nu * (2.0 / (h * h) + 1.0 / (hz * hz)));
  double t = 0.0;
  while (t < t_end) {
    // The explicit viscous limit in both (implicit: the same steps, like with like).
    t += solver.step(std::min(dt, t_end - t + 1e-300)).dt;
  }
  const auto& u = solver.velocity();
  const SolidMask mask(grid);
  PipeResult r;
  const int c = n / 2;
  double centre = 0.0;
  for (int j = c - 1; j <= c; ++j) {
    for (int i = c - 1; i <= c; ++i) {
      centre += 0.25 * u[2](i, j, 0);
    }
  }
  const double r2 = 0.5 * h * h; // the four cells' centres lie h / sqrt(2) from the axis
  const double exact = g * (kRadius * kRadius - r2) / (4.0 * kMu);
  r.centre_error = centre / exact - 1.0;
  double flow = 0.0;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      flow += u[2](i, j, 0) * h * h;
    }
  }
  r.flow_error = flow / (std::numbers::pi * g * std::pow(kRadius, 4) / (8.0 * kMu)) - 1.0;
  for (int a = 0; a < 3; ++a) {
    for (int k = 0; k <= 2; ++k) {
      for (int j = 0; j <= n; ++j) {
        for (int i = 0; i <= n; ++i) {
          if (mask.open_faces(a)(i, j, k) == 0.0) {
            r.closed_speed = std::max(r.closed_speed, std::abs(u[a](i, j, k)));
          }
        }
      }
    }
  }
  for (int k = 0; k < 2; ++k) {
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        if (mask.open_cells()(i, j, k) == 0.0) {
          continue;
        }
        double div = 0.0;
        for (int a = 0; a < 3; ++a) {
          std::array<int, 3> up = {i, j, k};
          up[static_cast<std::size_t>(a)] += 1;
          div += (u[a](up[0], up[1], up[2]) - u[a](i, j, k)) / grid.spacing(a);
        }
        r.divergence = std::max(r.divergence, std::abs(div) * h / centre);
      }
    }
  }
  return r;
}

// The wall is a staircase along the cells' faces with no slip there (the wall's shear at the
// closed tangential neighbours). The staircase holds the cells whose centre lies inside R, so
// its area tracks pi R^2 to O(h) on average, and the centreline speed's error falls with h:
// 2.8% at 16 cells across, 0.45% at 32 (a 2-D model of the same discrete problem gives these
// errors; below 5% at 16 cells is issue 40's bar).
class CylinderPipe : public ::testing::TestWithParam<bool> {};

// The implicit viscosity (the links to closed faces cut, the wall's shear on the diagonal)
// reaches the same steady state as the explicit one: the same discrete problem.
TEST_P(CylinderPipe, PipeFlowMeetsHagenPoiseuille) {
  const PipeResult coarse = pipe_flow(16, GetParam());
  const PipeResult fine = pipe_flow(32, GetParam());
  RecordProperty("centre_error_16", std::to_string(coarse.centre_error));
  RecordProperty("centre_error_32", std::to_string(fine.centre_error));
  RecordProperty("flow_error_16", std::to_string(coarse.flow_error));
  RecordProperty("flow_error_32", std::to_string(fine.flow_error));
  EXPECT_LT(std::abs(coarse.centre_error), 0.05);
  EXPECT_LT(std::abs(fine.centre_error), std::abs(coarse.centre_error));
  EXPECT_LT(std::abs(fine.flow_error), std::abs(coarse.flow_error));
  // The wall is closed exactly, and the gas cells hold the constraint to the solver's tolerance.
  EXPECT_EQ(coarse.closed_speed, 0.0);
  EXPECT_EQ(fine.closed_speed, 0.0);
  EXPECT_LT(coarse.divergence, 1e-8);
  EXPECT_LT(fine.divergence, 1e-8);
}

INSTANTIATE_TEST_SUITE_P(Viscosity, CylinderPipe, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& param) {
                           return std::string(param.param ? "implicit" : "explicit");
                         });

void stirred_column(bool implicit);

// A closed column (walls on every face) with a stirred start: the projection, whose solid rows
// are empty, leaves every gas cell divergence-free and no gas in the wall; the kinetic energy
// only decays.
TEST(CylinderGas, StirredClosedColumnStaysInside) {
  for (const bool implicit : {false, true}) {
    SCOPED_TRACE(implicit ? "implicit viscosity" : "explicit viscosity");
    stirred_column(implicit);
  }
}

void stirred_column(bool implicit) {
  MacGridSpec spec = box_spec({12, 10, 12}, {1.2e-3, 1e-3, 1.2e-3}, BoundaryKind::wall);
  spec.cylinder_axis = 1;
  spec.cylinder_radius = 0.55e-3; // not inscribed: a rim of solid cells all round
  const MacGrid grid(spec);
  GasSolverSettings settings;
  settings.gas = {kRho, kMu, {0.0, -9.81, 0.0}};
  settings.implicit_viscosity = implicit;
  GasSolver solver(grid, settings);
  auto& u = solver.velocity();
  for (int a = 0; a < 3; ++a) {
    for (int k = 0; k <= 12; ++k) {
      for (int j = 0; j <= 10; ++j) {
        for (int i = 0; i <= 12; ++i) {
          u[a](i, j, k) = 1e-2 * std::sin(1.3 * i + 2.1 * j + 0.7 * k + a);
        }
      }
    }
  }
  const SolidMask mask(grid);
  const auto energy = [&] {
    double e = 0.0;
    for (int a = 0; a < 3; ++a) {
      for (int k = 0; k < 12; ++k) {
        for (int j = 0; j < 10; ++j) {
          for (int i = 0; i < 12; ++i) {
            e += u[a](i, j, k) * u[a](i, j, k);
          }
        }
      }
    }
    return e;
  };
  solver.step(2e-5);
  double last = energy();
  for (int s = 0; s < 20; ++s) {
    solver.step(2e-5);
    const double e = energy();
    EXPECT_LE(e, last * (1.0 + 1e-12)) << "step " << s;
    last = e;
  }
  double worst_div = 0.0, closed = 0.0;
  for (int k = 0; k < 12; ++k) {
    for (int j = 0; j < 10; ++j) {
      for (int i = 0; i < 12; ++i) {
        for (int a = 0; a < 3; ++a) {
          if (mask.open_faces(a)(i, j, k) == 0.0) {
            closed = std::max(closed, std::abs(u[a](i, j, k)));
          }
        }
        if (mask.open_cells()(i, j, k) == 0.0) {
          continue;
        }
        const double div = (u[0](i + 1, j, k) - u[0](i, j, k) + u[1](i, j + 1, k) -
                            u[1](i, j, k) + u[2](i, j, k + 1) - u[2](i, j, k)) /
                           grid.spacing(0);
        worst_div = std::max(worst_div, std::abs(div));
      }
    }
  }
  EXPECT_EQ(closed, 0.0);
  EXPECT_LT(worst_div * grid.spacing(0), 1e-9 * 1e-2);
}

TEST(CylinderGas, RefusesWhatItCannotSolve) {
  MacGridSpec spec = pipe_spec(16);
  spec.cylinder_radius = 2.0 * kRadius; // wider than the box
  EXPECT_THROW(MacGrid{spec}, std::invalid_argument);
  spec = pipe_spec(16);
  spec.cylinder_radius = 1.5 * spec.extent[0] / 16; // 3 cells across
  EXPECT_THROW(MacGrid{spec}, std::invalid_argument);
  const MacGrid grid(pipe_spec(16));
  GasSolverSettings settings;
  settings.gas = {kRho, kMu, {0.0, 0.0, 0.0}};
  settings.projection.solver = PoissonSolver::hypre;
  EXPECT_THROW(GasSolver(grid, settings), std::invalid_argument);
}

} // namespace
} // namespace cfddem::fluid
