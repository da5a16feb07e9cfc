// The R-rank part of the islands scheme (dem/islands_scheme.hpp): what a rank holds besides the
// one-rank state -- the communicator and particle exchange, the decomposition, the rows of its
// owned particles over owned + ghosts (OrbLocalRows), the spanning islands and the rollback
// copies. Private to islands_scheme.cpp and islands_ranks.cpp.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_exchange.hpp"
#include "dem/contact_history.hpp"
#include "dem/global_pairs.hpp"
#include "dem/islands_kernels.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/near_rows.hpp"
#include "dem/orb_local_rows.hpp"
#include "partition/orb_tree.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::dem {

struct IslandsScheme::RankPart {
  explicit RankPart(const Communicator& c) : comm(c), exchange(c) {}

  const Communicator& comm;
  ParticleExchange exchange;
  partition::RankDecomposition decomposition;
  partition::Aabb domain;
  int levels = 0;
  double r_max = 0.0, mass_global = 0.0;
  // The islands skin; the largest bound of the last link rounds (over all ranks); the skin a
  // short build asked for.
  double base_skin = 0.0, last_max_bound = 0.0, grown_skin = 0.0;
  // Whether the rows were built in this sub-iteration's search (a retry at the skin cap stops).
  bool fresh_rows = false;
  std::int64_t last_regrid = -1;
  // Spanning particles over all ranks in the last link round.
  std::int64_t spanning_global = 0;
  bool need_rebuild = true;
  bool ext_on = false; // some rank holds an external force (its columns migrate)
  OrbLocalRows rows;
  std::vector<std::uint32_t> leaf0;        // all zero: the rows' one "leaf" of owned particles
  std::vector<double> x_ref, y_ref, z_ref; // owned positions at the last build
  std::vector<unsigned char> spans;        // per island: has a ghost member
  std::vector<std::uint32_t> span_members; // owned members of spanning islands (or all)
  std::vector<double> sx0, sy0, sz0;       // ... their start positions
  // ... their leads (islands_ranks.cpp, span_leads), from entry times per particle (owned and
  // ghosts).
  std::vector<std::int64_t> span_lead;
  std::vector<double> span_entry;
  // Start of the sub-iteration in the dense mode (rollback): x, y, z, vx, vy, vz, h_prev.
  std::array<std::vector<double>, 7> start;
  // Friction: the ids of the store's slots at the last build (the rows' history is read by
  // them), the records a restore or a save left for the next build, and the spins and history
  // at the start of a dense sub-iteration (rollback).
  std::vector<std::int64_t> hist_ids;
  ContactHistory pending;
  std::array<std::vector<double>, 6> start_spin; // wx, wy, wz (owned), hx, hy, hz (rows)
  double max_ratio_local = 0.0; // this rank's largest overlap ratio not yet reduced
  islands::NearRows near; // the dense mode's near rows (dem/near_rows.hpp)
  // The link rounds after the first (make_links_ranks): per rows entry, whether it is a link;
  // each link's entry (the key that orders the links: the owned row's, of two owned particles
  // the lower index's); the particles whose bound changed in the last round; for each ghost, the
  // owned rows' entries that hold it (rebuilt with the rows).
  std::vector<unsigned char> linked_entry, mark;
  std::vector<std::uint32_t> link_key, new_key, changed, ghost_off, ghost_entry;
  std::vector<double> ghost_bound;
  bool ghost_index_stale = true;
  bool incremental_on = true;
  std::int64_t incremental_rounds = 0;
  // The dense mode without friction: each pair of the near rows once through the explicit
  // scheme's pair pass, and the pairs counted per step over the ranks (step_together).
  GlobalPairs dense_pairs;
  std::int64_t dense_once = 0;
};

} // namespace cfddem::dem
