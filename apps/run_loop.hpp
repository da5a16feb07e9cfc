// The one time loop of a run, for every scheme and rank count, with the gas optional: the
// paper's Algorithm 1. Per outer step (a fluid step of dt_f with a gas, one particle step
// without):
//   1. with a gas: deposit, gas step and particle force (GasSide::step), held by the scheme;
//   2. the particle sub-cycle: n_sub particle steps (explicit: steps of dt, n_sub =
//      ceil(dt_f / dt_dem); orb and islands: sub-iterations of dt_sp = dt_f / dem.nsubit;
//      islands with dem.nsubit = "auto": the outer step is a control interval, without a gas
//      dem.regrid_interval, taken in the sub-iterations the scheme chose for it);
//   3. the rows and snapshots that fall due at the step's end are marked: the gas is taken then,
//      and the next particle step writes them with the synchronised particles (the state at t
//      needs the forces at t), so the loop ends with one particle step past the end;
//   4. checkpoints at their interval, before the next step.
// Each phase is a named member of TimeLoop (apps/time_loop.hpp); what differs by scheme sits in
// its adapter (apps/scheme_runs.hpp).
#pragma once

#include "apps/time_loop.hpp"

namespace cfddem::apps {

template <class Run>
RunResult run_loop(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  TimeLoop<Run> loop(scene, opt, env); // checkpoint, particles, particle clock, scheme, gas
  loop.print_banner();
  loop.start(); // start or restore; the run directory and the outputs at t = 0
  while (!loop.at_end())
    loop.outer_step(); // gas step, particle sub-cycle, outputs due, checkpoint
  loop.complete_last_row();
  return loop.report(); // run.json and the summary
}

} // namespace cfddem::apps
