// The coupled loop (gas + explicit particles) over MPI ranks.
#pragma once

#include "apps/simulation.hpp"

namespace cfddem::apps {

// The explicit coupled loop of simulation.cpp on R ranks: the gas grid is cut into one box per
// rank, each rank owns the particles in its box (dem::DistributedExplicitScheme with the boxes
// as its fixed decomposition) and the gas force on them; rows are reduced over the ranks and
// written by rank 0. Snapshots, checkpoints and restarts of such runs are not distributed yet
// (ConfigError naming the key). Collective.
RunResult run_coupled_distributed(const Scene& scene, const RunOptions& opt,
                                  const ParallelEnv& env);

} // namespace cfddem::apps
