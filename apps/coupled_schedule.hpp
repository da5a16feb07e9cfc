// The schedule of the coupled loops (one rank and R ranks alike): how many particle steps the
// next fluid step takes, and which rows and snapshots fall due at the end of a fluid step (the
// gas is taken then; the next particle step writes them with the synchronised particles).
#pragma once

#include <algorithm>
#include <cmath>

#include "apps/checkpoint.hpp"
#include "apps/coupled_step.hpp"
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

// A fixed fluid.dt, or a sub-iterated scheme (orb, islands: `subiterated`, whose sub-iterations
// divide whatever step the gas takes): n_fixed. Adaptive: as many particle steps of dt as fit
// in the gas's next adaptive step (GasCoupling::adaptive_dt: Courant step with forcing,
// fluid.max_dt, the drag time, 1.1x growth, no end sliver), at least one.
inline long long particle_steps_per_fluid_step(const Scene& scene, const GasCoupling& gas,
                                               long long n_fixed, double dt, double time_left,
                                               bool subiterated = false) {
  if (scene.fluid.dt > 0.0 || subiterated)
    return n_fixed;
  const double want = gas.adaptive_dt(time_left);
  return std::max(1LL, static_cast<long long>(std::floor(want / dt * (1 + 1e-12))));
}

// The length of the next fluid step: n_sub particle steps of dt. With an adaptive gas and no
// particles at all, or a sub-iterated scheme (`subiterated`), the gas's own adaptive step: an
// empty scene's particle step (set from no particle) must not set it, and orb and islands take
// any length in their sub-iterations (set_interval). Collective on R ranks as adaptive_dt() is.
inline double fluid_step_length(const Scene& scene, const GasCoupling& gas, bool no_particles,
                                long long n_sub, double dt, double time_left,
                                bool subiterated = false) {
  if ((no_particles || subiterated) && scene.fluid.dt <= 0.0)
    return gas.adaptive_dt(time_left);
  return static_cast<double>(n_sub) * dt;
}

// At fluid time t (last: the run's end): a row or snapshot that is due takes the gas now
// (collective on R ranks: diagnostics are reduced) and is marked pending.
inline void mark_due_outputs(CoupledLoopState& loop, const GasCoupling& gas, const Scene& scene,
                             double t, bool last, double tol) {
  if (t >= loop.next_output - tol || last) {
    loop.row_fluid = gas.diagnostics();
    loop.row_time = t;
    loop.row_pending = true;
    while (loop.next_output <= t + tol)
      loop.next_output += scene.output.interval;
  }
  if (scene.output.snapshot_interval > 0.0 && (t >= loop.next_snapshot - tol || last)) {
    loop.snapshot_cells = gas.cell_fields();
    loop.row_time = t;
    loop.snapshot_pending = true;
    while (loop.next_snapshot <= t + tol)
      loop.next_snapshot += scene.output.snapshot_interval;
  }
}

} // namespace cfddem::apps
