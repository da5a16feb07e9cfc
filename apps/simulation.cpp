#include "apps/simulation.hpp"

#include <array>
#include <algorithm>
#include <chrono>
#include <span>
#include <type_traits>
#include <cmath>
#include <filesystem>
#include <limits>
#include <numeric>
#include <optional>
#include <stdexcept>

#include <fmt/format.h>
#include <HYPRE_utilities.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/coupled_distributed.hpp"
#include "apps/coupled_schedule.hpp"
#include "apps/coupled_step.hpp"
#include "apps/derived_numbers.hpp"
#include "apps/diagnostics_file.hpp"
#include "apps/distributed_subiterated_run.hpp"
#include "apps/rank_checkpoint.hpp"
#include "apps/rank_setup.hpp"
#include "apps/run_output.hpp"
#include "core/atomic_file.hpp"
#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"
#include "core/particle_snapshot.hpp"
#include "core/phase_timer.hpp"
#include "dem/distributed_explicit_scheme.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/granular_diagnostics.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"

namespace cfddem::apps {

namespace {

// The islands scheme's run.json entries: collisions its bound could have missed (none expected)
// and the island size distribution.
void add_island_json(nlohmann::ordered_json& j, const dem::IslandsScheme& scheme) {
  j["bound_violations"] = scheme.bound_violations();
  j["global_subiterations"] = scheme.global_subiterations();
  j["global_subiterations_definition"] =
      "sub-iterations where more than a quarter of the particles were linked, so every particle "
      "took the fine steps together (a dense bed: the explicit scheme's work)";
  nlohmann::ordered_json hist;
  const auto h = scheme.island_size_histogram();
  for (std::size_t b = 0; b < h.size(); ++b)
    if (h[b] > 0)
      hist[b == 0 ? std::string("1") : b == 1 ? std::string("2")
                                       : fmt::format("{}-{}", (1LL << (b - 1)) + 1, 1LL << b)] = h[b];
  j["island_sizes"] = hist;
  const auto d = scheme.fine_fraction_distribution();
  j["fine_fraction_per_particle"] = {{"mean", d[0]}, {"min", d[1]}, {"p10", d[2]}, {"p50", d[3]},
                                     {"p90", d[4]}, {"p99", d[5]}, {"max", d[6]}};
  j["fine_fraction_per_particle_definition"] =
      "distribution over particles of the fraction of sub-iterations each spent in a fine island";
  j["island_sizes_definition"] = "islands of each size, one count per island per sub-iteration "
                                 "(size 1: lone particles in free flight, or tied to a wall)";
}

// Positions wrapped into the periodic box for a snapshot (the schemes wrap only when they
// rebuild their lists or regrid).
struct WrappedPositions {
  std::vector<double> x, y, z;
  WrappedPositions(const dem::DomainGeometry& g, std::span<const double> px,
                   std::span<const double> py, std::span<const double> pz)
      : x(px.size()), y(py.size()), z(pz.size()) {
    for (std::size_t i = 0; i < px.size(); ++i)
      x[i] = g.wrap(px[i], 0), y[i] = g.wrap(py[i], 1), z[i] = g.wrap(pz[i], 2);
  }
};

RunResult run_distributed(const Scene& scene, const RunOptions& opt, const ParallelEnv& env);
template <class Scheme>
RunResult run_subiterated(const Scene& scene, const RunOptions& opt, const ParallelEnv& env);
RunResult run_coupled(const Scene& scene, const RunOptions& opt, const ParallelEnv& env);

// Steps between two events at a simulated-time interval (0: never).
long long every(double interval, double dt) {
  return interval > 0.0 ? std::max(1LL, std::llround(interval / dt)) : 0;
}

} // namespace

RunResult run_simulation(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  if (env.ranks() > 1) {
    // What is distributed so far: the explicit scheme (with friction too), the orb scheme and
    // the islands scheme (frictionless: they refuse friction themselves); all three with a gas
    // too.
    if (scene.dem.scheme != "explicit" && scene.dem.scheme != "orb" &&
        scene.dem.scheme != "islands")
      throw ConfigError("scene key 'dem.scheme'",
                        fmt::format("dem.scheme = \"{}\" is not yet distributed over MPI ranks: "
                                    "run it on one rank, or use dem.scheme = \"explicit\", "
                                    "\"orb\" or \"islands\"",
                                    scene.dem.scheme));
    if (scene.fluid.enabled) {
      validate_fluid(scene);
      return run_coupled_distributed(scene, opt, env);
    }
    if (scene.dem.scheme == "orb") return run_distributed_orb(scene, opt, env);
    if (scene.dem.scheme == "islands")
      return run_distributed_islands(scene, opt, env);
    return run_distributed(scene, opt, env);
  }
  if (scene.fluid.enabled) {
    validate_fluid(scene);
    return run_coupled(scene, opt, env);
  }
  if (scene.dem.scheme == "orb") return run_subiterated<dem::OrbScheme>(scene, opt, env);
  if (scene.dem.scheme == "islands") return run_subiterated<dem::IslandsScheme>(scene, opt, env);
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
  MeanTracker means;
  if (ck) {
    if (ck->state.x_ref.empty() && !ck->state.offsets.empty()) {
      // An R-rank checkpoint with friction: its rows hold only the contact history, over the
      // saved particles (the store's order here). Reinstated as a list due for a rebuild, they
      // are carried over by ids as any rebuild carries the history.
      ck->state.x_ref = particles.x, ck->state.y_ref = particles.y, ck->state.z_ref = particles.z;
      ck->state.need_rebuild = true;
    }
    scheme.restore_state(std::move(ck->state));
    for (auto& r : ck->rows) add_row(std::move(r));
    snapshots.restore(ck->snapshots);
    k_last_row = ck->last_row_step;
    if (!rows.empty()) means.resume(rows.back());
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
    add_row(row(0.0, 0, s0, particles.size(), scheme, 0.0, dem::LeafStepStats{0, 0, 0, 1},
                means.next(0.0, v0x, v0y, v0z)));
    if (snap_every > 0) snapshot(0, particles.x, particles.y, particles.z, v0x, v0y, v0z);
  }

  auto last_progress = clock::now();
  // The state at step K (x(K), v(K)) is known once step K+1 has evaluated the forces at K, so
  // the loop runs one step past the last row; rows every out_every steps and at the end.
  for (long long k = k0; k <= n_end && n_end > 0; ++k) {
    if (ckpt_every > 0 && k > k0 && k % ckpt_every == 0) {
      // The state before step k: x(k), v(k - 1/2), the list and history the step will use.
      PhaseTimer::Scope io(timer, Phase::io);
      Checkpoint c = checkpoint_header(scene, "explicit", scheme.dt(), k, k_last_row, rows,
                                       snapshots.entries());
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
      const double t = static_cast<double>(k) * scheme.dt();
      add_row(row(t, k, st, particles.size(), scheme, seconds_since(t_loop),
                  dem::LeafStepStats{steps, steps, steps, 1.0}, means.next(t, s.vx, s.vy, s.vz)));
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
  const double loop_seconds = seconds_since(t_loop);

  nlohmann::ordered_json j =
      run_json_header(scene, scene.name, derived, env, particles.size());
  j["dt"] = scheme.dt();
  j["steps"] = scheme.steps_taken();
  j["end_time"] = static_cast<double>(n_end) * scheme.dt();
  j["loop_seconds"] = loop_seconds;
  j["setup_seconds"] = std::chrono::duration<double>(t_loop - t_setup).count();
  nlohmann::ordered_json ph = phase_json(timer, loop_seconds);
  j["phase_seconds"] = ph;
  add_work_counters(j, scheme, loop_seconds,
                    "neighbor-list pairs evaluated (each pair once per step)");
  write_file_atomically((fs::path(opt.out_dir) / "run.json").string(), j.dump(2) + "\n");

  if (!opt.quiet) {
    fmt::print(stderr,
               "Loop time of {:.4g} s on {} rank(s) x {} thread(s) for {} steps with {} "
               "particles ({} to run.end_time and one that completes the last row)\n",
               loop_seconds, env.ranks(), env.threads(), scheme.steps_taken(), particles.size(),
               n_end);
    fmt::print(stderr, "Performance: {:.4g} particle-steps/s; neighbor {:.3g} s ({} builds), "
                       "force {:.3g} s, integrate {:.3g} s, io {:.3g} s\n",
               j["particle_steps_per_second"].get<double>(), timer.seconds(Phase::neighbor),
               scheme.neighbor_builds(), timer.seconds(Phase::force),
               timer.seconds(Phase::integrate), timer.seconds(Phase::io));
  }
  return {opt.out_dir, loop_seconds, scheme.steps_taken(), scheme.particle_steps()};
}

namespace {

// The loop of the sub-iterated schemes (orb, islands): rows at multiples of output.interval
// rounded to whole sub-iterations. As in the explicit loop, the state at sub-iteration K is
// recorded by sub-iteration K+1 (its first local step evaluates the forces at K), so the loop
// runs one sub-iteration past the end.
template <class Scheme>
RunResult run_subiterated(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  namespace fs = std::filesystem;
  constexpr bool kOrb = std::is_same_v<Scheme, dem::OrbScheme>;
  const char* scheme_name = kOrb ? "orb" : "islands";
  const auto t_setup = clock::now();
  std::optional<Checkpoint> ck;
  if (!opt.restart.empty()) ck = load_checkpoint(scene, opt.restart);
  ParticleStore particles = ck ? std::move(ck->particles) : make_initial_particles(scene);
  const DerivedNumbers derived = derive(scene, particles);
  PhaseTimer timer;
  Scheme scheme(scene, particles, timer);
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
  // orb: checkpoints only at regrid points (multiples of dem.nsubit), where the ORB is rebuilt
  // from the store: the interval is rounded up to a whole number of regrid intervals. islands:
  // between any two sub-iterations.
  long long ckpt_every = every(scene.output.checkpoint_interval, dt_sp);
  if (kOrb && ckpt_every > 0)
    ckpt_every = (ckpt_every + scheme.nsubit() - 1) / scheme.nsubit() * scheme.nsubit();
  SnapshotIndex snapshots(opt.out_dir);
  const dem::DomainGeometry geom(scene.domain);
  // Synchronised state at sub-iteration k with each particle's ORB leaf and local step.
  auto snapshot = [&](long long k) {
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s = scheme.synchronised_previous();
    const WrappedPositions w(geom, s.x, s.y, s.z);
    SnapshotFields f;
    f.time = static_cast<double>(k) * dt_sp;
    f.step = k;
    f.x = w.x, f.y = w.y, f.z = w.z, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
    f.radius = s.radius, f.mass = s.mass, f.id = s.id, f.leaf = s.leaf, f.local_dt = s.local_dt;
    snapshots.add(write_particle_snapshot(opt.out_dir, f));
  };
  if (!opt.quiet)
    fmt::print(stderr, "cfddem: scene '{}', {} particles, {} scheme{}, dt_sp = {:.4e} s "
                       "(fine dt = {:.4e} s), {} sub-iterations, {} rank(s) x {} thread(s)\n",
               scene.name, particles.size(), scheme_name,
               kOrb ? fmt::format(": {} leaves", 1 << scene.partition.orb_levels) : "", dt_sp,
               scheme.dt_fine(), n_end, env.ranks(), env.threads());
  const auto t_loop = clock::now();
  MeanTracker means;
  if (ck) {
    if constexpr (kOrb)
      scheme.restore_state(std::move(ck->orb));
    else
      scheme.restore_state(std::move(ck->islands));
    for (auto& r : ck->rows) add_row(std::move(r));
    snapshots.restore(ck->snapshots);
    if (!rows.empty()) means.resume(rows.back());
  } else {
    scheme.start();
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s0 = dem::measure({particles.x, particles.y, particles.z, particles.vx,
                                  particles.vy, particles.vz, particles.mass});
    add_row(row(0.0, 0, s0, particles.size(), scheme, 0.0, dem::LeafStepStats{},
                means.next(0.0, particles.vx, particles.vy, particles.vz)));
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
      Checkpoint c = checkpoint_header(scene, scheme_name, dt_sp, k, 0, rows, snapshots.entries());
      c.particles = particles;
      if constexpr (kOrb)
        c.orb = scheme.save_state();
      else
        c.islands = scheme.save_state();
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
      const double t = static_cast<double>(k) * dt_sp;
      add_row(row(t, k, st, particles.size(), scheme, seconds_since(t_loop), ls,
                  means.next(t, s.vx, s.vy, s.vz)));
    }
    if (!opt.quiet && std::chrono::duration<double>(clock::now() - last_progress).count() >=
                          scene.output.progress_seconds) {
      last_progress = clock::now();
      const double wall = seconds_since(t_loop);
      const double frac = static_cast<double>(k) / static_cast<double>(n_end);
      fmt::print(stderr, "sub-iteration {:>8} t = {:.6e} s ({:5.1f}%)  fine {} {:.2f}  ETA {}\n",
                 k, scheme.time(), 100 * frac, kOrb ? "leaves" : "particles",
                 scheme.last_fine_fraction(),
                 format_eta(wall * (1 - frac) / std::max(frac, 1e-12)));
    }
  }
  const double loop_seconds = seconds_since(t_loop);

  nlohmann::ordered_json j =
      run_json_header(scene, scene.name, derived, env, particles.size());
  j["scheme"] = scheme_name;
  j["dt"] = scheme.dt_fine();
  j["dt_sp"] = dt_sp;
  if constexpr (kOrb) j["leaves"] = scheme.leaf_count();
  j["steps"] = scheme.subiterations();
  j["steps_definition"] = "sub-iterations of dt_sp (one past the end, as the explicit loop)";
  if constexpr (kOrb) j["regrids"] = scheme.regrids();
  j["end_time"] = static_cast<double>(n_end) * dt_sp;
  j["loop_seconds"] = loop_seconds;
  j["setup_seconds"] = std::chrono::duration<double>(t_loop - t_setup).count();
  nlohmann::ordered_json ph = phase_json(timer, loop_seconds);
  ph["note"] = kOrb ? "neighbor: ORB regrid and re-sort; force: the leaves' tasks (ghosts, local "
                     "lists, force and update)"
                   : "neighbor: speed bounds, links, islands and Verlet list builds; force: free "
                     "flight and the islands' tasks (force and update)";
  j["phase_seconds"] = ph;
  j["particle_steps"] = scheme.particle_steps();
  j["force_evaluations"] = scheme.pair_evaluations();
  if constexpr (kOrb) {
    j["force_evaluations_definition"] =
        "candidate pairs evaluated per local step: pairs within a leaf once, pairs across a leaf "
        "boundary once per side (each leaf evaluates its side against the other's frozen copy)";
    j["subiteration_retries"] = scheme.retries();
  } else {
    j["force_evaluations_definition"] =
        "neighbor-list pairs inside a fine island evaluated per local step (each pair once)";
    add_island_json(j, scheme);
  }
  j["final_skin"] = scheme.skin();
  j["neighbor_builds"] = scheme.neighbor_builds();
  j["max_overlap_ratio"] = scheme.max_overlap_ratio();
  j["overlap_violations"] = scheme.overlap_violations();
  j["particle_steps_per_second"] =
      loop_seconds > 0 ? static_cast<double>(scheme.particle_steps()) / loop_seconds : 0.0;
  write_file_atomically((fs::path(opt.out_dir) / "run.json").string(), j.dump(2) + "\n");

  if (!opt.quiet) {
    fmt::print(stderr,
               "Loop time of {:.4g} s on {} rank(s) x {} thread(s) for {} sub-iterations "
               "with {} particles ({} to run.end_time and one that completes the last "
               "row)\n",
               loop_seconds, env.ranks(), env.threads(), scheme.subiterations(), particles.size(),
               n_end);
    fmt::print(stderr, "Performance: {:.4g} particle-steps/s; {} force evaluations; {} "
                       "{:.3g} s, {} {:.3g} s, io {:.3g} s; max overlap {:.3g} r ({} "
                       "beyond dem.max_overlap)\n",
               j["particle_steps_per_second"].get<double>(), scheme.pair_evaluations(),
               kOrb ? "regrid+resort" : "islands", timer.seconds(Phase::neighbor),
               kOrb ? "leaves" : "steps", timer.seconds(Phase::force),
               timer.seconds(Phase::io), scheme.max_overlap_ratio(), scheme.overlap_violations());
  }
  return {opt.out_dir, loop_seconds, scheme.subiterations(), scheme.particle_steps()};
}


// The explicit loop over MPI ranks (dem::DistributedExplicitScheme). Every rank starts from its
// share of the particles (rank_share; start() sends each to its owner). Rows hold values
// reduced over the ranks; only rank 0 writes diagnostics.csv and run.json.
RunResult run_distributed(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  namespace fs = std::filesystem;
  const auto t_setup = clock::now();
  const Communicator comm = Communicator::world();
  const bool root = comm.rank() == 0;
  // A restart: every rank reads the checkpoint (the same error on every rank if it is bad) and
  // keeps its share of the particles, as at the start.
  std::optional<Checkpoint> ck;
  if (!opt.restart.empty()) ck = load_checkpoint(scene, opt.restart);
  // With friction the checkpoint's history rows (over its particles) become records by id,
  // which restore() hands to each particle's owner.
  dem::ContactHistory saved_history;
  if (ck)
    saved_history = saved_contact_history(*ck);
  ParticleStore particles = rank_share(scene, ck, comm);
  dem::ParticleRange range;
  const DerivedNumbers derived = derive(scene, particles, comm, &range);
  const dem::StepModel model = dem::make_step_model(scene, range);
  const std::size_t n_total = derived.particles;
  PhaseTimer timer;
  dem::DistributedExplicitScheme scheme(scene, particles, model, comm, timer);
  const long long n_end = derived.steps;
  if (ck && ck->dt != scheme.dt())
    throw ConfigError(opt.restart, fmt::format("checkpoint dt {:.17g} s differs from the "
                                               "scene's {:.17g} s", ck->dt, scheme.dt()));
  const long long k0 = ck ? ck->step : 0;
  if (ck && k0 > std::max(n_end, 0LL))
    throw ConfigError("run.end_time", fmt::format("the checkpoint is at step {}, past the end of "
                                                  "the run (step {})",
                                                  k0, n_end));

  std::optional<DiagnosticsFile> diag = open_root_diagnostics(comm, opt.out_dir, kColumns);
  std::vector<std::vector<double>> rows; // kept for checkpoints (the same on every rank)
  auto add_row = [&](std::vector<double> r) {
    add_root_row(diag, r);
    rows.push_back(std::move(r));
  };
  const long long ckpt_every = every(scene.output.checkpoint_interval, scheme.dt());
  if (!opt.quiet)
    fmt::print(stderr, "cfddem: scene '{}', {} particles, dt = {:.4e} s, {} steps, {} rank(s) x {} "
                       "thread(s), {} boxes\n",
               scene.name, n_total, scheme.dt(), n_end, env.ranks(), env.threads(),
               1 << scheme.levels());
  const long long out_every = std::max(1LL, std::llround(scene.output.interval / scheme.dt()));
  const long long snap_every = every(scene.output.snapshot_interval, scheme.dt());
  std::optional<SnapshotIndex> snapshots;
  if (root) snapshots.emplace(opt.out_dir);
  // A snapshot of the owned particles of every rank, written collectively into one file with
  // parallel HDF5 (the ranks' particles in rank order), with the ORB box of each particle as its
  // `leaf` (the decomposition, seen in ParaView).
  auto snapshot = [&](long long k, std::span<const double> x, std::span<const double> y,
                      std::span<const double> z, std::span<const double> vx,
                      std::span<const double> vy, std::span<const double> vz) {
    PhaseTimer::Scope io(timer, Phase::io);
    const dem::DomainGeometry g(scene.domain);
    const std::size_t n = x.size();
    std::vector<double> w[3] = {std::vector<double>(n), std::vector<double>(n),
                                std::vector<double>(n)};
    std::vector<std::int64_t> box(n);
    for (std::size_t i = 0; i < n; ++i) {
      w[0][i] = g.wrap(x[i], 0), w[1][i] = g.wrap(y[i], 1), w[2][i] = g.wrap(z[i], 2);
      box[i] = scheme.decomposition().tree.locate(w[0][i], w[1][i], w[2][i]);
    }
    SnapshotFields f;
    f.time = static_cast<double>(k) * scheme.dt();
    f.step = k;
    f.x = w[0], f.y = w[1], f.z = w[2], f.vx = vx, f.vy = vy, f.vz = vz;
    f.radius = {particles.radius.data(), n}, f.mass = {particles.mass.data(), n};
    f.id = {particles.id.data(), n}, f.leaf = box;
    f.dt = scheme.dt();
    const SnapshotEntry e = write_particle_snapshot(opt.out_dir, f, comm); // collective
    std::string error;
    if (root) {
      try {
        snapshots->add(e);
      } catch (const std::exception& ex) {
        error = ex.what();
      }
    }
    if (const std::string m = comm.agree_on_error(0, error); !m.empty()) throw RunError(m);
  };
  const auto t_loop = clock::now();
  MeanTracker means;
  long long k_last_row = 0;
  if (ck) {
    for (auto& r : ck->rows) add_row(std::move(r));
    if (root) snapshots->restore(ck->snapshots);
    if (!rows.empty()) means.resume(rows.back());
    k_last_row = ck->last_row_step;
    scheme.restore({k0, ck->state.particle_steps, ck->state.pair_evaluations, ck->state.builds},
                   saved_history);
  } else {
  scheme.start();
  {
    // Row at t = 0 from the initial velocities (before the half-step shift).
    PhaseTimer::Scope io(timer, Phase::io);
    const std::size_t n = scheme.owned();
    std::vector<double> v0x(n), v0y(n), v0z(n);
    const double h = 0.5 * scheme.dt();
    const auto& gr = scheme.model().gravity;
    for (std::size_t i = 0; i < n; ++i) {
      v0x[i] = particles.vx[i] + (particles.fx[i] * particles.inv_mass[i] + gr[0]) * h;
      v0y[i] = particles.vy[i] + (particles.fy[i] * particles.inv_mass[i] + gr[1]) * h;
      v0z[i] = particles.vz[i] + (particles.fz[i] * particles.inv_mass[i] + gr[2]) * h;
    }
    const std::span<const double> x(particles.x.data(), n), y(particles.y.data(), n),
        z(particles.z.data(), n), m(particles.mass.data(), n);
    const auto s0 = dem::measure({x, y, z, v0x, v0y, v0z, m}, comm);
    add_row(row(0.0, 0, s0, n_total, scheme, 0.0, dem::LeafStepStats{0, 0, 0, 1},
                means.next(0.0, s0.mean_velocity)));
    if (snap_every > 0) snapshot(0, x, y, z, v0x, v0y, v0z);
  }
  }
  // A checkpoint at step k: the scheme is put in its canonical state (restore() rebuilds the
  // same), the particles are gathered to rank 0 in id order and written there atomically.
  auto checkpoint = [&](long long k) {
    PhaseTimer::Scope io(timer, Phase::io);
    scheme.canonicalize();
    Checkpoint c;
    if (root)
      c = checkpoint_header(scene, "explicit", scheme.dt(), k, k_last_row, rows,
                            snapshots->entries());
    gather_rank_particles(scheme, particles, comm, c); // collective
    std::string error;
    if (root) {
      try {
        write_checkpoint((fs::path(opt.out_dir) / fmt::format("checkpoint_{:09d}.h5", k)).string(), c);
      } catch (const std::exception& e) {
        error = e.what();
      }
    }
    if (const std::string m = comm.agree_on_error(0, error); !m.empty()) throw RunError(m);
  };
  auto last_progress = clock::now();
  for (long long k = k0; k <= n_end && n_end > 0; ++k) {
    if (ckpt_every > 0 && k > k0 && k % ckpt_every == 0) checkpoint(k);
    const bool record = k > 0 && (k % out_every == 0 || k == n_end);
    const bool snap = k > 0 && snap_every > 0 && (k % snap_every == 0 || k == n_end);
    scheme.step(record || snap);
    if (snap) {
      const auto s = scheme.synchronised_previous();
      snapshot(k, s.x, s.y, s.z, s.vx, s.vy, s.vz);
    }
    if (record) {
      PhaseTimer::Scope io(timer, Phase::io);
      const auto s = scheme.synchronised_previous();
      const std::span<const double> m(particles.mass.data(), scheme.owned());
      const auto st = dem::measure({s.x, s.y, s.z, s.vx, s.vy, s.vz, m}, comm);
      const auto steps = static_cast<double>(k - k_last_row);
      k_last_row = k;
      const double t = static_cast<double>(k) * scheme.dt();
      add_row(row(t, k, st, n_total, scheme, seconds_since(t_loop),
                  dem::LeafStepStats{steps, steps, steps, 1.0}, means.next(t, st.mean_velocity)));
    }
    if (!opt.quiet && std::chrono::duration<double>(clock::now() - last_progress).count() >=
                          scene.output.progress_seconds) {
      last_progress = clock::now();
      const double wall = seconds_since(t_loop);
      const double frac = static_cast<double>(k) / static_cast<double>(n_end);
      fmt::print(stderr, "step {:>10} t = {:.6e} s ({:5.1f}%)  ETA {}\n", k, scheme.time(),
                 100 * frac, format_eta(wall * (1 - frac) / std::max(frac, 1e-12)));
    }
  }
  const double loop_seconds = seconds_since(t_loop);
  const std::vector<double> waits = comm.gather(comm.wait_seconds());
  const std::vector<double> owned = comm.gather(static_cast<double>(scheme.owned()));
  const std::vector<double> busy = comm.gather(
      timer.seconds(Phase::neighbor) + timer.seconds(Phase::force) + timer.seconds(Phase::integrate));
  const nlohmann::ordered_json counts =
      rank_counts_json(comm, scheme.local_particle_steps(), scheme.local_pair_evaluations(), 0);
  if (root) {
    nlohmann::ordered_json j = run_json_header(scene, scene.name, derived, env, n_total);
    j["scheme"] = "explicit";
    j["distributed"] = true;
    j["dt"] = scheme.dt();
    j["steps"] = scheme.steps_taken();
    j["end_time"] = static_cast<double>(n_end) * scheme.dt();
    j["loop_seconds"] = loop_seconds;
    j["setup_seconds"] = std::chrono::duration<double>(t_loop - t_setup).count();
    nlohmann::ordered_json ph = phase_json(timer, loop_seconds);
    ph["note"] = "rank 0's phases; neighbor: regrid, migration, ghost exchange and the local "
                 "list; force: includes waiting for the ghost forward (after the interior rows); "
                 "other: mostly posting the forward and the per-step flag reduction";
    j["phase_seconds"] = ph;
    add_work_counters(j, scheme, loop_seconds,
                      "neighbor-list pairs evaluated (each pair once per step), over all ranks");
    j["mpi_wait_seconds"] = waits;
    j["mpi_wait_definition"] = "per rank: wall time inside MPI calls (reductions, the parallel "
                               "ORB, particle and ghost exchanges), set-up included";
    j["owned_particles_at_end"] = owned;
    j["busy_seconds"] = busy;
    j["busy_definition"] = "per rank: neighbor + force + integrate phases (rebuilds with their "
                           "exchanges, forces, updates); their spread is the load imbalance in time";
    j["boxes"] = 1 << scheme.levels();
    j["rank_counts"] = counts;
    j["regrid_policy"] = "ORB + Hilbert knapsack at the first neighbor rebuild after "
                         "dem.regrid_interval; migration and ghosts at every rebuild";
    nlohmann::ordered_json regrids = nlohmann::ordered_json::array();
    double worst = 1.0;
    for (const auto& r : scheme.regrids()) {
      regrids.push_back({{"step", r.step}, {"imbalance", r.imbalance}});
      worst = std::max(worst, r.imbalance);
    }
    j["load_imbalance"] = regrids;
    j["load_imbalance_definition"] = "per regrid: max over ranks / mean of particles owned";
    j["load_imbalance_max"] = worst;
    write_file_atomically((fs::path(opt.out_dir) / "run.json").string(), j.dump(2) + "\n");
  }
  if (!opt.quiet) {
    double wait_max = 0.0;
    for (const double w : waits) wait_max = std::max(wait_max, w);
    fmt::print(stderr,
               "Loop time of {:.4g} s on {} rank(s) x {} thread(s) for {} steps with {} "
               "particles ({} to run.end_time and one that completes the last row)\n",
               loop_seconds, env.ranks(), env.threads(), scheme.steps_taken(), n_total, n_end);
    fmt::print(stderr, "Performance: {:.4g} particle-steps/s; rank 0: neighbor+exchange {:.3g} s "
                       "({} builds, {} regrids), force {:.3g} s, integrate {:.3g} s; MPI wait "
                       "max {:.3g} s\n",
               loop_seconds > 0 ? static_cast<double>(scheme.particle_steps()) / loop_seconds : 0.0,
               timer.seconds(Phase::neighbor), scheme.neighbor_builds(), scheme.regrids().size(),
               timer.seconds(Phase::force), timer.seconds(Phase::integrate), wait_max);
  }
  return {opt.out_dir, loop_seconds, scheme.steps_taken(), scheme.particle_steps()};
}

// The coupled loop (the paper's Algorithm 1): per fluid step of dt_f, deposit + gas step +
// particle force (GasCoupling::step), then the particle sub-cycle: explicit, n_sub steps of
// dt_f / n_sub (n_sub = ceil(dt_f / dt_dem), so the sub-cycle lands exactly on the fluid step);
// orb, dem.nsubit sub-iterations of dt_f / nsubit (dem.regrid_interval is set to dt_f).
// A row or snapshot at fluid time t is written by the first particle step after t (as in the
// explicit loop, the synchronised state at t needs the forces at t), with the gas taken at t.
// Checkpoints are written at fluid-step boundaries (an ORB regrid point), before the next gas
// step, with the gas force the scheme holds (read by the step past the end when a run resumes
// at its end time).
template <class Scheme>
RunResult run_coupled_with(const Scene& scene_in, const RunOptions& opt, const ParallelEnv& env) {
  // kOrb: a sub-iterated scheme (orb or islands), dem.nsubit sub-iterations per fluid step.
  constexpr bool kOrb = !std::is_same_v<Scheme, dem::ExplicitScheme>;
  constexpr bool kLeaves = std::is_same_v<Scheme, dem::OrbScheme>;
  namespace fs = std::filesystem;
  const auto t_setup = clock::now();
  std::optional<Checkpoint> ck;
  if (!opt.restart.empty()) ck = load_checkpoint(scene_in, opt.restart);
  ParticleStore particles = ck ? std::move(ck->particles) : make_initial_particles(scene_in);
  const DerivedNumbers derived = derive(scene_in, particles);
  Scene scene = scene_in;
  const double dt_dem = dem::make_step_model(scene_in, particles).dt;
  if constexpr (kOrb) (void)dt_dem;
  const bool fixed = scene.fluid.dt > 0.0;
  long long n_fixed = 0;
  if (kOrb) {
    n_fixed = scene.dem.nsubit;
    scene.dem.regrid_interval = scene.fluid.dt; // validate_fluid: orb needs a fixed fluid.dt
  } else if (fixed) {
    n_fixed = std::max(1LL, static_cast<long long>(std::ceil(scene.fluid.dt / dt_dem * (1 - 1e-12))));
    scene.dem.dt = scene.fluid.dt / static_cast<double>(n_fixed);
  } else {
    scene.dem.dt = dt_dem;
  }
  PhaseTimer timer;
  static const bool hypre_ready = (HYPRE_Init(), true); // once per process; freed at exit
  (void)hypre_ready;
  GasCoupling gas(scene, particles);
  Scheme scheme(scene, particles, timer);
  double dt = 0.0;
  if constexpr (kOrb)
    dt = scheme.dt_sub();
  else
    dt = scheme.dt();
  const double end = scene.run.end_time;
  CoupledLoopState loop;
  loop.next_output = scene.output.interval;
  loop.next_snapshot = scene.output.snapshot_interval;
  long long k_last_row = 0;
  if (ck) {
    // Everything is checked and restored before the run directory is touched.
    if (ck->dt != dt)
      throw ConfigError(opt.restart, fmt::format("checkpoint particle step {:.17g} s differs from "
                                                 "the scene's {:.17g} s", ck->dt, dt));
    if (ck->loop.time > end + 1e-6 * dt)
      throw ConfigError("run.end_time", fmt::format("the checkpoint is at t = {:.17g} s, past the "
                                                    "end of the run ({:.17g} s)",
                                                    ck->loop.time, end));
    try {
      gas.restore_state(ck->gas_state);
      if constexpr (kLeaves)
        scheme.restore_state(std::move(ck->orb));
      else if constexpr (kOrb)
        scheme.restore_state(std::move(ck->islands));
      else
        scheme.restore_state(std::move(ck->state));
      const auto& hf = ck->loop.held_force;
      scheme.set_external_force(hf[0], hf[1], hf[2]);
    } catch (const std::invalid_argument& e) {
      throw ConfigError(opt.restart, fmt::format("cannot restart: held gas force: {}", e.what()));
    } catch (const RunError& e) {
      throw ConfigError(opt.restart, fmt::format("cannot restart: {}", e.what()));
    }
    loop = std::move(ck->loop);
    k_last_row = ck->last_row_step;
    // A checkpoint from R ranks leaves the pending snapshot's cells to the gas restored.
    if (loop.snapshot_pending && loop.snapshot_cells.eps_g.empty())
      loop.snapshot_cells = gas.cell_fields();
  }

  fs::create_directories(opt.out_dir);
  DiagnosticsFile diag((fs::path(opt.out_dir) / "diagnostics.csv").string(), kColumns);
  std::vector<std::vector<double>> rows; // kept for checkpoints
  auto add_row = [&](std::vector<double> r) {
    diag.add_row(r);
    rows.push_back(std::move(r));
  };
  SnapshotIndex snapshots(opt.out_dir);
  const dem::DomainGeometry geom(scene.domain);
  double snap_dt = dt; // the particles' step (orb: the fine one; snapshots give each local step)
  if constexpr (kOrb) snap_dt = scheme.dt_fine();
  // Synchronised particles of the last recorded step with the gas kept from time t_snap.
  auto snapshot = [&](double t_snap, long long k, const CellFields& cells) {
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s = scheme.synchronised_previous();
    const WrappedPositions w(geom, s.x, s.y, s.z);
    SnapshotFields f;
    f.time = t_snap;
    f.step = k;
    f.x = w.x, f.y = w.y, f.z = w.z, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
    if constexpr (kOrb)
      f.radius = s.radius, f.mass = s.mass, f.id = s.id, f.leaf = s.leaf, f.local_dt = s.local_dt;
    else
      f.radius = particles.radius, f.mass = particles.mass, f.id = particles.id;
    f.dt = snap_dt;
    f.cells = &cells;
    snapshots.add(write_particle_snapshot(opt.out_dir, f));
  };
  if (!opt.quiet) {
    const auto& c = scene.fluid.cells;
    fmt::print(
        stderr,
        "cfddem: scene '{}', {} particles, gas {} x {} x {} cells ({} drag, {} "
        "deposition), dt_f = {}, {}{}, {} rank(s) x {} "
        "thread(s){}\n",
        scene.name, particles.size(), c[0], c[1], c[2], scene.fluid.drag, scene.fluid.deposition,
        fixed ? fmt::format("{:.4e} s", scene.fluid.dt)
              : fmt::format("adaptive (cfl {})", scene.fluid.cfl),
        kOrb ? fmt::format("dt_sp = {:.4e} s (fine dt = {:.4e} s)", dt, snap_dt)
             : fmt::format("particle dt = {:.4e} s", dt),
        fixed ? fmt::format(" ({} {} per fluid step)", n_fixed, kOrb ? "sub-iterations" : "steps")
              : std::string(),
        env.ranks(), env.threads(),
        ck ? fmt::format(", restarted at t = {:.6e} s from {}", loop.time, opt.restart) : "");
  }
  // The loop's wall time starts before start() and the t = 0 outputs, which the phase timer
  // counts too (else phase_seconds.other came out negative).
  const auto t_loop = clock::now();
  MeanTracker means;
  if (ck) {
    for (auto& r : ck->rows) add_row(std::move(r));
    snapshots.restore(ck->snapshots);
    if (!rows.empty()) means.resume(rows.back());
  } else {
    if (loop.next_snapshot > 0.0) {
      // t = 0 before start() (which shifts the explicit velocities to the half step).
      const CellFields cells = gas.cell_fields();
      SnapshotFields f;
      f.x = particles.x, f.y = particles.y, f.z = particles.z, f.vx = particles.vx;
      f.vy = particles.vy, f.vz = particles.vz, f.radius = particles.radius;
      f.mass = particles.mass, f.id = particles.id, f.dt = snap_dt;
      f.cells = &cells;
      snapshots.add(write_particle_snapshot(opt.out_dir, f));
    }
    scheme.start();
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s0 = dem::measure({particles.x, particles.y, particles.z, particles.vx,
                                  particles.vy, particles.vz, particles.mass});
    add_row(row(0.0, 0, s0, particles.size(), scheme, 0.0, dem::LeafStepStats{0, 0, 0, 1},
                means.next(0.0, particles.vx, particles.vy, particles.vz, gas.diagnostics())));
  }
  double& t = loop.time;
  auto last_progress = clock::now();
  auto particle_step = [&](bool record, bool snap) {
    dem::LeafStepStats ls{};
    long long k = 0;
    if constexpr (kOrb) {
      if (record) ls = scheme.take_interval_stats();
      scheme.subiterate(record || snap);
      k = scheme.subiterations() - 1;
    } else {
      scheme.step(record || snap);
      k = scheme.steps_taken() - 1;
    }
    if (snap) snapshot(loop.row_time, k, loop.snapshot_cells);
    if (!record) return;
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s = scheme.synchronised_previous();
    std::span<const double> mass = particles.mass;
    if constexpr (kOrb) mass = s.mass;
    const auto st = dem::measure({s.x, s.y, s.z, s.vx, s.vy, s.vz, mass});
    if constexpr (!kOrb) {
      const auto steps = static_cast<double>(k - k_last_row);
      ls = dem::LeafStepStats{steps, steps, steps, 1.0};
    }
    k_last_row = k;
    add_row(row(loop.row_time, k, st, particles.size(), scheme, seconds_since(t_loop), ls,
                means.next(loop.row_time, s.vx, s.vy, s.vz, loop.row_fluid)));
  };
  // Checkpoints at the fluid times that are multiples of the interval, after the restart time.
  const double ckpt_interval = scene.output.checkpoint_interval;
  double next_ckpt = ckpt_interval > 0.0
                         ? (std::floor(t / ckpt_interval + 1e-6) + 1.0) * ckpt_interval
                         : std::numeric_limits<double>::infinity();
  const double tol = 1e-6 * dt;
  while (end - t > tol) {
    const bool no_particles = particles.size() == 0 && !fixed;
    const long long n_sub =
        no_particles ? 1 : particle_steps_per_fluid_step(scene, gas, n_fixed, dt, end - t);
    const double dt_f = fluid_step_length(scene, gas, no_particles, n_sub, dt, end - t);
    {
      PhaseTimer::Scope fl(timer, Phase::fluid);
      gas.step(particles, dt_f);
      // Sub-iterated: the owed half kick settled with the old force (replace_external_force).
      if constexpr (kOrb)
        scheme.replace_external_force(gas.force(0), gas.force(1), gas.force(2));
      else
        scheme.set_external_force(gas.force(0), gas.force(1), gas.force(2));
    }
    for (long long q = 0; q < n_sub; ++q) {
      particle_step(q == 0 && loop.row_pending, q == 0 && loop.snapshot_pending);
      if (q == 0) loop.row_pending = loop.snapshot_pending = false;
    }
    ++loop.fluid_steps;
    loop.dt_f_sum += dt_f;
    // A fixed step counts steps (no drift of a running sum against the output times).
    t = fixed ? static_cast<double>(loop.fluid_steps) * scene.fluid.dt : t + dt_f;
    const bool last = end - t <= tol;
    {
      PhaseTimer::Scope io(timer, Phase::io);
      mark_due_outputs(loop, gas, scene, t, last, tol);
    }
    if (t >= next_ckpt - tol) {
      PhaseTimer::Scope io(timer, Phase::io);
      Checkpoint c = checkpoint_header(scene_in, kLeaves ? "orb" : kOrb ? "islands" : "explicit",
                                       dt, loop.fluid_steps, k_last_row, rows, snapshots.entries());
      c.particles = particles;
      if constexpr (kLeaves)
        c.orb = scheme.save_state();
      else if constexpr (kOrb)
        c.islands = scheme.save_state();
      else
        c.state = scheme.save_state();
      c.gas = true;
      c.gas_cells = gas.solver().grid().global_cells();
      c.gas_state = gas.save_state();
      c.loop = loop;
      c.loop.held_force = gas.force_in_order(particles.id);
      write_checkpoint(
          (fs::path(opt.out_dir) / fmt::format("checkpoint_{:09d}.h5", loop.fluid_steps)).string(),
          c);
      while (next_ckpt <= t + tol) next_ckpt += ckpt_interval;
    }
    if (!opt.quiet && std::chrono::duration<double>(clock::now() - last_progress).count() >=
                          scene.output.progress_seconds) {
      last_progress = clock::now();
      const double wall = seconds_since(t_loop);
      const double frac = t / end;
      fmt::print(stderr, "fluid step {:>8} t = {:.6e} s ({:5.1f}%)  fluid {:.0f}% of wall  ETA {}\n",
                 loop.fluid_steps, t, 100 * frac, 100 * timer.seconds(Phase::fluid) / wall,
                 format_eta(wall * (1 - frac) / std::max(frac, 1e-12)));
    }
  }
  // One particle step past the end, as the explicit loop.
  if (loop.row_pending || loop.snapshot_pending)
    particle_step(loop.row_pending, loop.snapshot_pending);
  const double loop_seconds = seconds_since(t_loop);
  const long long fluid_steps = loop.fluid_steps;

  nlohmann::ordered_json j =
      run_json_header(scene_in, scene.name, derived, env, particles.size());
  j["scheme"] = kLeaves ? "orb" : kOrb ? "islands" : "explicit";
  if constexpr (kOrb) {
    j["dt"] = scheme.dt_fine();
    j["dt_sp"] = dt;
    if constexpr (kLeaves) j["leaves"] = scheme.leaf_count();
    else add_island_json(j, scheme);
    j["steps"] = scheme.subiterations();
    j["max_overlap_ratio"] = scheme.max_overlap_ratio();
    j["overlap_violations"] = scheme.overlap_violations();
  } else {
    j["dt"] = dt;
    j["steps"] = scheme.steps_taken();
  }
  j["fluid_steps"] = fluid_steps;
  j["fluid_dt_mean"] = fluid_steps > 0 ? loop.dt_f_sum / static_cast<double>(fluid_steps) : 0.0;
  j["gas_substeps"] = gas.gas_substeps();
  j["projection_iterations"] = gas.projection_iterations();
  j["projection_fallbacks"] = gas.projection_fallbacks();
  j["end_time"] = t;
  j["loop_seconds"] = loop_seconds;
  j["setup_seconds"] = std::chrono::duration<double>(t_loop - t_setup).count();
  j["wall_seconds_per_fluid_step"] =
      fluid_steps > 0 ? loop_seconds / static_cast<double>(fluid_steps) : 0.0;
  nlohmann::ordered_json ph = phase_json(timer, loop_seconds);
  ph["note"] = "fluid: deposition, gas step (predictor, projection), interpolation and particle "
               "forces; neighbor + force: the particle sub-cycle";
  j["phase_seconds"] = ph;
  add_work_counters(j, scheme, loop_seconds);
  write_file_atomically((fs::path(opt.out_dir) / "run.json").string(), j.dump(2) + "\n");
  if (!opt.quiet) {
    fmt::print(stderr, "Loop time of {:.4g} s for {} fluid steps ({:.4g} s each) and {} particle "
                       "steps with {} particles; fluid {:.3g} s ({:.0f}%), particles {:.3g} s\n",
               loop_seconds, fluid_steps, j["wall_seconds_per_fluid_step"].get<double>(),
               static_cast<long long>(scheme.particle_steps() /
                                      std::max<std::int64_t>(1, static_cast<std::int64_t>(particles.size()))),
               particles.size(), timer.seconds(Phase::fluid),
               100 * timer.seconds(Phase::fluid) / std::max(loop_seconds, 1e-300),
               timer.seconds(Phase::neighbor) + timer.seconds(Phase::force));
  }
  return {opt.out_dir, loop_seconds, k_last_row + 1, scheme.particle_steps()};
}

RunResult run_coupled(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  if (scene.dem.scheme == "orb") return run_coupled_with<dem::OrbScheme>(scene, opt, env);
  if (scene.dem.scheme == "islands") return run_coupled_with<dem::IslandsScheme>(scene, opt, env);
  return run_coupled_with<dem::ExplicitScheme>(scene, opt, env);
}

} // namespace

} // namespace cfddem::apps
