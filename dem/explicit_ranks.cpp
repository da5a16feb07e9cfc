// ExplicitScheme's rank-related part on R > 1 ranks: ownership by the rank decomposition,
// migration, ghost copies, regrid and the ghost forward that overlaps the next step's forces
// (dem/explicit_scheme.hpp describes the sequence).
#include "dem/explicit_ranks.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>

#include <fmt/format.h>

#include "core/error.hpp"
#include "dem/scheme_support.hpp"

namespace cfddem::dem {

namespace {
int ceil_log2(int n) {
  int l = 0;
  while ((1 << l) < n)
    ++l;
  return l;
}

// Ghost copies of the owned particles [0, owned): one per (rank, periodic shift) whose boxes
// hold the particle's image within `halo`, other than the particle itself.
void ghost_copies(const ParticleStore& p, std::size_t owned,
                  const partition::RankDecomposition& decomposition, const DomainGeometry& geom,
                  double halo, int me, std::vector<ParticleExchange::Copy>& out) {
  out.clear();
  const partition::OrbTree& tree = decomposition.tree;
  std::vector<std::pair<int, std::array<int, 3>>> seen;
  for (std::size_t i = 0; i < owned; ++i) {
    const partition::Aabb q{{p.x[i] - halo, p.y[i] - halo, p.z[i] - halo},
                            {p.x[i] + halo, p.y[i] + halo, p.z[i] + halo}};
    if (halo_inside_own_leaf(tree, p.x[i], p.y[i], p.z[i], q))
      continue;
    seen.clear();
    // (leaf, s): the particle's image p + s L lies within the halo of the leaf.
    for (const partition::LeafImage& li : tree.leaf_images_overlapping(q, geom.periodic)) {
      const int r = decomposition.owner[static_cast<std::size_t>(li.leaf)];
      if (r == me && li.shift == std::array<int, 3>{0, 0, 0})
        continue; // the particle itself
      const std::pair<int, std::array<int, 3>> key{r, li.shift};
      if (std::find(seen.begin(), seen.end(), key) != seen.end())
        continue;
      seen.push_back(key);
      ParticleExchange::Copy c;
      c.rank = r;
      c.index = static_cast<std::uint32_t>(i);
      for (int a = 0; a < 3; ++a)
        c.shift[a] = li.shift[a] * geom.length[a];
      out.push_back(c);
    }
  }
}
} // namespace

ExplicitScheme::RankPart::RankPart(const Scene& scene, const ParticleStore& p,
                                   const StepModel& model, const Communicator& c)
    : comm(c), exchange(c) {
  // Enough boxes that the knapsack can balance: at least 4 per rank (partition.orb_levels when
  // that is more).
  levels = std::min(20, std::max(scene.partition.orb_levels, ceil_log2(comm.size()) + 2));
  double r_max = 0.0;
  for (const double r : p.radius)
    r_max = std::max(r_max, r);
  r_max = comm.max(r_max);
  halo = 2.0 * r_max + model.skin; // the Verlet cutoff: every pair the list can hold
  n_global = comm.sum(static_cast<std::int64_t>(p.size()));
  const DomainGeometry geom(scene.domain);
  for (int a = 0; a < 3; ++a)
    // As VerletList::build: one image of a neighbour within reach at most.
    if (n_global > 0 && geom.periodic[a] && geom.length[a] <= 2.0 * (halo + model.skin))
      throw RunError(fmt::format(
          "periodic axis {} is {:.6g} m long, not more than twice the neighbor cutoff plus skin "
          "{:.6g} m (largest diameter + 2 skins): enlarge the domain or reduce dem.neighbor_skin",
          a, geom.length[a], halo + model.skin));
  // Regrid at the first neighbor rebuild after dem.regrid_interval (simulated seconds).
  regrid_every =
      std::max<std::int64_t>(1, std::llround(model.interval / std::max(model.dt, 1e-300)));
  owned = p.size();
}

void ExplicitScheme::finish_forward() {
  if (!rank_ || !rank_->forward_pending)
    return;
  rank_->exchange.forward_end(p_);
  rank_->forward_pending = false;
}

void ExplicitScheme::exchange_after_step(bool& moved, bool& failed) {
  // One reduction: did any particle anywhere move past skin/2, and did any rank fail a check;
  // in flight together with the ghost forward (wasted, and overwritten, before a rebuild).
  RankPart& r = *rank_;
  std::array<std::int64_t, 2> flags{moved ? 1 : 0, failed ? 1 : 0};
  r.comm.max_begin(flags);
  r.exchange.forward_begin(p_);
  r.forward_pending = true;
  r.comm.max_wait();
  moved = flags[0] != 0, failed = flags[1] != 0;
  if (failed)
    finish_forward();
}

void ExplicitScheme::rebuild_ranks() {
  RankPart& r = *rank_;
  const Communicator& comm = r.comm;
  // The owned rows' history by ids (partners may be ghosts, about to go), with any records a
  // restart handed in.
  ContactHistory held;
  if (model_.friction) {
    held = collect_history(p_, rows_.list, r.owned, rows_.hx, rows_.hy, rows_.hz);
    held.append(rows_.pending);
    rows_.pending = ContactHistory{};
  }
  p_.resize(r.owned); // the ghosts go; they come back from their owners below
  for (std::size_t i = 0; i < r.owned; ++i)
    p_.x[i] = geom_.wrap(p_.x[i], 0), p_.y[i] = geom_.wrap(p_.y[i], 1),
    p_.z[i] = geom_.wrap(p_.z[i], 2);
  // A fixed decomposition is never redone, but the first build sorts as a regrid does.
  const bool regrid = r.last_regrid < 0 ||
                      (!r.fixed_decomposition && stats_.steps - r.last_regrid >= r.regrid_every);
  if (regrid && !r.fixed_decomposition) {
    PhaseTimer::Scope t(timer_, Phase::regrid);
    const partition::Aabb domain{scene_.domain.lo, scene_.domain.hi};
    r.decomposition = partition::decompose(comm, p_.x, p_.y, p_.z, domain, r.levels);
    r.regrids.push_back({stats_.steps, r.decomposition.imbalance});
  }
  if (regrid)
    r.last_regrid = stats_.steps;
  std::vector<int> dest(r.owned);
  std::string outside; // the update's checks stop such a particle first; agreed on all ranks
  std::int64_t outside_id = 0;
  for (std::size_t i = 0; i < r.owned; ++i) {
    dest[i] = r.decomposition.owner_of(p_.x[i], p_.y[i], p_.z[i]);
    if (dest[i] < 0 && outside.empty()) {
      outside_id = p_.id[i];
      outside = fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m is outside "
                            "the domain (rank {})",
                            time(), p_.id[i], p_.x[i], p_.y[i], p_.z[i], comm.rank());
    }
  }
  if (const std::string e = comm.agree_on_error(outside_id, outside); !e.empty())
    throw RunError(e);
  ContactHistory arrived;
  std::int64_t moved_history = 0;
  if (model_.friction)
    arrived = route_history(held, p_, r.owned, dest, r.exchange, comm.rank(), moved_history);
  if (r.ext_on) {
    // Every rank alike (the record sizes must agree), a rank without particles included.
    std::vector<double>* force[3] = {&ext_.x, &ext_.y, &ext_.z};
    r.exchange.migrate(p_, dest, force);
  } else {
    r.exchange.migrate(p_, dest);
  }
  r.owned = p_.size();
  if (regrid) {
    // Locality: owned particles in cell order (cells of the halo width), as the one-rank list
    // sorts its store; then rows and their neighbours are near in memory.
    std::vector<std::uint64_t> key(r.owned);
    for (std::size_t i = 0; i < r.owned; ++i) {
      const double q[3] = {p_.x[i], p_.y[i], p_.z[i]};
      std::uint64_t k = 0;
      for (int a = 2; a >= 0; --a)
        k = k * (std::uint64_t{1} << 20) +
            static_cast<std::uint64_t>(std::clamp((q[a] - geom_.lo[a]) / r.halo, 0.0, 1048575.0));
      key[i] = k;
    }
    std::vector<std::uint32_t> order(r.owned);
    std::iota(order.begin(), order.end(), 0U);
    // Ties by id: the order (hence every force sum) does not depend on the order in which the
    // particles arrived, so a restart rebuilds it exactly.
    std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
      return key[a] != key[b] ? key[a] < key[b] : p_.id[a] < p_.id[b];
    });
    p_.permute(order);
    ext_.permute(order);
  }
  std::vector<ParticleExchange::Copy> copies;
  ghost_copies(p_, r.owned, r.decomposition, geom_, r.halo, comm.rank(), copies);
  r.exchange.build_ghosts(p_, r.owned, std::move(copies));
  rows_.list.build_local(p_, r.owned, model_.skin);
  if (model_.friction)
    attach_history(std::move(arrived), p_, rows_.list, r.owned, rows_.hx, rows_.hy, rows_.hz);
  // No particle lost: the owned counts add up to the initial total (and the pair count: a pair
  // with a ghost is listed on both its ranks, so entries count twice, ghost entries once).
  std::array<std::int64_t, 3> totals{static_cast<std::int64_t>(r.owned), local_pair_entries2(),
                                     moved_history};
  comm.sum(totals);
  if (totals[0] != r.n_global)
    throw RunError(fmt::format("t = {:.9g} s: {} particles on the ranks after migration, {} "
                               "expected",
                               time(), totals[0], r.n_global));
  r.global_pairs = totals[1] / 2;
  r.history_migrations += totals[2];
}

} // namespace cfddem::dem
