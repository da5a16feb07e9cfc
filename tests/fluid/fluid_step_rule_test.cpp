// The adaptive coupling step's rule (fluid/fluid_step_rule.hpp).
#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "fluid/fluid_step_rule.hpp"

namespace cfddem::fluid {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// Without forcing the rule is the Courant step cfl / (C + V); with forcing alone it is
// cfl / sqrt(F), and the step from both solves (C + V) dt + F dt^2 / cfl = cfl.
TEST(FluidStepRule, CourantStepWithForcing) {
  EXPECT_DOUBLE_EQ(courant_step({100.0, 50.0, 0.0}, 0.5), 0.5 / 150.0);
  EXPECT_DOUBLE_EQ(courant_step({0.0, 0.0, 1e6}, 0.5), 0.5 / 1e3);
  EXPECT_EQ(courant_step({0.0, 0.0, 0.0}, 0.5), kInf);
  const FluidStepRates r{200.0, 30.0, 4e5};
  const double dt = courant_step(r, 0.9);
  EXPECT_NEAR((r.advection + r.viscous) * dt + r.forcing * dt * dt / 0.9, 0.9, 1e-12);
  // Forcing only shortens the step.
  EXPECT_LT(dt, courant_step({200.0, 30.0, 0.0}, 0.9));
}

TEST(FluidStepRule, CapsGrowthDragTimeAndMaxDt) {
  const FluidStepRates still{0.0, 0.0, 0.0};
  // A gas at rest: fluid.max_dt, or the drag time's fraction where it is shorter.
  EXPECT_EQ(next_fluid_step(still, 0.5, {1e-3, kInf, 0.0}, 1.0), 1e-3);
  EXPECT_EQ(next_fluid_step(still, 0.5, {1e-3, 2e-3, 0.0}, 1.0), kDragStepFraction * 2e-3);
  // After a step of 1e-4 s the next is at most 1.1e-4 s, however long the Courant step.
  EXPECT_DOUBLE_EQ(next_fluid_step(still, 0.5, {1e-3, kInf, 1e-4}, 1.0),
                   kMaxFluidStepGrowth * 1e-4);
  // A shrinking step is not held back.
  EXPECT_DOUBLE_EQ(next_fluid_step({1e4, 0.0, 0.0}, 0.5, {1e-3, kInf, 1e-4}, 1.0), 0.5e-4);
}

// Near the end: the rest when it fits in one step, two equal halves when it fits in two, so no
// step is a sliver of the others.
TEST(FluidStepRule, NoSliverAtTheEnd) {
  const FluidStepRates still{0.0, 0.0, 0.0};
  const FluidStepCaps caps{1e-3, kInf, 0.0};
  EXPECT_EQ(next_fluid_step(still, 0.5, caps, 0.7e-3), 0.7e-3);
  EXPECT_EQ(next_fluid_step(still, 0.5, caps, 1.5e-3), 0.75e-3);
  EXPECT_EQ(next_fluid_step(still, 0.5, caps, 2.5e-3), 1e-3);
  // Walking to the end: every step at least half the cap.
  double left = 3.0001e-3;
  while (left > 0.0) {
    const double dt = next_fluid_step(still, 0.5, caps, left);
    EXPECT_GE(dt, 0.5e-3 * (1 - 1e-12));
    left -= dt;
  }
}

} // namespace
} // namespace cfddem::fluid
