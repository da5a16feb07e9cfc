#include "apps/simulation.hpp"

#include <chrono>
#include <cmath>
#include <filesystem>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/derived_numbers.hpp"
#include "apps/diagnostics_file.hpp"
#include "core/atomic_file.hpp"
#include "core/initial_conditions.hpp"
#include "core/phase_timer.hpp"
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

} // namespace

RunResult run_simulation(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  if (scene.dem.scheme == "orb") return run_orb(scene, opt, env);
  namespace fs = std::filesystem;
  const auto t_setup = clock::now();
  ParticleStore particles = make_initial_particles(scene);
  const DerivedNumbers derived = derive(scene, particles);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(scene, particles, timer);

  fs::create_directories(opt.out_dir);
  const std::string diag_path = (fs::path(opt.out_dir) / "diagnostics.csv").string();
  DiagnosticsFile diag(diag_path, kColumns);
  if (!opt.quiet)
    fmt::print(stderr, "cfddem: scene '{}', {} particles, dt = {:.4e} s, {} steps, {} rank(s) x {} "
                       "thread(s)\n",
               scene.name, particles.size(), scheme.dt(), derived.steps, env.ranks(),
               env.threads());

  const long long n_end = derived.steps;
  const long long out_every = std::max(1LL, std::llround(scene.output.interval / scheme.dt()));
  scheme.start();
  const auto t_loop = clock::now();
  {
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
    diag.add_row(row(0.0, 0, s0, particles.size(), scheme, 0.0, dem::LeafStepStats{0, 0, 0, 1}));
  }

  auto last_progress = clock::now();
  long long k_last_row = 0;
  // The state at step K (x(K), v(K)) is known once step K+1 has evaluated the forces at K, so
  // the loop runs one step past the last row; rows every out_every steps and at the end.
  for (long long k = 0; k <= n_end && n_end > 0; ++k) {
    const bool record = k > 0 && (k % out_every == 0 || k == n_end);
    scheme.step(record);
    if (record) {
      PhaseTimer::Scope io(timer, Phase::io);
      const auto s = scheme.synchronised_previous();
      const auto st = dem::measure({s.x, s.y, s.z, s.vx, s.vy, s.vz, particles.mass});
      const auto steps = static_cast<double>(k - k_last_row);
      k_last_row = k;
      diag.add_row(row(static_cast<double>(k) * scheme.dt(), k, st, particles.size(), scheme,
                       seconds_since(t_loop), dem::LeafStepStats{steps, steps, steps, 1.0}));
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
  ParticleStore particles = make_initial_particles(scene);
  const DerivedNumbers derived = derive(scene, particles);
  PhaseTimer timer;
  dem::OrbScheme scheme(scene, particles, timer);

  fs::create_directories(opt.out_dir);
  const std::string diag_path = (fs::path(opt.out_dir) / "diagnostics.csv").string();
  DiagnosticsFile diag(diag_path, kColumns);
  const double dt_sp = scheme.dt_sub();
  const long long n_end = std::max(1LL, std::llround(scene.run.end_time / dt_sp));
  const long long out_every = std::max(1LL, std::llround(scene.output.interval / dt_sp));
  if (!opt.quiet)
    fmt::print(stderr, "cfddem: scene '{}', {} particles, orb scheme: {} leaves, dt_sp = {:.4e} s "
                       "(fine dt = {:.4e} s), {} sub-iterations, {} rank(s) x {} thread(s)\n",
               scene.name, particles.size(), 1 << scene.partition.orb_levels, dt_sp,
               scheme.dt_fine(), n_end, env.ranks(), env.threads());
  scheme.start();
  const auto t_loop = clock::now();
  {
    PhaseTimer::Scope io(timer, Phase::io);
    const auto s0 = dem::measure({particles.x, particles.y, particles.z, particles.vx,
                                  particles.vy, particles.vz, particles.mass});
    diag.add_row(row(0.0, 0, s0, particles.size(), scheme, 0.0, dem::LeafStepStats{}));
  }
  auto last_progress = clock::now();
  for (long long k = 0; k <= n_end; ++k) {
    const bool record = k > 0 && (k % out_every == 0 || k == n_end);
    const dem::LeafStepStats ls = record ? scheme.take_interval_stats() : dem::LeafStepStats{};
    scheme.subiterate(record);
    if (record) {
      PhaseTimer::Scope io(timer, Phase::io);
      const auto s = scheme.synchronised_previous();
      const auto st = dem::measure({s.x, s.y, s.z, s.vx, s.vy, s.vz, s.mass});
      diag.add_row(row(static_cast<double>(k) * dt_sp, k, st, particles.size(), scheme,
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
      "candidate pairs evaluated per local step: pairs within a leaf once, pairs across a leaf "
      "boundary once per side (each leaf evaluates its side against the other's frozen copy)";
  j["subiteration_retries"] = scheme.retries();
  j["final_skin"] = scheme.skin();
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
