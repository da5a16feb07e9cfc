// What ExplicitScheme holds only on R > 1 ranks (dem/explicit_scheme.hpp describes the
// ownership, ghosts and the overlapped forward): the communicator and exchange plan, the rank
// decomposition and its regrid clock, and the global counts a step adds. Internal to the
// scheme's sources (explicit_scheme.cpp, explicit_ranks.cpp).
#pragma once

#include <cstdint>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_exchange.hpp"
#include "dem/explicit_scheme.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::dem {

struct ExplicitScheme::RankPart {
  // Collective: the halo (2 r_max + skin over all ranks), the global count, the ORB levels and
  // the regrid interval. Throws RunError for a periodic axis too short for one image.
  RankPart(const Scene& scene, const ParticleStore& p, const StepModel& model,
           const Communicator& comm);

  const Communicator& comm;
  DomainGeometry local; // the frame of the rank-local list: no periodic axis
  ParticleExchange exchange;
  partition::RankDecomposition decomposition;
  std::vector<Regrid> regrids;
  std::size_t owned = 0;
  int levels = 0;
  double halo = 0.0;
  std::int64_t regrid_every = 0, last_regrid = -1;
  std::int64_t n_global = 0, global_pairs = 0, history_migrations = 0;
  bool ext_on = false; // set_external_force: on for every rank alike
  bool fixed_decomposition = false;
  bool forward_pending = false; // ghost x, v (w) of the last step still in flight
};

} // namespace cfddem::dem
