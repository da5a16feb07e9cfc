// The momentum right-hand side's row loops run as copies compiled for x86-64, x86-64-v3 and
// x86-64-v4 (core/simd_level.hpp, at_simd_level): every copy this CPU can run must give bitwise
// the baseline copy's fields, for both limiters, viscous or not, with the Laplacian left to the
// implicit solve or not, on a walled column with inflow and outflow and on a periodic box.
#include <array>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include "core/simd_level.hpp"
#include "fluid/momentum_rhs.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

using test::same_bits;

// Rows of 19 and 21 points: two full AVX-512 vectors and a remainder.
MacGridSpec spec_of(bool periodic) {
  if (periodic) {
    return test::box_spec({19, 8, 5}, {1.9e-3, 8e-4, 5e-4}, BoundaryKind::periodic);
  }
  MacGridSpec spec = test::box_spec({20, 7, 6}, {2e-3, 7e-4, 6e-4}, BoundaryKind::wall);
  spec.bc[2] = test::bc_of(BoundaryKind::inflow);
  spec.bc[2].velocity = {0.002, 0.012, 0.0};
  spec.bc[3] = test::bc_of(BoundaryKind::outflow);
  return spec;
}

// Every value of the field, ghosts included, from rng: both copies read the same numbers.
void fill_random(GridField& f, std::mt19937_64& rng, double lo, double hi) {
  std::uniform_real_distribution<double> uni(lo, hi);
  for (double& v : f.values()) {
    v = uni(rng);
  }
}

struct Inputs {
  std::array<GridField, 3> u, lap, gain, push;
  GridField eps, pressure;
};

Inputs random_inputs(const MacGrid& grid) {
  std::mt19937_64 rng(11);
  Inputs in;
  for (int a = 0; a < 3; ++a) {
    const auto s = static_cast<std::size_t>(a);
    in.u[s] = grid.make_field();
    in.lap[s] = grid.make_field();
    in.gain[s] = grid.make_field();
    in.push[s] = grid.make_field();
    fill_random(in.u[s], rng, -0.05, 0.05); // both signs: every upwind branch is taken
    fill_random(in.lap[s], rng, -1.0, 1.0);
    fill_random(in.gain[s], rng, 1.0, 3.0);
    fill_random(in.push[s], rng, -1e-3, 1e-3);
  }
  in.eps = grid.make_field();
  in.pressure = grid.make_field();
  fill_random(in.eps, rng, 0.4, 1.0);
  fill_random(in.pressure, rng, -1.0, 1.0);
  return in;
}

// The fields one call writes: the right-hand side, and Godunov's base states and half steps.
struct Outputs {
  std::array<GridField, 3> rhs;
  MomentumWorkspace work;
};

Outputs run(const MacGrid& grid, const Inputs& in, SimdLevel level, Limiter limiter,
            double viscosity, bool exclude_laplacian, bool godunov) {
  Outputs out;
  for (GridField& f : out.rhs) {
    f = grid.make_field();
  }
  const GasProperties gas{1.2, viscosity, {0.0, -9.80665, 0.0}};
  const std::array<double, 3> body = {0.0, -9.80665, 0.0};
  if (godunov) {
    EdgePrediction pred;
    pred.dt = 1e-4;
    pred.pressure = &in.pressure;
    pred.laplacian = exclude_laplacian ? &in.lap : nullptr;
    pred.drag_gain = &in.gain;
    pred.drag_push = &in.push;
    godunov_momentum_rhs(grid, gas, limiter, in.u, in.eps, body, pred, out.rhs, out.work,
                         exclude_laplacian, level);
  } else {
    momentum_rhs(grid, gas, limiter, in.u, in.eps, body, out.rhs, out.work, exclude_laplacian,
                 level);
  }
  return out;
}

TEST(MomentumRhsCopies, EveryInstructionSetCopyMatchesTheBaselineBitwise) {
  const SimdLevel cpu = cpu_simd_level();
  std::printf("this CPU runs the copies up to %s\n", std::string(simd_level_name(cpu)).c_str());
  for (const bool periodic : {false, true}) {
    const MacGrid grid(spec_of(periodic));
    const Inputs in = random_inputs(grid);
    for (const bool godunov : {false, true}) {
      for (const Limiter limiter : {Limiter::minmod, Limiter::van_leer}) {
        for (const double viscosity : {0.0, 1.8e-5}) {
          for (const bool exclude : {false, true}) {
            SCOPED_TRACE(std::string(periodic ? "periodic" : "column") +
                         (godunov ? ", godunov" : ", method of lines") +
                         (limiter == Limiter::minmod ? ", minmod" : ", van Leer") +
                         (viscosity > 0.0 ? ", viscous" : ", inviscid") +
                         (exclude ? ", Laplacian implicit" : ""));
            const Outputs base =
                run(grid, in, SimdLevel::x86_64, limiter, viscosity, exclude, godunov);
            for (int l = 1; l <= static_cast<int>(cpu); ++l) {
              const auto level = static_cast<SimdLevel>(l);
              const Outputs copy = run(grid, in, level, limiter, viscosity, exclude, godunov);
              for (std::size_t a = 0; a < 3; ++a) {
                EXPECT_TRUE(same_bits(base.rhs[a], copy.rhs[a]))
                    << simd_level_name(level) << ": rhs component " << a;
                if (godunov) {
                  EXPECT_TRUE(same_bits(base.work.half[a], copy.work.half[a]))
                      << simd_level_name(level) << ": half step of component " << a;
                  for (std::size_t b = 0; b < 3; ++b) {
                    EXPECT_TRUE(same_bits(base.work.base[a][b], copy.work.base[a][b]))
                        << simd_level_name(level) << ": base state " << a << " along " << b;
                  }
                }
              }
            }
          }
        }
      }
    }
  }
}

} // namespace
} // namespace cfddem::fluid
