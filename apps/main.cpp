// cfddem: the command-line program. `run` a scene, `check` it, or ask for --help / --version.
// Exit codes: 0 success, 2 command-line, configuration or input error, 3 run-time failure
// (docs/hostile_input.md).
#include <charconv>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <new>
#include <string_view>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "apps/coupled_step.hpp"
#include "apps/default_scene.hpp"
#include "apps/derived_numbers.hpp"
#include "apps/gas_check.hpp"
#include "apps/run_directory.hpp"
#include "apps/setting_warnings.hpp"
#include "apps/simulation.hpp"
#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"
#include "core/parallel_env.hpp"
#include "core/scene.hpp"
#include "core/scene_config.hpp"

#include <tbb/info.h>

namespace {

struct Args {
  std::string scene;
  std::vector<std::string> overrides;
  int threads = 0;
  std::string out;
  bool quiet = false;
  std::string restart;
  bool overwrite = false;
};

// --threads: a whole number >= 1 (CLI11's PositiveNumber accepts 0 and names a range of doubles).
const CLI::Validator kThreadCount(
    [](std::string& text) -> std::string {
      long long v = 0;
      const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
      if (ec != std::errc() || end != text.data() + text.size())
        return "must be a whole number >= 1, got '" + text + "'";
      if (v < 1)
        return "must be >= 1, got " + text;
      if (v > 1 << 16)
        return "must be at most 65536, got " + text;
      return {};
    },
    "INT>=1");

// The command line did not parse: say why in one plain line and exit 2. A word where a
// subcommand belongs that is none of them is named, with the subcommands there are.
int command_line_error(const CLI::App& app, const CLI::ParseError& e, int argc, char** argv) {
  std::vector<std::string> names;
  for (const CLI::App* sub : app.get_subcommands([](const CLI::App*) { return true; }))
    names.push_back(sub->get_name());
  std::string first_word;
  for (int i = 1; i < argc && first_word.empty(); ++i)
    if (argv[i][0] != '-')
      first_word = argv[i];
  const bool known = std::find(names.begin(), names.end(), first_word) != names.end();
  if (!first_word.empty() && !known)
    fmt::print(stderr,
               "cfddem: error: unknown command '{}' (the commands are: {}; see "
               "`cfddem --help`)\n",
               first_word, fmt::join(names, ", "));
  else if (first_word.empty() && dynamic_cast<const CLI::RequiredError*>(&e) &&
           std::string_view(e.what()).find("subcommand") != std::string_view::npos)
    fmt::print(stderr, "cfddem: error: a command is required: {} (see `cfddem --help`)\n",
               fmt::join(names, " or "));
  else
    fmt::print(stderr, "cfddem: error: {} (see `cfddem {} --help`)\n", e.what(),
               known ? first_word : std::string());
  return 2;
}

// Load the scene file (or the embedded HCS), apply key=value overrides, validate.
cfddem::Scene load(Args& a, cfddem::SceneConfig& cfg) {
  namespace fs = std::filesystem;
  // `cfddem run key=value` (no file): the first positional is an override, not a scene.
  if (!a.scene.empty() && a.scene.find('=') != std::string::npos && !fs::exists(a.scene)) {
    a.overrides.insert(a.overrides.begin(), a.scene);
    a.scene.clear();
  }
  std::string default_name = "hcs";
  if (a.scene.empty()) {
    cfg = cfddem::SceneConfig::from_string(cfddem::apps::kDefaultScene, "built-in HCS scene");
  } else {
    if (!fs::exists(a.scene)) throw cfddem::ConfigError(a.scene, "scene file not found");
    if (fs::is_directory(a.scene))
      throw cfddem::ConfigError(a.scene, "is a directory, not a scene file (give the .toml file)");
    cfg = cfddem::SceneConfig::from_file(a.scene);
    default_name = fs::path(a.scene).stem().string();
  }
  for (const auto& o : a.overrides) cfg.apply_override(o);
  cfddem::Scene scene = cfddem::read_scene(cfg, default_name);
  cfddem::apps::validate_fluid(scene);
  return scene;
}

const char* kKeysHelp = R"(
Scene keys (TOML, dotted; any key can be overridden as key=value on the command line):
  name                       run name (default: the scene file's stem); output in runs/<name>
  domain.lo, domain.hi       box corners [x, y, z] in m
  domain.periodic            [bool, bool, bool]; a non-periodic axis has planar walls at lo and hi
  gravity                    [gx, gy, gz] in m/s^2 (default [0, 0, 0])
  particles.file             CSV with header x,y,z,vx,vy,vz,diameter,density (SI), relative to
                             the scene file; or the generator keys:
  particles.count, particles.diameter, particles.density
  particles.temperature      granular temperature T0 in m^2/s^2 (Gaussian velocities, zero momentum)
  particles.velocity         mean velocity added [vx, vy, vz]
  particles.placement        "random" (non-overlapping, seeded) | "lattice"
  particles.region_lo/hi     where to place them (default: the domain)
  particles.seed             RNG seed (default 1)
  particles.allow_overlap    accept overlapping initial particles (default false)
  dem.scheme                 "explicit" (one global step) | "orb" (adaptive steps per ORB leaf)
                             | "islands" (adaptive steps per contact island, no missed collision)
  dem.spring_constant        k_n in N/m
  dem.restitution            e in [0, 1]
  dem.friction               Coulomb coefficient (0 = frictionless, no rotation)
  dem.wall_spring_constant, dem.wall_restitution, dem.wall_friction   (default: as particles)
  dem.tangential_stiffness_ratio (k_t/k_n, default 2/7), dem.tangential_damping_ratio (0.5)
  dem.dt_factor              dt = tau_p * dt_factor, tau_p = sqrt(m/k) (default 0.02 = tau_p/50)
  dem.dt                     fixed step in s, overriding dt_factor (default 0: use dt_factor)
  dem.neighbor_skin          Verlet skin in m (default a quarter of the largest diameter)
  dem.max_overlap            stop when an overlap exceeds this fraction of the radius (0.3;
                             orb: counted and reported, not fatal)
  dem.nsubit                 orb, islands: sub-iterations per regrid interval (default 10)
  dem.regrid_interval        orb, islands: seconds between ORB rebuilds, dt_f (default 1e-4);
                             sub-iteration dt_sp = dem.regrid_interval / dem.nsubit
  dem.proximity_radii        orb: a leaf takes the fine step if a pair's centre distance is below
                             this many radii, (r_i + r_j) / 2 each (default 3)
  dem.local_dt               orb: "proximity" (the rule above, default) or "time_to_contact" (fine
                             if a pair's gap or a wall's could close within dt_sp at its speeds)
  partition.orb_levels       orb: 2^levels leaves, 0..20 (default 4); R > 1 ranks: ORB boxes
  fluid.*                    the gas (a scene without [fluid] has none): fluid.cells [nx, ny, nz],
                             fluid.density, fluid.viscosity, fluid.dt (fixed dt_f, paper 1e-4) or
                             fluid.cfl (<= 0.5) and fluid.max_dt (cap, 1e-3), fluid.drag ("bvk",
                             "bvk2", "koch_hill", "wen_yu", "none"), fluid.deposition
                             ("trilinear" | "dpvm" | "dpvm_sphere"),
                             fluid.deposition_width (particle diameters), fluid.bc.x_lo ...
                             fluid.bc.z_hi ("periodic", "wall", "inflow", "outflow"; default: as
                             domain.periodic, else wall), fluid.inflow_velocity,
                             fluid.outflow_pressure, fluid.pressure_drop [Pa per period],
                             fluid.velocity (initial), fluid.cell_size, fluid.implicit_viscosity,
                             fluid.time_order (2: predictor-corrector, default; 1: Euler, one
                             projection per gas step, first order in time),
                             fluid.tolerance, fluid.preconditioner ("pfmg" | "smg"),
                             fluid.solver ("multigrid" | "hypre" | "auto": multigrid on one
                             rank, hypre on R ranks; default auto)
  partition.weights          orb: "count" (default) | "cost" (particles x local steps of the
                             last regrid interval)
  partition.gas_regrid_interval  a gas on R ranks: simulated seconds between recuts of the gas
                             boxes by a weighted ORB (default 0: boxes fixed); cells and
                             particles move to their new owners
  partition.cell_weight      the weight of a gas cell in particle steps per fluid step
                             (default 400: measured on hcs_gas, one fluid cell step ~ 400
                             particle steps)
  run.end_time               simulated seconds
  output.interval            simulated seconds between diagnostics rows
  output.progress_seconds    wall seconds between progress lines (default 2)
  output.snapshot_interval   simulated seconds between HDF5 particle snapshots, indexed by
                             snapshots.xmf for ParaView (default 0: none)
  output.checkpoint_interval simulated seconds between checkpoints checkpoint_<step>.h5
                             (default 0: none; orb: whole regrid intervals); --restart FILE

Outputs (in --out, default runs/<name>): diagnostics.csv (one row per interval), run.json,
snapshot_<step>.h5 + snapshots.xmf, checkpoint_<step>.h5.
Examples:
  cfddem run                                   the built-in HCS (1222 particles, 30 ms)
  cfddem run scenes/hcs.toml dem.restitution=0.9 --threads 2
  cfddem check scenes/hcs.toml
  mpirun -np 2 cfddem run scenes/hcs.toml --threads 1   (any scheme, with or without a gas)
)";

} // namespace

int main(int argc, char** argv) {
  CLI::App app{"cfddem: CFD-DEM with adaptive particle time stepping (soft-sphere DEM, "
               "linear spring-dashpot contacts, velocity Verlet)"};
  app.footer(kKeysHelp);
  app.require_subcommand(1);
  app.set_version_flag("--version", "cfddem " CFDDEM_VERSION, "print the version and exit");
  Args a;
  auto* run = app.add_subcommand("run", "run a scene (default: the built-in HCS)");
  run->add_option("scene", a.scene, "scene file (TOML)");
  run->add_option("overrides", a.overrides, "key=value overrides of scene keys");
  run->add_option("--threads", a.threads,
                  "TBB threads per rank (default: OMP_NUM_THREADS, else "
                  "the cores available)")
      ->check(kThreadCount);
  run->add_option("--out", a.out, "output directory (default runs/<scene name>)");
  run->add_flag("--quiet", a.quiet, "no progress lines");
  run->add_flag("--overwrite", a.overwrite,
                "replace the outputs of an earlier run in the output directory (without it, a "
                "directory holding another run's outputs is refused)");
  run->add_option("--restart", a.restart,
                  "continue from a checkpoint file (checkpoint_<step>.h5 of the same scene: "
                  "explicit, orb or islands, with or without a gas, on any rank count); the run "
                  "ends at run.end_time");
  auto* check = app.add_subcommand("check", "validate a scene and print the resolved "
                                            "configuration and derived numbers; runs nothing");
  check->add_option("scene", a.scene, "scene file (TOML)");
  check->add_option("overrides", a.overrides, "key=value overrides of scene keys");

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    return command_line_error(app, e, argc, argv);
  }

  try {
    cfddem::ParallelEnv env(&argc, &argv, a.threads);
    // Legal but almost surely a mistake: more threads than this process has cores to run them.
    if (const int cores = tbb::info::default_concurrency(); a.threads > cores && env.rank() == 0)
      fmt::print(stderr,
                 "cfddem: warning: --threads {} exceeds the {} core(s) available to this "
                 "process; the extra threads only share those cores (slower, not "
                 "faster)\n",
                 a.threads, cores);
    if (env.rank() == 0 && !(run->parsed() && a.quiet))
      cfddem::set_setup_progress(
          [](const std::string& line) { fmt::print(stderr, "cfddem: {}\n", line); });
    try {
      cfddem::SceneConfig cfg;
      const cfddem::Scene scene = load(a, cfg);
      if (env.rank() == 0)
        for (const std::string& w : cfddem::apps::setting_warnings(scene))
          fmt::print(stderr, "cfddem: warning: {}\n", w);
      if (check->parsed()) {
        if (env.rank() == 0) {
          const auto particles = cfddem::make_initial_particles(scene);
          const auto derived = cfddem::apps::derive(scene, particles);
          fmt::print("# resolved configuration ({})\n", cfg.origin());
          for (const auto& [k, v] : cfddem::describe_scene(scene)) fmt::print("{} = {}\n", k, v);
          fmt::print("\n# derived numbers\n");
          for (const auto& [k, v] : derived.table()) fmt::print("{:<48} {}\n", k, v);
          if (scene.fluid.enabled) {
            const auto gas = cfddem::apps::check_gas(scene, derived);
            fmt::print("\n# gas\n");
            for (const auto& [k, v] : gas.table)
              fmt::print("{:<48} {}\n", k, v);
            for (const auto& w : gas.warnings)
              fmt::print(stderr, "cfddem: warning: {}\n", w);
          }
        }
        return 0;
      }
      cfddem::apps::RunOptions opt;
      opt.out_dir = a.out.empty() ? (std::filesystem::path("runs") / scene.name).string() : a.out;
      opt.quiet = a.quiet || env.rank() != 0;
      opt.restart = a.restart;
      // A particle count that cannot fit is named before the run directory is looked at.
      cfddem::check_packing_feasible(scene);
      {
        // Rank 0 looks at (and with --overwrite clears) the run directory; every rank raises
        // its refusal alike, after rank 0 is done (agree_on_error is collective).
        const auto comm = cfddem::Communicator::world();
        std::string refused;
        if (comm.rank() == 0) {
          try {
            cfddem::apps::prepare_run_directory(opt.out_dir, a.overwrite, a.restart);
          } catch (const cfddem::ConfigError& e) {
            refused = e.what();
          }
        }
        if (const std::string e = comm.agree_on_error(0, refused); !e.empty())
          throw cfddem::ConfigError("", e);
      }
      const auto result = cfddem::apps::run_simulation(scene, opt, env);
      if (env.rank() == 0 && !a.quiet) {
        // What the directory holds now: the diagnostics and run.json, and how many snapshots
        // and checkpoints.
        int snaps = 0, ckpts = 0;
        for (const auto& f : cfddem::apps::run_outputs_in(result.out_dir)) {
          const std::string n = f.filename().string();
          snaps += n.rfind("snapshot_", 0) == 0, ckpts += n.rfind("checkpoint_", 0) == 0;
        }
        std::string extra;
        if (snaps > 0)
          extra += fmt::format(", {} snapshot(s) + snapshots.xmf", snaps);
        if (ckpts > 0)
          extra += fmt::format(", {} checkpoint(s)", ckpts);
        fmt::print("cfddem: done; outputs in {}/ (diagnostics.csv, run.json{})\n", result.out_dir,
                   extra);
      }
      return 0;
    } catch (const cfddem::ConfigError& e) {
      // Configuration and run errors are raised by every rank alike: rank 0 says it once.
      if (env.rank() == 0) fmt::print(stderr, "cfddem: error: {}\n", e.what());
      return 2;
    } catch (const cfddem::RunError& e) {
      if (env.rank() == 0) fmt::print(stderr, "cfddem: run stopped: {}\n", e.what());
      return 3;
    } catch (const std::bad_alloc&) {
      fmt::print(stderr,
                 "cfddem: error (rank {}): out of memory: the scene needs more memory "
                 "than this process may use (fewer particles or fluid cells, or more "
                 "ranks)\n",
                 env.rank());
      if (env.ranks() > 1)
        env.abort(3);
      return 3;
    } catch (const std::exception& e) {
      // Anything else may have been raised by this rank alone: end the others too.
      fmt::print(stderr, "cfddem: error (rank {}): {}\n", env.rank(), e.what());
      if (env.ranks() > 1) env.abort(3);
      return 3;
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "cfddem: error: {}\n", e.what());
    return 3;
  }
}
