// A run: the scene's scheme on one rank or R, with or without a gas, through the one time loop
// (apps/run_loop.hpp): initial particles -> scheme -> diagnostics rows, snapshots, checkpoints,
// run.json.
#pragma once

#include <string>
#include <vector>

#include "core/parallel_env.hpp"
#include "core/scene.hpp"

namespace cfddem::apps {

struct RunOptions {
  std::string out_dir;
  bool quiet = false;
  std::string restart; // checkpoint file to continue from; empty: a fresh run
  std::vector<std::pair<std::string, std::string>> config; // resolved keys for run.json
};

struct RunResult {
  std::string out_dir;
  double loop_seconds = 0.0;
  long long steps = 0;
  long long particle_steps = 0;
};

RunResult run_simulation(const Scene& scene, const RunOptions& options, const ParallelEnv& env);

} // namespace cfddem::apps
