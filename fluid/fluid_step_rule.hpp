// The adaptive coupling step dt_f (fluid.dt = 0; docs/gas_step.md "The adaptive fluid step"):
// MFIX-Exa's rule (src/timestepping/mfix_compute_dt.cpp, after Almgren et al. 1998, J. Comput.
// Phys. 142, §4) with the caps a coupled step needs. Pure functions of a few rates.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string_view>

namespace cfddem::fluid {

// At most this factor of growth from one fluid step to the next (MFIX-Exa's dt_change_max): a
// step that jumps from a short start to the Courant step would jump the gas's time error too.
inline constexpr double kMaxFluidStepGrowth = 1.1;

// dt_f at most this fraction of the smallest particle relaxation time m_i / beta_i. The drag
// force is held over dt_f with v_i frozen (forward Euler on the drag relaxation), which is
// stable below 2 tau_p; its error per step is about dt_f / (2 tau_p), 5% here, and it does not
// accumulate at a steady slip.
inline constexpr double kDragStepFraction = 0.1;

// The most gas sub-steps one interval (fluid step) may take. The Courant rule at fluid.cfl sets
// their count; beyond this the interval would not end in any useful time: a tiny fluid.cfl
// (1e-9 on hcs_gas once its particles set the gas moving: 3.8e8 a fluid step), or a gas whose
// speed has run away. The set-up refuses what it can foresee from the scene's speeds
// (apps/gas_check.hpp); GasSolver::advance stops on what it meets.
inline constexpr double kMaxSubstepsPerInterval = 1e5;

// The gas's advection in time (fluid.advection): the single-stage Godunov step with time-centred
// edge states (fluid/momentum_rhs.hpp, godunov_momentum_rhs), or the method of lines, limited
// MUSCL edge states at t^n in an Euler or Heun step (GasSolverSettings::time_order).
enum class Advection { godunov, mol };

// The scheme a scene's fluid.advection names ("mol"; else, as the key's choices allow only the
// two, "godunov").
[[nodiscard]] constexpr Advection advection_named(std::string_view name) {
  return name == "mol" ? Advection::mol : Advection::godunov;
}

// The largest stable Courant number of each (as advective_rate measures it): 0.5 is the TVD
// limit of limited MUSCL with explicit (SSP) Euler stages on the sum of the axes' Courant
// numbers c_a = max|u_a| dt / dx_a. The Godunov step is linearly stable (von Neumann analysis of
// its unlimited form, docs/gas_step.md) where max(max_a c_a, sum_a c_a / 1.25) <= 0.95: the max
// binds on flow along an axis (1 alone), the sum on diagonal flow in 3D (the sum alone allows
// 1.5 there, but 1.29 where one axis's c_a is 0.93).
inline constexpr double kMaxMolCourant = 0.5;
inline constexpr double kMaxGodunovCourant = 0.95;
inline constexpr double kGodunovCourantSum = 1.25;
[[nodiscard]] constexpr double max_stable_courant(Advection advection) {
  return advection == Advection::godunov ? kMaxGodunovCourant : kMaxMolCourant;
}

// The advective Courant rate [1/s] of per-axis rates r_a = max|u_a| / dx_a, whose product with
// dt is held below max_stable_courant: sum_a r_a for the method of lines, max(max_a r_a,
// sum_a r_a / 1.25) for Godunov (both of its bounds at once). The axes are added in order x, y, z.
[[nodiscard]] inline double advective_rate(const std::array<double, 3>& rate, Advection advection) {
  const double sum = rate[0] + rate[1] + rate[2];
  if (advection == Advection::mol) {
    return sum;
  }
  return std::max({rate[0], rate[1], rate[2], sum / kGodunovCourantSum});
}

// What bounds the gas's step, per second: the advective rate C (advective_rate), the
// viscous rate V = 2 nu sum_a 1/dx_a^2 (0 when the Laplacian is implicit) and the forcing
// F = sum_a |f_a| / dx_a [1/s^2] of the body force per unit mass f.
struct FluidStepRates {
  double advection = 0.0;
  double viscous = 0.0;
  double forcing = 0.0;
};

// The rates of the largest face speed per axis, on cells of `spacing`, with kinematic viscosity
// nu (counted only when the Laplacian is explicit) and the body force per unit mass `body`
// (gravity less the background pressure gradient over rho_g). The axes are added in order x, y, z.
[[nodiscard]] inline FluidStepRates fluid_step_rates(const std::array<double, 3>& max_speed,
                                                     const std::array<double, 3>& spacing,
                                                     double nu, bool viscous_explicit,
                                                     const std::array<double, 3>& body,
                                                     Advection advection = Advection::mol) {
  FluidStepRates r;
  std::array<double, 3> advective{};
  for (std::size_t a = 0; a < 3; ++a) {
    const double dx = spacing[a];
    advective[a] = max_speed[a] / dx;
    if (viscous_explicit) {
      r.viscous += 2.0 * nu / (dx * dx);
    }
    r.forcing += std::abs(body[a]) / dx;
  }
  r.advection = advective_rate(advective, advection);
  return r;
}

// The step at Courant number `cfl` with the forcing: 2 cfl / (C + V + sqrt((C + V)^2 + 4 F))
// (MFIX-Exa); from rest it is cfl sqrt(dx / |f|), a fraction of the time a parcel takes to cross
// a cell from rest. Infinite for a gas at rest with no force.
[[nodiscard]] inline double courant_step(const FluidStepRates& r, double cfl) {
  const double b = r.advection + r.viscous;
  const double denominator = b + std::sqrt(b * b + 4.0 * r.forcing);
  return denominator > 0.0 ? 2.0 * cfl / denominator : std::numeric_limits<double>::infinity();
}

struct FluidStepCaps {
  double max_dt = std::numeric_limits<double>::infinity();     // fluid.max_dt
  double drag_time = std::numeric_limits<double>::infinity();  // min_i m_i / beta_i [s]
  double previous = 0.0; // the last fluid step (0: none yet, no growth cap)
};

// The next dt_f from `time_left` to the end of the run: the Courant step with the forcing,
// capped by fluid.max_dt, kDragStepFraction of the drag time and kMaxFluidStepGrowth of the
// previous step; where less than two such steps are left, the rest in two equal halves (no
// sliver of a step at the end, whose short interval would stand out in the gas's and the
// particles' errors), and where less than one is left, the rest.
[[nodiscard]] inline double next_fluid_step(const FluidStepRates& r, double cfl,
                                            const FluidStepCaps& caps, double time_left) {
  double dt = std::min({courant_step(r, cfl), caps.max_dt, kDragStepFraction * caps.drag_time});
  if (caps.previous > 0.0) {
    dt = std::min(dt, kMaxFluidStepGrowth * caps.previous);
  }
  if (time_left <= dt * (1.0 + 1e-12)) {
    return time_left;
  }
  if (time_left < 2.0 * dt) {
    return 0.5 * time_left;
  }
  return dt;
}

} // namespace cfddem::fluid
