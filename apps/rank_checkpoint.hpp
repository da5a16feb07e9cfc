// The particle part of a checkpoint written on R ranks, for the DEM-only loops
// (apps/run_loop.hpp, through apps/scheme_runs.hpp) and the coupled one
// (apps/coupled_checkpoint.hpp) alike: the owned particles of every rank gathered to rank 0 in
// id order (the file's order for any rank count) with the scheme's state. Explicit: with
// friction the spin and the contact history as rows over those particles (a serial
// checkpoint's layout), and the counters. Orb and islands: save_state()'s per-particle values
// (half step, and the cost or the fine-sub-iteration count) in the same order, and its counters;
// orb with friction also the spins and the tangential history records of every rank.
// No neighbor list or pair set is kept: a checkpoint is written in the scheme's canonical
// state, which the restart rebuilds from the particles.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "apps/checkpoint.hpp"
#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "dem/contact_history.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"

namespace cfddem::apps {

// Collective, after scheme.canonicalize(). Fills c.particles and c.scheme_state on rank 0 (other ranks'
// `c` is left as it is). Throws RunError on every rank when the history does not fit.
void gather_rank_particles(const dem::ExplicitScheme& scheme, const ParticleStore& particles,
                           const Communicator& comm, Checkpoint& c);

// The contact history a checkpoint holds (rows over its particles) as records by id, for
// ExplicitScheme::restore; empty without friction. Call before the particles are
// handed out (rank_share moves them).
dem::ContactHistory saved_contact_history(const Checkpoint& ck);

// Collective: scheme.save_state() (the canonical state) and the owned particles with its
// per-particle values gathered into rank 0's `c` in id order (c.scheme_state). Throws
// RunError on every rank when rank 0 fails.
template <class Scheme>
void gather_subiterated(Scheme& scheme, const ParticleStore& particles, const Communicator& comm,
                        Checkpoint& c);

// A restart: the checkpoint's scheme state with this rank's share of its per-particle values
// (`mine`: the checkpoint's particles rank_share gave this rank, in that order), for
// scheme.restore_state. Throws ConfigError naming `path` when they do not fit the particles.
template <class Scheme>
typename Scheme::State
subiterated_share(Checkpoint& ck, const std::vector<std::uint32_t>& mine, std::size_t particles,
                  const std::string& path);

} // namespace cfddem::apps
