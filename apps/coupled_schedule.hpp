// The schedule of the coupled loops (one rank and R ranks alike): how many particle steps the
// next fluid step takes, and which rows and snapshots fall due at the end of a fluid step (the
// gas is taken then; the next particle step writes them with the synchronised particles).
#pragma once

#include <algorithm>
#include <cmath>

#include "apps/checkpoint.hpp"
#include "apps/coupled_step.hpp"
#include "core/scene.hpp"

namespace cfddem::apps {

// A fixed fluid.dt, or a sub-iterated scheme (orb, islands: `subiterated`, whose sub-iterations
// divide whatever step the gas takes): n_fixed. Adaptive: as many particle steps of dt as fit
// in the gas's next adaptive step (GasCoupling::adaptive_dt: Courant step with forcing,
// fluid.max_dt, the drag time, 1.1x growth, no end sliver), at least one.
inline long long particle_steps_per_fluid_step(const Scene& scene, const GasCoupling& gas,
                                               long long n_fixed, double dt, double time_left,
                                               bool subiterated = false) {
  if (scene.fluid.dt > 0.0 || subiterated) return n_fixed;
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
    while (loop.next_output <= t + tol) loop.next_output += scene.output.interval;
  }
  if (scene.output.snapshot_interval > 0.0 && (t >= loop.next_snapshot - tol || last)) {
    loop.snapshot_cells = gas.cell_fields();
    loop.row_time = t;
    loop.snapshot_pending = true;
    while (loop.next_snapshot <= t + tol) loop.next_snapshot += scene.output.snapshot_interval;
  }
}

} // namespace cfddem::apps
