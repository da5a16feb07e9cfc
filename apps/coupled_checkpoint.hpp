// Checkpoint and restart of the coupled loop over R ranks (apps/coupled_distributed.cpp), into
// the file a one-rank coupled run writes (apps/checkpoint.hpp), so either restarts the other.
// What the R-rank loop holds at a fluid-step boundary goes in as follows:
//   - the particles (explicit; orb and islands: apps/rank_checkpoint.hpp, their save_state() and
//     per-particle values): the scheme is put in its canonical state first (as a DEM-only
//     checkpoint on R ranks: the run goes on from that state, a restart rebuilds the same), then
//     gathered to rank 0 in id order with the scheme's counters, and with friction their spin and
//     contact history (apps/rank_checkpoint.hpp; the neighbor list is rebuilt);
//   - the gas force the scheme holds over the sub-cycle: the last gas step's force, gathered by
//     particle id (particles may have changed rank since; the value is the one held);
//   - the gas: every rank's box of the solver's fields, written as hyperslabs of whole-grid
//     datasets (apps/gas_grid_io.hpp); the counters and the loop's position are the same on
//     every rank; a snapshot pending at that time is left out and taken again from the gas
//     restored (the same numbers).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "apps/checkpoint.hpp"
#include "apps/coupled_step.hpp"
#include "apps/rank_checkpoint.hpp"
#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "core/scene.hpp"
#include "dem/contact_history.hpp"
#include "dem/distributed_explicit_scheme.hpp"

namespace cfddem::apps {

// This rank's box of the gas grid (the boxes GasCoupling cuts it into).
GasBlock gas_block(const Scene& scene, const Communicator& comm);

// Collective. `header`: checkpoint_header's fields (rank 0's count); the rest is filled here.
// Scheme: dem::DistributedExplicitScheme, DistributedOrbScheme or IslandsScheme (the
// sub-iterated ones at a fluid-step boundary, a regrid point: their save_state()).
template <class Scheme>
void write_coupled_checkpoint(const std::string& path, Checkpoint header, Scheme& scheme,
                              const ParticleStore& particles, const GasCoupling& gas,
                              const CoupledLoopState& loop, const GasBlock& block,
                              const Communicator& comm);

// Restart, collective, in place of scheme.start(): this rank's share of the held force (the
// checkpoint's particles `taken` by rank_share), the counters and the contact history
// (saved_contact_history, read before rank_share); restore() moves every particle to its owner
// with its force and history.
void restore_coupled_scheme(const Checkpoint& ck, const std::vector<std::uint32_t>& taken,
                            const dem::ContactHistory& history,
                            dem::DistributedExplicitScheme& scheme);
// The same for a sub-iterated scheme: `state` is subiterated_share's (apps/rank_checkpoint.hpp).
template <class Scheme>
void restore_coupled_scheme(const Checkpoint& ck, const std::vector<std::uint32_t>& taken,
                            typename SubiteratedState<Scheme>::State state, Scheme& scheme);
// Then, with the gas built on the owned particles: its box's state, and the loop's position.
// Throws ConfigError naming the file when the state does not fit.
void restore_coupled_gas(Checkpoint& ck, const std::string& path, GasCoupling& gas,
                         CoupledLoopState& loop);

} // namespace cfddem::apps
