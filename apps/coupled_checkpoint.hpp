// Checkpoint and restart of the coupled loop over R ranks (apps/run_loop.hpp), into
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

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "apps/checkpoint.hpp"
#include "apps/coupled_step.hpp"
#include "apps/rank_checkpoint.hpp"
#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "core/scene.hpp"

namespace cfddem::apps {

// This rank's box of the gas grid (the boxes GasCoupling cuts it into).
GasBlock gas_block(const Scene& scene, const Communicator& comm);

// Collective. `c`: checkpoint_header's fields and the particles with the scheme's state (rank
// 0's); the held gas force, the loop's position and the gas are filled here, and the file is
// written.
void write_coupled_checkpoint(const std::string& path, Checkpoint c, const GasCoupling& gas,
                              const CoupledLoopState& loop, const GasBlock& block,
                              const Communicator& comm);

// A restart: this rank's share of the held gas force (the checkpoint's particles `taken` by
// rank_share); empty when no gas step came before the checkpoint.
std::array<std::vector<double>, 3> held_share(const Checkpoint& ck,
                                              const std::vector<std::uint32_t>& taken);

} // namespace cfddem::apps
