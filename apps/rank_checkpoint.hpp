// The particle part of a checkpoint written on R ranks by the distributed explicit scheme, for
// the DEM-only loop (apps/simulation.cpp) and the coupled one (apps/coupled_checkpoint.hpp)
// alike: the owned particles of every rank gathered to rank 0 in id order (the file's order for
// any rank count), with friction their spin and the contact history as rows over those
// particles (a serial checkpoint's layout), and the scheme's counters. The neighbor list is not
// kept: a checkpoint is written in the scheme's canonical state, which the restart rebuilds.
#pragma once

#include "apps/checkpoint.hpp"
#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "dem/contact_history.hpp"
#include "dem/distributed_explicit_scheme.hpp"

namespace cfddem::apps {

// Collective, after scheme.canonicalize(). Fills c.particles and c.state on rank 0 (other ranks'
// `c` is left as it is). Throws RunError on every rank when the history does not fit.
void gather_rank_particles(const dem::DistributedExplicitScheme& scheme,
                           const ParticleStore& particles, const Communicator& comm,
                           Checkpoint& c);

// The contact history a checkpoint holds (rows over its particles) as records by id, for
// DistributedExplicitScheme::restore; empty without friction. Call before the particles are
// handed out (rank_share moves them).
dem::ContactHistory saved_contact_history(const Checkpoint& ck);

} // namespace cfddem::apps
