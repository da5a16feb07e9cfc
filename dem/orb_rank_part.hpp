// What the orb scheme (dem/orb_scheme.hpp) holds only over R > 1 ranks: the communicator and its
// particle exchange, the rows over owned + ghosts (OrbLocalRows), where each owned particle goes
// and the leaves of other ranks near each leaf. Null on one rank.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_exchange.hpp"
#include "dem/orb_local_rows.hpp"
#include "dem/orb_scheme.hpp"
#include "partition/orb_tree.hpp"

namespace cfddem::dem {

struct OrbScheme::RankPart {
  explicit RankPart(const Communicator& c) : comm(c), exchange(c) {}
  const Communicator& comm;
  ParticleExchange exchange;
  OrbLocalRows rows;     // of the owned particles (rebuilt, or kept: rank_keep_rows)
  std::vector<int> dest; // per owned particle: the rank it goes to
  // Per leaf: leaves of other ranks than its owner (with the periodic image) within the cutoff
  // of its box, found when first needed in a sub-iteration.
  std::vector<std::vector<partition::LeafImage>> near_leaves;
  std::vector<unsigned char> near_known;
  bool ext_on = false; // an external force is set: on for every rank alike
  // The global mode's rows kept over sub-iterations (OrbScheme::rank_keep_rows): the local
  // positions at the build (owned + ghosts: the skin/2 tests and the head/tail split), whether
  // the rows hold the proximity candidates, whether this sub-iteration kept them, and then this
  // rank's leaves that hold a particle on some rank (the counters); scratch: the strays' reports
  // along the ghost plan, and per leaf its particles counted here and whether one is fine (zero
  // again between sub-iterations).
  std::array<std::vector<double>, 3> ref;
  bool keepable = false, kept = false;
  std::vector<int> kept_leaves;
  std::vector<double> stray;
  std::vector<std::uint32_t> leaf_count;
  std::vector<unsigned char> leaf_fine;
};

} // namespace cfddem::dem
