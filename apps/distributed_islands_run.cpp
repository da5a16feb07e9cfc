#include "apps/distributed_islands_run.hpp"

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/derived_numbers.hpp"
#include "apps/diagnostics_file.hpp"
#include "apps/rank_setup.hpp"
#include "apps/run_output.hpp"
#include "core/atomic_file.hpp"
#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/particle_snapshot.hpp"
#include "core/phase_timer.hpp"
#include "dem/distributed_islands_scheme.hpp"
#include "dem/granular_diagnostics.hpp"

namespace cfddem::apps {

// run_distributed_orb's loop (apps/simulation.cpp) with the islands scheme: rows at multiples of
// output.interval rounded to whole sub-iterations, the state at sub-iteration K recorded by
// sub-iteration K+1, so the loop runs one sub-iteration past the end.
RunResult run_distributed_islands(const Scene& scene, const RunOptions& opt,
                                  const ParallelEnv& env) {
  namespace fs = std::filesystem;
  const auto t_setup = clock::now();
  const Communicator comm = Communicator::world();
  const bool root = comm.rank() == 0;
  std::optional<Checkpoint> none;
  ParticleStore particles = rank_share(scene, none, comm);
  dem::ParticleRange range;
  const DerivedNumbers derived = derive(scene, particles, comm, &range);
  const dem::StepModel model = dem::make_step_model(scene, range);
  const std::size_t n_total = derived.particles;
  PhaseTimer timer;
  dem::DistributedIslandsScheme scheme(scene, particles, model, comm, timer);
  const double dt_sp = scheme.dt_sub();
  const long long n_end = std::max(1LL, std::llround(scene.run.end_time / dt_sp));
  std::optional<DiagnosticsFile> diag = open_root_diagnostics(comm, opt.out_dir, kColumns);
  std::vector<std::vector<double>> rows;
  auto add_row = [&](std::vector<double> r) {
    if (diag)
      diag->add_row(r);
    rows.push_back(std::move(r));
  };
  const long long out_every = std::max(1LL, std::llround(scene.output.interval / dt_sp));
  const double snap_interval = scene.output.snapshot_interval;
  const long long snap_every =
      snap_interval > 0.0 ? std::max(1LL, std::llround(snap_interval / dt_sp)) : 0;
  std::optional<SnapshotIndex> snapshots;
  if (root)
    snapshots.emplace(opt.out_dir);
  auto write_snapshot = [&](const SnapshotFields& f) {
    PhaseTimer::Scope io(timer, Phase::io);
    const SnapshotEntry e = write_particle_snapshot(opt.out_dir, f, comm);
    std::string error;
    if (root) {
      try {
        snapshots->add(e);
      } catch (const std::exception& ex) {
        error = ex.what();
      }
    }
    if (const std::string m = comm.agree_on_error(0, error); !m.empty())
      throw RunError(m);
  };
  if (!opt.quiet && root)
    fmt::print(stderr,
               "cfddem: scene '{}', {} particles, islands scheme, dt_sp = {:.4e} s "
               "(fine dt = {:.4e} s), {} sub-iterations, {} rank(s) x {} thread(s)\n",
               scene.name, n_total, dt_sp, scheme.dt_fine(), n_end, env.ranks(), env.threads());
  const auto t_loop = clock::now();
  MeanTracker means;
  scheme.start();
  {
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s0 = dem::measure({particles.x, particles.y, particles.z, particles.vx, particles.vy,
                                  particles.vz, particles.mass},
                                 comm);
    add_row(row(0.0, 0, s0, n_total, scheme, 0.0, dem::LeafStepStats{},
                means.next(0.0, s0.mean_velocity)));
  }
  if (snap_every > 0) {
    SnapshotFields f;
    f.x = particles.x, f.y = particles.y, f.z = particles.z, f.vx = particles.vx;
    f.vy = particles.vy, f.vz = particles.vz, f.radius = particles.radius;
    f.mass = particles.mass, f.id = particles.id, f.dt = scheme.dt_fine();
    write_snapshot(f);
  }
  auto last_progress = clock::now();
  for (long long k = 0; k <= n_end; ++k) {
    const bool record = k > 0 && (k % out_every == 0 || k == n_end);
    const dem::LeafStepStats ls = record ? scheme.take_interval_stats() : dem::LeafStepStats{};
    const bool snap = k > 0 && snap_every > 0 && (k % snap_every == 0 || k == n_end);
    scheme.subiterate(record || snap);
    if (snap) {
      const auto s = scheme.synchronised_previous(); // positions already wrapped
      SnapshotFields f;
      f.time = static_cast<double>(k) * dt_sp;
      f.step = k;
      f.x = s.x, f.y = s.y, f.z = s.z, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
      f.radius = s.radius, f.mass = s.mass, f.id = s.id, f.leaf = s.leaf, f.local_dt = s.local_dt;
      write_snapshot(f);
    }
    if (record) {
      PhaseTimer::Scope io(timer, Phase::io);
      const auto s = scheme.synchronised_previous();
      const auto st = dem::measure({s.x, s.y, s.z, s.vx, s.vy, s.vz, s.mass}, comm);
      const double t = static_cast<double>(k) * dt_sp;
      add_row(row(t, k, st, n_total, scheme, seconds_since(t_loop), ls,
                  means.next(t, st.mean_velocity)));
    }
    if (!opt.quiet && root &&
        std::chrono::duration<double>(clock::now() - last_progress).count() >=
            scene.output.progress_seconds) {
      last_progress = clock::now();
      const double wall = seconds_since(t_loop);
      const double frac = static_cast<double>(k) / static_cast<double>(n_end);
      fmt::print(stderr,
                 "sub-iteration {:>8} t = {:.6e} s ({:5.1f}%)  fine particles {:.2f}  "
                 "ETA {}\n",
                 k, scheme.time(), 100 * frac, scheme.last_fine_fraction(),
                 format_eta(wall * (1 - frac) / std::max(frac, 1e-12)));
    }
  }
  if (diag)
    diag->flush();
  const double loop_seconds = seconds_since(t_loop);
  const std::vector<double> waits = comm.gather(comm.wait_seconds());
  const std::vector<double> owned = comm.gather(static_cast<double>(scheme.owned()));
  const std::vector<double> busy =
      comm.gather(timer.seconds(Phase::neighbor) + timer.seconds(Phase::force) +
                  timer.seconds(Phase::integrate));
  if (root) {
    nlohmann::ordered_json j = run_json_header(scene, scene.name, derived, env, n_total);
    j["scheme"] = "islands";
    j["distributed"] = true;
    j["dt"] = scheme.dt_fine();
    j["dt_sp"] = dt_sp;
    j["steps"] = scheme.subiterations();
    j["steps_definition"] = "sub-iterations of dt_sp (one past the end, as the explicit loop)";
    j["regrids"] = scheme.regrids();
    j["end_time"] = static_cast<double>(n_end) * dt_sp;
    j["loop_seconds"] = loop_seconds;
    j["setup_seconds"] = std::chrono::duration<double>(t_loop - t_setup).count();
    nlohmann::ordered_json ph = phase_json(timer, loop_seconds);
    ph["note"] = "rank 0's phases; neighbor: regrid, migration, ghosts, rows, speed bounds, "
                 "links and islands (with their reductions); force: free flight, the local "
                 "islands' tasks and the spanning islands' fine steps with their ghost refreshes";
    j["phase_seconds"] = ph;
    add_work_counters(j, scheme, loop_seconds,
                      "pairs inside a fine island evaluated per local step, over all ranks (a "
                      "pair across ranks counted once)");
    j["bound_violations"] = scheme.bound_violations();
    j["global_subiterations"] = scheme.global_subiterations();
    j["global_subiterations_definition"] =
        "sub-iterations where more than a quarter of all particles were linked, so every "
        "particle took the fine steps together (the distributed explicit scheme's work)";
    const auto subits = static_cast<double>(std::max<std::int64_t>(1, scheme.subiterations()));
    j["spanning_subiterations"] = scheme.spanning_subiterations();
    j["spanning_subiteration_fraction"] =
        static_cast<double>(scheme.spanning_subiterations()) / subits;
    j["spanning_particles_mean"] = static_cast<double>(scheme.spanning_particles()) / subits;
    j["spanning_island_parts"] = scheme.spanning_island_parts();
    j["spanning_definition"] =
        "islands with members on more than one rank: sub-iterations with at least one (outside "
        "the dense mode), their member particles per sub-iteration (mean), and their parts summed "
        "over ranks and sub-iterations; they take the fine steps together with a ghost refresh "
        "per fine step";
    j["expired_builds"] = scheme.expired_builds();
    j["expired_builds_definition"] =
        "builds (of neighbor_builds) made inside a sub-iteration because two particles' reaches "
        "(displacement since the last build + speed bound x dt_sp) could add up to the skin";
    j["subiteration_retries"] = scheme.retries();
    j["final_skin"] = scheme.skin();
    j["max_overlap_ratio"] = scheme.max_overlap_ratio();
    j["overlap_violations"] = scheme.overlap_violations();
    j["mpi_wait_seconds"] = waits;
    j["mpi_wait_definition"] = "per rank: wall time inside MPI calls (reductions, the parallel "
                               "ORB, particle and ghost exchanges), set-up included";
    j["owned_particles_at_end"] = owned;
    j["busy_seconds"] = busy;
    j["busy_definition"] = "per rank: neighbor + force + integrate phases; their spread is the "
                           "load imbalance in time";
    double worst = 1.0;
    for (const double q : scheme.imbalances())
      worst = std::max(worst, q);
    j["load_imbalance_max"] = worst;
    j["load_imbalance_definition"] = "largest over the regrids of max over ranks / mean of the "
                                     "particles per rank";
    write_file_atomically((fs::path(opt.out_dir) / "run.json").string(), j.dump(2) + "\n");
  }
  if (!opt.quiet && root) {
    double wait_max = 0.0;
    for (const double w : waits)
      wait_max = std::max(wait_max, w);
    fmt::print(stderr,
               "Loop time of {:.4g} s on {} rank(s) x {} thread(s) for {} sub-iterations "
               "with {} particles\n",
               loop_seconds, env.ranks(), env.threads(), scheme.subiterations(), n_total);
    fmt::print(stderr,
               "Performance: {:.4g} particle-steps/s; {} force evaluations; spanning "
               "sub-iterations {} of {}; MPI wait max {:.3g} s; max overlap {:.3g} r ({} "
               "beyond dem.max_overlap); bound violations {}\n",
               loop_seconds > 0 ? static_cast<double>(scheme.particle_steps()) / loop_seconds : 0.0,
               scheme.pair_evaluations(), scheme.spanning_subiterations(), scheme.subiterations(),
               wait_max, scheme.max_overlap_ratio(), scheme.overlap_violations(),
               scheme.bound_violations());
  }
  return {opt.out_dir, loop_seconds, scheme.subiterations(), scheme.particle_steps()};
}

} // namespace cfddem::apps
