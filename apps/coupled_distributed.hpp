// The coupled loop (gas + explicit or orb particles) over MPI ranks.
#pragma once

#include "apps/simulation.hpp"

namespace cfddem::apps {

// The coupled loop of simulation.cpp on R ranks: the gas grid is cut into one box per rank and
// the gas is solved over the ranks; rows are reduced over the ranks and written by rank 0,
// snapshots written collectively. dem.scheme = "explicit": each rank owns the particles in its
// gas box (dem::DistributedExplicitScheme with the boxes as its fixed decomposition) and the gas
// force on them. dem.scheme = "orb": dem::OrbScheme's leaves decide the owners, and
// the particles are routed to their gas boxes and their forces back once per fluid step
// (apps/gas_routing.hpp). Other schemes, checkpoints and restarts of such runs are refused
// (ConfigError naming the key). Collective.
RunResult run_coupled_distributed(const Scene& scene, const RunOptions& opt,
                                  const ParallelEnv& env);

} // namespace cfddem::apps
