#include "apps/simulation.hpp"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <optional>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/derived_numbers.hpp"
#include "apps/diagnostics_file.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"
#include "core/particle_snapshot.hpp"
#include "core/phase_timer.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/orb_scheme.hpp"
#include "dem/granular_diagnostics.hpp"

namespace cfddem::apps {

namespace {

using clock = std::chrono::steady_clock;

double seconds_since(clock::time_point t0) {
  return std::chrono::duration<double>(clock::now() - t0).count();
}

const std::vector<std::string> kColumns = {
    "time",       "step",       "granular_temperature", "kinetic_energy", "mean_speed",
    "mean_x",     "mean_y",     "mean_z",               "momentum_x",     "momentum_y",
    "momentum_z", "particles",  "particle_steps",       "force_evaluations", "neighbor_builds",
    "wall_seconds", "leaf_steps_min", "leaf_steps_mean", "leaf_steps_max", "fine_leaf_fraction"};

template <class Scheme>
std::vector<double> row(double t, long long step, const dem::GranularState& s, std::size_t n,
                        const Scheme& scheme, double wall, const dem::LeafStepStats& ls) {
  return {t,
          static_cast<double>(step),
          s.granular_temperature,
          s.kinetic_energy,
          s.mean_speed,
          s.mean_position[0],
          s.mean_position[1],
          s.mean_position[2],
          s.momentum[0],
          s.momentum[1],
          s.momentum[2],
          static_cast<double>(n),
          static_cast<double>(scheme.particle_steps()),
          static_cast<double>(scheme.pair_evaluations()),
          static_cast<double>(scheme.neighbor_builds()),
          wall,
          ls.steps_min,
          ls.steps_mean,
          ls.steps_max,
          ls.fine_fraction};
}

std::string format_eta(double s) {
  if (!std::isfinite(s)) return "?";
  if (s < 120) return fmt::format("{:.0f}s", s);
  if (s < 7200) return fmt::format("{:.1f}min", s / 60);
  return fmt::format("{:.1f}h", s / 3600);
}

RunResult run_orb(const Scene& scene, const RunOptions& opt, const ParallelEnv& env);

// Steps between two events at a simulated-time interval (0: never).
long long every(double interval, double dt) {
  return interval > 0.0 ? std::max(1LL, std::llround(interval / dt)) : 0;
}

// Read a checkpoint and check it belongs to this scene; throws ConfigError (nothing written yet).
Checkpoint load_checkpoint(const Scene& scene, const std::string& path) {
  Checkpoint ck = read_checkpoint(path);
  if (ck.scheme != scene.dem.scheme)
    throw ConfigError(path, fmt::format("checkpoint of scheme \"{}\", the scene runs \"{}\"",
                                        ck.scheme, scene.dem.scheme));
  if (ck.columns != kColumns)
    throw ConfigError(path, "checkpoint diagnostics columns differ from this version's");
  const std::string now = restart_configuration(scene);
  if (ck.configuration != now) {
    // Name the first key that differs.
    std::size_t a = 0;
    while (a < now.size() && a < ck.configuration.size() && now[a] == ck.configuration[a]) ++a;
    const std::size_t b = now.rfind('\n', a == 0 ? 0 : a - 1);
    const std::size_t line = b == std::string::npos || a == 0 ? 0 : b + 1;
    throw ConfigError(path, fmt::format("the checkpoint was written with a different "
                                        "configuration; first difference at '{}' (only name, "
                                        "run.* and output.* may change at a restart)",
                                        now.substr(line, now.find('\n', line) - line)));
  }
  return ck;
}

} // namespace

RunResult run_simulation(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  if (scene.dem.scheme == "orb") return run_orb(scene, opt, env);
  namespace fs = std::filesystem;
  const auto t_setup = clock::now();
  std::optional<Checkpoint> ck;
  if (!opt.restart.empty()) ck = load_checkpoint(scene, opt.restart);
  ParticleStore particles = ck ? std::move(ck->particles) : make_initial_particles(scene);
  const DerivedNumbers derived = derive(scene, particles);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(scene, particles, timer);
  if (ck && ck->dt != scheme.dt())
    throw ConfigError(opt.restart, fmt::format("checkpoint dt {:.17g} s differs from the "
                                               "scene's {:.17g} s", ck->dt, scheme.dt()));

  const long long n_end = derived.steps;
  const long long k0 = ck ? ck->step : 0;
  if (ck && k0 > std::max(n_end, 0LL))
    throw ConfigError("run.end_time", fmt::format("the checkpoint is at step {}, past the end of "
                                                  "the run (step {})",
                                                  k0, n_end));

  fs::create_directories(opt.out_dir);
  const std::string diag_path = (fs::path(opt.out_dir) / "diagnostics.csv").string();
  DiagnosticsFile diag(diag_path, kColumns);
  std::vector<std::vector<double>> rows; // kept for checkpoints
  auto add_row = [&](std::vector<double> r) {
    diag.add_row(r);
    rows.push_back(std::move(r));
  };
  SnapshotIndex snapshots(opt.out_dir);
  if (!opt.quiet)
    fmt::print(stderr, "cfddem: scene '{}', {} particles, dt = {:.4e} s, {} steps, {} rank(s) x {} "
                       "thread(s){}\n",
               scene.name, particles.size(), scheme.dt(), derived.steps, env.ranks(),
               env.threads(),
               ck ? fmt::format(", restarted at step {} from {}", k0, opt.restart) : "");

  const long long out_every = std::max(1LL, std::llround(scene.output.interval / scheme.dt()));
  const long long snap_every = every(scene.output.snapshot_interval, scheme.dt());
  const long long ckpt_every = every(scene.output.checkpoint_interval, scheme.dt());
  auto snapshot = [&](long long k, std::span<const double> x, std::span<const double> y,
                      std::span<const double> z, std::span<const double> vx,
                      std::span<const double> vy, std::span<const double> vz) {
    PhaseTimer::Scope io(timer, Phase::io);
    SnapshotFields f;
    f.time = static_cast<double>(k) * scheme.dt();
    f.step = k;
    // Positions wrapped into the periodic box (the scheme wraps only at neighbor builds).
    const dem::DomainGeometry g(scene.domain);
    std::vector<double> wx(x.size()), wy(y.size()), wz(z.size());
    for (std::size_t i = 0; i < x.size(); ++i)
      wx[i] = g.wrap(x[i], 0), wy[i] = g.wrap(y[i], 1), wz[i] = g.wrap(z[i], 2);
    f.x = wx, f.y = wy, f.z = wz, f.vx = vx, f.vy = vy, f.vz = vz;
    f.radius = particles.radius, f.mass = particles.mass, f.id = particles.id;
    f.dt = scheme.dt();
    snapshots.add(write_particle_snapshot(opt.out_dir, f));
  };
  long long k_last_row = 0;
  const auto t_loop = clock::now();
  if (ck) {
    scheme.restore_state(std::move(ck->state));
    for (auto& r : ck->rows) add_row(std::move(r));
    snapshots.restore(ck->snapshots);
    k_last_row = ck->last_row_step;
  } else {
    scheme.start();
    // Row at t = 0 from the initial velocities (before the half-step shift).
    PhaseTimer::Scope io(timer, Phase::io);
    std::vector<double> v0x(particles.size()), v0y(particles.size()), v0z(particles.size());
    const double h = 0.5 * scheme.dt();
    const auto& gr = scheme.model().gravity;
    for (std::size_t i = 0; i < particles.size(); ++i) {
      v0x[i] = particles.vx[i] + (particles.fx[i] * particles.inv_mass[i] + gr[0]) * h;
      v0y[i] = particles.vy[i] + (particles.fy[i] * particles.inv_mass[i] + gr[1]) * h;
      v0z[i] = particles.vz[i] + (particles.fz[i] * particles.inv_mass[i] + gr[2]) * h;
    }
    const auto s0 = dem::measure({particles.x, particles.y, particles.z, v0x, v0y, v0z,
                                  particles.mass});
    add_row(row(0.0, 0, s0, particles.size(), scheme, 0.0, dem::LeafStepStats{0, 0, 0, 1}));
    if (snap_every > 0) snapshot(0, particles.x, particles.y, particles.z, v0x, v0y, v0z);
  }

  auto last_progress = clock::now();
  // The state at step K (x(K), v(K)) is known once step K+1 has evaluated the forces at K, so
  // the loop runs one step past the last row; rows every out_every steps and at the end.
  for (long long k = k0; k <= n_end && n_end > 0; ++k) {
    if (ckpt_every > 0 && k > k0 && k % ckpt_every == 0) {
      // The state before step k: x(k), v(k - 1/2), the list and history the step will use.
      PhaseTimer::Scope io(timer, Phase::io);
      diag.flush();
      Checkpoint c;
      c.dt = scheme.dt();
      c.step = k;
      c.last_row_step = k_last_row;
      c.columns = kColumns;
      c.rows = rows;
      c.snapshots = snapshots.entries();
      c.configuration = restart_configuration(scene);
      c.particles = particles;
      c.state = scheme.save_state();
      write_checkpoint((fs::path(opt.out_dir) / fmt::format("checkpoint_{:09d}.h5", k)).string(),
                       c);
    }
    const bool record = k > 0 && (k % out_every == 0 || k == n_end);
    const bool snap = k > 0 && snap_every > 0 && (k % snap_every == 0 || k == n_end);
    scheme.step(record || snap);
    if (record) {
      PhaseTimer::Scope io(timer, Phase::io);
      const auto s = scheme.synchronised_previous();
      const auto st = dem::measure({s.x, s.y, s.z, s.vx, s.vy, s.vz, particles.mass});
      const auto steps = static_cast<double>(k - k_last_row);
      k_last_row = k;
      add_row(row(static_cast<double>(k) * scheme.dt(), k, st, particles.size(), scheme,
                  seconds_since(t_loop), dem::LeafStepStats{steps, steps, steps, 1.0}));
    }
    if (snap) {
      const auto s = scheme.synchronised_previous();
      snapshot(k, s.x, s.y, s.z, s.vx, s.vy, s.vz);
    }
    if (!opt.quiet && (k & 63) == 0 &&
        std::chrono::duration<double>(clock::now() - last_progress).count() >=
            scene.output.progress_seconds) {
      last_progress = clock::now();
      const double wall = seconds_since(t_loop);
      const double frac = static_cast<double>(k) / static_cast<double>(n_end);
      fmt::print(stderr, "step {:>10} t = {:.6e} s ({:5.1f}%)  {:.3e} particle-steps/s  ETA {}\n",
                 k, scheme.time(), 100 * frac, scheme.particle_steps() / wall,
                 format_eta(wall * (1 - frac) / frac));
    }
  }
  diag.flush();
  const double loop_seconds = seconds_since(t_loop);

  nlohmann::ordered_json j;
  j["program"] = "cfddem";
  j["version"] = CFDDEM_VERSION;
  j["scene"] = scene.name;
  nlohmann::ordered_json cfg;
  for (const auto& [k, v] : describe_scene(scene)) cfg[k] = v;
  j["configuration"] = cfg;
  nlohmann::ordered_json der;
  for (const auto& [k, v] : derived.table()) der[k] = v;
  j["derived"] = der;
  j["ranks"] = env.ranks();
  j["threads"] = env.threads();
  j["particles"] = particles.size();
  j["dt"] = scheme.dt();
  j["steps"] = scheme.steps_taken();
  j["end_time"] = static_cast<double>(n_end) * scheme.dt();
  j["loop_seconds"] = loop_seconds;
  j["setup_seconds"] = std::chrono::duration<double>(t_loop - t_setup).count();
  nlohmann::ordered_json ph;
  ph["neighbor"] = timer.seconds(Phase::neighbor);
  ph["force"] = timer.seconds(Phase::force);
  ph["integrate"] = 0.0;
  ph["io"] = timer.seconds(Phase::io);
  ph["other"] = loop_seconds - timer.seconds(Phase::neighbor) - timer.seconds(Phase::force) -
                timer.seconds(Phase::io);
  ph["note"] = "the explicit scheme fuses force and integrate in one pass: both are in 'force'";
  j["phase_seconds"] = ph;
  j["particle_steps"] = scheme.particle_steps();
  j["force_evaluations"] = scheme.pair_evaluations();
  j["force_evaluations_definition"] = "neighbor-list pairs evaluated (each pair once per step)";
  j["neighbor_builds"] = scheme.neighbor_builds();
  j["particle_steps_per_second"] =
      loop_seconds > 0 ? static_cast<double>(scheme.particle_steps()) / loop_seconds : 0.0;
  write_file_atomically((fs::path(opt.out_dir) / "run.json").string(), j.dump(2) + "\n");

  if (!opt.quiet) {
    fmt::print(stderr, "Loop time of {:.4g} s on {} rank(s) x {} thread(s) for {} steps with {} "
                       "particles\n",
               loop_seconds, env.ranks(), env.threads(), scheme.steps_taken(), particles.size());
    fmt::print(stderr, "Performance: {:.4g} particle-steps/s; neighbor {:.3g} s ({} builds), "
                       "force+integrate {:.3g} s, io {:.3g} s\n",
               j["particle_steps_per_second"].get<double>(), timer.seconds(Phase::neighbor),
               scheme.neighbor_builds(), timer.seconds(Phase::force), timer.seconds(Phase::io));
  }
  return {opt.out_dir, loop_seconds, scheme.steps_taken(), scheme.particle_steps()};
}

namespace {

// The orb scheme's loop: rows at multiples of output.interval rounded to whole sub-iterations.
// As in the explicit loop, the state at sub-iteration K is recorded by sub-iteration K+1 (its
// first local step evaluates the forces at K), so the loop runs one sub-iteration past the end.
RunResult run_orb(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  namespace fs = std::filesystem;
  const auto t_setup = clock::now();
  std::optional<Checkpoint> ck;
  if (!opt.restart.empty()) ck = load_checkpoint(scene, opt.restart);
  ParticleStore particles = ck ? std::move(ck->particles) : make_initial_particles(scene);
  const DerivedNumbers derived = derive(scene, particles);
  PhaseTimer timer;
  dem::OrbScheme scheme(scene, particles, timer);
  const double dt_sp = scheme.dt_sub();
  if (ck && ck->dt != dt_sp)
    throw ConfigError(opt.restart, fmt::format("checkpoint dt_sp {:.17g} s differs from the "
                                               "scene's {:.17g} s", ck->dt, dt_sp));
  const long long n_end = std::max(1LL, std::llround(scene.run.end_time / dt_sp));
  const long long k0 = ck ? ck->step : 0;
  if (ck && k0 > n_end)
    throw ConfigError("run.end_time", fmt::format("the checkpoint is at sub-iteration {}, past "
                                                  "the end of the run ({})",
                                                  k0, n_end));

  fs::create_directories(opt.out_dir);
  const std::string diag_path = (fs::path(opt.out_dir) / "diagnostics.csv").string();
  DiagnosticsFile diag(diag_path, kColumns);
  std::vector<std::vector<double>> rows; // kept for checkpoints
  auto add_row = [&](std::vector<double> r) {
    diag.add_row(r);
    rows.push_back(std::move(r));
  };
  const long long out_every = std::max(1LL, std::llround(scene.output.interval / dt_sp));
  const long long snap_every = every(scene.output.snapshot_interval, dt_sp);
  // Checkpoints only at regrid points (multiples of dem.nsubit), where the ORB is rebuilt from
  // the store: the interval is rounded up to a whole number of regrid intervals.
  long long ckpt_every = every(scene.output.checkpoint_interval, dt_sp);
  if (ckpt_every > 0) ckpt_every = (ckpt_every + scheme.nsubit() - 1) / scheme.nsubit() * scheme.nsubit();
  SnapshotIndex snapshots(opt.out_dir);
  const dem::DomainGeometry geom(scene.domain);
  // Synchronised state at sub-iteration k with each particle's ORB leaf and local step.
  auto snapshot = [&](long long k) {
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s = scheme.synchronised_previous();
    std::vector<double> wx(s.x.size()), wy(s.x.size()), wz(s.x.size());
    for (std::size_t i = 0; i < s.x.size(); ++i)
      wx[i] = geom.wrap(s.x[i], 0), wy[i] = geom.wrap(s.y[i], 1), wz[i] = geom.wrap(s.z[i], 2);
    SnapshotFields f;
    f.time = static_cast<double>(k) * dt_sp;
    f.step = k;
    f.x = wx, f.y = wy, f.z = wz, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
    f.radius = s.radius, f.mass = s.mass, f.id = s.id, f.leaf = s.leaf, f.local_dt = s.local_dt;
    snapshots.add(write_particle_snapshot(opt.out_dir, f));
  };
  if (!opt.quiet)
    fmt::print(stderr, "cfddem: scene '{}', {} particles, orb scheme: {} leaves, dt_sp = {:.4e} s "
                       "(fine dt = {:.4e} s), {} sub-iterations, {} rank(s) x {} thread(s)\n",
               scene.name, particles.size(), 1 << scene.partition.orb_levels, dt_sp,
               scheme.dt_fine(), n_end, env.ranks(), env.threads());
  const auto t_loop = clock::now();
  if (ck) {
    scheme.restore_state(std::move(ck->orb));
    for (auto& r : ck->rows) add_row(std::move(r));
    snapshots.restore(ck->snapshots);
  } else {
    scheme.start();
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s0 = dem::measure({particles.x, particles.y, particles.z, particles.vx,
                                  particles.vy, particles.vz, particles.mass});
    add_row(row(0.0, 0, s0, particles.size(), scheme, 0.0, dem::LeafStepStats{}));
    if (snap_every > 0) {
      SnapshotFields f;
      f.x = particles.x, f.y = particles.y, f.z = particles.z, f.vx = particles.vx;
      f.vy = particles.vy, f.vz = particles.vz, f.radius = particles.radius;
      f.mass = particles.mass, f.id = particles.id, f.dt = scheme.dt_fine();
      snapshots.add(write_particle_snapshot(opt.out_dir, f));
    }
  }
  auto last_progress = clock::now();
  for (long long k = k0; k <= n_end; ++k) {
    if (ckpt_every > 0 && k > k0 && k % ckpt_every == 0) {
      PhaseTimer::Scope io(timer, Phase::io);
      diag.flush();
      Checkpoint c;
      c.scheme = "orb";
      c.dt = dt_sp;
      c.step = k;
      c.columns = kColumns;
      c.rows = rows;
      c.snapshots = snapshots.entries();
      c.configuration = restart_configuration(scene);
      c.particles = particles;
      c.orb = scheme.save_state();
      write_checkpoint((fs::path(opt.out_dir) / fmt::format("checkpoint_{:09d}.h5", k)).string(),
                       c);
    }
    const bool record = k > 0 && (k % out_every == 0 || k == n_end);
    const dem::LeafStepStats ls = record ? scheme.take_interval_stats() : dem::LeafStepStats{};
    const bool snap = k > 0 && snap_every > 0 && (k % snap_every == 0 || k == n_end);
    scheme.subiterate(record || snap);
    if (snap) snapshot(k);
    if (record) {
      PhaseTimer::Scope io(timer, Phase::io);
      const auto s = scheme.synchronised_previous();
      const auto st = dem::measure({s.x, s.y, s.z, s.vx, s.vy, s.vz, s.mass});
      add_row(row(static_cast<double>(k) * dt_sp, k, st, particles.size(), scheme,
                  seconds_since(t_loop), ls));
    }
    if (!opt.quiet && std::chrono::duration<double>(clock::now() - last_progress).count() >=
                          scene.output.progress_seconds) {
      last_progress = clock::now();
      const double wall = seconds_since(t_loop);
      const double frac = static_cast<double>(k) / static_cast<double>(n_end);
      fmt::print(stderr, "sub-iteration {:>8} t = {:.6e} s ({:5.1f}%)  fine leaves {:.2f}  ETA {}\n",
                 k, scheme.time(), 100 * frac, scheme.last_fine_fraction(),
                 format_eta(wall * (1 - frac) / std::max(frac, 1e-12)));
    }
  }
  diag.flush();
  const double loop_seconds = seconds_since(t_loop);

  nlohmann::ordered_json j;
  j["program"] = "cfddem";
  j["version"] = CFDDEM_VERSION;
  j["scene"] = scene.name;
  nlohmann::ordered_json cfg;
  for (const auto& [k, v] : describe_scene(scene)) cfg[k] = v;
  j["configuration"] = cfg;
  nlohmann::ordered_json der;
  for (const auto& [k, v] : derived.table()) der[k] = v;
  j["derived"] = der;
  j["ranks"] = env.ranks();
  j["threads"] = env.threads();
  j["particles"] = particles.size();
  j["scheme"] = "orb";
  j["dt"] = scheme.dt_fine();
  j["dt_sp"] = dt_sp;
  j["leaves"] = scheme.leaf_count();
  j["steps"] = scheme.subiterations();
  j["steps_definition"] = "sub-iterations of dt_sp (one past the end, as the explicit loop)";
  j["regrids"] = scheme.regrids();
  j["end_time"] = static_cast<double>(n_end) * dt_sp;
  j["loop_seconds"] = loop_seconds;
  j["setup_seconds"] = std::chrono::duration<double>(t_loop - t_setup).count();
  nlohmann::ordered_json ph;
  ph["neighbor"] = timer.seconds(Phase::neighbor);
  ph["force"] = timer.seconds(Phase::force);
  ph["integrate"] = 0.0;
  ph["io"] = timer.seconds(Phase::io);
  ph["other"] = loop_seconds - timer.seconds(Phase::neighbor) - timer.seconds(Phase::force) -
                timer.seconds(Phase::io);
  ph["note"] = "neighbor: ORB regrid and re-sort; force: the leaves' tasks (ghosts, local lists, "
               "force and update)";
  j["phase_seconds"] = ph;
  j["particle_steps"] = scheme.particle_steps();
  j["force_evaluations"] = scheme.pair_evaluations();
  j["force_evaluations_definition"] =
      "local-list pairs evaluated (own-own and own-ghost pairs once each per local step)";
  j["neighbor_builds"] = scheme.neighbor_builds();
  j["max_overlap_ratio"] = scheme.max_overlap_ratio();
  j["overlap_violations"] = scheme.overlap_violations();
  j["particle_steps_per_second"] =
      loop_seconds > 0 ? static_cast<double>(scheme.particle_steps()) / loop_seconds : 0.0;
  write_file_atomically((fs::path(opt.out_dir) / "run.json").string(), j.dump(2) + "\n");

  if (!opt.quiet) {
    fmt::print(stderr, "Loop time of {:.4g} s on {} rank(s) x {} thread(s) for {} sub-iterations "
                       "with {} particles\n",
               loop_seconds, env.ranks(), env.threads(), scheme.subiterations(), particles.size());
    fmt::print(stderr, "Performance: {:.4g} particle-steps/s; {} force evaluations; regrid+resort "
                       "{:.3g} s, leaves {:.3g} s, io {:.3g} s; max overlap {:.3g} r ({} "
                       "beyond dem.max_overlap)\n",
               j["particle_steps_per_second"].get<double>(), scheme.pair_evaluations(),
               timer.seconds(Phase::neighbor), timer.seconds(Phase::force),
               timer.seconds(Phase::io), scheme.max_overlap_ratio(), scheme.overlap_violations());
  }
  return {opt.out_dir, loop_seconds, scheme.subiterations(), scheme.particle_steps()};
}

} // namespace

} // namespace cfddem::apps
