// cfddem: the command-line program. `run` a scene, `check` it, list the `keys`, or ask for --help
// / --version.
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
#include "core/scene_keys_doc.hpp"
#include "core/simd_level.hpp"

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
  cfddem::apps::check_gas_numbers(scene);
  return scene;
}

// After the key listing (core/scene_keys_doc.cpp) in `cfddem --help`.
const char* kHelpTail = R"(
Outputs (in --out, default runs/<name>): diagnostics.csv (one row per interval), run.json,
snapshot_<step>.h5 + snapshots.xmf, checkpoint_<step>.h5.
Examples:
  cfddem run                                   the built-in HCS (1222 particles, 30 ms)
  cfddem run scenes/hcs.toml dem.restitution=0.9 --threads 2
  cfddem check scenes/hcs.toml
  cfddem keys                                  every scene key with its meaning
  mpirun -np 2 cfddem run scenes/hcs.toml --threads 1   (any scheme, with or without a gas)
)";

} // namespace

int main(int argc, char** argv) {
  CLI::App app{"cfddem: CFD-DEM with adaptive particle time stepping (soft-sphere DEM, "
               "linear spring-dashpot contacts, velocity Verlet)"};
  app.footer("\n" + cfddem::keys_help_text() + kHelpTail);
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
  bool markdown = false;
  auto* keys = app.add_subcommand("keys", "list the scene keys with their types, defaults and "
                                          "meanings; --markdown prints docs/keys.md");
  keys->add_flag("--markdown", markdown, "print docs/keys.md (Markdown) instead of plain text");

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

  if (keys->parsed()) {
    fmt::print("{}", markdown ? cfddem::keys_markdown() : cfddem::keys_text());
    return 0;
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
      // A bad CFDDEM_SIMD is refused here, before anything is read or written.
      (void)cfddem::simd_level();
      cfddem::SceneConfig cfg;
      const cfddem::Scene scene = load(a, cfg);
      cfddem::apps::check_gas_memory(scene, env.ranks());
      if (env.rank() == 0)
        for (const auto& [key, value] : cfg.repeated_overrides())
          fmt::print(stderr,
                     "cfddem: warning: scene key '{}' is set more than once on the command "
                     "line; the last value, {}, is used\n",
                     key, value);
      if (env.rank() == 0)
        for (const std::string& w : cfddem::apps::setting_warnings(scene))
          fmt::print(stderr, "cfddem: warning: {}\n", w);
      if (check->parsed()) {
        if (env.rank() == 0) {
          const auto particles = cfddem::make_initial_particles(scene);
          const auto derived = cfddem::apps::derive(scene, particles);
          for (const std::string& w : cfddem::apps::step_warnings(scene, derived))
            fmt::print(stderr, "cfddem: warning: {}\n", w);
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
            cfddem::apps::check_writable(opt.out_dir);
            // Locked first: --overwrite must not clear a directory another run is writing.
            cfddem::apps::lock_run_directory(opt.out_dir);
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
