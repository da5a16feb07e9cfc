// The islands scheme on R > 1 ranks (dem/islands_scheme.hpp): what only R ranks do. The
// sub-iteration's driver is the one of any rank count (dem/islands_subiteration.cpp); its steps
// that differ here are find_islands_ranks() and the verbs at the end of this file, no-ops or the
// identity on one rank. One sub-iteration t -> t + dt_sp on R ranks:
//   1. at a build (the first sub-iteration, or when step 3 finds the rows too short): a new
//      decomposition (parallel ORB + Hilbert knapsack) if dem.nsubit sub-iterations have passed
//      since the last; every particle migrates to its owner (with its half step, fine count and
//      external force), owned ones in id order; every owned particle within 2 r_max + skin of
//      another rank's box is copied there unshifted (separations take the minimum image); rows
//      of the owned particles over owned + ghosts (OrbLocalRows) with every pair within
//      r_i + r_j + skin, the skin the islands skin and at least 4 dt_sp x the largest bound;
//   2. own speed bounds of the owned particles; the ghosts' x, v (and spins, with friction) and
//      bounds from their owners (one forward_columns);
//   3. link rounds over pairs with an owned end. An island with a ghost member SPANS ranks; a
//      LOCAL one is raised to its s_max as on one rank; every spanning island's members on every
//      rank to one s_span from sums over all spanning particles of all ranks (energy summed,
//      lightest mass, largest acceleration and half step: at least any spanning island's own
//      s_max). Raised bounds go to the ghosts and the links are redone until no rank's islands
//      change (one reduction per round), so a link exists on one rank iff on every rank holding
//      its ends. The rows hold every pair that can link while twice the largest reach over all
//      ranks (largest_reaches) stays below the skin; else the sub-iteration builds again
//      (expired_builds(); a doubled skin when even a fresh build was short). Above
//      kGlobalFraction of all particles linked, everyone steps finely (the dense mode), and
//      the reach and the next build's skin take the particles' own bounds, not the raised ones;
//   4. lone particles fly free, local islands take the K fine steps (TBB tasks) as on one rank;
//      then, when some rank has a spanning island (or in the dense mode), all spanning members
//      (all particles) take them together, the ghosts' x and v refreshed before every step;
//   5. one reduction of the counters, particle count and mass (none may be lost), faults (every
//      rank throws the same RunError) and the dense mode's test: a particle that moved more than
//      half the skin since the build rolls every rank back to redo the sub-iteration after a
//      build with twice the skin (retries()).
// A sub-iteration without a build costs one ghost refresh, one reduction per link round (usually
// two) and one closing reduction, plus K - 1 ghost refreshes when an island spans ranks.
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>

#include <fmt/format.h>
#include <tbb/blocked_range.h>

#include "core/error.hpp"
#include "dem/contact_history.hpp"
#include "dem/flag_dispatch.hpp"
#include "dem/islands_rank_part.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/kick_drift_range.hpp"
#include "dem/near_rows.hpp"
#include "dem/scheme_support.hpp"
#include "dem/task_blocks.hpp"
#include "dem/verlet_passes.hpp"

namespace cfddem::dem {

namespace {
int ceil_log2(int n) {
  int l = 0;
  while ((1 << l) < n)
    ++l;
  return l;
}
} // namespace

void IslandsScheme::init_ranks() {
  RankPart& r = *rank_;
  r.domain = partition::Aabb{scene_.domain.lo, scene_.domain.hi};
  // Enough boxes that the knapsack can balance (the distributed explicit scheme's rule).
  r.levels = std::min(20, std::max(scene_.partition.orb_levels, ceil_log2(r.comm.size()) + 2));
  for (const double v : p_.radius)
    r.r_max = std::max(r.r_max, v);
  r.r_max = r.comm.max(r.r_max);
  n_global_ = r.comm.sum(static_cast<std::int64_t>(p_.size()));
  double m = 0.0;
  for (const double v : p_.mass)
    m += v;
  std::array<double, 1> ms{m};
  r.comm.sum(ms);
  r.mass_global = ms[0];
  r.base_skin = one_.islands_skin;
  skin_cap_ = periodic_skin_cap(geom_, r.r_max);
}

void IslandsScheme::set_external_force_ranks(std::span<const double> fx, std::span<const double> fy,
                                             std::span<const double> fz) {
  RankPart& r = *rank_;
  const bool on = r.comm.max(fx.empty() ? 0.0 : 1.0) > 0.0;
  const bool fits = on ? fx.size() == owned_ && fy.size() == owned_ && fz.size() == owned_
                       : fy.empty() && fz.empty();
  if (r.comm.max(fits ? 0.0 : 1.0) > 0.0)
    throw std::invalid_argument("set_external_force: one value per owned particle expected");
  r.ext_on = on;
  ext_.x.assign(fx.begin(), fx.end()), ext_.y.assign(fy.begin(), fy.end());
  ext_.z.assign(fz.begin(), fz.end());
}

void IslandsScheme::regrid() {
  PhaseTimer::Scope t(timer_, Phase::regrid);
  RankPart& r = *rank_;
  for (std::size_t i = 0; i < owned_; ++i)
    p_.x[i] = geom_.wrap(p_.x[i], 0), p_.y[i] = geom_.wrap(p_.y[i], 1),
    p_.z[i] = geom_.wrap(p_.z[i], 2);
  r.decomposition = partition::decompose(r.comm, p_.x, p_.y, p_.z, r.domain, r.levels);
  imbalances_.push_back(r.decomposition.imbalance);
  ++st_.regrids;
}

// Every owned particle to the rank owning its wrapped position, then the owned ones in id order
// (an order that depends on the particles only, whatever the arrival order). With friction each
// history record goes to the rank its owner particle goes to (records of particles this rank does
// not hold, a restore's of other ranks' shares, are dropped: their holder routes them).
ContactHistory IslandsScheme::migrate(ContactHistory held) {
  RankPart& r = *rank_;
  std::vector<int> dest(owned_);
  std::string outside;
  std::int64_t key = std::numeric_limits<std::int64_t>::max();
  for (std::size_t i = 0; i < owned_; ++i) {
    p_.x[i] = geom_.wrap(p_.x[i], 0), p_.y[i] = geom_.wrap(p_.y[i], 1),
    p_.z[i] = geom_.wrap(p_.z[i], 2);
    dest[i] = r.decomposition.owner_of(p_.x[i], p_.y[i], p_.z[i]);
    if (dest[i] < 0 && p_.id[i] < key) {
      key = p_.id[i];
      outside = fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m is outside "
                            "the domain (rank {})",
                            time(), p_.id[i], p_.x[i], p_.y[i], p_.z[i], r.comm.rank());
    }
  }
  if (const std::string e = r.comm.agree_on_error(key, outside); !e.empty())
    throw RunError(e);
  ContactHistory arrived;
  if (model_.friction) {
    std::int64_t moved = 0;
    arrived = route_history(held, p_, owned_, dest, r.exchange, r.comm.rank(), moved);
  }
  std::vector<std::vector<double>*> cols{&hprev_, &fine_};
  if (r.ext_on)
    cols.insert(cols.end(), {&ext_.x, &ext_.y, &ext_.z});
  r.exchange.migrate(p_, dest, cols);
  owned_ = p_.size();
  std::vector<std::uint32_t> order(owned_);
  std::iota(order.begin(), order.end(), 0U);
  std::sort(order.begin(), order.end(),
            [&](std::uint32_t a, std::uint32_t b) { return p_.id[a] < p_.id[b]; });
  p_.permute(order);
  for (std::vector<double>* c : cols) {
    std::vector<double> t(owned_);
    for (std::size_t k = 0; k < owned_; ++k)
      t[k] = (*c)[order[k]];
    c->swap(t);
  }
  return arrived;
}

// The own speed bounds of the owned particles (the ghosts' come from their owners).
void IslandsScheme::own_bounds() {
  ln_.bound.resize(owned_);
  islands::speed_bounds(cols(), owned_, model_.gravity, dt_sp_, ln_.bound.data());
}

// Ghosts within the halo 2 r_max + skin_ of this rank's boxes, their bounds, and the rows
// (step 1 of the header).
void IslandsScheme::build_ghosts_and_rows() {
  RankPart& r = *rank_;
  const double cutoff = 2.0 * r.r_max + skin_;
  for (int a = 0; a < 3; ++a)
    if (geom_.periodic[a] && 2.0 * cutoff >= geom_.length[a])
      throw RunError(fmt::format("t = {:.9g} s: periodic axis {} is {:.4g} m long, not more than "
                                 "twice the distributed islands scheme's halo {:.4g} m: raise "
                                 "dem.nsubit or run on one rank",
                                 time(), a, geom_.length[a], cutoff));
  const partition::OrbTree& tree = r.decomposition.tree;
  const int me = r.comm.rank();
  std::vector<ParticleExchange::Copy> copies;
  std::vector<int> ranks;
  for (std::size_t i = 0; i < owned_; ++i) {
    const partition::Aabb q{{p_.x[i] - cutoff, p_.y[i] - cutoff, p_.z[i] - cutoff},
                            {p_.x[i] + cutoff, p_.y[i] + cutoff, p_.z[i] + cutoff}};
    if (halo_inside_own_leaf(tree, p_.x[i], p_.y[i], p_.z[i], q))
      continue;
    ranks.clear();
    for (const partition::LeafImage& li : tree.leaf_images_overlapping(q, geom_.periodic)) {
      const int o = r.decomposition.owner[static_cast<std::size_t>(li.leaf)];
      if (o == me || std::find(ranks.begin(), ranks.end(), o) != ranks.end())
        continue;
      ranks.push_back(o);
    }
    // Unshifted: separations take the minimum image, as on one rank.
    for (const int o : ranks)
      copies.push_back({o, static_cast<std::uint32_t>(i), {}});
  }
  r.exchange.build_ghosts(p_, owned_, std::move(copies));
  const std::size_t n = p_.size();
  ln_.bound.resize(n);
  std::vector<double>* col[] = {&ln_.bound};
  r.exchange.forward_columns(col);
  r.leaf0.assign(owned_, 0);
  r.rows.build({geom_,
                {p_.x.data(), n},
                {p_.y.data(), n},
                {p_.z.data(), n},
                {p_.radius.data(), n},
                {p_.id.data(), n},
                {ln_.bound.data(), n},
                {r.leaf0.data(), owned_},
                owned_,
                cutoff,
                skin_,
                0.0,
                dt_sp_,
                false});
  r.ghost_index_stale = true;
  r.x_ref.assign(p_.x.begin(), p_.x.begin() + static_cast<std::ptrdiff_t>(owned_));
  r.y_ref.assign(p_.y.begin(), p_.y.begin() + static_cast<std::ptrdiff_t>(owned_));
  r.z_ref.assign(p_.z.begin(), p_.z.begin() + static_cast<std::ptrdiff_t>(owned_));
  ++st_.builds;
}

// The one-rank link test and wall tie over pairs with an owned end (each owned pair once), walls
// of owned particles; islands over the linked and tied particles (owned and ghosts); an island
// with a ghost member spans ranks.
void IslandsScheme::make_links_ranks(bool incremental) {
  RankPart& r = *rank_;
  const auto off = r.rows.off();
  const auto nb = r.rows.nb();
  const DomainGeometry& g = geom_;
  const double* bnd = ln_.bound.data();
  const bool friction = model_.friction;
  // The one-rank link test of the pair (i, j) from i's row.
  auto linked = [&](std::uint32_t i, std::uint32_t j) {
    const double dx = g.image(p_.x[j] - p_.x[i], 0), dy = g.image(p_.y[j] - p_.y[i], 1),
                 dz = g.image(p_.z[j] - p_.z[i], 2);
    return islands::may_touch(dx * dx + dy * dy + dz * dz, bnd[i], bnd[j], p_.radius[i],
                              p_.radius[j], dt_sp_, margin_);
  };
  auto tie = [&](std::uint32_t i) {
    bool t = false;
    for (int a = 0; a < 3; ++a) {
      const double pos = a == 0 ? p_.x[i] : a == 1 ? p_.y[i] : p_.z[i];
      t = t || (!g.periodic[a] &&
                islands::may_reach_wall(pos, g.lo[a], g.hi[a], p_.radius[i], bnd[i], dt_sp_,
                                        margin_));
    }
    return t || (g.cylinder && islands::may_reach_cylinder(g, p_.x[i], p_.y[i], p_.z[i],
                                                           p_.radius[i], bnd[i], dt_sp_, margin_));
  };
  if (!incremental) {
    ln_.ea.clear(), ln_.eb.clear(), ln_.ek.clear(), r.link_key.clear();
    r.linked_entry.assign(nb.size(), 0);
    for (std::uint32_t i = 0; i < owned_; ++i)
      for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
        const std::uint32_t j = nb[k];
        if (j < owned_ && j <= i)
          continue;
        if (linked(i, j)) {
          ln_.ea.push_back(i), ln_.eb.push_back(j), r.link_key.push_back(k);
          r.linked_entry[k] = 1;
        }
      }
    ln_.tied.clear();
    for (std::uint32_t i = 0; i < owned_; ++i)
      if (tie(i))
        ln_.tied.push_back(i);
  } else {
    // Bounds only grew since the last round (link_rounds checks), so a link stays a link and a
    // pair neither of whose ends changed tests as before: the new links are among the pairs of
    // the changed particles, each tested from the row the full scan tests it from, by the same
    // expression, and merged by entry, which is the full scan's order. The same links, in the
    // same order, as a full scan.
    if (r.ghost_index_stale)
      ghost_entries();
    r.mark.resize(p_.size(), 0); // zero but for this round's marks, cleared below
    for (const std::uint32_t c : r.changed)
      r.mark[c] = 1;
    r.new_key.clear();
    auto test = [&](std::uint32_t i, std::uint32_t j, std::uint32_t k) {
      if (!r.linked_entry[k] && linked(i, j))
        r.new_key.push_back(k), r.linked_entry[k] = 1;
    };
    for (const std::uint32_t c : r.changed) {
      if (c >= owned_) { // a ghost: from the owned rows that hold it, unless they changed too
        const std::uint32_t gq = c - static_cast<std::uint32_t>(owned_);
        for (std::uint32_t e = r.ghost_off[gq]; e < r.ghost_off[gq + 1]; ++e) {
          const std::uint32_t k = r.ghost_entry[e];
          const auto i = static_cast<std::uint32_t>(
              std::upper_bound(off.begin(), off.end(), k) - off.begin() - 1);
          if (!r.mark[i])
            test(i, c, k);
        }
        continue;
      }
      for (std::uint32_t k = off[c]; k < off[c + 1]; ++k) {
        const std::uint32_t j = nb[k];
        if (j >= owned_ || j > c) {
          test(c, j, k);
        } else if (!r.mark[j]) { // from j's row: its entry of c
          std::uint32_t kj = off[j];
          while (nb[kj] != c)
            ++kj;
          test(j, c, kj);
        }
      }
      if (tie(c))
        ln_.tied.push_back(c); // a duplicate is harmless: form() takes each particle once
    }
    for (const std::uint32_t c : r.changed)
      r.mark[c] = 0;
    std::sort(r.new_key.begin(), r.new_key.end());
    std::size_t q = r.link_key.size(), added = r.new_key.size();
    if (added > 0) { // merge, back to front, by entry
      ln_.ea.resize(q + added), ln_.eb.resize(q + added), r.link_key.resize(q + added);
      std::size_t w = q + added;
      while (added > 0) {
        const std::uint32_t kn = r.new_key[added - 1];
        --w;
        if (q > 0 && r.link_key[q - 1] > kn) {
          --q;
          ln_.ea[w] = ln_.ea[q], ln_.eb[w] = ln_.eb[q], r.link_key[w] = r.link_key[q];
        } else {
          --added;
          ln_.ea[w] = static_cast<std::uint32_t>(
              std::upper_bound(off.begin(), off.end(), kn) - off.begin() - 1);
          ln_.eb[w] = nb[kn], r.link_key[w] = kn;
        }
      }
    }
  }
  if (friction) // each link's entry in its owned row: its tangential spring enters the energy
    ln_.ek = r.link_key;
  ln_.form(p_.size(), std::numeric_limits<double>::infinity());
  rank_->spans.assign(ln_.islands.count(), 0);
  for (const std::uint32_t v : ln_.busy)
    if (v >= owned_)
      rank_->spans[ln_.island_of[v]] = 1;
}

std::int64_t IslandsScheme::incremental_link_rounds() const {
  return rank_ ? rank_->incremental_rounds : 0;
}

void IslandsScheme::use_incremental_links(bool on) {
  if (rank_)
    rank_->incremental_on = on;
}

// For each ghost, the entries of the owned rows that hold it (in entry order).
void IslandsScheme::ghost_entries() {
  RankPart& r = *rank_;
  const auto nb = r.rows.nb();
  const std::size_t ghosts = p_.size() - owned_;
  r.ghost_off.assign(ghosts + 1, 0);
  for (const std::uint32_t j : nb)
    if (j >= owned_)
      ++r.ghost_off[j - owned_ + 1];
  for (std::size_t q = 0; q < ghosts; ++q)
    r.ghost_off[q + 1] += r.ghost_off[q];
  r.ghost_entry.resize(r.ghost_off[ghosts]);
  std::vector<std::uint32_t> at(r.ghost_off.begin(), r.ghost_off.end() - 1);
  for (std::uint32_t k = 0; k < nb.size(); ++k)
    if (nb[k] >= owned_)
      r.ghost_entry[at[nb[k] - owned_]++] = k;
  r.ghost_index_stale = false;
}

// Link rounds (step 3 of the header); returns the largest reach over all ranks.
double IslandsScheme::link_rounds() {
  RankPart& r = *rank_;
  const std::size_t n = p_.size();
  // Own bounds saved the first time a particle is busy in this call, as on one rank.
  ln_.own_bound.resize(n);
  ln_.own_stamp.assign(n, 0);
  ln_.stamp = 1;
  global_ = false;
  // After the first round only the pairs of the particles whose bound changed are tested again,
  // while no bound shrank (make_links_ranks); a shrunk bound (not expected: islands only merge)
  // takes a full scan on that rank, which gives the same links.
  bool incremental = false;
  double own_reach = 0.0, own_bound_max = 0.0;
  for (int round = 0;; ++round) {
    make_links_ranks(incremental && r.incremental_on);
    r.incremental_rounds += incremental && r.incremental_on ? 1 : 0;
    const bool changed =
        round == 0 || ln_.busy != ln_.busy_before || ln_.islands.label != ln_.label_before;
    for (const std::uint32_t i : ln_.busy)
      if (ln_.own_stamp[i] != ln_.stamp)
        ln_.own_stamp[i] = ln_.stamp, ln_.own_bound[i] = ln_.bound[i];
    island_sums(owned_);
    // Spanning islands: one set of sums for all of them, over all ranks. A pair with a ghost end
    // is counted on both ranks (more energy: still conservative).
    const std::uint32_t nc = ln_.islands.count();
    double e_span = 0.0, m_span = std::numeric_limits<double>::infinity(), a_span = 0.0,
           hp_span = 0.0, busy_owned = 0.0, spanning = 0.0, bound_max = 0.0;
    for (std::uint32_t q = 0; q < nc; ++q)
      if (r.spans[q]) {
        e_span += ln_.energy[q], m_span = std::min(m_span, ln_.m_min[q]);
        a_span = std::max(a_span, ln_.a_max[q]), hp_span = std::max(hp_span, ln_.hp_max[q]);
      }
    for (const std::uint32_t i : ln_.busy) {
      if (i >= owned_)
        break; // busy is increasing: the ghosts come last
      busy_owned += 1.0;
      spanning += r.spans[ln_.island_of[i]];
    }
    // The rows and ghosts hold every pair that can link while no two particles' reaches
    // (displacement since the build + bound over the sub-iteration) add up to the skin.
    const islands::Reaches reach = islands::largest_reaches<true>(
        p_.x.data(), p_.y.data(), p_.z.data(), r.x_ref.data(), r.y_ref.data(), r.z_ref.data(),
        ln_.bound.data(), dt_sp_, owned_);
    for (std::size_t i = 0; i < owned_; ++i)
      bound_max = std::max(bound_max, ln_.bound[i]);
    std::array<double, 6> mx{changed ? 1.0 : 0.0, a_span, hp_span, -m_span, reach.first, bound_max};
    std::array<double, 3> sm{e_span, busy_owned, spanning};
    r.comm.sum_max(sm, mx);
    if (round == 0)
      own_reach = mx[4], own_bound_max = mx[5];
    r.last_max_bound = mx[5];
    r.spanning_global = static_cast<std::int64_t>(sm[2]);
    if (sm[1] > kGlobalFraction * static_cast<double>(n_global_)) {
      // A dense bed: everyone takes the fine steps, reading every partner live, so the islands'
      // raised bounds (an island's whole energy given to its lightest member: loose for a
      // bed-wide island) bound nothing. The rows need the particles' own reach (round 0's, before
      // any raise), and the dense mode's check against half the skin guards them (roll_back).
      // With the raised bounds, the 2-rank 1e5 bed built rows of 114 entries per particle at
      // a skin of 2.1 diameters (own bounds: 8e-3 m/s, raised: 0.53 m/s).
      global_ = true;
      r.last_max_bound = own_bound_max;
      return own_reach;
    }
    if (round > 0 && mx[0] == 0.0)
      return mx[4];
    const double m_all = -mx[3];
    const double s_span =
        std::isfinite(m_all) ? islands::island_speed(sm[0], m_all, mx[1], mx[2], dt_sp_) : 0.0;
    r.changed.clear();
    incremental = true;
    for (const std::uint32_t i : ln_.busy) {
      if (i >= owned_)
        break;
      const std::uint32_t c = ln_.island_of[i];
      const double s = r.spans[c] ? s_span
                                  : islands::island_speed(ln_.energy[c], ln_.m_min[c], ln_.a_max[c],
                                                          ln_.hp_max[c], dt_sp_);
      const double b = std::max(ln_.own_bound[i], s);
      if (b != ln_.bound[i])
        r.changed.push_back(i), incremental = incremental && b > ln_.bound[i];
      ln_.bound[i] = b;
    }
    r.ghost_bound.assign(ln_.bound.begin() + static_cast<std::ptrdiff_t>(owned_), ln_.bound.end());
    std::vector<double>* col[] = {&ln_.bound};
    r.exchange.forward_columns(col); // the ghosts' raised bounds from their owners
    for (std::size_t q = 0; q < r.ghost_bound.size(); ++q) {
      const double b = ln_.bound[owned_ + q];
      if (b != r.ghost_bound[q])
        r.changed.push_back(static_cast<std::uint32_t>(owned_ + q)),
            incremental = incremental && b > r.ghost_bound[q];
    }
    ln_.busy_before = ln_.busy;
    ln_.label_before = ln_.islands.label;
  }
}

// The dense mode's K fine steps of every owned particle without friction, the forces of step k
// computed by between() before it (k > 0; the first before the call): the variable-step
// leapfrog of orb's global steps (leaf_kick_drift, dem/kick_drift_range.hpp), vectorised over
// blocks of the owned particles, the same arithmetic as the islands' per-member kick
// (islands::step_island, which reads every member through the member list, one at a time: 2x
// the time per particle step in the 2-rank 1e5 bed). A particle farther than half the skin from
// the build outruns the rows (bound_violations, one per block: the caller rolls back on any).
template <bool External, class Between>
islands::IslandResult IslandsScheme::dense_kicks(bool record, Between&& between) {
  RankPart& r = *rank_;
  const std::size_t n = owned_;
  constexpr std::size_t kBlock = 1024;
  // Per block: the sign bit stays set while every particle is within skin/2 of the build.
  std::vector<std::uint64_t> still((n + kBlock - 1) / kBlock, ~std::uint64_t{0});
  const KickDriftColumns columns = kick_drift_columns(
      p_, std::span<const double>(r.x_ref).first(n), std::span<const double>(r.y_ref).first(n),
      std::span<const double>(r.z_ref).first(n), External ? &ext_ : nullptr,
      std::span<double>(hprev_).first(n));
  const double half_skin2 = 0.25 * skin_ * skin_;
  double h_before = 0.0;
  for (std::int64_t k = 0; k < steps_.K; ++k) {
    const double hk = k + 1 == steps_.K ? steps_.h_last : steps_.h;
    if (k > 0)
      between();
    if (record && k == 0)
      record_start_velocities<External>(n);
    for_particle_blocks(still.size(), [&](std::size_t b) {
      leaf_kick_drift<External>(k, steps_.K,
                                columns.range(b * kBlock, std::min(n, (b + 1) * kBlock)), h_before,
                                hk, model_.gravity, half_skin2, still[b]);
    });
    h_before = hk;
  }
  islands::IslandResult res;
  for (const std::uint64_t v : still)
    res.bound_violations += (v >> 63) ? 0 : 1;
  res.steps = res.lead_steps = static_cast<std::int64_t>(n) * steps_.K;
  return res;
}

// The K fine steps of every spanning member (all: every owned particle, the dense mode), all
// ranks together: the ghosts' x and v (and spins) from their owners before every step but the first
// (collective, also on a rank with no member). In the dense mode the displacement check is
// against half the skin since the build (the rows may miss a pair: roll back).
islands::IslandResult IslandsScheme::fine_together(bool record, bool all) {
  return with_flags([&](auto ext, auto fr) { return step_together<ext, fr>(record, all); },
                    ext_.active(), model_.friction);
}

template <bool External, bool Friction>
islands::IslandResult IslandsScheme::step_together(bool record, bool all) {
  RankPart& r = *rank_;
  if (all) {
    r.span_members.resize(owned_);
    std::iota(r.span_members.begin(), r.span_members.end(), 0U);
  }
  const auto count = static_cast<std::uint32_t>(r.span_members.size());
  islands::Members mb{r.span_members, r.x_ref, r.y_ref, r.z_ref, {}, margin_, 0.25 * skin_ * skin_};
  if (!all) {
    r.sx0.resize(count), r.sy0.resize(count), r.sz0.resize(count);
    for (std::uint32_t u = 0; u < count; ++u) {
      const std::uint32_t i = r.span_members[u];
      r.sx0[u] = p_.x[i], r.sy0[u] = p_.y[i], r.sz0[u] = p_.z[i];
    }
    mb.x0 = r.sx0, mb.y0 = r.sy0, mb.z0 = r.sz0, mb.bound = ln_.bound;
  }
  const islands::ContactView view = contact_view();
  const auto* label = ln_.island_of.data();
  if (!all)
    span_leads(view, mb);
  // Spanning members belong to different islands: one member at a time, each with its own.
  auto forces = [&](std::uint32_t u0, std::uint32_t u1, double& max_ratio, std::int64_t& violations,
                    auto... hk) {
    std::int64_t pairs = 0;
    for (std::uint32_t u = u0; u < u1; ++u)
      pairs += islands::contact_forces<true, true, false, true, Friction>(
          view, mb.mem.data(), u, u + 1, label[mb.mem[u]], max_ratio, violations, hk...);
    return pairs;
  };
  auto refresh = [&] { r.exchange.forward(p_); };
  double* sv[3] = {record ? rec_.vx.data() : nullptr, record ? rec_.vy.data() : nullptr,
                   record ? rec_.vz.data() : nullptr};
  if (!all)
    return islands::step_island<External, true, Friction>(view.c, mb, steps_, model_.gravity,
                                                          sv[0], sv[1], sv[2], forces, refresh,
                                                          TaskBlocks{});
  // The dense mode: every particle's K fine steps over the near rows (dem/near_rows.hpp), taken
  // again from the wide rows whenever a particle of this rank has moved about half the explicit
  // scheme's skin (a local test: ghosts' positions are refreshed before every step).
  islands::NearRows& near = r.near;
  islands::ContactView dense = view;
  auto take_near = [&] {
    islands::filter_near_rows(view.rows, owned_, view.c, geom_, one_.global_skin, view.hx,
                              view.hy, view.hz, near, TaskBlocks{});
    dense.rows = near.rows();
    if (Friction)
      dense.hx = near.hx, dense.hy = near.hy, dense.hz = near.hz;
  };
  take_near();
  if constexpr (!Friction) {
    // Each pair once (the one-rank global mode's passes): the forces of a step are computed
    // before it, the first here and the others after the ghosts' refresh in between(), so the
    // members' force callback has nothing left to do.
    // The pairs from the near rows just taken: while no particle has moved half the explicit
    // skin from the filter, as the head/tail split needs. Every force cleared after a filter
    // (the islands' own steps and the last pass left some behind), else the last pass's.
    GlobalPairs& d = r.dense_pairs;
    islands::IslandResult passes;
    auto pass = [&](double hk, bool fresh) {
      if (fresh) {
        r.dense_once = d.from_rows(near.off, near.nb, owned_, p_.id);
        d.split(p_, owned_, {near.x_ref, near.y_ref, near.z_ref}, geom_, near.skin);
        for (std::vector<double>* c : {&p_.fx, &p_.fy, &p_.fz})
          std::fill(c->begin(), c->end(), 0.0);
      } else {
        d.clear_forces(p_);
      }
      StepReport rep;
      d.pass(p_, geom_, model_, hk, rep);
      double max_ratio = rep.max_ratio;
      std::int64_t violations = rep.overlaps;
      with_flags(
          [&](auto cyl) {
            constexpr bool Cylinder = decltype(cyl)::value;
            const double w[3] = {0.0, 0.0, 0.0};
            double tq[3] = {0.0, 0.0, 0.0};
            for (const std::uint32_t i : d.near_wall())
              islands::add_member_walls<false, Cylinder>(view, i, p_.fx[i], p_.fy[i], p_.fz[i], w,
                                                         tq, max_ratio, violations);
          },
          geom_.cylinder);
      passes.pairs += r.dense_once;
      passes.max_ratio = std::max(passes.max_ratio, max_ratio);
      passes.violations += violations;
    };
    std::int64_t k = 0; // the step the next pass is for
    auto step_length = [&] { return k + 1 == steps_.K ? steps_.h_last : steps_.h; };
    pass(step_length(), true);
    ++k;
    auto refresh_pass = [&] {
      r.exchange.forward(p_);
      const bool expired = islands::near_rows_expired(near, view.c, TaskBlocks{});
      if (expired)
        take_near();
      pass(step_length(), expired);
      ++k;
    };
    islands::IslandResult result = dense_kicks<External>(record, refresh_pass);
    result.pairs += passes.pairs;
    result.max_ratio = std::max(result.max_ratio, passes.max_ratio);
    result.violations += passes.violations;
    return result;
  }
  auto all_forces = [&](std::uint32_t u0, std::uint32_t u1, double& max_ratio,
                        std::int64_t& violations, auto... hk) {
    return islands::contact_forces<false, true, false, true, Friction>(
        dense, mb.mem.data(), u0, u1, 0, max_ratio, violations, hk...);
  };
  auto refresh_near = [&] {
    r.exchange.forward(p_);
    if (!islands::near_rows_expired(near, view.c, TaskBlocks{}))
      return;
    if (Friction) // the springs the near rows advanced, back before they are taken again
      islands::return_near_springs(near, view.hx, view.hy, view.hz);
    take_near();
  };
  islands::IslandResult result = islands::step_island<External, false, Friction>(
      view.c, mb, steps_, model_.gravity, sv[0], sv[1], sv[2], all_forces, refresh_near,
      TaskBlocks{});
  if (Friction)
    islands::return_near_springs(near, view.hx, view.hy, view.hz);
  return result;
}

// The spanning members' leads (islands_kernels.hpp, member_entry_time): each island's entry
// time is the least over its members, and its members lie on several ranks. Every rank takes its
// owned members' times (the ghost partners' own bounds from their owners), then the least
// spreads along the members' rows in the island, from ghosts to owners, until no rank lowers
// one: every member ends with its island's time, the one-rank value. Collective.
void IslandsScheme::span_leads(const islands::ContactView& view, islands::Members& mb) {
  RankPart& r = *rank_;
  const std::size_t n = p_.size();
  const auto* label = ln_.island_of.data();
  // The ghosts' own bounds from their owners (a ghost's saved one may have been raised already
  // when it first turned busy here).
  std::vector<double>* own[] = {&ln_.own_bound};
  r.exchange.forward_columns(own);
  r.span_entry.assign(n, std::numeric_limits<double>::infinity());
  for (const std::uint32_t i : r.span_members)
    r.span_entry[i] =
        islands::member_entry_time<false>(view, ln_.own_bound.data(), margin_, label[i], i);
  const std::uint32_t* off = view.rows.off.data();
  const std::uint32_t* nb = view.rows.nb.data();
  std::vector<double>* entry[] = {&r.span_entry};
  for (;;) {
    r.exchange.forward_columns(entry);
    double lowered = 0.0;
    for (const std::uint32_t i : r.span_members)
      for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
        const std::uint32_t j = nb[k];
        if (label[j] == label[i] && r.span_entry[j] < r.span_entry[i])
          r.span_entry[i] = r.span_entry[j], lowered = 1.0;
      }
    if (r.comm.max(lowered) == 0.0)
      break;
  }
  r.span_lead.resize(r.span_members.size());
  for (std::size_t u = 0; u < r.span_members.size(); ++u)
    r.span_lead[u] = islands::entry_lead(r.span_entry[r.span_members[u]], dt_sp_, steps_);
  mb.leads = r.span_lead;
}

// A fresh build: migration to the owners (a new decomposition once dem.nsubit sub-iterations
// have passed since the last), ghosts and rows with a skin for several sub-iterations; with
// friction the rows' history follows its pairs by ids to the new rows (migrate()).
void IslandsScheme::rebuild_ranks() {
  RankPart& r = *rank_;
  // With friction: the owned rows' history by ids (partners may be ghosts, about to go), with
  // any records a restore or a save left.
  ContactHistory held;
  if (model_.friction) {
    held = std::move(r.pending);
    r.pending = ContactHistory{};
    const auto off = r.rows.off();
    if (!off.empty() && hx_.size() == r.rows.nb().size())
      held.append(collect_history(r.hist_ids, off, r.rows.nb(), off.size() - 1, hx_, hy_, hz_));
  }
  p_.resize(owned_); // the ghosts go
  if (r.last_regrid < 0 || st_.subits - r.last_regrid >= nsubit_) {
    regrid();
    r.last_regrid = st_.subits;
  }
  ContactHistory arrived = migrate(std::move(held));
  own_bounds();
  double b = 0.0;
  for (std::size_t i = 0; i < owned_; ++i)
    b = std::max(b, ln_.bound[i]);
  const double speed = std::max(r.comm.max(b), r.last_max_bound);
  // The one-rank islands skin (three times the explicit scheme's unless dem.neighbor_skin is
  // set), at least four sub-iterations of the largest bound, or what a failed build asked for;
  // at most what a periodic axis allows (the link rounds then check that it still suffices).
  skin_ = std::max({r.base_skin, 4.0 * speed * dt_sp_ + 2.0 * margin_, r.grown_skin});
  if (skin_cap_ > 0.0)
    skin_ = std::min(skin_, skin_cap_);
  build_ghosts_and_rows();
  if (model_.friction) {
    attach_history(std::move(arrived), p_.id, r.rows.off(), r.rows.nb(), owned_, hx_, hy_, hz_);
    r.hist_ids = p_.id;
  }
  r.need_rebuild = false;
}

// Step 2 of the header's sequence, with the link rounds of step 3: the rows and ghosts (built
// when due), the ghosts' columns and bounds, the link rounds; rows too short for this
// sub-iteration's reach build again, wider when even a fresh build was too short.
void IslandsScheme::find_islands_ranks() {
  RankPart& r = *rank_;
  {
    PhaseTimer::Scope t(timer_, Phase::neighbor);
    bool fresh = false;
    for (;;) {
      if (r.need_rebuild) {
        rebuild_ranks();
        fresh = true;
      } else {
        refresh_ghosts();
      }
      ln_.island_of.assign(p_.size(), kAlone);
      ln_.busy.clear();
      ln_.mark.assign(p_.size(), 0);
      const double reach = link_rounds();
      if (2.0 * reach + margin_ < skin_)
        break;
      if (fresh) {
        // Even fresh rows are too short: a wider skin, up to the periodic cap (reach is the
        // largest over the ranks, so every rank grows, or stops, alike).
        const double need = 2.2 * reach + 2.0 * margin_;
        if (!(need < skin_cap_))
          throw RunError(travel_beyond_skin_cap(time(), 0.5 * need, skin_cap_,
                                                "raise dem.nsubit or run on one rank"));
        r.grown_skin = std::max(need, std::min(2.0 * skin_, skin_cap_));
      }
      r.need_rebuild = true;
      ++st_.expired_builds;
    }
    r.fresh_rows = fresh;
  }
  // "auto" chose the global mode for this interval: every rank steps everyone, as one rank
  // does (the links above still check the rows).
  if (auto_.global_now)
    global_ = true;
}

// The own speed bounds of the owned particles, then the ghosts' positions, velocities (spins,
// with friction: a partner's spin enters the tangential force) and own bounds from their
// owners, in one message round.
void IslandsScheme::refresh_ghosts() {
  RankPart& r = *rank_;
  own_bounds();
  ln_.bound.resize(p_.size());
  std::vector<double>* with_spins[] = {&p_.x,  &p_.y,  &p_.z,  &p_.vx, &p_.vy,
                                       &p_.vz, &p_.wx, &p_.wy, &p_.wz, &ln_.bound};
  std::vector<double>* without[] = {&p_.x, &p_.y, &p_.z, &p_.vx, &p_.vy, &p_.vz, &ln_.bound};
  if (model_.friction)
    r.exchange.forward_columns(with_spins);
  else
    r.exchange.forward_columns(without);
}

namespace {
// The columns a dense sub-iteration changes, in RankPart::start's order, and with friction in
// RankPart::start_spin's (the spins of the owned particles, the rows' history).
std::array<std::vector<double>*, 7> live_columns(ParticleStore& p, std::vector<double>& hprev) {
  return {&p.x, &p.y, &p.z, &p.vx, &p.vy, &p.vz, &hprev};
}
std::array<std::vector<double>*, 6> spin_columns(ParticleStore& p, std::vector<double>& hx,
                                                 std::vector<double>& hy, std::vector<double>& hz) {
  return {&p.wx, &p.wy, &p.wz, &hx, &hy, &hz};
}
} // namespace

// R ranks, dense mode: the start of the sub-iteration, which roll_back() returns to.
void IslandsScheme::keep_start() {
  if (!rank_ || !global_)
    return;
  RankPart& r = *rank_;
  const auto owned = static_cast<std::ptrdiff_t>(owned_);
  const auto live = live_columns(p_, hprev_);
  for (std::size_t q = 0; q < r.start.size(); ++q)
    r.start[q].assign(live[q]->begin(), live[q]->begin() + owned);
  if (!model_.friction)
    return;
  const auto spin = spin_columns(p_, hx_, hy_, hz_);
  for (std::size_t q = 0; q < r.start_spin.size(); ++q)
    r.start_spin[q].assign(spin[q]->begin(), q < 3 ? spin[q]->begin() + owned : spin[q]->end());
}

// The dense mode outran its rows somewhere: every rank goes back to the start and builds with
// twice the skin before redoing the sub-iteration (retries()).
void IslandsScheme::roll_back() {
  if (!rank_)
    return;
  RankPart& r = *rank_;
  const auto live = live_columns(p_, hprev_);
  for (std::size_t q = 0; q < r.start.size(); ++q)
    std::copy(r.start[q].begin(), r.start[q].end(), live[q]->begin());
  if (model_.friction) {
    const auto spin = spin_columns(p_, hx_, hy_, hz_);
    for (std::size_t q = 0; q < r.start_spin.size(); ++q)
      std::copy(r.start_spin[q].begin(), r.start_spin[q].end(), spin[q]->begin());
  }
  // Rows built for this very sub-iteration at the widest skin the periodic box allows cannot
  // grow; every rank sees the same skin and rows, so every rank stops alike.
  if (r.fresh_rows && !(skin_ < skin_cap_))
    throw RunError(outran_skin_cap(time(), skin_, "raise dem.nsubit or run on one rank"));
  r.grown_skin = std::min(2.0 * skin_, skin_cap_);
  r.need_rebuild = true;
  ++st_.retries;
}

// The islands with a member on another rank: their owned members (and the parts counted), and
// when some rank has one, the K fine steps of all of them on every rank together (collective,
// also on a rank with none).
void IslandsScheme::step_spanning(bool record, islands::SubiterationCounts& t) {
  if (!rank_)
    return;
  RankPart& r = *rank_;
  r.span_members.clear();
  const std::uint32_t nc = ln_.islands.count();
  for (std::uint32_t q = 0; q < nc; ++q)
    t.span_parts += r.spans[q];
  for (const std::uint32_t i : ln_.busy) {
    if (i >= owned_)
      break;
    if (r.spans[ln_.island_of[i]])
      r.span_members.push_back(i);
  }
  t.span_members = static_cast<double>(r.span_members.size());
  if (r.spanning_global > 0)
    t.add(fine_together(record, false));
}

// This rank's share of the steps and pairs (run.json's rank_counts), then on R ranks one
// reduction closes the sub-iteration, with the particle count and mass after migration.
void IslandsScheme::reduce_counts(islands::SubiterationCounts& t) {
  t.local_steps = static_cast<std::int64_t>(t.particle_steps);
  t.local_pairs = static_cast<std::int64_t>(t.pairs);
  if (!rank_)
    return;
  t.owned = static_cast<double>(owned_);
  for (std::size_t i = 0; i < owned_; ++i)
    t.mass += p_.mass[i];
  std::array<double, islands::SubiterationCounts::kSummed> v = t.summed();
  rank_->comm.sum(v);
  t.set_summed(v);
}

// R ranks: migration lost no particle and no mass.
void IslandsScheme::check_conservation(const islands::SubiterationCounts& t) const {
  if (!rank_)
    return;
  const RankPart& r = *rank_;
  if (t.owned != static_cast<double>(n_global_) ||
      std::abs(t.mass - r.mass_global) > 1e-9 * r.mass_global)
    throw RunError(fmt::format("t = {:.9g} s: {} particles of total mass {:.17g} kg on the ranks "
                               "after migration, {} of {:.17g} kg expected",
                               time(), t.owned, t.mass, n_global_, r.mass_global));
}

// The largest overlap ratio. R ranks reduce it only when the state is recorded (the orb
// scheme's budget); until then each rank keeps its own.
void IslandsScheme::note_overlap_ratio(double ratio, bool record) {
  if (!rank_) {
    st_.max_overlap_ratio = std::max(st_.max_overlap_ratio, ratio);
    return;
  }
  RankPart& r = *rank_;
  r.max_ratio_local = std::max(r.max_ratio_local, ratio);
  if (record)
    st_.max_overlap_ratio = std::max(st_.max_overlap_ratio, r.comm.max(r.max_ratio_local));
}

// NaN or a particle outside a wall on some rank: every rank throws the same RunError, the one of
// the lowest particle id over the ranks (one rank: its own).
void IslandsScheme::raise_fault(const std::optional<islands::Fault>& fault) const {
  std::string message;
  std::int64_t key = std::numeric_limits<std::int64_t>::max();
  if (fault) {
    key = p_.id[fault->index];
    message = islands::fault_message(p_, *fault, time() + dt_sp_, st_.subits, model_);
    if (rank_)
      message += fmt::format(" (rank {})", rank_->comm.rank());
  }
  throw RunError(rank_ ? rank_->comm.agree_on_error(key, message) : message);
}

// What a restart cannot know is reset on both sides: the decomposition and ownership (the next
// build regrids and migrates), the skin grown by short builds, the last sub-iteration's largest
// bound, and each rank's own unrecorded overlap ratio (the largest over the ranks instead).
// With friction the rows' history becomes records by ids (the rows are rebuilt, and a checkpoint
// saves the records).
void IslandsScheme::canonicalize() {
  RankPart& r = *rank_;
  if (model_.friction) {
    const auto off = r.rows.off();
    if (!off.empty() && hx_.size() == r.rows.nb().size())
      r.pending.append(
          collect_history(r.hist_ids, off, r.rows.nb(), off.size() - 1, hx_, hy_, hz_));
    hx_.clear(), hy_.clear(), hz_.clear();
  }
  r.need_rebuild = true;
  r.last_regrid = -1;
  r.grown_skin = 0.0;
  r.last_max_bound = 0.0;
  r.max_ratio_local = r.comm.max(r.max_ratio_local);
}

} // namespace cfddem::dem
