// fluid.time_order: the measured convergence order in time of the gas step on the Taylor-Green
// vortex, about 1 for Euler (time_order 1) and about 2 for the predictor-corrector (2).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include "fluid/gas_solver.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

constexpr double kRho = 1.0;
constexpr double kMu = 2e-5;
constexpr int kCells = 16;
constexpr double kLength = 1e-3;

// Face velocities of the vortex (Re = U L / nu = 5) after half its e-folding time of the
// velocity, 1 / (4 nu k^2), taken in `steps` equal steps of the given order, on one 16 x 16 grid:
// comparing runs on the same grid isolates the time error from the space error.
// The vortex's periodic n x n grid and the gas's settings, its projection converged far below
// every error measured here.
MacGrid vortex_grid(int n) {
  return MacGrid(
      test::box_spec({n, n, 1}, {kLength, kLength, kLength / n}, BoundaryKind::periodic));
}
GasSolverSettings vortex_settings() {
  GasSolverSettings settings;
  settings.gas = {kRho, kMu, {0.0, 0.0, 0.0}};
  settings.projection.tolerance = 1e-13;
  return settings;
}

// The vortex after `steps` steps with the given settings (vortex_settings with changes).
std::array<GridField, 3> taylor_green_with(const GasSolverSettings& settings, int steps) {
  const MacGrid grid = vortex_grid(kCells);
  GasSolver solver(grid, settings);
  const double nu = kMu / kRho;
  test::set_taylor_green(grid, solver.velocity(), 5.0 * nu / kLength);
  const double k = 2.0 * std::numbers::pi / kLength;
  const double dt = 1.0 / (4.0 * nu * k * k) / steps;
  for (int s = 0; s < steps; ++s) {
    (void)solver.step(dt);
  }
  return solver.velocity();
}

std::array<GridField, 3> taylor_green_after(int order, int steps, int projections = 2) {
  GasSolverSettings settings = vortex_settings();
  settings.time_order = order;
  settings.projections = projections;
  return taylor_green_with(settings, steps);
}

double max_difference(const std::array<GridField, 3>& a, const std::array<GridField, 3>& b) {
  double d = 0.0;
  for (int c = 0; c < 2; ++c) {
    for (int j = 0; j < kCells; ++j) {
      for (int i = 0; i < kCells; ++i) {
        d = std::max(d, std::abs(a[c](i, j, 0) - b[c](i, j, 0)));
      }
    }
  }
  return d;
}

std::string text(double v) {
  std::array<char, 32> s{};
  std::snprintf(s.data(), s.size(), "%.4g", v);
  return s.data();
}

TEST(GasTimeOrder, TaylorGreenConvergesAtFirstAndSecondOrderInTime) {
  // 32 steps is a Courant number of 0.30 (viscous part; the vortex's advection adds 0.03).
  // Reference: the predictor-corrector at 1024 steps, whose own time error, (1/32)^2 of the
  // 32-step one, is below 2% of the smallest error measured (128 steps, order 2), so it biases
  // the measured orders by < 0.03. The projection's tolerance (1e-13) is far below every error.
  const std::array<GridField, 3> reference = taylor_green_after(2, 1024);
  std::array<std::array<double, 3>, 2> error{};
  for (const int order : {1, 2}) {
    for (int r = 0; r < 3; ++r) {
      error[order - 1][r] = max_difference(taylor_green_after(order, 32 << r), reference);
    }
    for (int r = 0; r < 2; ++r) {
      const double measured = std::log2(error[order - 1][r] / error[order - 1][r + 1]);
      RecordProperty("order" + std::to_string(order) + "_steps" + std::to_string(32 << r) + "_" +
                         std::to_string(64 << r),
                     text(measured));
      SCOPED_TRACE("time_order " + std::to_string(order) + ", " + std::to_string(32 << r) + " -> " +
                   std::to_string(64 << r) + " steps: measured order " + text(measured));
      // A first-order method's error halves with the step, a second-order one's quarters; the
      // next term of the error expansion moves the ratio by O(dt) relative: +-0.15 at 32 steps.
      EXPECT_NEAR(measured, static_cast<double>(order), 0.15);
    }
    RecordProperty("order" + std::to_string(order) + "_error_32_steps", text(error[order - 1][0]));
  }
  // The accuracy cost of Euler at the same step (docs/gas_step.md).
  RecordProperty("error_ratio_order1_over_order2_32_steps", text(error[0][0] / error[1][0]));
  EXPECT_GT(error[0][0], 10.0 * error[1][0]);
}

// fluid.projections = 1: the predictor takes the last step's pressure gradient and only the
// corrector is projected. Its divergence error is O(dt^2), so the step stays second order in
// time; its error at 32 steps is within a factor 2 of Heun's with two projections.
TEST(GasTimeOrder, OneProjectionPredictorCorrectorIsSecondOrder) {
  const std::array<GridField, 3> reference = taylor_green_after(2, 1024);
  std::array<double, 3> error{};
  for (int r = 0; r < 3; ++r) {
    error[r] = max_difference(taylor_green_after(2, 32 << r, 1), reference);
  }
  for (int r = 0; r < 2; ++r) {
    const double measured = std::log2(error[r] / error[r + 1]);
    RecordProperty("one_projection_steps" + std::to_string(32 << r) + "_" +
                       std::to_string(64 << r),
                   text(measured));
    SCOPED_TRACE(std::to_string(32 << r) + " -> " + std::to_string(64 << r) +
                 " steps: measured order " + text(measured));
    EXPECT_NEAR(measured, 2.0, 0.15);
  }
  const double heun = max_difference(taylor_green_after(2, 32), reference);
  RecordProperty("error_ratio_one_over_two_projections_32_steps", text(error[0] / heun));
  EXPECT_LT(error[0], 2.0 * heun);
}

// The Re = 5 vortex of taylor_green_after with the viscous Laplacian implicit (backward Euler in
// the predictor, trapezoidal in the corrector), solved to 1e-13 or taken by one factored step
// (fluid.viscous_step = "factored": ImplicitViscosity::step_factored; the 16 x 16 x 1 grid's x
// and y lines).
std::array<GridField, 3> taylor_green_implicit(int steps, bool factored) {
  GasSolverSettings settings = vortex_settings();
  settings.time_order = 2;
  settings.implicit_viscosity = true;
  settings.viscous_tolerance = 1e-13;
  settings.factored_viscosity = factored;
  return taylor_green_with(settings, steps);
}

// The factored viscous step keeps the predictor-corrector's second order in time where the
// viscous term dominates (Re = 5; 16 steps is a viscous Courant number of 0.6, 64 of 0.15),
// and its error is no larger than the solved step's (measured: 0.60x; the factorization's
// error, c^2 N_x D^-1 N_y applied to the step's change, is itself O(dt^3) per step and here
// partly offsets the time error).
TEST(GasTimeOrder, FactoredViscousStepIsSecondOrderInTime) {
  const std::array<GridField, 3> reference = taylor_green_after(2, 1024);
  std::array<double, 3> factored{}, solved{};
  for (int r = 0; r < 3; ++r) {
    factored[r] = max_difference(taylor_green_implicit(16 << r, true), reference);
    solved[r] = max_difference(taylor_green_implicit(16 << r, false), reference);
  }
  for (int r = 0; r < 2; ++r) {
    const double measured = std::log2(factored[r] / factored[r + 1]);
    const double measured_solved = std::log2(solved[r] / solved[r + 1]);
    RecordProperty("factored_steps" + std::to_string(16 << r) + "_" + std::to_string(32 << r),
                   text(measured));
    std::printf("%d -> %d steps: factored %.4g -> %.4g (order %.3f), solved %.4g -> %.4g "
                "(order %.3f)\n",
                16 << r, 32 << r, factored[r], factored[r + 1], measured, solved[r], solved[r + 1],
                measured_solved);
    EXPECT_NEAR(measured, 2.0, 0.15);
  }
  RecordProperty("factored_over_solved_error_16_steps", text(factored[0] / solved[0]));
  EXPECT_LT(factored[0], 1.1 * solved[0]);
}

// Kinetic energy of the face velocities (uniform cells: a sum of squares).
double kinetic_energy(const MacGrid& grid, const std::array<GridField, 3>& u) {
  double e = 0.0;
  for (int a = 0; a < 3; ++a) {
    const auto& n = grid.cells();
    for (int k = 0; k < n[2] + (a == 2); ++k) {
      for (int j = 0; j < n[1] + (a == 1); ++j) {
        for (int i = 0; i < n[0] + (a == 0); ++i) {
          const double v = u[static_cast<std::size_t>(a)](i, j, k);
          e += v * v;
        }
      }
    }
  }
  return 0.5 * e;
}

// A closed box of the fluidized bed's 50 um cells at its 1e-4 s step (dt nu / dx^2 = 0.8 per
// axis: the trapezoidal rule's explicit half amplifies the grid-scale modes by up to 1 - 4.8):
// from a random velocity, neither viscous step may let the kinetic energy grow. A factored step
// that started from the explicit first guess instead of u^n grew the modes stiff along two or
// three axes (a gas-only quarter bed reached 1.2 m/s at its corners in 30 ms against 0.03).
TEST(GasTimeOrder, FactoredViscousStepDampsTheStiffModes) {
  const MacGrid grid(test::box_spec({8, 12, 8}, {4e-4, 6e-4, 4e-4}, BoundaryKind::wall));
  for (const bool factored : {true, false}) {
    SCOPED_TRACE(factored ? "factored" : "solved");
    GasSolverSettings settings = vortex_settings();
    settings.advection = Advection::godunov;
    settings.implicit_viscosity = true;
    settings.factored_viscosity = factored;
    GasSolver solver(grid, settings);
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> uni(-1.0, 1.0);
    for (GridField& f : solver.velocity()) {
      for (double& v : f.values()) {
        v = 0.01 * uni(rng);
      }
    }
    (void)solver.step(1e-4); // the projection makes it a flow of the box
    double last = kinetic_energy(grid, solver.velocity());
    const double first = last;
    ASSERT_GT(first, 0.0);
    for (int s = 0; s < 60; ++s) {
      (void)solver.step(1e-4);
      const double e = kinetic_energy(grid, solver.velocity());
      ASSERT_LE(e, last) << "step " << s;
      last = e;
    }
    EXPECT_LT(last, 0.5 * first); // and it does decay
  }
}

// The Taylor-Green vortex at Re = U L / nu = 100 against its exact decay, u = U sin(k x)
// cos(k y) exp(-2 nu k^2 t), after a tenth of its turnover time L / U, on an n x n grid in
// steps at the Courant number `courant`: grid and step refined together, as a Godunov scheme
// converges (its edge states' (1 - u dt/dx) slope term leaves an O(dt dx) error, so on a fixed
// grid it tends to its dt -> 0 limit at first order in dt). Returns the largest error of the
// face velocities; `used` receives the Courant number of the first step.
double vortex_error(Advection advection, int n, double courant, double* used = nullptr,
                    bool implicit_viscosity = true) {
  const MacGrid grid = vortex_grid(n);
  GasSolverSettings settings = vortex_settings();
  settings.advection = advection;
  settings.implicit_viscosity = implicit_viscosity;
  GasSolver solver(grid, settings);
  const double nu = kMu / kRho;
  const double speed = 100.0 * nu / kLength;
  test::set_taylor_green(grid, solver.velocity(), speed);
  const double end = 0.1 * kLength / speed;
  const int steps = static_cast<int>(std::ceil(end / solver.dt_for_courant(courant)));
  const double dt = end / steps;
  if (used != nullptr) {
    *used = solver.courant_number(dt);
  }
  for (int s = 0; s < steps; ++s) {
    (void)solver.step(dt);
  }
  const double k = 2.0 * std::numbers::pi / kLength;
  const double decay = std::exp(-2.0 * nu * k * k * end);
  const double h = kLength / n;
  double error = 0.0;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const double x = i * h;
      const double y = (j + 0.5) * h;
      const double u = speed * std::sin(k * x) * std::cos(k * y) * decay;
      const double v = -speed * std::cos(k * (x + 0.5 * h)) * std::sin(k * (j * h)) * decay;
      error = std::max({error, std::abs(solver.velocity()[0](i, j, 0) - u),
                        std::abs(solver.velocity()[1](i, j, 0) - v)});
    }
  }
  return error;
}

// The Godunov step at Courant number 0.9 converges at second order as grid and step are
// refined together, as the method of lines (Heun, one projection) does at 0.5; its error at
// 0.9 is reported beside Heun's at 0.5 (docs/gas_step.md).
TEST(GasTimeOrder, GodunovConvergesAtSecondOrderAtCourantNumberPointNine) {
  std::array<double, 4> godunov{}, heun{}, explicit_viscosity{};
  double courant = 0.0, heun_courant = 0.0;
  for (int r = 0; r < 4; ++r) {
    godunov[r] = vortex_error(Advection::godunov, 16 << r, 0.9, &courant);
    heun[r] = vortex_error(Advection::mol, 16 << r, 0.5, &heun_courant);
    explicit_viscosity[r] = vortex_error(Advection::godunov, 16 << r, 0.9, nullptr, false);
  }
  for (int r = 0; r < 3; ++r) {
    const double g = std::log2(godunov[r] / godunov[r + 1]);
    const double m = std::log2(heun[r] / heun[r + 1]);
    RecordProperty("godunov_order_" + std::to_string(16 << r), text(g));
    RecordProperty("heun_order_" + std::to_string(16 << r), text(m));
    std::printf("%d -> %d cells: godunov (C %.3g) %.3g -> %.3g, order %.3f; heun (C %.3g) %.3g "
                "-> %.3g, order %.3f\n",
                16 << r, 32 << r, courant, godunov[r], godunov[r + 1], g, heun_courant, heun[r],
                heun[r + 1], m);
    // Second order: the error falls 4x per halving (a first-order step would give 2x); the
    // limiter clips the slopes at the vortex's extrema, which moves single ratios (1.63 to 2.06
    // measured), so each is held above 1.5 and their mean over the three to 1.8.
    EXPECT_GT(g, 1.5);
    EXPECT_GT(m, 1.5);
  }
  const double mean_order = std::log2(godunov[0] / godunov[3]) / 3.0;
  RecordProperty("godunov_mean_order", text(mean_order));
  // With the viscous terms explicit (the midpoint rule on the half-step velocities) too.
  const double explicit_order = std::log2(explicit_viscosity[0] / explicit_viscosity[3]) / 3.0;
  RecordProperty("godunov_explicit_viscosity_mean_order", text(explicit_order));
  std::printf("explicit viscosity: %.3g %.3g %.3g %.3g, mean order %.3f\n",
              explicit_viscosity[0], explicit_viscosity[1], explicit_viscosity[2],
              explicit_viscosity[3], explicit_order);
  EXPECT_GT(explicit_order, 1.8);
  RecordProperty("godunov_over_heun_error_128", text(godunov[3] / heun[3]));
  EXPECT_GT(mean_order, 1.8);
  EXPECT_GT(courant, 0.85); // the step the test means to take
}

// The Godunov step at Courant number 0.9 on an inviscid periodic 3D flow: a uniform stream
// along an axis, across a face diagonal and along the body diagonal (where the bound on the sum
// of the axes' Courant numbers binds), carrying a divergence-free shear of 10% of it. The
// stream is conserved (periodic box), and so is the kinetic energy of the exact flow, hence the
// energy of the deviation from the stream: the scheme's upwinding can only dissipate it. A
// linearly unstable step grows its worst mode by a factor per step (with the bound on the sum
// of the axes' Courant numbers lifted, the rms deviation of the body-diagonal stream grew from
// 0.071 to 0.52): over 200 steps it must instead stay at most its start.
TEST(GasTimeOrder, GodunovIsStableAtCourantNumberPointNineIn3D) {
  constexpr int n = 12;
  for (const std::array<double, 3> dir :
       {std::array<double, 3>{1, 0, 0}, {1, 1, 0}, {1, 1, 1}, {1, 0.5, 0.2}}) {
    const MacGrid grid(
        test::box_spec({n, n, n}, {kLength, kLength, kLength}, BoundaryKind::periodic));
    GasSolverSettings settings;
    settings.gas = {kRho, 0.0, {0.0, 0.0, 0.0}};
    settings.advection = Advection::godunov;
    settings.cfl = 0.9;
    GasSolver solver(grid, settings);
    const double k = 2.0 * std::numbers::pi / kLength;
    const double h = kLength / n;
    const double shear = 0.1;
    auto& u = solver.velocity();
    for (int kk = 0; kk < n; ++kk) {
      for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
          // u_x varies along y, u_y along z, u_z along x: divergence-free.
          u[0](i, j, kk) = dir[0] + shear * std::sin(k * (j + 0.5) * h);
          u[1](i, j, kk) = dir[1] + shear * std::sin(k * (kk + 0.5) * h);
          u[2](i, j, kk) = dir[2] + shear * std::sin(k * (i + 0.5) * h);
        }
      }
    }
    for (int s = 0; s < 200; ++s) {
      (void)solver.step(); // at fluid cfl 0.9
    }
    double sum = 0.0;
    for (int a = 0; a < 3; ++a) {
      for (int kk = 0; kk < n; ++kk) {
        for (int j = 0; j < n; ++j) {
          for (int i = 0; i < n; ++i) {
            sum += (u[a](i, j, kk) - dir[a]) * (u[a](i, j, kk) - dir[a]);
          }
        }
      }
    }
    const double rms = std::sqrt(sum / (3.0 * n * n * n));
    const double start = shear / std::sqrt(2.0); // each component's sine
    SCOPED_TRACE("stream " + text(dir[0]) + ", " + text(dir[1]) + ", " + text(dir[2]) +
                 ": rms deviation " + text(rms) + " from " + text(start));
    EXPECT_LE(rms, start * (1.0 + 1e-9));
    EXPECT_GT(rms, 0.1 * start); // the shear is carried, not erased
  }
}

} // namespace
} // namespace cfddem::fluid
