// Checkpoint/restart of the gas solver: a solver rebuilt from save_state() continues bit for bit
// (the coupled restart test in tests/apps/io_test.py checks the whole program; this isolates the
// gas: every field a step reads from the previous one must be in the state).
#include <array>
#include <cmath>
#include <stdexcept>

#include <gtest/gtest.h>

#include "fluid/gas_solver.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

// Walls in y, periodic x and z, a different cell count per axis; implicit viscosity so the CG
// first guess (the previous velocity) is part of what must be restored.
MacGrid channel() {
  MacGridSpec spec = test::box_spec({6, 5, 4}, {1.2e-3, 1e-3, 0.8e-3}, BoundaryKind::periodic);
  test::set_axis(spec, 1, BoundaryKind::wall);
  spec.pressure_drop[0] = 1e-3;
  return MacGrid(spec);
}

GasSolverSettings settings() {
  GasSolverSettings s;
  s.gas = {1.0, 2e-5, {0.0, -9.81, 0.0}};
  s.implicit_viscosity = true;
  return s;
}

// The coupling's inputs at fluid step n: eps_g and the deposited drag change every step (so
// d(eps)/dt and the previous eps_g matter), as moving particles make them.
void set_inputs(GasSolver& g, int n) {
  const auto& c = g.grid().cells();
  for (int k = 0; k < c[2]; ++k)
    for (int j = 0; j < c[1]; ++j)
      for (int i = 0; i < c[0]; ++i) {
        const double phase = 0.7 * i + 1.3 * j + 0.4 * k + 0.5 * n;
        g.volume_fraction()(i, j, k) = 0.9 + 0.05 * std::sin(phase);
        g.drag_coefficient()(i, j, k) = 50.0 * (1.0 + std::cos(phase));
        for (int a = 0; a < 3; ++a)
          g.drag_velocity_sum(a)(i, j, k) = g.drag_coefficient()(i, j, k) * 0.01 * (a + 1);
      }
}

void expect_same(const GridField& a, const GridField& b, const char* name) {
  const auto va = a.values(), vb = b.values();
  ASSERT_EQ(va.size(), vb.size()) << name;
  for (std::size_t m = 0; m < va.size(); ++m)
    ASSERT_EQ(va[m], vb[m]) << name << " at " << m; // bitwise: no tolerance
}

TEST(GasSolverRestart, RestoredSolverContinuesBitForBit) {
  const MacGrid grid = channel();
  const double dt_f = 2e-4;
  GasSolver a(grid, settings());
  set_inputs(a, 0);
  a.reset_volume_fraction_history();
  for (int n = 1; n <= 3; ++n) {
    set_inputs(a, n);
    a.advance(dt_f);
  }
  const GasSolver::State saved = a.save_state();
  GasSolver b(grid, settings());
  b.restore_state(saved);
  for (int n = 4; n <= 6; ++n) {
    set_inputs(a, n);
    set_inputs(b, n);
    a.advance(dt_f);
    b.advance(dt_f);
  }
  for (int c = 0; c < 3; ++c) expect_same(a.velocity()[c], b.velocity()[c], "velocity");
  expect_same(a.pressure(), b.pressure(), "pressure");
  expect_same(a.volume_fraction(), b.volume_fraction(), "eps_g");
  // The gas moved: the test compares something.
  double umax = 0.0;
  for (double u : a.velocity()[0].values()) umax = std::max(umax, std::abs(u));
  EXPECT_GT(umax, 0.0);
}

// The step declares eps_g to the implicit viscosity once (GasSolverSettings::declare_eps), so
// its face coefficients are made once a step rather than checked against a copy at every call.
// That holds only while nothing writes eps_g between the step's viscous calls: with eps_g, the
// drag and the step length changing every fluid step, and sub-steps that interpolate eps_g in
// time, every scheme and viscous step gives the bits of the path that compares.
TEST(GasSolverDeclaredEps, StepsGiveTheBitsOfTheComparedPath) {
  const MacGrid grid = channel();
  struct Variant {
    Advection advection;
    bool factored;
  };
  for (const Variant v : {Variant{Advection::godunov, true}, Variant{Advection::godunov, false},
                          Variant{Advection::mol, true}, Variant{Advection::mol, false}}) {
    std::array<GasSolverSettings, 2> s{settings(), settings()};
    for (GasSolverSettings& x : s) {
      x.advection = v.advection;
      x.factored_viscosity = v.factored;
      x.cfl = 0.3; // sub-steps: eps_g interpolated in time inside advance()
    }
    s[1].declare_eps = false;
    GasSolver declared(grid, s[0]), compared(grid, s[1]);
    for (GasSolver* g : {&declared, &compared}) {
      set_inputs(*g, 0);
      g->reset_volume_fraction_history();
      g->velocity()[0].fill(0.5); // Courant number 0.5-0.8 a fluid step: sub-steps
    }
    int substeps = 0;
    for (int n = 1; n <= 4; ++n) {
      for (GasSolver* g : {&declared, &compared}) {
        set_inputs(*g, n);
        g->advance(n % 2 == 0 ? 2e-4 : 1.3e-4, &substeps);
      }
    }
    EXPECT_GE(substeps, 2); // the last interval was taken in sub-steps
    for (int c = 0; c < 3; ++c)
      expect_same(declared.velocity()[c], compared.velocity()[c], "velocity");
    expect_same(declared.pressure(), compared.pressure(), "pressure");
    double umax = 0.0;
    for (double u : declared.velocity()[1].values())
      umax = std::max(umax, std::abs(u));
    EXPECT_GT(umax, 0.0);
  }
}

TEST(GasSolverRestart, StateOfAnotherGridIsRefused) {
  GasSolver a(channel(), settings());
  GasSolver b(MacGrid(test::box_spec({4, 4, 4}, {1e-3, 1e-3, 1e-3}, BoundaryKind::periodic)),
              settings());
  EXPECT_THROW(b.restore_state(a.save_state()), std::invalid_argument);
}

} // namespace
} // namespace cfddem::fluid
