// The schedule of the coupled loops (one rank and R ranks alike): how many particle steps the
// next fluid step takes, and which rows and snapshots fall due at the end of a fluid step (the
// gas is taken then; the next particle step writes them with the synchronised particles).
#pragma once

#include <algorithm>
#include <cmath>

#include "apps/checkpoint.hpp"
#include "apps/coupled_step.hpp"
#include "core/next_time.hpp"
#include "core/scene.hpp"
#include "dem/step_model.hpp"

namespace cfddem::apps {

// The particles' clock a scheme is built with, as a value (the scene stays as read); n_fixed:
// the particle steps per fixed fluid step of the schedule (0 without a gas). Without a gas, the
// scene's own (dem.dt or dem.dt_factor; dem.regrid_interval). With one the particle steps divide
// the fluid step: explicit takes n_fixed = ceil(dt_f / dt_dem) equal steps of a fixed fluid.dt
// (adaptive: the contact step dt_dem); orb and islands take dem.nsubit sub-iterations of it
// (islands "auto": one step of the schedule, sub-iterated as the scheme chooses), the fluid step
// being their control interval. On an adaptive fluid.dt each step's length reaches them by
// set_interval; they are built for fluid.max_dt, or one fine step per sub-iteration.
template <bool kSubiterated>
dem::StepClock particle_clock(const Scene& scene, double dt_dem, long long& n_fixed) {
  n_fixed = 0;
  if (!scene.fluid.enabled)
    return {};
  const bool fixed = scene.fluid.dt > 0.0;
  if constexpr (kSubiterated) {
    n_fixed = scene.dem.nsubit_auto ? 1 : scene.dem.nsubit;
    return {0.0, fixed                      ? scene.fluid.dt
                 : scene.fluid.max_dt > 0.0 ? scene.fluid.max_dt
                                            : static_cast<double>(n_fixed) * dt_dem};
  } else {
    if (!fixed)
      return {dt_dem, 0.0};
    n_fixed =
        std::max(1LL, static_cast<long long>(std::ceil(scene.fluid.dt / dt_dem * (1 - 1e-12))));
    return {scene.fluid.dt / static_cast<double>(n_fixed), 0.0};
  }
}

// The next fluid step: its particle steps n_sub of dt and its length dt_f.
//  - A fixed fluid.dt: n_fixed steps, dt_f = n_fixed dt.
//  - Adaptive (GasCoupling::adaptive_dt: Courant step with forcing, fluid.max_dt, the drag
//    time, 1.1x growth, no end sliver), explicit: as many steps of dt as fit in the gas's step
//    (at least one), dt_f their sum; orb and islands (`subiterated`): n_fixed, dt_f the gas's
//    step itself (their sub-iterations divide any length, set_interval); no particles at all:
//    one empty step, dt_f the gas's step (an empty scene's particle step must not set it).
// Collective on R ranks when adaptive, as adaptive_dt() is.
struct FluidStepPlan {
  long long n_sub = 1;
  double dt_f = 0.0;
};
inline FluidStepPlan plan_fluid_step(const Scene& scene, const GasCoupling& gas, bool no_particles,
                                     bool subiterated, long long n_fixed, double dt,
                                     double time_left) {
  if (scene.fluid.dt > 0.0)
    return {n_fixed, static_cast<double>(n_fixed) * dt};
  if (no_particles || subiterated)
    return {no_particles ? 1 : n_fixed, gas.adaptive_dt(time_left)};
  const double want = gas.adaptive_dt(time_left);
  const long long n = std::max(1LL, static_cast<long long>(std::floor(want / dt * (1 + 1e-12))));
  return {n, static_cast<double>(n) * dt};
}

// At fluid time t (last: the run's end): a row or snapshot that is due takes the gas now
// (collective on R ranks: diagnostics are reduced) and is marked pending.
inline void mark_due_outputs(CoupledLoopState& loop, const GasCoupling& gas, const Scene& scene,
                             double t, bool last, double tol) {
  if (t >= loop.next_output - tol || last) {
    loop.row_fluid = gas.diagnostics();
    loop.row_time = t;
    loop.row_pending = true;
    loop.next_output = next_time_after(loop.next_output, scene.output.interval, t + tol);
  }
  if (scene.output.snapshot_interval > 0.0 && (t >= loop.next_snapshot - tol || last)) {
    loop.snapshot_cells = gas.cell_fields();
    loop.row_time = t;
    loop.snapshot_pending = true;
    loop.next_snapshot =
        next_time_after(loop.next_snapshot, scene.output.snapshot_interval, t + tol);
  }
}

} // namespace cfddem::apps
