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
// Around it the phases every run goes through once: the checkpoint loaded, dt checked, the
// banner, start or restore, the run directory (diagnostics, snapshots), and at the end run.json
// and the summary. What differs by scheme sits in its adapter (apps/scheme_runs.hpp), what
// differs by rank count in the communicator's size (1 or R) and the adapters' rank parts.
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <HYPRE_utilities.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/column_profiles.hpp"
#include "apps/coupled_schedule.hpp"
#include "apps/gas_side.hpp"
#include "apps/particle_flux.hpp"
#include "apps/particle_inlet.hpp"
#include "apps/run_output.hpp"
#include "apps/run_outputs.hpp"
#include "apps/scheme_runs.hpp"
#include "apps/setting_warnings.hpp"
#include "apps/simulation.hpp"
#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/parallel_env.hpp"
#include "core/phase_timer.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/granular_diagnostics.hpp"

namespace cfddem::apps {

// Steps between two events at a simulated-time interval (0: never).
inline long long steps_every(double interval, double dt) {
  return interval > 0.0 ? std::max(1LL, std::llround(interval / dt)) : 0;
}

template <class Run>
RunResult run_loop(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  const auto t_setup = clock::now();
  const bool gas_on = scene.fluid.enabled;
  // One rank takes the serial communicator (no MPI calls at all), as it always has; R ranks the
  // world. The rank count is known only here, at run time: every branch on it below and in the
  // adapter is outside the schemes' per-particle work.
  const Communicator comm = env.ranks() > 1 ? Communicator::world() : Communicator::serial();
  const bool one = comm.size() == 1, root = comm.rank() == 0;
  const RankParts parts(comm);

  // The checkpoint (every rank reads it: the same error everywhere if it is bad) and this rank's
  // particles.
  std::optional<Checkpoint> ck;
  if (!opt.restart.empty())
    ck = gas_on && !one ? load_checkpoint(scene, opt.restart, gas_block(scene, comm), comm)
                        : load_checkpoint(scene, opt.restart);
  typename Run::Restart share;
  ParticleStore particles = Run::particles(scene, ck, comm, opt.restart, share);
  dem::ParticleRange range;
  const DerivedNumbers derived = parts.derived(scene, particles, comm, range);
  widen_for_inlet(scene, range); // the particle step and cut-offs fit what the inlet adds
  // The particle count: it falls when particles leave through an outflow face.
  std::size_t n_total = one ? particles.size() : derived.particles;
  if (root) // as `cfddem check` warns (apps/main.cpp), now that the particles are known
    for (const std::string& w : step_warnings(scene, derived))
      fmt::print(stderr, "cfddem: warning: {}\n", w);

  // The particles' clock, a value the scheme is built with (the scene stays as read).
  const bool fixed = gas_on && scene.fluid.dt > 0.0;
  long long n_fixed = 0;
  const dem::StepClock step_clock =
      particle_clock<Run::kSub>(scene, parts.step_model(scene, particles, range).dt, n_fixed);
  if (gas_on) {
    static const bool hypre_ready = (HYPRE_Init(), true); // once per process; freed at exit
    (void)hypre_ready;
  }
  PhaseTimer timer;
  // Held in an optional: particles leaving or entering rebuild it on the new set
  // (change_particles, apps/particle_flux.hpp).
  std::optional<Run> run;
  run.emplace(scene, particles, range, comm, timer, step_clock);
  std::optional<GasSide> gas;
  if (gas_on) {
    gas.emplace(scene, comm, Run::kSub);
    if (!one && !Run::kSub)
      run->own_by(gas->box_owners(), false); // explicit: by the gas boxes
    gas->prepare(particles); // the grid, solver and fields: set-up, not the loop's start
  }

  // dt checked against the checkpoint, and the end of the run: a number of particle steps
  // without a gas, a time with one.
  const double dt = run->dt();
  if (ck && ck->dt != dt)
    throw ConfigError(opt.restart,
                      fmt::format("checkpoint {} {:.17g} s differs from the scene's {:.17g} s",
                                  gas_on      ? "particle step"
                                  : Run::kSub ? "dt_sp"
                                              : "dt",
                                  ck->dt, dt));
  const double end = scene.run.end_time;
  const long long n_end = gas_on      ? 0
                          : Run::kSub ? std::max(1LL, std::llround(end / dt))
                                      : derived.steps;
  const long long k0 = ck ? ck->step : 0;
  if (ck && gas_on && ck->loop.time > end + 1e-6 * dt)
    throw ConfigError("run.end_time", fmt::format("the checkpoint is at t = {:.17g} s, past the "
                                                  "end of the run ({:.17g} s)",
                                                  ck->loop.time, end));
  if (ck && !gas_on && k0 > std::max(n_end, 0LL))
    throw ConfigError("run.end_time",
                      Run::kSub ? fmt::format("the checkpoint is at sub-iteration {}, past the end "
                                              "of the run ({})",
                                              k0, n_end)
                                : fmt::format("the checkpoint is at step {}, past the end of the "
                                              "run (step {})",
                                              k0, n_end));

  if (!opt.quiet && root) {
    const std::string restarted =
        !ck      ? std::string()
        : gas_on ? fmt::format(", restarted at t = {:.6e} s from {}", ck->loop.time, opt.restart)
                 : fmt::format(", restarted at {} {} from {}", Run::kStepWord, k0, opt.restart);
    if (gas_on) {
      const auto& c = scene.fluid.cells;
      fmt::print(stderr,
                 "cfddem: scene '{}', {} particles, gas {} x {} x {} cells ({} drag, {} "
                 "deposition), dt_f = {}, {}{}, {} rank(s) x {} thread(s){}\n",
                 scene.name, n_total, c[0], c[1], c[2], scene.fluid.drag, scene.fluid.deposition,
                 fixed ? fmt::format("{:.4e} s", scene.fluid.dt)
                       : fmt::format("adaptive (cfl {})", scene.fluid.cfl),
                 Run::kSub
                     ? fmt::format("dt_sp = {:.4e} s (fine dt = {:.4e} s)", dt, run->fine_dt())
                           : fmt::format("particle dt = {:.4e} s", dt),
                 fixed ? fmt::format(" ({} {} per fluid step)", n_fixed,
                                     Run::kSub ? "sub-iterations" : "steps")
                       : std::string(),
                 env.ranks(), env.threads(), restarted);
    } else {
      fmt::print(stderr, "cfddem: scene '{}', {} particles, {}, {} rank(s) x {} thread(s){}{}\n",
                 scene.name, n_total, run->banner(n_end), env.ranks(), env.threads(),
                 run->banner_tail(), restarted);
    }
  }

  // The loop's wall time starts before start() and the t = 0 outputs, which the phase timer
  // counts too (else phase_seconds.other came out negative).
  const auto t_loop = clock::now();
  // Start or restore. The snapshot at t = 0 with a gas holds the velocities before start()
  // shifts them to the half step: this rank's share, kept here.
  ParticleStore initial;
  if (!ck && gas_on && scene.output.snapshot_interval > 0)
    initial = particles;
  CoupledLoopState loop;
  long long k_last_row = 0;
  { // the start: the scheme's start or restore, the gas's first deposition
    const PhaseTimer::Scope starting(timer, Phase::start);
    if (ck) {
      k_last_row = ck->last_row_step;
      std::optional<std::array<std::vector<double>, 3>> held;
      if (gas_on)
        held = parts.held(*ck, share.taken);
      try {
        run->restore(*ck, share, held ? &*held : nullptr);
      } catch (const std::invalid_argument& e) {
        if (!gas_on || !one)
          throw;
        throw ConfigError(opt.restart, fmt::format("cannot restart: held gas force: {}", e.what()));
      } catch (const RunError& e) {
        if (!gas_on || !one)
          throw;
        throw ConfigError(opt.restart, fmt::format("cannot restart: {}", e.what()));
      }
    } else {
      run->start();
    }
    if (gas) {
      gas->attach(particles, run->owned());
      if (ck)
        gas->restore(*ck, opt.restart, loop);
    }
  }
  // Without a gas the loop's position is the particle step k = loop.fluid_steps; a row or
  // snapshot is due at multiples of its interval and at the end.
  const long long out_every = std::max(1LL, std::llround(scene.output.interval / dt));
  const long long snap_every = steps_every(scene.output.snapshot_interval, dt);
  const long long ckpt_every =
      run->checkpoint_every(steps_every(scene.output.checkpoint_interval, dt));
  auto mark_due_steps = [&](long long k) {
    loop.fluid_steps = k;
    loop.row_pending = k > 0 && (k % out_every == 0 || k == n_end);
    loop.snapshot_pending = k > 0 && snap_every > 0 && (k % snap_every == 0 || k == n_end);
    loop.row_time = static_cast<double>(k) * dt;
  };
  if (!gas_on) {
    mark_due_steps(k0);
  } else if (!ck) {
    loop.next_output = scene.output.interval;
    loop.next_snapshot = scene.output.snapshot_interval;
  }

  // The run directory: diagnostics.csv, snapshots; profiles.csv when the scene asks for it,
  // with the gas part of a row's profiles taken when the row falls due (as its diagnostics).
  RunOutputs out(comm, opt.out_dir, diagnostics_columns(scene.output.contact_census));
  std::optional<ColumnProfiles> profiles;
  std::vector<double> profile_gas;
  if (const auto spec = profile_spec(scene)) {
    profiles.emplace(*spec, gas_on);
    out.open_profiles(
        profiles->columns(),
        ck && !ck->rows.empty() ? std::optional<double>(ck->rows.back()[0]) : std::nullopt,
        ck ? std::filesystem::path(opt.restart).parent_path().string() : std::string());
  }
  auto take_profile_gas = [&] {
    if (profiles && gas)
      profile_gas = profiles->gas_sums(gas->coupling().cell_fields());
  };
  if (ck && loop.row_pending)
    take_profile_gas(); // the restored gas is the gas of the pending row's time
  MeanTracker means;
  CensusColumns census(scene);
  const dem::DomainGeometry geom(scene.domain);
  // A snapshot of every rank's particles (positions wrapped into the periodic box: the schemes
  // wrap only when they rebuild their lists or regrid), with the gas at its time.
  auto snapshot = [&](SnapshotFields f, const CellFields* cells) {
    PhaseTimer::Scope io(timer, Phase::io);
    std::vector<double> w[3];
    const std::span<const double> x[3] = {f.x, f.y, f.z};
    for (int a = 0; a < 3; ++a) {
      w[a].resize(x[a].size());
      for (std::size_t i = 0; i < x[a].size(); ++i)
        w[a][i] = geom.wrap(x[a][i], a);
    }
    f.x = w[0], f.y = w[1], f.z = w[2];
    std::vector<std::int64_t> box;
    if (f.leaf.empty() && !gas_on) {
      box = run->boxes(w[0], w[1], w[2]); // R-rank explicit: its ORB box
      f.leaf = box;
    }
    f.dt = run->fine_dt();
    f.cells = cells;
    out.add_snapshot(f);
  };
  // A row from the synchronised particles of step k (reduced over the ranks).
  auto add_row = [&](double t, long long k, const SyncedParticles& s, const dem::LeafStepStats& ls,
                     const FluidDiagnostics& fd, double wall) {
    PhaseTimer::Scope io(timer, Phase::io);
    const dem::ParticleSpans p{s.x, s.y, s.z, s.vx, s.vy, s.vz, s.mass};
    const auto st = one ? dem::measure(p) : dem::measure(p, comm);
    const RowExtra x =
        one ? means.next(t, s.vx, s.vy, s.vz, fd) : means.next(t, st.mean_velocity, fd);
    const std::vector<double> contacts = census.row(comm, {s.x, s.y, s.z, s.radius, s.mass});
    const ParticleMass mass{st.mass, loop.mass_in, loop.mass_out};
    out.add_row(row(t, k, st, n_total, run->scheme, wall, ls, x, mass, contacts));
    if (profiles)
      out.add_profile_rows(profiles->rows(t, {s.x, s.y, s.z, s.vx, s.vy, s.vz, s.radius, s.mass},
                                          profile_gas, one ? nullptr : &comm));
  };
  if (ck) {
    out.resume(std::move(ck->rows), ck->snapshots);
    if (!out.rows().empty())
      means.resume(out.rows().back());
  } else {
    const std::size_t n = run->owned();
    auto own = [n](const std::vector<double>& v) { return std::span<const double>(v.data(), n); };
    if (gas_on && scene.output.snapshot_interval > 0) {
      const CellFields cells = gas->coupling().cell_fields();
      SnapshotFields f;
      f.x = initial.x, f.y = initial.y, f.z = initial.z, f.vx = initial.vx, f.vy = initial.vy;
      f.vz = initial.vz, f.radius = initial.radius, f.mass = initial.mass, f.id = initial.id;
      snapshot(f, &cells);
      initial = ParticleStore();
    }
    // Row at t = 0. Without a gas, explicit: from the initial velocities (before start()'s
    // half-step shift); with a gas (and orb, islands): the velocities start() left.
    std::vector<double> v0[3];
    const bool shifted = !gas_on && run->initial_velocities(v0);
    SyncedParticles s{own(particles.x),
                      own(particles.y),
                      own(particles.z),
                      own(particles.vx),
                      own(particles.vy),
                      own(particles.vz),
                      own(particles.mass),
                      own(particles.radius),
                      {particles.id.data(), n},
                      {},
                      {}};
    if (shifted)
      s.vx = v0[0], s.vy = v0[1], s.vz = v0[2];
    const dem::LeafStepStats ls0 =
        Run::kSub && !gas_on ? dem::LeafStepStats{} : dem::LeafStepStats{0, 0, 0, 1};
    take_profile_gas();
    add_row(0.0, 0, s, ls0, gas ? gas->coupling().diagnostics() : FluidDiagnostics{}, 0.0);
    if (!gas_on && snap_every > 0) {
      SnapshotFields f;
      f.x = s.x, f.y = s.y, f.z = s.z, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
      f.radius = s.radius, f.mass = s.mass, f.id = s.id;
      snapshot(f, nullptr);
    }
  }

  // One particle step; it writes the row and snapshot pending at its start.
  auto particle_step = [&](bool record, bool snap) {
    long long k = 0;
    const dem::LeafStepStats ls = run->advance(record, record || snap, k_last_row, k);
    if (!record && !snap)
      return;
    const SyncedParticles s = run->synced();
    if (snap) {
      SnapshotFields f;
      f.time = loop.row_time;
      f.step = k;
      f.x = s.x, f.y = s.y, f.z = s.z, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
      f.radius = s.radius, f.mass = s.mass, f.id = s.id, f.leaf = s.leaf, f.local_dt = s.local_dt;
      snapshot(f, gas_on ? &loop.snapshot_cells : nullptr);
    }
    if (record) {
      add_row(loop.row_time, k, s, ls, loop.row_fluid, seconds_since(t_loop));
      k_last_row = k;
    }
  };
  const ParticleFlux flux(scene);


  // A checkpoint between two outer steps: rank 0's header, the particles and scheme state
  // (gathered to rank 0 in id order on R ranks), and with a gas its state and the loop's.
  auto checkpoint = [&] {
    PhaseTimer::Scope io(timer, Phase::io);
    Checkpoint c;
    if (root)
      c = checkpoint_header(scene, Run::kName, dt, loop.fluid_steps, k_last_row, out.rows(),
                            out.snapshots());
    run->save(c, comm); // collective
    if (gas)
      gas->write_checkpoint(out.checkpoint_path(loop.fluid_steps), std::move(c), particles, loop);
    else
      out.write_checkpoint(loop.fluid_steps, c);
  };

  // A restart's counters continue those of the run it continues: the rates and the closing line
  // count the work of this run (they said "600 fluid steps" when 400 were run).
  const long long fluid_steps_before = gas_on ? loop.fluid_steps : 0;
  const std::int64_t particle_steps_before = run->scheme.particle_steps();
  double& t = loop.time;
  const double tol = 1e-6 * dt;
  // With a gas: checkpoints at the fluid times that are multiples of the interval, after the
  // restart time.
  const double ckpt_interval = scene.output.checkpoint_interval;
  double next_ckpt = ckpt_interval > 0.0
                         ? (std::floor(t / ckpt_interval + 1e-6) + 1.0) * ckpt_interval
                         : std::numeric_limits<double>::infinity();
  long long last_n_sub = 0;
  auto last_progress = clock::now();
  while (gas_on ? end - t > tol : loop.fluid_steps < n_end) {
    long long n_sub = 1;
    double dt_f = 0.0;
    if (gas) {
      {
        PhaseTimer::Scope fl(timer, Phase::fluid);
        if (auto owners = gas->regrid(particles, run->owned(), t, tol, last_n_sub))
          run->own_by(std::move(*owners), true);
      }
      const FluidStepPlan next =
          plan_fluid_step(scene, gas->coupling(), n_total == 0, Run::kSub, n_fixed, dt, end - t);
      n_sub = last_n_sub = next.n_sub;
      dt_f = next.dt_f;
      if (flux.on()) { // particles through the open faces (apps/particle_flux.hpp)
        const std::int64_t change = change_particles(flux, run, scene, particles, range, comm,
                                                     timer, step_clock, loop, dt_f);
        n_total = static_cast<std::size_t>(static_cast<std::int64_t>(n_total) + change);
      }
      if constexpr (Run::kSub)
        if (!fixed)
          run->set_interval(dt_f); // the sub-iterations divide this step
      PhaseTimer::Scope fl(timer, Phase::fluid);
      run->hold_gas_force(gas->step(particles, run->owned(), dt_f));
    }
    // dem.nsubit = "auto": the outer step (dt, a control interval) in the chosen sub-iterations
    // (after the gas force: its change bounds them).
    if (run->auto_length())
      n_sub = run->begin_interval();
    for (long long q = 0; q < n_sub; ++q) {
      particle_step(q == 0 && loop.row_pending, q == 0 && loop.snapshot_pending);
      if (q == 0)
        loop.row_pending = loop.snapshot_pending = false;
    }
    bool checkpoint_due = false;
    if (gas) {
      ++loop.fluid_steps;
      loop.dt_f_sum += dt_f;
      // A fixed step counts steps (no drift of a running sum against the output times).
      t = fixed ? static_cast<double>(loop.fluid_steps) * scene.fluid.dt : t + dt_f;
      {
        PhaseTimer::Scope io(timer, Phase::io);
        mark_due_outputs(loop, gas->coupling(), scene, t, end - t <= tol, tol);
        if (loop.row_pending)
          take_profile_gas();
      }
      checkpoint_due = t >= next_ckpt - tol;
      while (checkpoint_due && next_ckpt <= t + tol)
        next_ckpt += ckpt_interval;
    } else {
      mark_due_steps(loop.fluid_steps + 1);
      checkpoint_due = ckpt_every > 0 && loop.fluid_steps % ckpt_every == 0;
    }
    if (checkpoint_due)
      checkpoint();
    if (!opt.quiet && root && (Run::kSub || gas_on || (loop.fluid_steps & 63) == 0) &&
        std::chrono::duration<double>(clock::now() - last_progress).count() >=
            scene.output.progress_seconds) {
      last_progress = clock::now();
      const double wall = seconds_since(t_loop);
      const double frac =
          gas_on ? t / end : static_cast<double>(loop.fluid_steps) / static_cast<double>(n_end);
      const std::string eta = format_eta(wall * (1 - frac) / std::max(frac, 1e-12));
      if (gas_on)
        fmt::print(stderr,
                   "fluid step {:>8} t = {:.6e} s ({:5.1f}%)  fluid {:.0f}% of wall  ETA {}\n",
                   loop.fluid_steps, t, 100 * frac, 100 * timer.seconds(Phase::fluid) / wall, eta);
      else
        fmt::print(stderr, "{}\n", run->progress(loop.fluid_steps, frac, wall, eta));
    }
  }
  // One particle step past the end completes the last row (with "auto" a short one: the state
  // it records is at its start).
  if (loop.row_pending || loop.snapshot_pending) {
    run->begin_completion();
    particle_step(loop.row_pending, loop.snapshot_pending);
  }
  const double loop_seconds = seconds_since(t_loop);

  // run.json (rank 0) and the summary. Collective: the per-rank figures are gathered first.
  const auto& sch = run->scheme;
  const std::int64_t particle_steps_run = sch.particle_steps() - particle_steps_before;
  const long long fluid_steps_run = loop.fluid_steps - fluid_steps_before;
  const double pss =
      loop_seconds > 0 ? static_cast<double>(particle_steps_run) / loop_seconds : 0.0;
  nlohmann::ordered_json j = run_json_header(scene, scene.name, derived, env, n_total);
  j["scheme"] = Run::kName;
  if (!one)
    j["distributed"] = true;
  run->describe(j, out.rows());
  if (gas)
    gas->describe(j, loop, fluid_steps_run, loop_seconds, timer.seconds(Phase::fluid)); // coll.
  j["end_time"] = gas_on ? t : static_cast<double>(n_end) * dt;
  j["loop_seconds"] = loop_seconds;
  if (census.enabled()) {
    j["census_seconds"] = census.seconds();
    j["census_definition"] = "rank 0's wall time in the contact census of the diagnostics rows "
                             "(output.contact_census; part of phase_seconds.io and loop_seconds)";
  }
  j["setup_seconds"] = std::chrono::duration<double>(t_loop - t_setup).count();
  nlohmann::ordered_json ph = phase_json(timer, loop_seconds);
  const char* note = run->phase_note();
  if (gas_on)
    note = one ? "fluid: deposition, gas step (predictor, projection), interpolation and particle "
                 "forces; neighbor + regrid + force: the particle sub-cycle"
               : "rank 0's phases; fluid: deposition, gas step (predictor, projection over the "
                 "ranks), interpolation and particle forces (with orb: and the routing of the "
                 "particles to the gas boxes and of their forces back); neighbor + regrid + force: "
                 "the particle sub-cycle";
  if (note)
    ph["note"] = note;
  j["phase_seconds"] = ph;
  add_work_counters(j, sch, loop_seconds, run->force_definition(), particle_steps_before);
  double wait_max = 0.0;
  if (!one) {
    const std::vector<double> waits = comm.gather(comm.wait_seconds());
    for (const double w : waits)
      wait_max = std::max(wait_max, w);
    j["mpi_wait_seconds"] = waits;
    j["mpi_wait_definition"] = "per rank: wall time inside MPI calls (reductions, the parallel "
                               "ORB, particle and ghost exchanges), set-up included";
    j["owned_particles_at_end"] = comm.gather(static_cast<double>(run->owned()));
    if (!gas_on) {
      j["busy_seconds"] = comm.gather(timer.rebuild_seconds() + timer.seconds(Phase::force) +
                                      timer.seconds(Phase::integrate));
      j["busy_definition"] =
          "per rank: neighbor + regrid + force + integrate phases (rebuilds with their "
          "exchanges, forces, updates); their spread is the load imbalance in "
          "time";
    }
    const auto work = parts.local_work(sch);
    j["rank_counts"] = rank_counts_json(comm, work[0], work[1], gas ? gas->cell_updates() : 0);
    if (!gas_on)
      run->describe_balance(j);
  }
  out.write_run_json(j);

  if (!opt.quiet && root) {
    const double fluid = timer.seconds(Phase::fluid);
    if (!gas_on) {
      fmt::print(stderr,
                 "Loop time of {:.4g} s on {} rank(s) x {} thread(s) for {} {} with {} "
                 "particles ({} to run.end_time and one that completes the last row)\n",
                 loop_seconds, env.ranks(), env.threads(), run->steps(), Run::kStepsWord, n_total,
                 n_end);
      fmt::print(stderr, "{}\n", run->performance(timer, pss, wait_max));
    } else if (one) {
      fmt::print(
          stderr,
          "Loop time of {:.4g} s for {} fluid steps ({:.4g} s each) and {} particle "
          "steps with {} particles; fluid {:.3g} s ({:.0f}%), particles {:.3g} s\n",
          loop_seconds, fluid_steps_run, j["wall_seconds_per_fluid_step"].get<double>(),
          static_cast<long long>(particle_steps_run /
                                 std::max<std::int64_t>(1, static_cast<std::int64_t>(n_total))),
          n_total, fluid, 100 * fluid / std::max(loop_seconds, 1e-300),
          timer.rebuild_seconds() + timer.seconds(Phase::force));
    } else {
      fmt::print(stderr,
                 "Loop time of {:.4g} s for {} fluid steps on {} rank(s) x {} thread(s) "
                 "with {} particles; fluid {:.3g} s ({:.0f}%) on rank 0\n",
                 loop_seconds, fluid_steps_run, env.ranks(), env.threads(), n_total, fluid,
                 100 * fluid / std::max(loop_seconds, 1e-300));
    }
  }
  return {opt.out_dir, loop_seconds, run->steps(), sch.particle_steps()};
}

} // namespace cfddem::apps
