// The parts of the one time loop (apps/run_loop.hpp), for every scheme and rank count, with the
// gas optional. A TimeLoop holds what a run holds between its phases: the checkpoint it
// restarts, this rank's particles, the scheme's adapter (apps/scheme_runs.hpp), the gas side,
// the loop's position (CoupledLoopState), the run directory and the phase timer. Each phase of
// run_loop is one named member:
//   TimeLoop(...)        set-up: the checkpoint read and checked, the particles, the particles'
//                        clock (a value the scheme is built with: the scene stays as read), the
//                        scheme and the gas's grid and solver;
//   print_banner()       the run's first line;
//   start()              the scheme's start or restore, the gas's first deposition, the run
//                        directory and the outputs at t = 0 (or the restored rows);
//   outer_step()         one fluid step (one particle step without a gas): the gas step and the
//                        particle force, the particle sub-cycle, the outputs that fall due at its
//                        end, a checkpoint at its interval, the progress line;
//   complete_last_row()  one particle step past the end writes the last row;
//   report()             run.json and the summary.
// What differs by scheme sits in the adapter, what differs by rank count in the communicator's
// size (1 or R) and the adapters' rank parts.
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <limits>
#include <optional>
#include <ranges>
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
#include "core/next_time.hpp"
#include "core/parallel_env.hpp"
#include "core/phase_timer.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/granular_diagnostics.hpp"

namespace cfddem::apps {

// Steps between two events at a simulated-time interval (0: never).
inline long long steps_every(double interval, double dt) {
  return interval > 0.0 ? std::max(1LL, std::llround(interval / dt)) : 0;
}

template <class Run> class TimeLoop {
public:
  // Set-up: everything before the loop's clock starts (run.json setup_seconds).
  TimeLoop(const Scene& scene, const RunOptions& opt, const ParallelEnv& env)
      : scene_(scene), opt_(opt), env_(env), gas_on_(scene.fluid.enabled),
        // One rank takes the serial communicator (no MPI calls at all), R ranks the world. The
        // rank count is known only here, at run time: every branch on it below and in the
        // adapter is outside the schemes' per-particle work.
        comm_(env.ranks() > 1 ? Communicator::world() : Communicator::serial()),
        one_(comm_.size() == 1), root_(comm_.rank() == 0), parts_(comm_), census_(scene),
        geom_(scene.domain), flux_(scene) {
    read_checkpoint_and_particles();
    build_scheme_and_gas();
    check_against_checkpoint();
  }
  TimeLoop(const TimeLoop&) = delete; // the outputs, scheme and gas hold references into it
  TimeLoop& operator=(const TimeLoop&) = delete;

  void print_banner() const;
  void start();
  bool at_end() const {
    return gas_on_ ? !(end_ - loop_.time > tol_) : !(loop_.fluid_steps < n_end_);
  }
  void outer_step();
  void complete_last_row();
  RunResult report();

private:
  void read_checkpoint_and_particles();
  void build_scheme_and_gas();
  void check_against_checkpoint() const;
  void start_or_restore();
  void schedule_outputs();
  void open_outputs(ParticleStore& initial);
  FluidStepPlan gas_step(); // the step's length: n_sub particle steps in dt_f
  bool advance_clock(double dt_f);
  bool progress_due();
  void print_progress();
  void print_substep_progress(int count, double t, double dt, double dt_f);
  void mark_due_steps(long long k);
  void take_profile_gas();
  void particle_step(bool record, bool snap);
  void write_snapshot(SnapshotFields f, const CellFields* cells);
  void add_row(double t, long long k, const SyncedParticles& s, const dem::LeafStepStats& ls,
               const FluidDiagnostics& fd, double wall);
  void write_checkpoint();
  nlohmann::ordered_json run_json(double loop_seconds, double& wait_max) const;
  void print_summary(double loop_seconds, const nlohmann::ordered_json& j, double wait_max) const;
  double inlet_mass_waiting() const;
  void warn_inlet_behind() const;

  const Scene& scene_;
  const RunOptions& opt_;
  const ParallelEnv& env_;
  const clock::time_point t_setup_ = clock::now();
  const bool gas_on_;
  const Communicator comm_;
  const bool one_, root_;
  const RankParts parts_;

  std::optional<Checkpoint> ck_;
  typename Run::Restart share_;
  ParticleStore particles_;
  dem::ParticleRange range_;
  DerivedNumbers derived_;
  std::size_t n_total_ = 0; // falls when particles leave through an outflow face
  bool fixed_ = false;      // a fixed fluid step
  long long n_fixed_ = 0;   // particle steps per fixed fluid step
  dem::StepClock step_clock_;
  PhaseTimer timer_;
  // Held in an optional: particles leaving or entering rebuild it on the new set
  // (change_particles, apps/particle_flux.hpp).
  std::optional<Run> run_;
  std::optional<GasSide> gas_;
  double dt_ = 0.0, end_ = 0.0, tol_ = 0.0;
  long long n_end_ = 0, k0_ = 0;

  clock::time_point t_loop_, last_progress_;
  CoupledLoopState loop_;
  long long k_last_row_ = 0;
  long long out_every_ = 1, snap_every_ = 0, ckpt_every_ = 0;
  double ckpt_interval_ = 0.0, next_ckpt_ = std::numeric_limits<double>::infinity();
  // A restart's counters continue those of the run it continues: the rates and the closing line
  // count the work of this run.
  long long fluid_steps_before_ = 0;
  std::int64_t particle_steps_before_ = 0;

  std::optional<RunOutputs> out_; // the run directory, created once the start has succeeded
  std::optional<ColumnProfiles> profiles_;
  std::vector<double> profile_gas_;
  MeanTracker means_;
  CensusColumns census_;
  const dem::DomainGeometry geom_;
  const ParticleFlux flux_;
};

// The checkpoint (every rank reads it: the same error everywhere if it is bad), this rank's
// particles, the derived numbers and the range the particle step is chosen over.
template <class Run> void TimeLoop<Run>::read_checkpoint_and_particles() {
  if (!opt_.restart.empty())
    ck_ = gas_on_ && !one_
              ? load_checkpoint(scene_, opt_.restart, gas_block(scene_, comm_), comm_)
              : load_checkpoint(scene_, opt_.restart);
  particles_ = Run::particles(scene_, ck_, comm_, opt_.restart, share_);
  derived_ = parts_.derived(scene_, particles_, comm_, range_);
  widen_for_inlet(scene_, range_); // the particle step and cut-offs fit what the inlet adds
  n_total_ = one_ ? particles_.size() : derived_.particles;
  if (root_) // as `cfddem check` warns (apps/main.cpp), now that the particles are known
    for (const std::string& w : step_warnings(scene_, derived_))
      fmt::print(stderr, "cfddem: warning: {}\n", w);
}

// The particles' clock (a value the scheme is built with), the scheme, and the gas's grid,
// solver and fields (set-up, not the loop's start).
template <class Run> void TimeLoop<Run>::build_scheme_and_gas() {
  fixed_ = gas_on_ && scene_.fluid.dt > 0.0;
  step_clock_ = particle_clock<Run::kSub>(
      scene_, parts_.step_model(scene_, particles_, range_).dt, n_fixed_);
  if (gas_on_) {
    static const bool hypre_ready = (HYPRE_Init(), true); // once per process; freed at exit
    (void)hypre_ready;
  }
  run_.emplace(scene_, particles_, range_, comm_, timer_, step_clock_);
  if (gas_on_) {
    // A restart on R ranks goes on from the gas boxes its checkpoint was written from.
    gas_.emplace(scene_, comm_, Run::kSub, ck_ ? ck_->gas_boxes : std::vector<CellBox>{});
    if (!one_ && !Run::kSub)
      run_->own_by(gas_->box_owners(), false); // explicit: by the gas boxes
    gas_->prepare(particles_);
    if (!opt_.quiet && root_) // a fluid step of many gas sub-steps shows its progress too
      gas_->coupling().observe_substeps([this](int count, double t, double dt, double dt_f) {
        print_substep_progress(count, t, dt, dt_f);
      });
  }
  // The end of the run: a number of particle steps without a gas, a time with one.
  dt_ = run_->dt();
  tol_ = 1e-6 * dt_;
  end_ = scene_.run.end_time;
  n_end_ = gas_on_      ? 0
           : Run::kSub ? std::max(1LL, std::llround(end_ / dt_))
                       : derived_.steps;
  k0_ = ck_ ? ck_->step : 0;
}

// The checkpoint's step length and position against the scene's.
template <class Run> void TimeLoop<Run>::check_against_checkpoint() const {
  if (!ck_)
    return;
  if (ck_->dt != dt_)
    throw ConfigError(opt_.restart,
                      fmt::format("checkpoint {} {:.17g} s differs from the scene's {:.17g} s",
                                  gas_on_     ? "particle step"
                                  : Run::kSub ? "dt_sp"
                                              : "dt",
                                  ck_->dt, dt_));
  if (gas_on_ && ck_->loop.time > end_ + 1e-6 * dt_)
    throw ConfigError("run.end_time", fmt::format("the checkpoint is at t = {:.17g} s, past the "
                                                  "end of the run ({:.17g} s)",
                                                  ck_->loop.time, end_));
  if (!gas_on_ && k0_ > std::max(n_end_, 0LL))
    throw ConfigError("run.end_time",
                      Run::kSub ? fmt::format("the checkpoint is at sub-iteration {}, past the end "
                                              "of the run ({})",
                                              k0_, n_end_)
                                : fmt::format("the checkpoint is at step {}, past the end of the "
                                              "run (step {})",
                                              k0_, n_end_));
}

template <class Run> void TimeLoop<Run>::print_banner() const {
  if (opt_.quiet || !root_)
    return;
  const std::string restarted =
      !ck_      ? std::string()
      : gas_on_ ? fmt::format(", restarted at t = {:.6e} s from {}", ck_->loop.time, opt_.restart)
                : fmt::format(", restarted at {} {} from {}", Run::kStepWord, k0_, opt_.restart);
  if (gas_on_) {
    const auto& c = scene_.fluid.cells;
    fmt::print(stderr,
               "cfddem: scene '{}', {} particles, gas {} x {} x {} cells ({} drag, {} "
               "deposition), dt_f = {}, {}{}, {} rank(s) x {} thread(s){}\n",
               scene_.name, n_total_, c[0], c[1], c[2], scene_.fluid.drag, scene_.fluid.deposition,
               fixed_ ? fmt::format("{:.4e} s", scene_.fluid.dt)
                      : fmt::format("adaptive (cfl {})", scene_.fluid.cfl),
               Run::kSub ? fmt::format("dt_sp = {:.4e} s (fine dt = {:.4e} s)", dt_,
                                       run_->fine_dt())
                         : fmt::format("particle dt = {:.4e} s", dt_),
               fixed_ ? fmt::format(" ({} {} per fluid step)", n_fixed_,
                                    Run::kSub ? "sub-iterations" : "steps")
                      : std::string(),
               env_.ranks(), env_.threads(), restarted);
  } else {
    fmt::print(stderr, "cfddem: scene '{}', {} particles, {}, {} rank(s) x {} thread(s){}{}\n",
               scene_.name, n_total_, run_->banner(n_end_), env_.ranks(), env_.threads(),
               run_->banner_tail(), restarted);
  }
}

// The loop's wall time starts before the start and the t = 0 outputs, which the phase timer
// counts too (else phase_seconds.other came out negative).
template <class Run> void TimeLoop<Run>::start() {
  t_loop_ = clock::now();
  // The snapshot at t = 0 with a gas holds the velocities before start() shifts them to the half
  // step: this rank's share, kept here.
  ParticleStore initial;
  if (!ck_ && gas_on_ && scene_.output.snapshot_interval > 0)
    initial = particles_;
  start_or_restore();
  schedule_outputs();
  open_outputs(initial);
  // A restart at the end of a run with a gas: no fluid step comes to mark the row at the end,
  // which every run writes (without a gas mark_due_steps marked it), so the diagnostics ended
  // at the last row before the checkpoint.
  if (ck_ && gas_on_ && at_end()) {
    mark_due_outputs(loop_, gas_->coupling(), scene_, loop_.time, true, tol_);
    if (loop_.row_pending)
      take_profile_gas();
  }
  fluid_steps_before_ = gas_on_ ? loop_.fluid_steps : 0;
  particle_steps_before_ = run_->scheme.particle_steps();
  // With a gas: checkpoints at the fluid times that are multiples of the interval, after the
  // restart time.
  ckpt_interval_ = scene_.output.checkpoint_interval;
  if (ckpt_interval_ > 0.0)
    next_ckpt_ = multiple_after(loop_.time, ckpt_interval_, 1e-6);
  last_progress_ = clock::now();
}

// The scheme's start or restore, the gas's first deposition (or its restored state).
template <class Run> void TimeLoop<Run>::start_or_restore() {
  const PhaseTimer::Scope starting(timer_, Phase::start);
  if (ck_) {
    k_last_row_ = ck_->last_row_step;
    std::optional<std::array<std::vector<double>, 3>> held;
    if (gas_on_)
      held = parts_.held(*ck_, share_.taken);
    try {
      run_->restore(*ck_, share_, held ? &*held : nullptr);
    } catch (const std::invalid_argument& e) {
      if (!gas_on_ || !one_)
        throw;
      throw ConfigError(opt_.restart, fmt::format("cannot restart: held gas force: {}", e.what()));
    } catch (const RunError& e) {
      if (!gas_on_ || !one_)
        throw;
      throw ConfigError(opt_.restart, fmt::format("cannot restart: {}", e.what()));
    }
  } else {
    run_->start();
  }
  if (gas_) {
    gas_->attach(particles_, run_->owned());
    if (ck_)
      gas_->restore(*ck_, opt_.restart, loop_);
  }
}

// Without a gas the loop's position is the particle step k = loop.fluid_steps; a row or
// snapshot is due at multiples of its interval and at the end. With one, at fluid times.
template <class Run> void TimeLoop<Run>::schedule_outputs() {
  out_every_ = std::max(1LL, std::llround(scene_.output.interval / dt_));
  snap_every_ = steps_every(scene_.output.snapshot_interval, dt_);
  ckpt_every_ = run_->checkpoint_every(steps_every(scene_.output.checkpoint_interval, dt_));
  if (!gas_on_) {
    mark_due_steps(k0_);
  } else if (!ck_) {
    loop_.next_output = scene_.output.interval;
    loop_.next_snapshot = scene_.output.snapshot_interval;
  }
}

template <class Run> void TimeLoop<Run>::mark_due_steps(long long k) {
  loop_.fluid_steps = k;
  loop_.row_pending = k > 0 && (k % out_every_ == 0 || k == n_end_);
  loop_.snapshot_pending = k > 0 && snap_every_ > 0 && (k % snap_every_ == 0 || k == n_end_);
  loop_.row_time = static_cast<double>(k) * dt_;
}

// The run directory: diagnostics.csv, snapshots; profiles.csv when the scene asks for it, with
// the gas part of a row's profiles taken when the row falls due (as its diagnostics). A restart
// resumes the checkpoint's rows; a fresh run writes the row (and snapshot) at t = 0.
template <class Run> void TimeLoop<Run>::open_outputs(ParticleStore& initial) {
  out_.emplace(comm_, opt_.out_dir, diagnostics_columns(scene_.output.contact_census));
  if (const auto spec = profile_spec(scene_)) {
    profiles_.emplace(*spec, gas_on_);
    out_->open_profiles(
        profiles_->columns(),
        ck_ && !ck_->rows.empty() ? std::optional<double>(ck_->rows.back()[0]) : std::nullopt,
        ck_ ? std::filesystem::path(opt_.restart).parent_path().string() : std::string());
  }
  if (ck_ && loop_.row_pending)
    take_profile_gas(); // the restored gas is the gas of the pending row's time
  if (ck_) {
    out_->resume(std::move(ck_->rows), ck_->snapshots);
    if (!out_->rows().empty())
      means_.resume(out_->rows().back());
    return;
  }
  const std::size_t n = run_->owned();
  auto own = [n](const std::vector<double>& v) { return std::span<const double>(v.data(), n); };
  if (gas_on_ && scene_.output.snapshot_interval > 0) {
    const CellFields cells = gas_->coupling().cell_fields();
    SnapshotFields f;
    f.x = initial.x, f.y = initial.y, f.z = initial.z, f.vx = initial.vx, f.vy = initial.vy;
    f.vz = initial.vz, f.radius = initial.radius, f.mass = initial.mass, f.id = initial.id;
    write_snapshot(f, &cells);
    initial = ParticleStore();
  }
  // Row at t = 0. Without a gas, explicit: from the initial velocities (before start()'s
  // half-step shift); with a gas (and orb, islands): the velocities start() left.
  std::vector<double> v0[3];
  const bool shifted = !gas_on_ && run_->initial_velocities(v0);
  SyncedParticles s{own(particles_.x),
                    own(particles_.y),
                    own(particles_.z),
                    own(particles_.vx),
                    own(particles_.vy),
                    own(particles_.vz),
                    own(particles_.mass),
                    own(particles_.radius),
                    {particles_.id.data(), n},
                    {},
                    {}};
  if (shifted)
    s.vx = v0[0], s.vy = v0[1], s.vz = v0[2];
  const dem::LeafStepStats ls0 =
      Run::kSub && !gas_on_ ? dem::LeafStepStats{} : dem::LeafStepStats{0, 0, 0, 1};
  take_profile_gas();
  add_row(0.0, 0, s, ls0, gas_ ? gas_->coupling().diagnostics() : FluidDiagnostics{}, 0.0);
  if (!gas_on_ && snap_every_ > 0) {
    SnapshotFields f;
    f.x = s.x, f.y = s.y, f.z = s.z, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
    f.radius = s.radius, f.mass = s.mass, f.id = s.id;
    write_snapshot(f, nullptr);
  }
}

template <class Run> void TimeLoop<Run>::take_profile_gas() {
  if (profiles_ && gas_)
    profile_gas_ = profiles_->gas_sums(gas_->coupling().cell_fields());
}

// One outer step of the paper's Algorithm 1: with a gas, deposit, gas step and particle force
// (held by the scheme); the particle sub-cycle (explicit: n_sub steps of dt; orb and islands:
// sub-iterations of dt_sp; islands "auto": the sub-iterations it chose for the interval); the
// rows and snapshots due at the step's end marked (the next particle step writes them with the
// synchronised particles: the state at t needs the forces at t); a checkpoint at its interval.
template <class Run> void TimeLoop<Run>::outer_step() {
  FluidStepPlan s; // without a gas: one particle step
  if (gas_)
    s = gas_step();
  // dem.nsubit = "auto": the outer step (dt, a control interval) in the chosen sub-iterations
  // (after the gas force: its change bounds them).
  if (run_->auto_length())
    s.n_sub = run_->begin_interval();
  for (long long q = 0; q < s.n_sub; ++q) {
    particle_step(q == 0 && loop_.row_pending, q == 0 && loop_.snapshot_pending);
    if (q == 0)
      loop_.row_pending = loop_.snapshot_pending = false;
  }
  if (advance_clock(s.dt_f))
    write_checkpoint();
  print_progress();
}

// The gas half: the gas boxes regridded when due, the step's length planned, particles through
// the open faces, and the gas step with the force the scheme holds over the sub-cycle.
template <class Run> FluidStepPlan TimeLoop<Run>::gas_step() {
  {
    PhaseTimer::Scope fl(timer_, Phase::fluid);
    if (auto owners = gas_->regrid(particles_, run_->owned(), loop_.time, tol_, loop_.last_n_sub))
      run_->own_by(std::move(*owners), true);
  }
  const FluidStepPlan next = plan_fluid_step(scene_, gas_->coupling(), n_total_ == 0, Run::kSub,
                                             n_fixed_, dt_, end_ - loop_.time);
  loop_.last_n_sub = next.n_sub;
  if (flux_.on()) { // particles through the open faces (apps/particle_flux.hpp)
    const std::int64_t change = change_particles(flux_, run_, scene_, particles_, range_, comm_,
                                                 timer_, step_clock_, loop_, next.dt_f);
    n_total_ = static_cast<std::size_t>(static_cast<std::int64_t>(n_total_) + change);
  }
  if constexpr (Run::kSub)
    if (!fixed_)
      run_->set_interval(next.dt_f); // the sub-iterations divide this step
  PhaseTimer::Scope fl(timer_, Phase::fluid);
  {
    const ParticleFault fault = unfollowable_fault(
        particles_, std::views::iota(std::size_t{0}, run_->owned()), run_->scheme.model());
    if (const std::string agreed = comm_.agree_on_error(fault.id, fault.message); !agreed.empty())
      throw RunError(fmt::format("t = {:.9g} s, before fluid step {}: {}", loop_.time,
                                 loop_.fluid_steps + 1, agreed));
  }
  try {
    run_->hold_gas_force(gas_->step(particles_, run_->owned(), next.dt_f));
  } catch (const RunError& e) { // raised on every rank alike (the gas step is collective)
    throw RunError(fmt::format("t = {:.9g} s, fluid step {}: {}", loop_.time, loop_.fluid_steps + 1,
                               e.what()));
  }
  return next;
}

// The loop's position after an outer step, and the outputs that fall due; true when a
// checkpoint is due.
template <class Run> bool TimeLoop<Run>::advance_clock(double dt_f) {
  if (!gas_) {
    mark_due_steps(loop_.fluid_steps + 1);
    return ckpt_every_ > 0 && loop_.fluid_steps % ckpt_every_ == 0;
  }
  double& t = loop_.time;
  ++loop_.fluid_steps;
  loop_.dt_f_sum += dt_f;
  // A fixed step counts steps (no drift of a running sum against the output times).
  t = fixed_ ? static_cast<double>(loop_.fluid_steps) * scene_.fluid.dt : t + dt_f;
  {
    PhaseTimer::Scope io(timer_, Phase::io);
    mark_due_outputs(loop_, gas_->coupling(), scene_, t, end_ - t <= tol_, tol_);
    if (loop_.row_pending)
      take_profile_gas();
  }
  const bool due = t >= next_ckpt_ - tol_;
  if (due)
    next_ckpt_ = next_time_after(next_ckpt_, ckpt_interval_, t + tol_);
  return due;
}

// Whether output.progress_seconds have passed since the last progress line (and the clock
// restarts for the next one).
template <class Run> bool TimeLoop<Run>::progress_due() {
  const clock::time_point now = clock::now();
  if (std::chrono::duration<double>(now - last_progress_).count() < scene_.output.progress_seconds)
    return false;
  last_progress_ = now;
  return true;
}

template <class Run> void TimeLoop<Run>::print_progress() {
  if (opt_.quiet || !root_ || !(Run::kSub || gas_on_ || (loop_.fluid_steps & 63) == 0) ||
      !progress_due())
    return;
  const double wall = seconds_since(t_loop_);
  const double frac = gas_on_ ? loop_.time / end_
                              : static_cast<double>(loop_.fluid_steps) /
                                    static_cast<double>(n_end_);
  const std::string eta = format_eta(wall * (1 - frac) / std::max(frac, 1e-12));
  if (gas_on_)
    fmt::print(stderr, "fluid step {:>8} t = {:.6e} s ({:5.1f}%)  fluid {:.0f}% of wall  ETA {}\n",
               loop_.fluid_steps, loop_.time, 100 * frac,
               100 * timer_.seconds(Phase::fluid) / wall, eta);
  else
    fmt::print(stderr, "{}\n", run_->progress(loop_.fluid_steps, frac, wall, eta));
}

// Inside a fluid step: a fixed fluid.dt at a small fluid.cfl can take the gas 1e5 sub-steps
// and more (setting_warnings), minutes without a line from print_progress, which runs between
// fluid steps. Every rank takes the sub-steps; the root says where it is.
template <class Run>
void TimeLoop<Run>::print_substep_progress(int count, double t, double dt, double dt_f) {
  if (!progress_due())
    return;
  fmt::print(stderr,
             "fluid step {:>8} t = {:.6e} s: gas sub-step {} ({:.3g} s), {:.0f}% of the fluid "
             "step\n",
             loop_.fluid_steps + 1, loop_.time + t, count, dt, 100.0 * t / dt_f);
}

// One particle step past the end completes the last row (with "auto" a short one: the state it
// records is at its start).
template <class Run> void TimeLoop<Run>::complete_last_row() {
  if (!loop_.row_pending && !loop_.snapshot_pending)
    return;
  run_->begin_completion();
  particle_step(loop_.row_pending, loop_.snapshot_pending);
}

// One particle step; it writes the row and snapshot pending at its start.
template <class Run> void TimeLoop<Run>::particle_step(bool record, bool snap) {
  long long k = 0;
  const dem::LeafStepStats ls = run_->advance(record, record || snap, k_last_row_, k);
  if (!record && !snap)
    return;
  const SyncedParticles s = run_->synced();
  if (snap) {
    SnapshotFields f;
    f.time = loop_.row_time;
    f.step = k;
    f.x = s.x, f.y = s.y, f.z = s.z, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
    f.radius = s.radius, f.mass = s.mass, f.id = s.id, f.leaf = s.leaf, f.local_dt = s.local_dt;
    write_snapshot(f, gas_on_ ? &loop_.snapshot_cells : nullptr);
  }
  if (record) {
    add_row(loop_.row_time, k, s, ls, loop_.row_fluid, seconds_since(t_loop_));
    k_last_row_ = k;
  }
}

// A snapshot of every rank's particles (positions wrapped into the periodic box: the schemes
// wrap only when they rebuild their lists or regrid), with the gas at its time.
template <class Run>
void TimeLoop<Run>::write_snapshot(SnapshotFields f, const CellFields* cells) {
  PhaseTimer::Scope io(timer_, Phase::io);
  std::vector<double> w[3];
  const std::span<const double> x[3] = {f.x, f.y, f.z};
  for (int a = 0; a < 3; ++a) {
    w[a].resize(x[a].size());
    for (std::size_t i = 0; i < x[a].size(); ++i)
      w[a][i] = geom_.wrap(x[a][i], a);
  }
  f.x = w[0], f.y = w[1], f.z = w[2];
  std::vector<std::int64_t> box;
  if (f.leaf.empty() && !gas_on_) {
    box = run_->boxes(w[0], w[1], w[2]); // R-rank explicit: its ORB box
    f.leaf = box;
  }
  f.dt = run_->fine_dt();
  f.cells = cells;
  out_->add_snapshot(f);
}

// A row from the synchronised particles of step k (reduced over the ranks).
template <class Run>
void TimeLoop<Run>::add_row(double t, long long k, const SyncedParticles& s,
                            const dem::LeafStepStats& ls, const FluidDiagnostics& fd,
                            double wall) {
  PhaseTimer::Scope io(timer_, Phase::io);
  const dem::ParticleSpans p{s.x, s.y, s.z, s.vx, s.vy, s.vz, s.mass};
  const auto st = one_ ? dem::measure(p) : dem::measure(p, comm_);
  const RowExtra x =
      one_ ? means_.next(t, s.vx, s.vy, s.vz, fd) : means_.next(t, st.mean_velocity, fd);
  const std::vector<double> contacts = census_.row(comm_, {s.x, s.y, s.z, s.radius, s.mass});
  const ParticleMass mass{st.mass, loop_.mass_in, loop_.mass_out};
  out_->add_row(row(t, k, st, n_total_, run_->scheme, wall, ls, x, mass, contacts));
  if (profiles_)
    out_->add_profile_rows(profiles_->rows(t,
                                           {s.x, s.y, s.z, s.vx, s.vy, s.vz, s.radius, s.mass},
                                           profile_gas_, one_ ? nullptr : &comm_));
}

// A checkpoint between two outer steps: rank 0's header, the particles and scheme state
// (gathered to rank 0 in id order on R ranks), and with a gas its state and the loop's.
template <class Run> void TimeLoop<Run>::write_checkpoint() {
  PhaseTimer::Scope io(timer_, Phase::io);
  Checkpoint c;
  if (root_)
    c = checkpoint_header(scene_, Run::kName, dt_, loop_.fluid_steps, k_last_row_, out_->rows(),
                          out_->snapshots());
  run_->save(c, comm_); // collective
  if (gas_)
    gas_->write_checkpoint(out_->checkpoint_path(loop_.fluid_steps), std::move(c), particles_,
                           loop_);
  else
    out_->write_checkpoint(loop_.fluid_steps, c);
}

// run.json (rank 0) and the summary. Collective: the per-rank figures are gathered first.
template <class Run> RunResult TimeLoop<Run>::report() {
  const double loop_seconds = seconds_since(t_loop_);
  double wait_max = 0.0;
  const nlohmann::ordered_json j = run_json(loop_seconds, wait_max);
  out_->write_run_json(j);
  print_summary(loop_seconds, j, wait_max);
  warn_inlet_behind();
  return {opt_.out_dir, loop_seconds, run_->steps(), run_->scheme.particle_steps()};
}

template <class Run>
nlohmann::ordered_json TimeLoop<Run>::run_json(double loop_seconds, double& wait_max) const {
  const auto& sch = run_->scheme;
  const long long fluid_steps_run = loop_.fluid_steps - fluid_steps_before_;
  nlohmann::ordered_json j = run_json_header(scene_, scene_.name, derived_, env_, n_total_);
  j["scheme"] = Run::kName;
  if (!one_)
    j["distributed"] = true;
  run_->describe(j, out_->rows());
  if (gas_) // collective
    gas_->describe(j, loop_, fluid_steps_run, loop_seconds, timer_.seconds(Phase::fluid));
  if (flux_.inlet.on()) { // rank 0's counts (the inlet decides there)
    j["inlet"] = {{"particles_in", loop_.particles_in},
                  {"mass_in_kg", loop_.mass_in},
                  {"mass_waiting_kg", inlet_mass_waiting()},
                  {"recycled_particles_waiting", loop_.inlet.queue_mass.size()},
                  {"definition", "particles and mass that entered through the inlet region "
                                 "since the start of the run; the mass due (inlet.mass_rate) "
                                 "and recycled that found no place yet and waits at the end"}};
  }
  j["end_time"] = gas_on_ ? loop_.time : static_cast<double>(n_end_) * dt_;
  j["loop_seconds"] = loop_seconds;
  if (census_.enabled()) {
    j["census_seconds"] = census_.seconds();
    j["census_definition"] = "rank 0's wall time in the contact census of the diagnostics rows "
                             "(output.contact_census; part of phase_seconds.io and loop_seconds)";
  }
  j["setup_seconds"] = std::chrono::duration<double>(t_loop_ - t_setup_).count();
  nlohmann::ordered_json ph = phase_json(timer_, loop_seconds);
  const char* note = run_->phase_note();
  if (gas_on_)
    note = one_ ? "fluid: deposition, gas step (predictor, projection), interpolation and "
                  "particle forces; neighbor + regrid + force: the particle sub-cycle"
                : "rank 0's phases; fluid: deposition, gas step (predictor, projection over the "
                  "ranks), interpolation and particle forces (with orb: and the routing of the "
                  "particles to the gas boxes and of their forces back); neighbor + regrid + "
                  "force: the particle sub-cycle";
  if (note)
    ph["note"] = note;
  j["phase_seconds"] = ph;
  add_work_counters(j, sch, loop_seconds, run_->force_definition(), particle_steps_before_);
  if (one_)
    return j;
  const std::vector<double> waits = comm_.gather(comm_.wait_seconds());
  for (const double w : waits)
    wait_max = std::max(wait_max, w);
  j["mpi_wait_seconds"] = waits;
  j["mpi_wait_definition"] = "per rank: wall time inside MPI calls (reductions, the parallel "
                             "ORB, particle and ghost exchanges), set-up included";
  j["owned_particles_at_end"] = comm_.gather(static_cast<double>(run_->owned()));
  if (!gas_on_) {
    j["busy_seconds"] = comm_.gather(timer_.rebuild_seconds() + timer_.seconds(Phase::force) +
                                     timer_.seconds(Phase::integrate));
    j["busy_definition"] = "per rank: neighbor + regrid + force + integrate phases (rebuilds with "
                           "their exchanges, forces, updates); their spread is the load imbalance "
                           "in time";
  }
  const auto work = parts_.local_work(sch);
  j["rank_counts"] = rank_counts_json(comm_, work[0], work[1], gas_ ? gas_->cell_updates() : 0);
  if (!gas_on_)
    run_->describe_balance(j);
  return j;
}

template <class Run> double TimeLoop<Run>::inlet_mass_waiting() const {
  double m = loop_.inlet.owed;
  for (const double q : loop_.inlet.queue_mass)
    m += q;
  return m;
}

// An inlet whose region is full delivers less than it is asked to, and the rows' mass_in shows
// it only against a sum the user must make: the run says so when more than a tenth of what
// was due still waits (and more than a particle's worth: the mass due is placed a particle at a
// time, so up to one particle's mass always waits).
template <class Run> void TimeLoop<Run>::warn_inlet_behind() const {
  if (!root_ || !flux_.inlet.on())
    return;
  const double waiting = inlet_mass_waiting();
  const double due = waiting + loop_.mass_in;
  const double one =
      ParticleStore::sphere_mass(scene_.inlet.density, 0.5 * flux_.inlet.mean_diameter());
  if (due > 0.0 && waiting > 0.1 * due && waiting > 2.0 * one)
    fmt::print(stderr,
               "cfddem: warning: the inlet placed {:.3g} kg of the {:.3g} kg due ({:.0f}%): "
               "{:.3g} kg waits for room in its region (inlet.region_lo, inlet.region_hi; run.json "
               "\"inlet\")\n",
               loop_.mass_in, due, 100.0 * loop_.mass_in / due, waiting);
}

template <class Run>
void TimeLoop<Run>::print_summary(double loop_seconds, const nlohmann::ordered_json& j,
                                  double wait_max) const {
  if (opt_.quiet || !root_)
    return;
  const std::int64_t particle_steps_run = run_->scheme.particle_steps() - particle_steps_before_;
  const long long fluid_steps_run = loop_.fluid_steps - fluid_steps_before_;
  const double fluid = timer_.seconds(Phase::fluid);
  if (!gas_on_) {
    const double pss =
        loop_seconds > 0 ? static_cast<double>(particle_steps_run) / loop_seconds : 0.0;
    fmt::print(stderr,
               "Loop time of {:.4g} s on {} rank(s) x {} thread(s) for {} {} with {} "
               "particles ({} to run.end_time and one that completes the last row)\n",
               loop_seconds, env_.ranks(), env_.threads(), run_->steps(), Run::kStepsWord,
               n_total_, n_end_);
    fmt::print(stderr, "{}\n", run_->performance(timer_, pss, wait_max));
  } else if (one_) {
    fmt::print(stderr,
               "Loop time of {:.4g} s for {} fluid steps ({:.4g} s each) and {} particle "
               "steps with {} particles; fluid {:.3g} s ({:.0f}%), particles {:.3g} s\n",
               loop_seconds, fluid_steps_run, j["wall_seconds_per_fluid_step"].get<double>(),
               static_cast<long long>(particle_steps_run /
                                      std::max<std::int64_t>(1,
                                                             static_cast<std::int64_t>(n_total_))),
               n_total_, fluid, 100 * fluid / std::max(loop_seconds, 1e-300),
               timer_.rebuild_seconds() + timer_.seconds(Phase::force));
  } else {
    fmt::print(stderr,
               "Loop time of {:.4g} s for {} fluid steps on {} rank(s) x {} thread(s) "
               "with {} particles; fluid {:.3g} s ({:.0f}%) on rank 0\n",
               loop_seconds, fluid_steps_run, env_.ranks(), env_.threads(), n_total_, fluid,
               100 * fluid / std::max(loop_seconds, 1e-300));
  }
}

} // namespace cfddem::apps
