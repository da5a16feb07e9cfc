// The loop of the islands scheme over MPI ranks (dem::DistributedIslandsScheme): DEM only.
#pragma once

#include "apps/simulation.hpp"

namespace cfddem::apps {

// Collective. Rows hold values reduced over the ranks; rank 0 writes diagnostics.csv and
// run.json (with how often islands spanned ranks). No checkpoint or restart yet: the caller
// refuses output.checkpoint_interval and --restart.
RunResult run_distributed_islands(const Scene& scene, const RunOptions& opt,
                                  const ParallelEnv& env);

} // namespace cfddem::apps
