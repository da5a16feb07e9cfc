#include "apps/distributed_subiterated_run.hpp"

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <numeric>
#include <optional>
#include <string>
#include <type_traits>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/derived_numbers.hpp"
#include "apps/diagnostics_file.hpp"
#include "apps/rank_checkpoint.hpp"
#include "apps/rank_setup.hpp"
#include "apps/run_output.hpp"
#include "core/atomic_file.hpp"
#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/particle_snapshot.hpp"
#include "core/phase_timer.hpp"
#include "dem/distributed_orb_scheme.hpp"
#include "dem/granular_diagnostics.hpp"
#include "dem/islands_scheme.hpp"

namespace cfddem::apps {

namespace {

template <class Scheme>
RunResult run_distributed_subiterated(const Scene& scene, const RunOptions& opt,
                                      const ParallelEnv& env) {
  using Sub = SubiteratedState<Scheme>;
  constexpr bool kOrb = std::is_same_v<Scheme, dem::DistributedOrbScheme>;
  namespace fs = std::filesystem;
  const auto t_setup = clock::now();
  const Communicator comm = Communicator::world();
  const bool root = comm.rank() == 0;
  std::optional<Checkpoint> ck;
  if (!opt.restart.empty())
    ck = load_checkpoint(scene, opt.restart);
  const std::size_t n_saved = ck ? ck->particles.size() : 0;
  std::vector<std::uint32_t> mine;
  ParticleStore particles = rank_share(scene, ck, comm, &mine);
  std::optional<typename Sub::State> saved; // a restart: this rank's share of the scheme state
  if (ck)
    saved = subiterated_share<Scheme>(*ck, mine, n_saved, opt.restart);
  dem::ParticleRange range;
  const DerivedNumbers derived = derive(scene, particles, comm, &range);
  const dem::StepModel model = dem::make_step_model(scene, range);
  const std::size_t n_total = derived.particles;
  PhaseTimer timer;
  Scheme scheme(scene, particles, model, comm, timer);
  const double dt_sp = scheme.dt_sub();
  if (ck && ck->dt != dt_sp)
    throw ConfigError(opt.restart, fmt::format("checkpoint dt_sp {:.17g} s differs from the "
                                               "scene's {:.17g} s",
                                               ck->dt, dt_sp));
  const long long n_end = std::max(1LL, std::llround(scene.run.end_time / dt_sp));
  const long long k0 = ck ? ck->step : 0;
  if (ck && k0 > n_end)
    throw ConfigError("run.end_time", fmt::format("the checkpoint is at sub-iteration {}, past "
                                                  "the end of the run ({})",
                                                  k0, n_end));
  std::optional<DiagnosticsFile> diag = open_root_diagnostics(comm, opt.out_dir, kColumns);
  std::vector<std::vector<double>> rows; // kept for checkpoints (the same on every rank)
  auto add_row = [&](std::vector<double> r) {
    add_root_row(diag, r);
    rows.push_back(std::move(r));
  };
  auto every = [&](double interval) {
    return interval > 0.0 ? std::max(1LL, std::llround(interval / dt_sp)) : 0LL;
  };
  const long long out_every = std::max(1LL, std::llround(scene.output.interval / dt_sp));
  const long long snap_every = every(scene.output.snapshot_interval);
  // orb: checkpoints only at regrid points, as run_subiterated's; islands: at any sub-iteration.
  long long ckpt_every = every(scene.output.checkpoint_interval);
  if (kOrb && ckpt_every > 0)
    ckpt_every = (ckpt_every + scheme.nsubit() - 1) / scheme.nsubit() * scheme.nsubit();
  std::optional<SnapshotIndex> snapshots;
  if (root)
    snapshots.emplace(opt.out_dir);
  // Collective: every rank's owned particles into one file (rank order), each with its leaf.
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
  auto snapshot = [&](long long k) {
    const auto s = scheme.synchronised_previous(); // positions already wrapped
    SnapshotFields f;
    f.time = static_cast<double>(k) * dt_sp;
    f.step = k;
    f.x = s.x, f.y = s.y, f.z = s.z, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
    f.radius = s.radius, f.mass = s.mass, f.id = s.id, f.leaf = s.leaf, f.local_dt = s.local_dt;
    write_snapshot(f);
  };
  if (!opt.quiet && root)
    fmt::print(
        stderr,
        "cfddem: scene '{}', {} particles, {} scheme{}, dt_sp = {:.4e} s (fine dt = "
        "{:.4e} s), {} sub-iterations, {} rank(s) x {} thread(s){}\n",
        scene.name, n_total, Sub::kName,
        [&] {
          if constexpr (kOrb)
            return fmt::format(": {} leaves", scheme.leaf_count());
          else
            return std::string();
        }(),
        dt_sp, scheme.dt_fine(), n_end, env.ranks(), env.threads(),
        ck ? fmt::format(", restarted at sub-iteration {} from {}", k0, opt.restart) : "");
  const auto t_loop = clock::now();
  MeanTracker means;
  if (ck) {
    scheme.restore_state(std::move(*saved));
    for (auto& r : ck->rows)
      add_row(std::move(r));
    if (root)
      snapshots->restore(ck->snapshots);
    if (!rows.empty())
      means.resume(rows.back());
  } else {
    scheme.start();
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s0 = dem::measure({particles.x, particles.y, particles.z, particles.vx, particles.vy,
                                  particles.vz, particles.mass},
                                 comm);
    add_row(row(0.0, 0, s0, n_total, scheme, 0.0, dem::LeafStepStats{},
                means.next(0.0, s0.mean_velocity)));
    if (snap_every > 0) {
      SnapshotFields f;
      f.x = particles.x, f.y = particles.y, f.z = particles.z, f.vx = particles.vx;
      f.vy = particles.vy, f.vz = particles.vz, f.radius = particles.radius;
      f.mass = particles.mass, f.id = particles.id, f.dt = scheme.dt_fine();
      write_snapshot(f);
    }
  }
  // A checkpoint at sub-iteration k (apps/rank_checkpoint.hpp), written by rank 0.
  auto checkpoint = [&](long long k) {
    PhaseTimer::Scope io(timer, Phase::io);
    Checkpoint c;
    if (root)
      c = checkpoint_header(scene, Sub::kName, dt_sp, k, 0, rows, snapshots->entries());
    gather_subiterated(scheme, particles, comm, c); // collective
    std::string error;
    if (root) {
      try {
        write_checkpoint((fs::path(opt.out_dir) / fmt::format("checkpoint_{:09d}.h5", k)).string(),
                         c);
      } catch (const std::exception& e) {
        error = e.what();
      }
    }
    if (const std::string m = comm.agree_on_error(0, error); !m.empty())
      throw RunError(m);
  };
  auto last_progress = clock::now();
  for (long long k = k0; k <= n_end; ++k) {
    if (ckpt_every > 0 && k > k0 && k % ckpt_every == 0)
      checkpoint(k);
    const bool record = k > 0 && (k % out_every == 0 || k == n_end);
    const dem::LeafStepStats ls = record ? scheme.take_interval_stats() : dem::LeafStepStats{};
    const bool snap = k > 0 && snap_every > 0 && (k % snap_every == 0 || k == n_end);
    scheme.subiterate(record || snap);
    if (snap)
      snapshot(k);
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
      fmt::print(stderr, "sub-iteration {:>8} t = {:.6e} s ({:5.1f}%)  fine {} {:.2f}  ETA {}\n", k,
                 scheme.time(), 100 * frac, kOrb ? "leaves" : "particles",
                 scheme.last_fine_fraction(),
                 format_eta(wall * (1 - frac) / std::max(frac, 1e-12)));
    }
  }
  const double loop_seconds = seconds_since(t_loop);
  const std::vector<double> waits = comm.gather(comm.wait_seconds());
  const std::vector<double> owned = comm.gather(static_cast<double>(scheme.owned()));
  const std::vector<double> busy =
      comm.gather(timer.seconds(Phase::neighbor) + timer.seconds(Phase::force) +
                  timer.seconds(Phase::integrate));
  const nlohmann::ordered_json counts =
      rank_counts_json(comm, scheme.local_particle_steps(), scheme.local_pair_evaluations(), 0);
  if (root) {
    nlohmann::ordered_json j = run_json_header(scene, scene.name, derived, env, n_total);
    j["scheme"] = Sub::kName;
    j["distributed"] = true;
    j["dt"] = scheme.dt_fine();
    j["dt_sp"] = dt_sp;
    if constexpr (kOrb)
      j["leaves"] = scheme.leaf_count();
    j["steps"] = scheme.subiterations();
    j["steps_definition"] = "sub-iterations of dt_sp (one past the end, as the explicit loop)";
    j["regrids"] = scheme.regrids();
    j["rank_counts"] = counts;
    j["end_time"] = static_cast<double>(n_end) * dt_sp;
    j["loop_seconds"] = loop_seconds;
    j["setup_seconds"] = std::chrono::duration<double>(t_loop - t_setup).count();
    nlohmann::ordered_json ph = phase_json(timer, loop_seconds);
    if constexpr (kOrb)
      ph["note"] = "rank 0's phases; neighbor: regrid, migration, ghost exchange and the rows; "
                   "force: its leaves' local steps and the reductions that close a "
                   "sub-iteration";
    else
      ph["note"] = "rank 0's phases; neighbor: regrid, migration, ghosts, rows, speed bounds, "
                   "links and islands (with their reductions); force: free flight, the local "
                   "islands' tasks and the spanning islands' fine steps with their ghost "
                   "refreshes";
    j["phase_seconds"] = ph;
    add_work_counters(j, scheme, loop_seconds,
                      kOrb ? "candidate pairs evaluated per local step, over all ranks: pairs "
                             "within a leaf once, pairs across a leaf boundary once per side "
                             "(rows rebuilt at every sub-iteration)"
                           : "pairs inside a fine island evaluated per local step, over all "
                             "ranks (a pair across ranks counted once)");
    if constexpr (kOrb) {
      double fine = 0.0;
      std::size_t intervals = 0;
      const auto col = static_cast<std::size_t>(
          std::find(kColumns.begin(), kColumns.end(), "fine_leaf_fraction") - kColumns.begin());
      for (std::size_t r = 1; r < rows.size(); ++r)
        fine += rows[r][col], ++intervals;
      j["fine_leaf_fraction_mean"] = intervals > 0 ? fine / static_cast<double>(intervals) : 0.0;
      j["fine_leaf_fraction_definition"] =
          "mean over the diagnostics rows of the fraction of (non-empty leaf, sub-iteration) "
          "pairs on the fine step, over all ranks";
    } else {
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
          "islands with members on more than one rank: sub-iterations with at least one "
          "(outside the dense mode), their member particles per sub-iteration (mean), and their "
          "parts summed over ranks and sub-iterations; they take the fine steps together with a "
          "ghost refresh per fine step";
      j["expired_builds"] = scheme.expired_builds();
      j["expired_builds_definition"] =
          "builds (of neighbor_builds) made inside a sub-iteration because two particles' "
          "reaches (displacement since the last build + speed bound x dt_sp) could add up to "
          "the skin";
    }
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
    if constexpr (kOrb)
      j["regrid_policy"] = "parallel ORB + Hilbert knapsack every dem.regrid_interval (weights: "
                           "partition.weights); migration and ghosts at every sub-iteration";
    else
      j["regrid_policy"] = "parallel ORB + Hilbert knapsack at the first build after dem.nsubit "
                           "sub-iterations; migration, ghosts and rows at a build (when the "
                           "rows could miss a pair), not at every sub-iteration";
    double worst = 1.0;
    for (const double q : scheme.imbalances())
      worst = std::max(worst, q);
    j["load_imbalance"] = scheme.imbalances();
    j["load_imbalance_definition"] = "per regrid in this run: max over ranks / mean of the "
                                     "knapsack weight (orb: particles, or particles x local "
                                     "steps; islands: particles)";
    j["load_imbalance_max"] = worst;
    write_file_atomically((fs::path(opt.out_dir) / "run.json").string(), j.dump(2) + "\n");
  }
  if (!opt.quiet && root) {
    double wait_max = 0.0;
    for (const double w : waits)
      wait_max = std::max(wait_max, w);
    fmt::print(stderr,
               "Loop time of {:.4g} s on {} rank(s) x {} thread(s) for {} sub-iterations "
               "with {} particles ({} to run.end_time and one that completes the last row)\n",
               loop_seconds, env.ranks(), env.threads(), scheme.subiterations(), n_total, n_end);
    fmt::print(stderr,
               "Performance: {:.4g} particle-steps/s; {} force evaluations; rank 0: "
               "neighbor+exchange {:.3g} s, stepping {:.3g} s; MPI wait max {:.3g} s; max "
               "overlap {:.3g} r ({} beyond dem.max_overlap){}\n",
               loop_seconds > 0 ? static_cast<double>(scheme.particle_steps()) / loop_seconds : 0.0,
               scheme.pair_evaluations(), timer.seconds(Phase::neighbor),
               timer.seconds(Phase::force), wait_max, scheme.max_overlap_ratio(),
               scheme.overlap_violations(), [&] {
                 if constexpr (kOrb)
                   return std::string();
                 else
                   return fmt::format("; spanning sub-iterations {} of {}; bound violations {}",
                                      scheme.spanning_subiterations(), scheme.subiterations(),
                                      scheme.bound_violations());
               }());
  }
  return {opt.out_dir, loop_seconds, scheme.subiterations(), scheme.particle_steps()};
}

} // namespace

RunResult run_distributed_orb(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  return run_distributed_subiterated<dem::DistributedOrbScheme>(scene, opt, env);
}

RunResult run_distributed_islands(const Scene& scene, const RunOptions& opt,
                                  const ParallelEnv& env) {
  return run_distributed_subiterated<dem::IslandsScheme>(scene, opt, env);
}

} // namespace cfddem::apps
