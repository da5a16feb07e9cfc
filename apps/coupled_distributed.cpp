#include "apps/coupled_distributed.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <optional>

#include <HYPRE_utilities.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/coupled_checkpoint.hpp"
#include "apps/coupled_step.hpp"
#include "apps/derived_numbers.hpp"
#include "apps/diagnostics_file.hpp"
#include "apps/coupled_schedule.hpp"
#include "apps/rank_setup.hpp"
#include "apps/run_output.hpp"
#include "core/atomic_file.hpp"
#include "core/communicator.hpp"
#include "core/particle_snapshot.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"
#include "core/phase_timer.hpp"
#include "dem/distributed_explicit_scheme.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/granular_diagnostics.hpp"
#include "partition/cell_box_decomposition.hpp"

namespace cfddem::apps {

// Mirrors run_coupled_with<ExplicitScheme> (simulation.cpp) step for step, so that the rows
// agree with the one-rank run to round-off: the same fluid-step lengths and sub-cycles, rows
// written by the first particle step after an output time with the gas taken at that time.
RunResult run_coupled_distributed(const Scene& scene_in, const RunOptions& opt,
                                  const ParallelEnv& env) {
  namespace fs = std::filesystem;
  const auto t_setup = clock::now();
  const Communicator comm = Communicator::world();
  const bool root = comm.rank() == 0;
  // Every rank builds its share of the particles (every R-th, make_initial_share, or of the
  // checkpoint's); start() or the restore sends each to the rank whose gas box holds it.
  const GasBlock block = gas_block(scene_in, comm);
  std::optional<Checkpoint> ck;
  if (!opt.restart.empty()) ck = load_checkpoint(scene_in, opt.restart, block, comm);
  std::vector<std::uint32_t> taken;
  ParticleStore particles = rank_share(scene_in, ck, comm, &taken);
  dem::ParticleRange range;
  const DerivedNumbers derived = derive(scene_in, particles, comm, &range);
  const std::size_t n_total = derived.particles;
  Scene scene = scene_in;
  const double dt_dem = dem::make_step_model(scene_in, range).dt;
  const bool fixed = scene.fluid.dt > 0.0;
  long long n_fixed = 0;
  if (fixed) {
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
  dem::DistributedExplicitScheme scheme(scene, particles, model, comm, timer);
  {
    const fluid::MacGridSpec spec = fluid_grid_spec(scene);
    std::array<double, 3> spacing{};
    for (int a = 0; a < 3; ++a)
      spacing[a] = spec.spacing[a] > 0.0 ? spec.spacing[a] : spec.extent[a] / spec.cells[a];
    std::vector<CellBox> boxes;
    try {
      boxes = orb_cell_boxes(spec.cells, comm.size(), fluid::kMinBoxWidth);
    } catch (const std::invalid_argument& e) {
      throw ConfigError("scene key 'fluid.cells'", e.what());
    }
    scheme.set_decomposition(partition::decomposition_of_cell_boxes(
        boxes, spec.origin, spacing, {scene.domain.lo, scene.domain.hi}));
  }
  const double dt = scheme.dt();
  const double end = scene.run.end_time;
  if (ck && ck->dt != dt)
    throw ConfigError(opt.restart, fmt::format("checkpoint particle step {:.17g} s differs from "
                                               "the scene's {:.17g} s", ck->dt, dt));
  if (ck && ck->loop.time > end + 1e-6 * dt)
    throw ConfigError("run.end_time", fmt::format("the checkpoint is at t = {:.17g} s, past the "
                                                  "end of the run ({:.17g} s)",
                                                  ck->loop.time, end));

  std::optional<DiagnosticsFile> diag = open_root_diagnostics(comm, opt.out_dir, kColumns);
  std::vector<std::vector<double>> rows; // kept for checkpoints (the same on every rank)
  auto add_row = [&](std::vector<double> r) {
    if (diag)
      diag->add_row(r);
    rows.push_back(std::move(r));
  };
  // Snapshots: every rank's particles and gas box written collectively into one file (parallel
  // HDF5); rank 0 keeps the XDMF index. Particles as on one rank (the synchronised state of the
  // first particle step after the snapshot time), the gas taken at that time.
  std::optional<SnapshotIndex> snapshots;
  if (root && scene.output.snapshot_interval > 0)
    snapshots.emplace(opt.out_dir);
  const dem::DomainGeometry geom(scene.domain);
  auto write_snapshot = [&](SnapshotFields& f, const CellFields& cells) {
    PhaseTimer::Scope io(timer, Phase::io);
    const std::size_t n = f.x.size();
    std::vector<double> w[3] = {std::vector<double>(n), std::vector<double>(n),
                                std::vector<double>(n)};
    for (std::size_t i = 0; i < n; ++i)
      w[0][i] = geom.wrap(f.x[i], 0), w[1][i] = geom.wrap(f.y[i], 1), w[2][i] = geom.wrap(f.z[i], 2);
    f.x = w[0], f.y = w[1], f.z = w[2];
    f.dt = dt;
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
    fmt::print(stderr,
               "cfddem: scene '{}', {} particles, gas {} x {} x {} cells ({} drag, {} "
               "deposition), dt_f = {}, particle dt = {:.4e} s{}, {} rank(s) x {} "
               "thread(s){}\n",
               scene.name, n_total, c[0], c[1], c[2], scene.fluid.drag, scene.fluid.deposition,
               fixed ? fmt::format("{:.4e} s", scene.fluid.dt)
                     : fmt::format("adaptive (cfl {})", scene.fluid.cfl),
               dt, fixed ? fmt::format(" ({} steps per fluid step)", n_fixed) : std::string(),
               env.ranks(), env.threads(),
               ck ? fmt::format(", restarted at t = {:.6e} s from {}", ck->loop.time, opt.restart)
                  : "");
  }
  // The snapshot at t = 0 holds the initial velocities, as on one rank: this rank's share,
  // kept before start() shifts them to the half step.
  ParticleStore initial;
  if (!ck && scene.output.snapshot_interval > 0)
    initial = particles;
  // start() moves every particle to its box's rank; the gas then deposits the owned ones.
  if (ck)
    restore_coupled_scheme(*ck, taken, scheme);
  else
    scheme.start();
  GasCoupling gas(scene, particles, &comm, scheme.owned());
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
  const auto t_loop = clock::now();
  double& t = loop.time;
  auto last_progress = clock::now();
  auto particle_step = [&](bool record, bool snap) {
    scheme.step(record || snap);
    const long long k = scheme.steps_taken() - 1;
    if (snap) {
      const auto s = scheme.synchronised_previous();
      const std::size_t n = s.x.size();
      SnapshotFields f;
      f.time = loop.row_time;
      f.step = k;
      f.x = s.x, f.y = s.y, f.z = s.z, f.vx = s.vx, f.vy = s.vy, f.vz = s.vz;
      f.radius = {particles.radius.data(), n}, f.mass = {particles.mass.data(), n};
      f.id = {particles.id.data(), n};
      write_snapshot(f, loop.snapshot_cells);
    }
    if (!record)
      return;
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s = scheme.synchronised_previous();
    const std::span<const double> m(particles.mass.data(), scheme.owned());
    const auto st = dem::measure({s.x, s.y, s.z, s.vx, s.vy, s.vz, m}, comm);
    const auto steps = static_cast<double>(k - k_last_row);
    k_last_row = k;
    add_row(row(loop.row_time, k, st, n_total, scheme, seconds_since(t_loop),
                dem::LeafStepStats{steps, steps, steps, 1.0},
                means.next(loop.row_time, st.mean_velocity, loop.row_fluid)));
  };
  // Checkpoints at the fluid times that are multiples of the interval, after the restart time.
  const double ckpt_interval = scene.output.checkpoint_interval;
  double next_ckpt = ckpt_interval > 0.0
                         ? (std::floor(t / ckpt_interval + 1e-6) + 1.0) * ckpt_interval
                         : std::numeric_limits<double>::infinity();
  const double tol = 1e-6 * dt;
  while (end - t > tol) {
    const long long n_sub = particle_steps_per_fluid_step(scene, gas, n_fixed, dt, end - t);
    const double dt_f = static_cast<double>(n_sub) * dt;
    {
      PhaseTimer::Scope fl(timer, Phase::fluid);
      gas.step(particles, dt_f, scheme.owned());
      scheme.set_external_force(gas.force(0), gas.force(1), gas.force(2));
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
      if (diag)
        diag->flush();
      write_coupled_checkpoint(
          (fs::path(opt.out_dir) / fmt::format("checkpoint_{:09d}.h5", loop.fluid_steps)).string(),
          checkpoint_header(scene_in, "explicit", dt, loop.fluid_steps, k_last_row, rows,
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
  if (diag)
    diag->flush();
  const double loop_seconds = seconds_since(t_loop);
  const std::vector<double> waits = comm.gather(comm.wait_seconds());
  const std::vector<double> owned = comm.gather(static_cast<double>(scheme.owned()));
  const std::vector<double> fluid_seconds = comm.gather(timer.seconds(Phase::fluid));
  if (root) {
    nlohmann::ordered_json j = run_json_header(scene_in, scene.name, derived, env, n_total);
    j["scheme"] = "explicit";
    j["distributed"] = true;
    j["dt"] = dt;
    j["steps"] = scheme.steps_taken();
    j["fluid_steps"] = loop.fluid_steps;
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
                 "ranks), interpolation and particle forces; neighbor + force: the particle "
                 "sub-cycle";
    j["phase_seconds"] = ph;
    add_work_counters(j, scheme, loop_seconds,
                      "neighbor-list pairs evaluated (each pair once per step), over all ranks");
    j["mpi_wait_seconds"] = waits;
    j["fluid_seconds"] = fluid_seconds;
    j["owned_particles_at_end"] = owned;
    std::vector<std::int64_t> cells;
    for (const CellBox& b : gas.boxes())
      cells.push_back(b.count());
    j["gas_cells_per_rank"] = cells;
    j["decomposition"] = "the gas grid's ORB boxes, one per rank; particles owned by the rank "
                         "whose box holds them (settled at neighbor rebuilds)";
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

} // namespace cfddem::apps
