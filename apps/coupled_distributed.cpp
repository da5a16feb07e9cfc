#include "apps/coupled_distributed.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <optional>
#include <type_traits>

#include <HYPRE_utilities.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/coupled_checkpoint.hpp"
#include "apps/coupled_schedule.hpp"
#include "apps/coupled_step.hpp"
#include "apps/derived_numbers.hpp"
#include "apps/diagnostics_file.hpp"
#include "apps/gas_rebalance.hpp"
#include "apps/gas_routing.hpp"
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
#include "dem/distributed_orb_scheme.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/granular_diagnostics.hpp"
#include "dem/islands_scheme.hpp"
#include "partition/cell_box_decomposition.hpp"

namespace cfddem::apps {

namespace {

// The gas grid's boxes, one per rank (GasCoupling's), as a decomposition of the domain: the
// explicit scheme's ownership and the routing's destination rule, the same on every rank.
partition::RankDecomposition box_decomposition(const Scene& scene,
                                               const std::vector<CellBox>& boxes) {
  const fluid::MacGridSpec spec = fluid_grid_spec(scene);
  std::array<double, 3> spacing{};
  for (int a = 0; a < 3; ++a)
    spacing[a] = spec.spacing[a] > 0.0 ? spec.spacing[a] : spec.extent[a] / spec.cells[a];
  return partition::decomposition_of_cell_boxes(boxes, spec.origin, spacing,
                                                {scene.domain.lo, scene.domain.hi});
}

// Mirrors run_coupled_with<ExplicitScheme / OrbScheme> (simulation.cpp) step for step, so that
// the rows agree with the one-rank run to round-off: the same fluid-step lengths and sub-cycles
// (explicit: ceil(dt_f / dt_dem) steps; sub-iterated: dem.nsubit sub-iterations of dt_f / nsubit,
// a regrid at every fluid step), rows written by the first particle step after an output time
// with the gas taken at that time.
// Scheme: dem::DistributedExplicitScheme owns particles by gas box (its decomposition is the gas
// boxes), so the gas deposits its owned particles directly. A sub-iterated scheme
// (dem::DistributedOrbScheme; any with its interface: start, subiterate, take_interval_stats,
// set_external_force, owned, synchronised_previous) owns them by its own leaves, so each fluid
// step routes them to the gas boxes and the forces back (GasRouting).
template <class Scheme>
RunResult run_coupled_ranks(const Scene& scene_in, const RunOptions& opt, const ParallelEnv& env) {
  constexpr bool kSub = !std::is_same_v<Scheme, dem::DistributedExplicitScheme>;
  constexpr bool kLeaves = std::is_same_v<Scheme, dem::DistributedOrbScheme>;
  const char* scheme_name = kLeaves ? "orb" : kSub ? "islands" : "explicit";
  namespace fs = std::filesystem;
  const auto t_setup = clock::now();
  const Communicator comm = Communicator::world();
  const bool root = comm.rank() == 0;
  // Every rank builds its share of the particles (every R-th, make_initial_share, or of the
  // checkpoint's); the first particle step or the restore sends each to its owner (explicit: its
  // gas box's rank; orb: its leaf's).
  const GasBlock block0 = gas_block(scene_in, comm);
  std::optional<Checkpoint> ck;
  if (!opt.restart.empty())
    ck = load_checkpoint(scene_in, opt.restart, block0, comm);
  const dem::ContactHistory saved_history = ck ? saved_contact_history(*ck) : dem::ContactHistory{};
  const std::size_t n_saved = ck ? ck->particles.size() : 0;
  std::vector<std::uint32_t> taken;
  ParticleStore particles = rank_share(scene_in, ck, comm, &taken);
  // Sub-iterated: this rank's share of the scheme state (orb: half steps and costs; islands:
  // half steps and fine-sub-iteration counts).
  using SavedState =
      typename SubiteratedState<std::conditional_t<kSub, Scheme, dem::DistributedOrbScheme>>::State;
  std::optional<SavedState> saved;
  if constexpr (kSub)
    if (ck)
      saved = subiterated_share<Scheme>(*ck, taken, n_saved, opt.restart);
  dem::ParticleRange range;
  const DerivedNumbers derived = derive(scene_in, particles, comm, &range);
  const std::size_t n_total = derived.particles;
  Scene scene = scene_in;
  const double dt_dem = dem::make_step_model(scene_in, range).dt;
  const bool fixed = scene.fluid.dt > 0.0;
  long long n_fixed = 0;
  if (kSub) {
    n_fixed = scene.dem.nsubit;
    scene.dem.regrid_interval = scene.fluid.dt; // validate_fluid: a fixed fluid.dt
  } else if (fixed) {
    n_fixed =
        std::max(1LL, static_cast<long long>(std::ceil(scene.fluid.dt / dt_dem * (1 - 1e-12))));
    scene.dem.dt = scene.fluid.dt / static_cast<double>(n_fixed);
  } else {
    scene.dem.dt = dt_dem;
  }
  const dem::StepModel model = dem::make_step_model(scene, range);
  PhaseTimer timer;
  static const bool hypre_ready = (HYPRE_Init(), true); // once per process; freed at exit
  (void)hypre_ready;
  Scheme scheme(scene, particles, model, comm, timer);
  const dem::DomainGeometry geom(scene.domain);
  std::optional<GasRouting> routing;
  std::vector<CellBox> boxes0;
  try {
    boxes0 = orb_cell_boxes(fluid_grid_spec(scene).cells, comm.size(), fluid::kMinBoxWidth);
  } catch (const std::invalid_argument& e) {
    throw ConfigError("scene key 'fluid.cells'", e.what());
  }
  // The gas boxes decide the explicit scheme's owners and the routing's destinations (at the
  // start the count cut, later the weighted cuts of the gas regrids).
  const auto own_by_boxes = [&](const std::vector<CellBox>& boxes) {
    if constexpr (kSub)
      routing->set_boxes(box_decomposition(scene, boxes));
    else
      scheme.set_decomposition(box_decomposition(scene, boxes));
  };
  double dt = 0.0, snap_dt = 0.0; // snap_dt: the particles' fine step (snapshots)
  if constexpr (kSub) {
    routing.emplace(comm, box_decomposition(scene, boxes0), geom);
    dt = scheme.dt_sub();
    snap_dt = scheme.dt_fine();
  } else {
    own_by_boxes(boxes0);
    dt = snap_dt = scheme.dt();
  }
  const double end = scene.run.end_time;
  if (ck && ck->dt != dt)
    throw ConfigError(opt.restart, fmt::format("checkpoint particle step {:.17g} s differs from "
                                               "the scene's {:.17g} s",
                                               ck->dt, dt));
  if (ck && ck->loop.time > end + 1e-6 * dt)
    throw ConfigError("run.end_time", fmt::format("the checkpoint is at t = {:.17g} s, past the "
                                                  "end of the run ({:.17g} s)",
                                                  ck->loop.time, end));

  std::optional<DiagnosticsFile> diag = open_root_diagnostics(comm, opt.out_dir, kColumns);
  std::vector<std::vector<double>> rows; // kept for checkpoints (the same on every rank)
  auto add_row = [&](std::vector<double> r) {
    add_root_row(diag, r);
    rows.push_back(std::move(r));
  };
  // Snapshots: every rank's particles and gas box written collectively into one file (parallel
  // HDF5); rank 0 keeps the XDMF index. Particles as on one rank (the synchronised state of the
  // first particle step after the snapshot time), the gas taken at that time.
  std::optional<SnapshotIndex> snapshots;
  if (root && scene.output.snapshot_interval > 0)
    snapshots.emplace(opt.out_dir);
  auto write_snapshot = [&](SnapshotFields& f, const CellFields& cells) {
    PhaseTimer::Scope io(timer, Phase::io);
    const std::size_t n = f.x.size();
    std::vector<double> w[3] = {std::vector<double>(n), std::vector<double>(n),
                                std::vector<double>(n)};
    for (std::size_t i = 0; i < n; ++i)
      w[0][i] = geom.wrap(f.x[i], 0), w[1][i] = geom.wrap(f.y[i], 1), w[2][i] = geom.wrap(f.z[i], 2);
    f.x = w[0], f.y = w[1], f.z = w[2];
    f.dt = snap_dt;
    f.cells = &cells;
    const SnapshotEntry e = write_particle_snapshot(opt.out_dir, f, comm); // collective
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
  if (!opt.quiet && root) {
    const auto& c = scene.fluid.cells;
    fmt::print(
        stderr,
        "cfddem: scene '{}', {} particles, gas {} x {} x {} cells ({} drag, {} "
        "deposition), dt_f = {}, {} = {:.4e} s{}, {} rank(s) x {} "
        "thread(s), {} scheme{}\n",
        scene.name, n_total, c[0], c[1], c[2], scene.fluid.drag, scene.fluid.deposition,
        fixed ? fmt::format("{:.4e} s", scene.fluid.dt)
              : fmt::format("adaptive (cfl {})", scene.fluid.cfl),
        kSub ? "dt_sp (sub-iteration)" : "particle dt", dt,
        fixed ? fmt::format(" ({} {} per fluid step)", n_fixed, kSub ? "sub-iterations" : "steps")
              : std::string(),
        env.ranks(), env.threads(), scheme_name,
        ck ? fmt::format(", restarted at t = {:.6e} s from {}", ck->loop.time, opt.restart) : "");
  }
  // The loop's wall time starts before start() and the t = 0 outputs, which the phase timer
  // counts too (else phase_seconds.other came out negative).
  const auto t_loop = clock::now();
  // The snapshot at t = 0 holds the initial velocities, as on one rank: this rank's share,
  // kept before start() shifts them to the half step.
  ParticleStore initial;
  if (!ck && scene.output.snapshot_interval > 0)
    initial = particles;
  // Explicit: start() (or the restore) moves every particle to its box's rank; the gas then
  // deposits the owned ones. Sub-iterated: the owned particles (any split until the first
  // sub-iteration) go to the gas boxes by routing.
  if (!ck)
    scheme.start();
  else if constexpr (kSub)
    restore_coupled_scheme<Scheme>(*ck, taken, std::move(*saved), scheme);
  else
    restore_coupled_scheme(*ck, taken, saved_history, scheme);
  // The particles the gas deposits and their force afterwards, one per owned particle.
  auto to_gas = [&]() -> const ParticleStore& {
    if constexpr (kSub)
      return routing->route(particles, scheme.owned());
    else
      return particles;
  };
  GasCoupling gas(scene, to_gas(), &comm, kSub ? GasCoupling::kAllParticles : scheme.owned());
  // Deposit, gas step, force; the scheme holds the force for the particle sub-cycle.
  auto gas_step = [&](double dt_f) {
    if constexpr (kSub) {
      gas.step(to_gas(), dt_f);
      routing->return_force({gas.force(0), gas.force(1), gas.force(2)});
      // The owed half kick settled with the old force (replace_external_force).
      scheme.replace_external_force(routing->force(0), routing->force(1), routing->force(2));
    } else {
      gas.step(particles, dt_f, scheme.owned());
      scheme.set_external_force(gas.force(0), gas.force(1), gas.force(2));
    }
  };
  CoupledLoopState loop;
  loop.next_output = scene.output.interval;
  loop.next_snapshot = scene.output.snapshot_interval;
  long long k_last_row = 0;
  MeanTracker means;
  if (ck) {
    restore_coupled_gas(*ck, opt.restart, gas, loop);
    k_last_row = ck->last_row_step;
    for (auto& r : ck->rows)
      add_row(std::move(r));
    if (snapshots)
      snapshots->restore(ck->snapshots);
    if (!rows.empty())
      means.resume(rows.back());
  }
  if (!ck && scene.output.snapshot_interval > 0) {
    const CellFields cells = gas.cell_fields();
    SnapshotFields f;
    f.x = initial.x, f.y = initial.y, f.z = initial.z, f.vx = initial.vx, f.vy = initial.vy;
    f.vz = initial.vz, f.radius = initial.radius, f.mass = initial.mass, f.id = initial.id;
    write_snapshot(f, cells);
    initial = ParticleStore();
  }
  if (!ck) {
    PhaseTimer::Scope io(timer, Phase::io);
    // As the one-rank loop: the velocities after start() (the half step).
    const std::size_t n = scheme.owned();
    const auto s0 = dem::measure({{particles.x.data(), n},
                                  {particles.y.data(), n},
                                  {particles.z.data(), n},
                                  {particles.vx.data(), n},
                                  {particles.vy.data(), n},
                                  {particles.vz.data(), n},
                                  {particles.mass.data(), n}},
                                 comm);
    add_row(row(0.0, 0, s0, n_total, scheme, 0.0, dem::LeafStepStats{0, 0, 0, 1},
                means.next(0.0, s0.mean_velocity, gas.diagnostics())));
  }
  double& t = loop.time;
  auto last_progress = clock::now();
  auto particle_step = [&](bool record, bool snap) {
    dem::LeafStepStats ls{};
    long long k = 0;
    if constexpr (kSub) {
      if (record)
        ls = scheme.take_interval_stats(); // collective
      scheme.subiterate(record || snap);
      k = scheme.subiterations() - 1;
    } else {
      scheme.step(record || snap);
      k = scheme.steps_taken() - 1;
    }
    const auto s = scheme.synchronised_previous();
    const std::size_t n = s.x.size();
    // The owned particles' mass, radius and id in the synchronised order.
    std::span<const double> mass(particles.mass.data(), n), radius(particles.radius.data(), n);
    std::span<const std::int64_t> id(particles.id.data(), n);
    if constexpr (kSub)
      mass = s.mass, radius = s.radius, id = s.id;
    if (snap) {
      SnapshotFields f;
      f.time = loop.row_time;
      f.step = k;
      f.x = s.x, f.y = s.y, f.z = s.z, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
      f.radius = radius, f.mass = mass, f.id = id;
      if constexpr (kSub)
        f.leaf = s.leaf, f.local_dt = s.local_dt;
      write_snapshot(f, loop.snapshot_cells);
    }
    if (!record)
      return;
    PhaseTimer::Scope io(timer, Phase::io);
    const auto st = dem::measure({s.x, s.y, s.z, s.vx, s.vy, s.vz, mass}, comm);
    if constexpr (!kSub) {
      const auto steps = static_cast<double>(k - k_last_row);
      ls = dem::LeafStepStats{steps, steps, steps, 1.0};
    }
    k_last_row = k;
    add_row(row(loop.row_time, k, st, n_total, scheme, seconds_since(t_loop), ls,
                means.next(loop.row_time, st.mean_velocity, loop.row_fluid)));
  };
  // Checkpoints at the fluid times that are multiples of the interval, after the restart time.
  const double ckpt_interval = scene.output.checkpoint_interval;
  double next_ckpt = ckpt_interval > 0.0
                         ? (std::floor(t / ckpt_interval + 1e-6) + 1.0) * ckpt_interval
                         : std::numeric_limits<double>::infinity();
  const double tol = 1e-6 * dt;
  // Gas regrids (partition.gas_regrid_interval): the boxes cut again by the cells' weights with
  // the particle steps of the last fluid step; moved when that is predicted to cut the largest
  // load by more than kRegridGain of the mean, so a balanced run does not churn.
  constexpr double kRegridGain = 0.02;
  const double regrid_every = scene.partition.gas_regrid_interval;
  // After a restart: the first multiple of the interval from the checkpoint's time on (the gas
  // boxes restart from the count cut and are recut after the first fluid step).
  double next_regrid = regrid_every;
  while (regrid_every > 0.0 && next_regrid < t - tol)
    next_regrid += regrid_every;
  long long last_n_sub = 0;
  nlohmann::ordered_json regrids = nlohmann::ordered_json::array();
  auto gas_regrid = [&] {
    PhaseTimer::Scope fl(timer, Phase::fluid);
    // The particles this rank's gas box deposits (sub-iterated: the routed copies of the last
    // fluid step, wrapped; each weighs its dem.nsubit sub-iterations, not its local steps).
    const ParticleStore& dep = kSub ? routing->routed() : particles;
    const std::size_t n = kSub ? dep.size() : scheme.owned();
    std::vector<double> w[3] = {std::vector<double>(n), std::vector<double>(n),
                                std::vector<double>(n)};
    for (std::size_t i = 0; i < n; ++i)
      w[0][i] = geom.wrap(dep.x[i], 0), w[1][i] = geom.wrap(dep.y[i], 1),
      w[2][i] = geom.wrap(dep.z[i], 2);
    const std::vector<double> steps(n, static_cast<double>(last_n_sub));
    GasBalance b;
    try {
      b = balance_gas_boxes(gas, w[0], w[1], w[2], steps, scene.partition.cell_weight, comm);
    } catch (const std::invalid_argument& e) {
      throw ConfigError("scene key 'fluid.cells'", e.what());
    }
    const bool move = b.boxes != gas.boxes() && b.imbalance_after < b.imbalance_before - kRegridGain;
    std::size_t sent = 0;
    if (move) {
      sent = gas.rebox(b.boxes);
      own_by_boxes(b.boxes); // sub-iterated: the next route() follows the new boxes
      if constexpr (!kSub)
        scheme.redistribute_now();
    }
    regrids.push_back({{"time", t},
                       {"imbalance_before", b.imbalance_before},
                       {"imbalance_after", move ? b.imbalance_after : b.imbalance_before},
                       {"moved", move},
                       {"gas_values_sent", comm.sum(static_cast<std::int64_t>(sent))}});
  };
  while (end - t > tol) {
    if (regrid_every > 0.0 && last_n_sub > 0 && t >= next_regrid - tol) {
      gas_regrid();
      while (next_regrid <= t + tol) next_regrid += regrid_every;
    }
    const bool no_particles = n_total == 0 && !fixed;
    const long long n_sub =
        no_particles ? 1 : particle_steps_per_fluid_step(scene, gas, n_fixed, dt, end - t);
    last_n_sub = n_sub;
    const double dt_f = fluid_step_length(scene, gas, no_particles, n_sub, dt, end - t);
    {
      PhaseTimer::Scope fl(timer, Phase::fluid);
      gas_step(dt_f);
    }
    for (long long q = 0; q < n_sub; ++q) {
      particle_step(q == 0 && loop.row_pending, q == 0 && loop.snapshot_pending);
      if (q == 0)
        loop.row_pending = loop.snapshot_pending = false;
    }
    ++loop.fluid_steps;
    loop.dt_f_sum += dt_f;
    t = fixed ? static_cast<double>(loop.fluid_steps) * scene.fluid.dt : t + dt_f;
    const bool last = end - t <= tol;
    {
      PhaseTimer::Scope io(timer, Phase::io);
      mark_due_outputs(loop, gas, scene, t, last, tol);
    }
    if (t >= next_ckpt - tol) {
      PhaseTimer::Scope io(timer, Phase::io);
      // The gas box now (a gas regrid may have moved it from the count cut).
      const GasBlock block{block0.cells, gas.boxes()[static_cast<std::size_t>(comm.rank())]};
      write_coupled_checkpoint(
          (fs::path(opt.out_dir) / fmt::format("checkpoint_{:09d}.h5", loop.fluid_steps)).string(),
          checkpoint_header(scene_in, scheme_name, dt, loop.fluid_steps, k_last_row, rows,
                            snapshots ? snapshots->entries() : std::vector<SnapshotEntry>{}),
          scheme, particles, gas, loop, block, comm);
      while (next_ckpt <= t + tol)
        next_ckpt += ckpt_interval;
    }
    if (!opt.quiet && root &&
        std::chrono::duration<double>(clock::now() - last_progress).count() >=
            scene.output.progress_seconds) {
      last_progress = clock::now();
      const double wall = seconds_since(t_loop);
      const double frac = t / end;
      fmt::print(stderr,
                 "fluid step {:>8} t = {:.6e} s ({:5.1f}%)  fluid {:.0f}% of wall  ETA {}\n",
                 loop.fluid_steps, t, 100 * frac, 100 * timer.seconds(Phase::fluid) / wall,
                 format_eta(wall * (1 - frac) / std::max(frac, 1e-12)));
    }
  }
  if (loop.row_pending || loop.snapshot_pending)
    particle_step(loop.row_pending, loop.snapshot_pending); // one step past the end, as on one rank
  const double loop_seconds = seconds_since(t_loop);
  const std::vector<double> waits = comm.gather(comm.wait_seconds());
  const std::vector<double> owned = comm.gather(static_cast<double>(scheme.owned()));
  const std::vector<double> fluid_seconds = comm.gather(timer.seconds(Phase::fluid));
  const std::vector<double> routing_seconds = comm.gather(routing ? routing->seconds() : 0.0);
  const std::vector<double> routed_away =
      comm.gather(routing ? static_cast<double>(routing->sent_away()) : 0.0);
  const auto& box = gas.solver().grid().cells();
  const nlohmann::ordered_json counts = rank_counts_json(
      comm, scheme.local_particle_steps(), scheme.local_pair_evaluations(),
      static_cast<std::int64_t>(box[0]) * box[1] * box[2] * gas.gas_substeps());
  if (root) {
    nlohmann::ordered_json j = run_json_header(scene_in, scene.name, derived, env, n_total);
    j["scheme"] = scheme_name;
    j["distributed"] = true;
    if constexpr (kSub) {
      j["dt"] = scheme.dt_fine();
      j["dt_sp"] = dt;
      if constexpr (kLeaves)
        j["leaves"] = scheme.leaf_count();
      j["steps"] = scheme.subiterations();
      j["subiteration_retries"] = scheme.retries();
      j["max_overlap_ratio"] = scheme.max_overlap_ratio();
      j["overlap_violations"] = scheme.overlap_violations();
      if constexpr (!kLeaves) {
        // Islands: as the DEM-only R-rank run.json (apps/distributed_subiterated_run.cpp).
        const auto subits = static_cast<double>(std::max<std::int64_t>(1, scheme.subiterations()));
        j["bound_violations"] = scheme.bound_violations();
        j["global_subiterations"] = scheme.global_subiterations();
        j["spanning_subiterations"] = scheme.spanning_subiterations();
        j["spanning_particles_mean"] = static_cast<double>(scheme.spanning_particles()) / subits;
        j["spanning_definition"] =
            "sub-iterations with an island whose members are on more than one rank (outside the "
            "dense mode), and their member particles per sub-iteration (mean)";
      }
    } else {
      j["dt"] = dt;
      j["steps"] = scheme.steps_taken();
    }
    j["fluid_steps"] = loop.fluid_steps;
    j["rank_counts"] = counts;
    j["fluid_dt_mean"] =
        loop.fluid_steps > 0 ? loop.dt_f_sum / static_cast<double>(loop.fluid_steps) : 0.0;
    j["gas_substeps"] = gas.gas_substeps();
    j["projection_iterations"] = gas.projection_iterations();
    j["projection_fallbacks"] = gas.projection_fallbacks();
    j["end_time"] = t;
    j["loop_seconds"] = loop_seconds;
    j["setup_seconds"] = std::chrono::duration<double>(t_loop - t_setup).count();
    j["wall_seconds_per_fluid_step"] =
        loop.fluid_steps > 0 ? loop_seconds / static_cast<double>(loop.fluid_steps) : 0.0;
    nlohmann::ordered_json ph = phase_json(timer, loop_seconds);
    ph["note"] = "rank 0's phases; fluid: deposition, gas step (predictor, projection over the "
                 "ranks), interpolation and particle forces (with orb: and the routing of the "
                 "particles to the gas boxes and of their forces back); neighbor + force: the "
                 "particle sub-cycle";
    j["phase_seconds"] = ph;
    add_work_counters(j, scheme, loop_seconds,
                      kSub ? "candidate pairs evaluated per local step, over all ranks: pairs "
                             "within a leaf once, pairs across a leaf boundary once per side "
                             "(rows rebuilt at every sub-iteration)"
                           : "neighbor-list pairs evaluated (each pair once per step), over all "
                             "ranks");
    j["mpi_wait_seconds"] = waits;
    j["fluid_seconds"] = fluid_seconds;
    j["owned_particles_at_end"] = owned;
    std::vector<std::int64_t> cells;
    for (const CellBox& b : gas.boxes())
      cells.push_back(b.count());
    j["gas_cells_per_rank"] = cells;
    if constexpr (kSub) {
      j["decomposition"] = "the gas grid's ORB boxes, one per rank; particles owned by their "
                           "leaf's rank (parallel ORB + knapsack), routed to their gas box's rank "
                           "and their force back once per fluid step (boxes cut by cell count, "
                           "then by weight at gas regrids)";
      double worst = 0.0;
      for (const double r : routing_seconds)
        worst = std::max(worst, r);
      j["gas_routing_seconds"] = routing_seconds;
      j["gas_routing_seconds_per_fluid_step"] =
          loop.fluid_steps > 0 ? worst / static_cast<double>(loop.fluid_steps) : 0.0;
      j["gas_routing_copies_away_at_end"] = routed_away;
      j["gas_routing_definition"] = "per rank: wall time packing, sending and unpacking the "
                                    "particle copies to the gas boxes and their forces back "
                                    "(part of the fluid phase); per fluid step: the slowest "
                                    "rank's; copies away: particles of the last fluid step "
                                    "whose gas box is on another rank";
    } else {
      j["decomposition"] = "the gas grid's ORB boxes, one per rank (cut by cell count, then by "
                           "weight at gas regrids); particles owned by the rank whose box holds "
                           "them (settled at neighbor rebuilds and gas regrids)";
    }
    j["gas_regrids"] = regrids;
    write_file_atomically((fs::path(opt.out_dir) / "run.json").string(), j.dump(2) + "\n");
  }
  if (!opt.quiet && root)
    fmt::print(stderr,
               "Loop time of {:.4g} s for {} fluid steps on {} rank(s) x {} thread(s) "
               "with {} particles; fluid {:.3g} s ({:.0f}%) on rank 0\n",
               loop_seconds, loop.fluid_steps, env.ranks(), env.threads(), n_total,
               timer.seconds(Phase::fluid),
               100 * timer.seconds(Phase::fluid) / std::max(loop_seconds, 1e-300));
  return {opt.out_dir, loop_seconds, k_last_row + 1, scheme.particle_steps()};
}

} // namespace

RunResult run_coupled_distributed(const Scene& scene, const RunOptions& opt,
                                  const ParallelEnv& env) {
  if (scene.dem.scheme == "orb")
    return run_coupled_ranks<dem::DistributedOrbScheme>(scene, opt, env);
  if (scene.dem.scheme == "islands")
    return run_coupled_ranks<dem::IslandsScheme>(scene, opt, env);
  return run_coupled_ranks<dem::DistributedExplicitScheme>(scene, opt, env);
}

} // namespace cfddem::apps
