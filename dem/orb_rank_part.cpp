// The orb scheme's steps over R > 1 ranks (dem/orb_scheme.hpp, RankPart): the parallel regrid
// and knapsack, the leaf and destination rank of every owned particle, and the one round of
// messages that moves particles to their owners and brings the ghosts, followed by the rows over
// owned + ghosts.
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <string>
#include <utility>

#include <fmt/format.h>

#include "core/error.hpp"
#include "dem/contact_history.hpp"
#include "dem/orb_rank_part.hpp"
#include "dem/scheme_support.hpp"

namespace cfddem::dem {

// A new ORB over all ranks' particles (regrid's: wrapped positions, weights = counts, or
// the local steps since the last regrid once there are some), then the knapsack over ranks.
void OrbScheme::rank_regrid() {
  PhaseTimer::Scope t(timer_, Phase::regrid);
  wrap_positions(); // the owned particles (the ghosts are gone); their rows are built again
  bool use_cost = cfg_.cost_weights;
  if (use_cost) {
    double total = 0.0;
    for (const double c : cost_)
      total += c;
    use_cost = rank_->comm.max(total) > 0.0; // the first regrid has no measurement yet: count
  }
  decomp_ = partition::decompose(
      rank_->comm, std::span<const double>(p_.x.data(), owned_),
      std::span<const double>(p_.y.data(), owned_), std::span<const double>(p_.z.data(), owned_),
      use_cost ? std::span<const double>(cost_) : std::span<const double>(), domain_,
      partition::OrbOptions{cfg_.levels, orb_snap_grid(scene_)}); // the one-rank cuts
  imbalances_.push_back(decomp_.imbalance);
  std::fill(cost_.begin(), cost_.end(), 0.0);
  ++stats_.regrids;
}

// The leaf of every owned particle (resort's rule: inside its half-open box a particle
// keeps its leaf, otherwise it is located at its wrapped position) and the rank it goes to.
// Returns the particles outside the domain (an error, raised after the next reduction), with
// the message of the first.
std::int64_t OrbScheme::rank_locate(bool regridding, std::string& message, std::int64_t& key) {
  const partition::OrbTree& tree = decomp_.tree;
  const auto leaves = tree.leaves();
  std::int64_t outside = 0;
  rank_->dest.resize(owned_);
  leaves_.of.resize(owned_);
  for (std::size_t i = 0; i < owned_; ++i) {
    const double px = p_.x[i], py = p_.y[i], pz = p_.z[i];
    int l = -1;
    if (!regridding) {
      const partition::Aabb& b = leaves[leaves_.of[i]].box;
      if (b.lo[0] <= px && px < b.hi[0] && b.lo[1] <= py && py < b.hi[1] && b.lo[2] <= pz &&
          pz < b.hi[2])
        l = static_cast<int>(leaves_.of[i]);
    }
    if (l < 0)
      l = tree.locate(geom_.wrap(px, 0), geom_.wrap(py, 1), geom_.wrap(pz, 2));
    if (l < 0) {
      ++outside;
      if (p_.id[i] < key) {
        key = p_.id[i];
        message = fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m left the "
                              "domain (rank {})",
                              time(), p_.id[i], px, py, pz, rank_->comm.rank());
      }
      l = regridding ? 0 : static_cast<int>(leaves_.of[i]); // kept here; the run stops below
      rank_->dest[i] = rank_->comm.rank();
    } else {
      rank_->dest[i] = decomp_.owner[static_cast<std::size_t>(l)];
    }
    leaves_.of[i] = static_cast<std::uint32_t>(l);
  }
  return outside;
}

// One round of messages: every owned particle to the rank of its leaf (rank_->dest), and a ghost
// copy of it, UNSHIFTED, to every other rank with a leaf within the cutoff (periodic images
// included), each with its half step, cost, leaf and speed bound (where the global mode may be
// taken: the migration, then the same ghosts from their owners, in two rounds). Then the owned
// particles in (leaf, id) order, the leaves' ranges, and the owned particles' rows and proximity
// flags from a cell list over owned + ghosts.
void OrbScheme::rank_exchange_and_rows() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  p_.resize(owned_);
  // With friction: the owned rows' history by ids (partners may be ghosts, about to go), with
  // any records a restore handed in, each record routed to the rank its owner particle goes to
  // (records of particles this rank does not hold, a restore's of other ranks' shares, are
  // dropped: their holder routes them), as the explicit scheme carries it (explicit_ranks.cpp).
  ContactHistory arrived;
  if (model_.friction) {
    ContactHistory held = hist_.pending;
    hist_.pending = ContactHistory{};
    const auto off = rank_->rows.off();
    if (off.size() >= 1 && hist_.hx.size() == rank_->rows.nb().size())
      held.append(collect_history(hist_.ids, off, rank_->rows.nb(), off.size() - 1, hist_.hx,
                                  hist_.hy, hist_.hz));
    std::int64_t moved = 0;
    arrived =
        route_history(held, p_, owned_, rank_->dest, rank_->exchange, rank_->comm.rank(), moved);
  }
  if (cfg_.time_to_contact)
    time_to_contact_speeds();
  else
    speed_.assign(owned_, 0.0);
  // Rows that the global mode may keep over the next sub-iterations hold the proximity
  // candidates too (rank_keep_rows), which takes a longer cutoff.
  const bool keep = rank_rows_keepable();
  const double cutoff = rank_cutoff(keep);
  rank_->kept = false;
  // The global mode refreshes the ghosts along a forward plan, which only build_ghosts() makes:
  // where it may be taken, the particles migrate first and the ghosts follow from their owners
  // (two rounds of messages; the same ghosts, and rows ordered by id do not depend on theirs).
  const bool plan = global_allowed();
  {
    std::vector<double> leaf(owned_);
    for (std::size_t i = 0; i < owned_; ++i)
      leaf[i] = static_cast<double>(leaves_.of[i]);
    std::vector<std::vector<double>*> extra{&hprev_, &cost_, &leaf, &speed_};
    if (rank_->ext_on)
      extra.insert(extra.end(), {&ext_.x, &ext_.y, &ext_.z});
    if (plan) {
      rank_->exchange.migrate(p_, rank_->dest, extra);
      owned_ = p_.size();
    } else {
      owned_ = rank_->exchange.redistribute(p_, rank_->dest, rank_halo_copies(cutoff), extra);
    }
    if (rank_->ext_on)
      ext_.x.resize(owned_), ext_.y.resize(owned_), ext_.z.resize(owned_);
    hprev_.resize(owned_), cost_.resize(owned_);
    leaves_.of.resize(owned_);
    for (std::size_t i = 0; i < owned_; ++i)
      leaves_.of[i] = static_cast<std::uint32_t>(leaf[i]);
  }
  ++stats_.builds;
  const std::size_t n = p_.size();
  // (leaf, id) order of the owned particles: each leaf contiguous, in an order that depends on
  // the particles only (ghosts keep theirs).
  bool sorted = true;
  for (std::size_t i = 1; i < owned_ && sorted; ++i)
    sorted = leaves_.of[i - 1] < leaves_.of[i] ||
             (leaves_.of[i - 1] == leaves_.of[i] && p_.id[i - 1] < p_.id[i]);
  if (!sorted) {
    std::vector<std::uint32_t> order(n);
    std::iota(order.begin(), order.end(), 0U);
    std::sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(owned_),
              [&](std::uint32_t a, std::uint32_t b) {
                return leaves_.of[a] != leaves_.of[b] ? leaves_.of[a] < leaves_.of[b]
                                                      : p_.id[a] < p_.id[b];
              });
    p_.permute(order);
    auto permute = [&](auto& v, std::size_t m) {
      auto tmp = v;
      for (std::size_t k = 0; k < m; ++k)
        tmp[k] = v[order[k]];
      v.swap(tmp);
    };
    permute(hprev_, owned_), permute(cost_, owned_), permute(leaves_.of, owned_);
    permute(speed_, owned_);
    if (rank_->ext_on)
      permute(ext_.x, owned_), permute(ext_.y, owned_), permute(ext_.z, owned_);
  }
  leaves_.id.clear();
  leaves_.range.assign(1, 0);
  for (std::size_t i = 0; i < owned_; ++i)
    if (leaves_.id.empty() || static_cast<std::uint32_t>(leaves_.id.back()) != leaves_.of[i]) {
      if (!leaves_.id.empty())
        leaves_.range.push_back(static_cast<std::uint32_t>(i));
      leaves_.id.push_back(static_cast<int>(leaves_.of[i]));
    }
  if (!leaves_.id.empty())
    leaves_.range.push_back(static_cast<std::uint32_t>(owned_));
  if (plan) {
    rank_->dest.assign(owned_, rank_->comm.rank());
    rank_->exchange.build_ghosts(p_, owned_, rank_halo_copies(cutoff));
    speed_.resize(p_.size(), 0.0);
    if (cfg_.time_to_contact) {
      std::vector<double>* col[] = {&speed_};
      rank_->exchange.forward_columns(col);
    }
  }
  rank_rows(cutoff, keep);
  if (model_.friction) {
    attach_history(std::move(arrived), p_.id, rank_->rows.off(), rank_->rows.nb(), owned_, hist_.hx,
                   hist_.hy, hist_.hz);
    hist_.ids = p_.id;
  }
}

// Every distance a test of the R-rank rows compares: contact candidates, the proximity or reach
// test, with `keep` the proximity candidates.
double OrbScheme::rank_reach(bool keep) const {
  double cutoff = 2.0 * cfg_.r_max + skin_;
  cutoff = std::max(cutoff, cfg_.time_to_contact ? 2.0 * cfg_.r_max + 2.0 * reach_
                                                 : 2.0 * cfg_.prox * cfg_.r_max);
  if (keep)
    cutoff = std::max(cutoff, 2.0 * cfg_.prox * cfg_.r_max + skin_);
  return cutoff;
}

// The first periodic axis not longer than twice `cutoff` (where the minimum image within the
// cutoff would not be unique), or -1.
int OrbScheme::short_periodic_axis(double cutoff) const {
  for (int a = 0; a < 3; ++a)
    if (geom_.periodic[a] && 2.0 * cutoff >= geom_.length[a])
      return a;
  return -1;
}

// rank_reach(keep), which must fit the periodic box.
double OrbScheme::rank_cutoff(bool keep) const {
  const double cutoff = rank_reach(keep);
  if (const int a = short_periodic_axis(cutoff); a >= 0)
    throw RunError(fmt::format("periodic axis {} is {:.4g} m long, not more than twice the "
                               "distributed orb scheme's cutoff {:.4g} m (contact, proximity "
                               "or reach): enlarge the domain or run on one rank",
                               a, geom_.length[a], cutoff));
  return cutoff;
}

// Whether the rows built now may be kept over the next sub-iterations (rank_keep_rows): the
// global mode may be taken, under the proximity rule (time_to_contact's reach follows speed bounds
// that change at every sub-iteration), with the proximity candidates' cutoff below half of each
// periodic length.
bool OrbScheme::rank_rows_keepable() const {
  return global_allowed() && !cfg_.time_to_contact && short_periodic_axis(rank_reach(true)) < 0;
}

// R ranks, a sub-iteration after a global one of the same interval (not at a regrid, not
// recorded): the global mode keeps the last build's rows and ghosts while no particle has moved
// skin/2 from the build, instead of the exchange and rows of every sub-iteration (the neighbor
// phase was 1.3 s of 4 s in the 2-rank 1e5 bed at dem.nsubit = 35; one rank keeps its pairs the
// same way). The ghosts' x and v come from their owners; the proximity flags from the build's
// proximity candidates, by the build's expressions, so the choice is one rank's.
// A particle stays on its rank when it crosses into another rank's leaf (a stray). Its new leaf's
// owner holds a ghost copy of it: the particle lies within skin/2 of where it was at the build,
// inside this rank's leaf, so within the cutoff of its new leaf, and the build sent it to every
// rank with a leaf that close. So each rank reports its strays to the ranks holding their ghosts
// (2 leaf + near + 1, 0 for the others, one value per ghost along the plan), and each leaf's
// owner knows whether it holds a particle and a fine one, with no message that grows with the
// leaves. One sum then gives the fine particles, the particles counted (each once, by its leaf's
// owner: all of them unless the rows expired) and the expiries (rows_expire: a particle may move
// skin/2 from the build within this sub-iteration). False (every rank alike): rebuild, as the
// sub-iteration may not be global or may outrun the rows. Only while the rows are keepable (the
// global mode may be taken: the same rule for the whole interval).
bool OrbScheme::rank_keep_rows() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  rank_->kept = false;
  rank_->exchange.forward(p_);
  const std::size_t n = p_.size();
  rank_->rows.proximity_flags(geom_, {p_.x.data(), n}, {p_.y.data(), n}, {p_.z.data(), n},
                              {p_.radius.data(), n}, cfg_.prox);
  const std::span<unsigned char> near = rank_->rows.near();
  mark_walls(near);
  const int me = rank_->comm.rank();
  const std::vector<int>& owner = decomp_.owner;
  std::vector<double>& stray = rank_->stray;
  stray.assign(n, 0.0);
  for (std::size_t i = 0; i < owned_; ++i)
    if (owner[leaves_.of[i]] != me)
      stray[i] = 2.0 * static_cast<double>(leaves_.of[i]) + (near[i] ? 2.0 : 1.0);
  std::vector<double>* col[] = {&stray};
  rank_->exchange.forward_columns(col);
  // This rank's leaves: the particles counted in each (its owned ones and the strays reported
  // to it) and whether one of them is fine; the leaves touched, to be zeroed again after.
  const std::size_t nl = decomp_.tree.leaves().size();
  std::vector<std::uint32_t>& count = rank_->leaf_count;
  std::vector<unsigned char>& fine = rank_->leaf_fine;
  count.resize(nl, 0), fine.resize(nl, 0);
  std::vector<int>& mine = rank_->kept_leaves;
  mine.clear();
  const auto add = [&](std::size_t l, bool f) {
    if (count[l]++ == 0)
      mine.push_back(static_cast<int>(l));
    fine[l] |= static_cast<unsigned char>(f);
  };
  for (std::size_t i = 0; i < owned_; ++i)
    if (owner[leaves_.of[i]] == me)
      add(leaves_.of[i], near[i] != 0);
  for (std::size_t g = owned_; g < n; ++g) {
    const auto code = static_cast<std::int64_t>(stray[g]) - 1; // 2 leaf + near, or -1
    if (code >= 0 && owner[static_cast<std::size_t>(code / 2)] == me)
      add(static_cast<std::size_t>(code / 2), code % 2 != 0);
  }
  std::array<std::int64_t, 3> c{0, 0, 0};
  for (const int l : mine) {
    c[0] += fine[l] ? count[l] : 0, c[1] += count[l];
    count[l] = 0, fine[l] = 0;
  }
  c[2] = rows_expire(owned_, {rank_->ref[0].data(), rank_->ref[1].data(), rank_->ref[2].data()})
             ? 1
             : 0;
  rank_->comm.sum(c);
  if (c[2] > 0 || c[1] != cfg_.n_global) // an expiry (then a stray may have gone uncounted)
    return false;
  if (!global_.hold &&
      !(static_cast<double>(c[0]) > kGlobalFraction * static_cast<double>(cfg_.n_global)))
    return false;
  global_.on = true;
  rank_->kept = true;
  global_.pairs.clear_forces(p_); // the last sub-iteration's last pass
  return true;
}

// The ghost copies of the owned particles: each UNSHIFTED to every rank other than its
// destination (rank_->dest) with a leaf within `cutoff` of it (periodic images included).
std::vector<ParticleExchange::Copy> OrbScheme::rank_halo_copies(double cutoff) {
  std::vector<ParticleExchange::Copy> copies;
  {
    const partition::OrbTree& tree = decomp_.tree;
    const auto leaves = tree.leaves();
    std::vector<int> ranks;
    // Per leaf holding a particle here, the (leaf, periodic image) pairs of other ranks than its
    // owner within the cutoff of its box: a particle's halo lies inside its leaf's, and it goes
    // to the leaf's owner, so only those can need its ghost. Most leaves have none.
    rank_->near_leaves.resize(leaves.size());
    rank_->near_known.assign(leaves.size(), 0);
    auto candidates = [&](std::uint32_t l) -> const std::vector<partition::LeafImage>& {
      if (!rank_->near_known[l]) {
        rank_->near_known[l] = 1;
        rank_->near_leaves[l].clear();
        partition::Aabb q = leaves[l].box;
        for (int a = 0; a < 3; ++a)
          q.lo[a] -= cutoff, q.hi[a] += cutoff;
        for (const partition::LeafImage& li : tree.leaf_images_overlapping(q, geom_.periodic))
          if (decomp_.owner[static_cast<std::size_t>(li.leaf)] != decomp_.owner[l])
            rank_->near_leaves[l].push_back(li);
      }
      return rank_->near_leaves[l];
    };
    for (std::size_t i = 0; i < owned_; ++i) {
      const std::vector<partition::LeafImage>& cand = candidates(leaves_.of[i]);
      if (cand.empty())
        continue;
      const double w[3] = {geom_.wrap(p_.x[i], 0), geom_.wrap(p_.y[i], 1), geom_.wrap(p_.z[i], 2)};
      ranks.clear();
      for (const partition::LeafImage& li : cand) {
        const int r = decomp_.owner[static_cast<std::size_t>(li.leaf)];
        if (r == rank_->dest[i] || std::find(ranks.begin(), ranks.end(), r) != ranks.end())
          continue;
        // Closed overlap of the particle's halo, seen through the image, with the leaf's box
        // (OrbTree's test: conservative, a ghost too many costs only its copy).
        const partition::Aabb& b = leaves[static_cast<std::size_t>(li.leaf)].box;
        bool touch = true;
        for (int a = 0; a < 3; ++a) {
          const double s = static_cast<double>(li.shift[a]) * geom_.length[a];
          touch = touch && w[a] - cutoff + s <= b.hi[a] && w[a] + cutoff + s >= b.lo[a];
        }
        if (touch)
          ranks.push_back(r);
      }
      for (const int r : ranks)
        copies.push_back({r, static_cast<std::uint32_t>(i), {}});
    }
  }
  return copies;
}

// The rows of the owned particles over owned + ghosts (with their proximity flags), cleared
// forces, the own-leaf entries before each owned particle (the batches' force evaluations) and
// the walls as partners.
void OrbScheme::rank_rows(double cutoff, bool keep) {
  const std::size_t n = p_.size();
  rank_->keepable = keep;
  global_.stale = true;
  for (int a = 0; a < 3; ++a) {
    const std::vector<double>& pos = a == 0 ? p_.x : a == 1 ? p_.y : p_.z;
    rank_->ref[static_cast<std::size_t>(a)].assign(pos.begin(), pos.end());
  }
  rank_->rows.build({geom_,
                     {p_.x.data(), n},
                     {p_.y.data(), n},
                     {p_.z.data(), n},
                     {p_.radius.data(), n},
                     {p_.id.data(), n},
                     {speed_.data(), n},
                     {leaves_.of.data(), owned_},
                     owned_,
                     cutoff,
                     skin_,
                     cfg_.prox,
                     cfg_.dt_sp,
                     cfg_.time_to_contact,
                     keep});
  // Only particles with a row get their contact force rewritten at each step: clear the rest.
  std::fill(p_.fx.begin(), p_.fx.end(), 0.0);
  std::fill(p_.fy.begin(), p_.fy.end(), 0.0);
  std::fill(p_.fz.begin(), p_.fz.end(), 0.0);
  if (model_.friction) {
    std::fill(p_.tx.begin(), p_.tx.end(), 0.0);
    std::fill(p_.ty.begin(), p_.ty.end(), 0.0);
    std::fill(p_.tz.begin(), p_.tz.end(), 0.0);
  }
  const auto off = rank_->rows.off(), mid = rank_->rows.mid();
  rows_.own_before.resize(owned_ + 1);
  rows_.own_before[0] = 0;
  for (std::size_t i = 0; i < owned_; ++i)
    rows_.own_before[i + 1] = rows_.own_before[i] + (mid[i] - off[i]);
  mark_walls(rank_->rows.near());
}

// The global mode over R ranks (OrbScheme::kGlobalFraction): the fine particles of every rank's
// leaves (rows' proximity flags at the build) against all particles, one reduction, so that
// every rank takes the choice one rank takes.
bool OrbScheme::rank_choose_global() {
  mark_fine_leaves(rank_->rows.near());
  if (!global_allowed())
    return false;
  std::array<std::int64_t, 2> c{0, static_cast<std::int64_t>(owned_)};
  for (std::size_t k = 0; k < leaves_.fine.size(); ++k)
    c[0] += leaves_.fine[k] ? leaves_.range[k + 1] - leaves_.range[k] : 0;
  rank_->comm.sum(c);
  return static_cast<double>(c[0]) > kGlobalFraction * static_cast<double>(c[1]);
}

} // namespace cfddem::dem
