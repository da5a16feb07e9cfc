// The sub-iterated schemes' loop over MPI ranks, DEM only: dem.scheme = "orb"
// (dem::DistributedOrbScheme) and "islands" (dem::IslandsScheme).
#pragma once

#include "apps/simulation.hpp"

namespace cfddem::apps {

// Collective. Every rank starts from its share of the particles (rank_share: every R-th, or of
// the checkpoint's); rows hold values reduced over the ranks, rows at multiples of
// output.interval rounded to whole sub-iterations (the state at sub-iteration K recorded by
// sub-iteration K + 1, so the loop runs one past the end); snapshots are written collectively;
// rank 0 writes diagnostics.csv, run.json and the checkpoints. A checkpoint holds the particles
// in id order with their per-particle scheme state (orb: half step and cost, at regrid points;
// islands: half step and fine-sub-iteration count, at any sub-iteration) and the counters; the
// scheme rebuilds everything else from them, so a restart on the same rank count continues bit
// for bit and on another (one included) to round-off.
RunResult run_distributed_orb(const Scene& scene, const RunOptions& opt, const ParallelEnv& env);
RunResult run_distributed_islands(const Scene& scene, const RunOptions& opt,
                                  const ParallelEnv& env);

} // namespace cfddem::apps
