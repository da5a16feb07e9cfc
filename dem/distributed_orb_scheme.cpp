#include "dem/distributed_orb_scheme.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

#include "core/error.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/kick_drift_range.hpp"
#include "dem/scheme_support.hpp"

namespace cfddem::dem {

namespace {
enum : int { kNoFault = 0, kNaN = 1, kLeftDomain = 2 };
} // namespace

DistributedOrbScheme::DistributedOrbScheme(const Scene& scene, ParticleStore& particles,
                                           const StepModel& model, const Communicator& comm,
                                           PhaseTimer& timer)
    : scene_(scene), p_(particles), comm_(comm), timer_(timer), geom_(scene.domain), model_(model),
      exchange_(comm) {
  require_frictionless(model_, "orb");
  domain_ = partition::Aabb{scene.domain.lo, scene.domain.hi};
  levels_ = scene.partition.orb_levels;
  for (const double r : p_.radius)
    r_max_ = std::max(r_max_, r);
  r_max_ = comm_.max(r_max_);
  n_global_ = comm_.sum(static_cast<std::int64_t>(p_.size()));
  if (n_global_ == 0)
    r_max_ = model_.r_min;
  nsubit_ = scene.dem.nsubit;
  dt_sp_ = scene.dem.regrid_interval / static_cast<double>(nsubit_);
  skin_ = model_.skin;
  cost_weights_ = scene.partition.weights == "cost";
  time_to_contact_ = scene.dem.local_dt == "time_to_contact";
  // OrbScheme's check (the same message): minimum image needs the cutoff below half a period.
  for (int a = 0; a < 3; ++a)
    if (geom_.periodic[a] && geom_.length[a] <= 2.0 * (2.0 * r_max_ + model_.skin))
      throw RunError(fmt::format("periodic axis {} is {:.4g} m long, not more than twice the "
                                 "neighbor cutoff {:.4g} m",
                                 a, geom_.length[a], 2.0 * r_max_ + model_.skin));
  skin_cap_ = periodic_skin_cap(geom_, r_max_);
  owned_ = p_.size();
  hprev_.assign(owned_, 0.0);
  cost_.assign(owned_, 0.0);
  leaf_steps_.assign(std::size_t{1} << levels_, 0);
}

void DistributedOrbScheme::start() {
  hprev_.assign(owned_, 0.0);
  subits_ = 0;
}

// A new ORB over all ranks' particles (OrbScheme::regrid: wrapped positions, weights = counts, or
// the local steps since the last regrid once there are some), then the knapsack over ranks.
void DistributedOrbScheme::regrid() {
  for (std::size_t i = 0; i < owned_; ++i)
    p_.x[i] = geom_.wrap(p_.x[i], 0), p_.y[i] = geom_.wrap(p_.y[i], 1),
    p_.z[i] = geom_.wrap(p_.z[i], 2);
  bool use_cost = cost_weights_;
  if (use_cost) {
    double total = 0.0;
    for (const double c : cost_)
      total += c;
    use_cost = comm_.max(total) > 0.0; // the first regrid has no measurement yet: count
  }
  decomposition_ = partition::decompose(
      comm_, std::span<const double>(p_.x.data(), owned_),
      std::span<const double>(p_.y.data(), owned_), std::span<const double>(p_.z.data(), owned_),
      use_cost ? std::span<const double>(cost_) : std::span<const double>(), domain_,
      partition::OrbOptions{levels_, orb_snap_grid(scene_)}); // OrbScheme's cuts
  imbalances_.push_back(decomposition_.imbalance);
  std::fill(cost_.begin(), cost_.end(), 0.0);
  skin_ = model_.skin; // a skin grown by a retry or by time_to_contact lasts until the regrid
  ++regrids_;
}

// The leaf of every owned particle (OrbScheme::resort's rule: inside its half-open box a particle
// keeps its leaf, otherwise it is located at its wrapped position) and the rank it goes to.
// Returns the particles outside the domain (an error, raised after the next reduction), with
// the message of the first.
std::int64_t DistributedOrbScheme::locate(bool regridding, std::string& message,
                                          std::int64_t& key) {
  const partition::OrbTree& tree = decomposition_.tree;
  const auto leaves = tree.leaves();
  std::int64_t outside = 0;
  dest_.resize(owned_);
  leaf_of_.resize(owned_);
  for (std::size_t i = 0; i < owned_; ++i) {
    const double px = p_.x[i], py = p_.y[i], pz = p_.z[i];
    int l = -1;
    if (!regridding) {
      const partition::Aabb& b = leaves[leaf_of_[i]].box;
      if (b.lo[0] <= px && px < b.hi[0] && b.lo[1] <= py && py < b.hi[1] && b.lo[2] <= pz &&
          pz < b.hi[2])
        l = static_cast<int>(leaf_of_[i]);
    }
    if (l < 0)
      l = tree.locate(geom_.wrap(px, 0), geom_.wrap(py, 1), geom_.wrap(pz, 2));
    if (l < 0) {
      ++outside;
      if (p_.id[i] < key) {
        key = p_.id[i];
        message = fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m left the "
                              "domain (rank {})",
                              time(), p_.id[i], px, py, pz, comm_.rank());
      }
      l = regridding ? 0 : static_cast<int>(leaf_of_[i]); // kept here; the run stops below
      dest_[i] = comm_.rank();
    } else {
      dest_[i] = decomposition_.owner[static_cast<std::size_t>(l)];
    }
    leaf_of_[i] = static_cast<std::uint32_t>(l);
  }
  return outside;
}

// One round of messages: every owned particle to the rank of its leaf (dest_), and a ghost copy
// of it, UNSHIFTED, to every other rank with a leaf within the cutoff (periodic images
// included), each with its half step, cost, leaf and speed bound. Then the owned particles in
// (leaf, id) order, the leaves' ranges, and the owned particles' rows and proximity flags from a
// cell list over owned + ghosts.
void DistributedOrbScheme::exchange_and_rows() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  p_.resize(owned_);
  const double prox = 0.5 * scene_.dem.proximity_radii;
  if (time_to_contact_) {
    // OrbScheme's speed bounds, and a skin covering two reaches (until the next regrid).
    speed_.resize(owned_);
    double reach = 0.0;
    for (std::size_t i = 0; i < owned_; ++i) {
      double ax = model_.gravity[0], ay = model_.gravity[1], az = model_.gravity[2];
      if (ext_on_)
        ax += ex_[i] * p_.inv_mass[i], ay += ey_[i] * p_.inv_mass[i], az += ez_[i] * p_.inv_mass[i];
      speed_[i] = std::sqrt(p_.vx[i] * p_.vx[i] + p_.vy[i] * p_.vy[i] + p_.vz[i] * p_.vz[i]) +
                  std::sqrt(ax * ax + ay * ay + az * az) * (hprev_[i] + dt_sp_);
      reach = std::max(reach, speed_[i] * dt_sp_);
    }
    reach_ = comm_.max(reach);
    if (2.1 * reach_ > skin_ && skin_ < skin_cap_)
      skin_ = std::min(2.1 * reach_, skin_cap_);
  } else {
    speed_.assign(owned_, 0.0);
  }
  // Every distance a test below compares: contact candidates, the proximity or reach test.
  double cutoff = 2.0 * r_max_ + skin_;
  cutoff = std::max(cutoff, time_to_contact_ ? 2.0 * r_max_ + 2.0 * reach_ : 2.0 * prox * r_max_);
  for (int a = 0; a < 3; ++a)
    if (geom_.periodic[a] && 2.0 * cutoff >= geom_.length[a])
      throw RunError(fmt::format("periodic axis {} is {:.4g} m long, not more than twice the "
                                 "distributed orb scheme's cutoff {:.4g} m (contact, proximity "
                                 "or reach): enlarge the domain or run on one rank",
                                 a, geom_.length[a], cutoff));
  {
    const partition::OrbTree& tree = decomposition_.tree;
    const auto leaves = tree.leaves();
    std::vector<ParticleExchange::Copy> copies;
    std::vector<int> ranks;
    // Per leaf holding a particle here, the (leaf, periodic image) pairs of other ranks than its
    // owner within the cutoff of its box: a particle's halo lies inside its leaf's, and it goes
    // to the leaf's owner, so only those can need its ghost. Most leaves have none.
    near_leaves_.resize(leaves.size());
    near_known_.assign(leaves.size(), 0);
    auto candidates = [&](std::uint32_t l) -> const std::vector<partition::LeafImage>& {
      if (!near_known_[l]) {
        near_known_[l] = 1;
        near_leaves_[l].clear();
        partition::Aabb q = leaves[l].box;
        for (int a = 0; a < 3; ++a)
          q.lo[a] -= cutoff, q.hi[a] += cutoff;
        for (const partition::LeafImage& li : tree.leaf_images_overlapping(q, geom_.periodic))
          if (decomposition_.owner[static_cast<std::size_t>(li.leaf)] != decomposition_.owner[l])
            near_leaves_[l].push_back(li);
      }
      return near_leaves_[l];
    };
    for (std::size_t i = 0; i < owned_; ++i) {
      const std::vector<partition::LeafImage>& cand = candidates(leaf_of_[i]);
      if (cand.empty())
        continue;
      const double w[3] = {geom_.wrap(p_.x[i], 0), geom_.wrap(p_.y[i], 1), geom_.wrap(p_.z[i], 2)};
      ranks.clear();
      for (const partition::LeafImage& li : cand) {
        const int r = decomposition_.owner[static_cast<std::size_t>(li.leaf)];
        if (r == dest_[i] || std::find(ranks.begin(), ranks.end(), r) != ranks.end())
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
    std::vector<double> leaf(owned_);
    for (std::size_t i = 0; i < owned_; ++i)
      leaf[i] = static_cast<double>(leaf_of_[i]);
    std::vector<std::vector<double>*> extra{&hprev_, &cost_, &leaf, &speed_};
    if (ext_on_)
      extra.insert(extra.end(), {&ex_, &ey_, &ez_});
    owned_ = exchange_.redistribute(p_, dest_, std::move(copies), extra);
    if (ext_on_)
      ex_.resize(owned_), ey_.resize(owned_), ez_.resize(owned_);
    hprev_.resize(owned_), cost_.resize(owned_);
    leaf_of_.resize(owned_);
    for (std::size_t i = 0; i < owned_; ++i)
      leaf_of_[i] = static_cast<std::uint32_t>(leaf[i]);
  }
  ++builds_;
  const std::size_t n = p_.size();
  // (leaf, id) order of the owned particles: each leaf contiguous, in an order that depends on
  // the particles only (ghosts keep theirs).
  bool sorted = true;
  for (std::size_t i = 1; i < owned_ && sorted; ++i)
    sorted = leaf_of_[i - 1] < leaf_of_[i] ||
             (leaf_of_[i - 1] == leaf_of_[i] && p_.id[i - 1] < p_.id[i]);
  if (!sorted) {
    std::vector<std::uint32_t> order(n);
    std::iota(order.begin(), order.end(), 0U);
    std::sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(owned_),
              [&](std::uint32_t a, std::uint32_t b) {
                return leaf_of_[a] != leaf_of_[b] ? leaf_of_[a] < leaf_of_[b] : p_.id[a] < p_.id[b];
              });
    p_.permute(order);
    auto permute = [&](auto& v, std::size_t m) {
      auto tmp = v;
      for (std::size_t k = 0; k < m; ++k)
        tmp[k] = v[order[k]];
      v.swap(tmp);
    };
    permute(hprev_, owned_), permute(cost_, owned_), permute(leaf_of_, owned_);
    permute(speed_, owned_);
    if (ext_on_)
      permute(ex_, owned_), permute(ey_, owned_), permute(ez_, owned_);
  }
  ids_.clear();
  ranges_.assign(1, 0);
  for (std::size_t i = 0; i < owned_; ++i)
    if (ids_.empty() || static_cast<std::uint32_t>(ids_.back()) != leaf_of_[i]) {
      if (!ids_.empty())
        ranges_.push_back(static_cast<std::uint32_t>(i));
      ids_.push_back(static_cast<int>(leaf_of_[i]));
    }
  if (!ids_.empty())
    ranges_.push_back(static_cast<std::uint32_t>(owned_));
  rows_.build({geom_,
               {p_.x.data(), n},
               {p_.y.data(), n},
               {p_.z.data(), n},
               {p_.radius.data(), n},
               {p_.id.data(), n},
               {speed_.data(), n},
               {leaf_of_.data(), owned_},
               owned_,
               cutoff,
               skin_,
               prox,
               dt_sp_,
               time_to_contact_});
  // Only particles with a row get their contact force rewritten at each step: clear the rest.
  std::fill(p_.fx.begin(), p_.fx.end(), 0.0);
  std::fill(p_.fy.begin(), p_.fy.end(), 0.0);
  std::fill(p_.fz.begin(), p_.fz.end(), 0.0);
  // A wall is a partner too (OrbScheme's rule, either local_dt).
  const std::span<unsigned char> near = rows_.near();
  for (int a = 0; a < 3; ++a) {
    if (geom_.periodic[a])
      continue;
    const std::vector<double>& pos = a == 0 ? p_.x : a == 1 ? p_.y : p_.z;
    for (std::size_t i = 0; i < owned_; ++i) {
      const double d =
          time_to_contact_ ? p_.radius[i] + speed_[i] * dt_sp_ : 2.0 * prox * p_.radius[i];
      near[i] |= pos[i] - geom_.lo[a] < d || geom_.hi[a] - pos[i] < d;
    }
  }
}

void DistributedOrbScheme::run_batch(std::size_t which, bool record) {
  ext_on_ ? run_batch_impl<true>(which, record) : run_batch_impl<false>(which, record);
}

// Batch `which`'s K local steps: OrbScheme::run_batch_impl's arithmetic, own-leaf partners read
// live, every other partner from the copies at the sub-iteration start. With External, the
// external force is added to the contact force in every kick and in the synchronised velocity.
template <bool External> void DistributedOrbScheme::run_batch_impl(std::size_t which, bool record) {
  Batch& bt = batches_[which];
  bt.violations = 0, bt.max_ratio = 0.0, bt.outran = false, bt.fault = kNoFault;
  const std::uint32_t b = bt.b, e = bt.e;
  const DomainGeometry g = geom_;
  const StepModel m = model_;
  double* __restrict x = p_.x.data();
  double* __restrict y = p_.y.data();
  double* __restrict z = p_.z.data();
  double* __restrict vx = p_.vx.data();
  double* __restrict vy = p_.vy.data();
  double* __restrict vz = p_.vz.data();
  double* __restrict fx = p_.fx.data();
  double* __restrict fy = p_.fy.data();
  double* __restrict fz = p_.fz.data();
  double* __restrict hp = hprev_.data();
  const double* __restrict gx = gx_.data();
  const double* __restrict gy = gy_.data();
  const double* __restrict gz = gz_.data();
  const double* __restrict gvx = gvx_.data();
  const double* __restrict gvy = gvy_.data();
  const double* __restrict gvz = gvz_.data();
  const double* __restrict rad = p_.radius.data();
  const double* __restrict mass = p_.mass.data();
  const double* __restrict im = p_.inv_mass.data();
  const double* __restrict fex = External ? ex_.data() : nullptr;
  const double* __restrict fey = External ? ey_.data() : nullptr;
  const double* __restrict fez = External ? ez_.data() : nullptr;
  const std::uint32_t* __restrict off = rows_.off().data();
  const std::uint32_t* __restrict mid = rows_.mid().data();
  const std::uint32_t* __restrict nb = rows_.nb().data();
  const std::uint32_t* __restrict act = rows_.active().data();
  const bool walls = !(g.periodic[0] && g.periodic[1] && g.periodic[2]);
  const double lim = m.max_overlap;
  const double half_skin2 = 0.25 * skin_ * skin_;
  double max_ratio = 0.0;
  std::int64_t violations = 0;
  double h_before = 0.0;
  // The reference of the skin test is the position at the sub-iteration start (gx, gy, gz).
  KickDriftColumns columns = kick_drift_columns(p_, gx_, gy_, gz_, nullptr, hprev_);
  if constexpr (External)
    columns.ex = ex_, columns.ey = ey_, columns.ez = ez_;
  for (std::int64_t step = 0; step < bt.K; ++step) {
    const double hk = step + 1 == bt.K ? bt.h_last : bt.h;
    leaf_contact_pass(bt.a0, bt.a1, act, off, mid, nb, x, y, z, vx, vy, vz, gx, gy, gz, gvx, gvy,
                      gvz, rad, mass, fx, fy, fz, g, m, max_ratio, violations);
    if (walls)
      add_wall_forces(b, e, off, x, y, z, vx, vy, vz, rad, mass, fx, fy, fz, g, m.wall, lim,
                      max_ratio, violations);
    if (record && step == 0)
      synchronised_velocities<External>(b, e, vx, vy, vz, fx, fy, fz, fex, fey, fez, im, hp,
                                        m.gravity, svx_.data(), svy_.data(), svz_.data());
    // The reference of the skin test is the position at the sub-iteration start (the rows are
    // built there).
    std::uint64_t still = ~std::uint64_t{0};
    leaf_kick_drift<External>(step, bt.K, columns.range(b, e), h_before, hk, m.gravity, half_skin2,
                              still);
    h_before = hk;
    if (step + 1 < bt.K && !(still >> 63)) {
      bt.outran = true;
      break;
    }
  }
  bt.max_ratio = max_ratio;
  bt.violations = violations;
  // Faults are rare: a branch-free pass (it vectorizes) says whether to look for one
  // (OrbScheme's: NaN or inf in the sum, or a coordinate outside a wall's closed interval).
  const WallBounds wb(g);
  {
    const double inf = std::numeric_limits<double>::infinity();
    std::uint64_t bad = 0;
    for (std::uint32_t i = b; i < e; ++i) {
      const double v2 = vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i];
      const double t = v2 + x[i] + y[i] + z[i];
      bad |= sign_unless(t > -inf) | sign_unless(t < inf) | sign_unless(x[i] >= wb.lo[0]) |
             sign_unless(x[i] <= wb.hi[0]) | sign_unless(y[i] >= wb.lo[1]) |
             sign_unless(y[i] <= wb.hi[1]) | sign_unless(z[i] >= wb.lo[2]) |
             sign_unless(z[i] <= wb.hi[2]);
    }
    if (!(bad >> 63))
      return;
  }
  for (std::uint32_t i = b; i < e && bt.fault == kNoFault; ++i) {
    const double q[3] = {x[i], y[i], z[i]};
    const double v2 = vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i];
    if (!std::isfinite(v2 + q[0] + q[1] + q[2])) {
      bt.fault = kNaN, bt.fault_index = i, bt.fault_value = v2;
      break;
    }
    for (int a = 0; a < 3; ++a)
      if (!(q[a] >= wb.lo[a] && q[a] <= wb.hi[a])) {
        bt.fault = kLeftDomain, bt.fault_index = i, bt.fault_value = q[a];
        break;
      }
  }
}

// The owned leaves' local steps (one TBB task per batch); whether one of them outran its rows.
bool DistributedOrbScheme::attempt(bool record) {
  const int nb = static_cast<int>(batches_.size());
  tbb::parallel_for(
      tbb::blocked_range<int>(0, nb, 1),
      [&](const tbb::blocked_range<int>& r) {
        for (int q = r.begin(); q != r.end(); ++q)
          run_batch(static_cast<std::size_t>(q), record);
      },
      tbb::simple_partitioner{});
  for (const Batch& bt : batches_)
    if (bt.outran && bt.fault == kNoFault)
      return true;
  return false;
}

void DistributedOrbScheme::subiterate(bool record) {
  p_.resize(owned_); // the last sub-iteration's ghosts go
  const bool regridding = subits_ % nsubit_ == 0;
  std::string outside_message;
  std::int64_t outside_key = std::numeric_limits<std::int64_t>::max();
  std::int64_t outside = 0;
  {
    PhaseTimer::Scope t(timer_, Phase::neighbor);
    if (regridding)
      regrid();
    outside = locate(regridding, outside_message, outside_key);
  }
  const FineSteps steps = fine_steps(dt_sp_, model_.dt);
  const std::int64_t K_fine = steps.K;
  const double h_fine = steps.h;
  const double h_fine_last = steps.h_last;
  // One reduction closes the sub-iteration: {outran, faults, outside, owned, particle steps,
  // force evaluations, overlaps beyond the bound, fine leaves, non-empty leaves}.
  std::array<std::int64_t, 9> c{};
  while (true) {
    exchange_and_rows();
    PhaseTimer::Scope t(timer_, Phase::force);
    gx_ = p_.x, gy_ = p_.y, gz_ = p_.z, gvx_ = p_.vx, gvy_ = p_.vy, gvz_ = p_.vz, ghp_ = hprev_;
    runs_.assign(ids_.size(), LeafRun{});
    const std::span<unsigned char> near = rows_.near();
    const auto off = rows_.off(), mid = rows_.mid();
    const auto active = rows_.active();
    for (std::size_t k = 0; k < ids_.size(); ++k) {
      LeafRun& r = runs_[k];
      unsigned char any = 0;
      for (std::uint32_t i = ranges_[k]; i < ranges_[k + 1]; ++i)
        any |= near[i];
      r.fine = any && model_.dt < dt_sp_;
      r.K = r.fine ? K_fine : 1;
      r.h = r.fine ? h_fine : dt_sp_;
      r.h_last = r.fine ? h_fine_last : dt_sp_;
      std::int64_t own = 0, all = 0;
      for (std::uint32_t i = ranges_[k]; i < ranges_[k + 1]; ++i)
        own += mid[i] - off[i], all += off[i + 1] - off[i];
      r.evals = own / 2 + (all - own);
    }
    // Batches: runs of consecutive leaves with the same step, cut at about `grain` particles
    // (OrbScheme's grouping: leaves never read each other's live state, so it changes no bit).
    const auto threads = static_cast<std::size_t>(tbb::this_task_arena::max_concurrency());
    const std::size_t grain =
        std::max<std::size_t>(256, owned_ / (4 * std::max<std::size_t>(threads, 1)));
    batches_.clear();
    for (std::size_t k = 0; k < ids_.size(); ++k) {
      const LeafRun& r = runs_[k];
      if (batches_.empty() || batches_.back().K != r.K ||
          batches_.back().e - batches_.back().b >= grain) {
        Batch bt;
        bt.b = ranges_[k], bt.K = r.K, bt.h = r.h, bt.h_last = r.h_last;
        batches_.push_back(bt);
      }
      batches_.back().e = ranges_[k + 1];
    }
    for (Batch& bt : batches_) {
      bt.a0 = static_cast<std::uint32_t>(std::lower_bound(active.begin(), active.end(), bt.b) -
                                         active.begin());
      bt.a1 = static_cast<std::uint32_t>(std::lower_bound(active.begin(), active.end(), bt.e) -
                                         active.begin());
    }
    if (record) {
      const std::size_t n = owned_;
      sx_.resize(n), sy_.resize(n), sz_.resize(n), svx_.resize(n), svy_.resize(n), svz_.resize(n);
      for (std::size_t i = 0; i < n; ++i)
        sx_[i] = geom_.wrap(p_.x[i], 0), sy_[i] = geom_.wrap(p_.y[i], 1),
        sz_[i] = geom_.wrap(p_.z[i], 2);
      smass_.assign(p_.mass.begin(), p_.mass.begin() + static_cast<std::ptrdiff_t>(n));
      sradius_.assign(p_.radius.begin(), p_.radius.begin() + static_cast<std::ptrdiff_t>(n));
      sid_.assign(p_.id.begin(), p_.id.begin() + static_cast<std::ptrdiff_t>(n));
      sleaf_.resize(n), sdt_.resize(n);
      for (std::size_t k = 0; k < ids_.size(); ++k)
        for (std::uint32_t i = ranges_[k]; i < ranges_[k + 1]; ++i)
          sleaf_[i] = ids_[k], sdt_[i] = dt_sp_ / static_cast<double>(runs_[k].K);
    }
    c = {};
    c[0] = attempt(record) ? 1 : 0;
    c[2] = outside;
    c[3] = static_cast<std::int64_t>(owned_);
    for (std::size_t k = 0; k < ids_.size(); ++k) {
      const LeafRun& r = runs_[k];
      c[4] += static_cast<std::int64_t>(ranges_[k + 1] - ranges_[k]) * r.K;
      c[5] += r.evals * r.K;
      c[7] += r.fine ? 1 : 0;
      c[8] += 1;
    }
    for (const Batch& bt : batches_)
      c[1] += bt.fault != kNoFault ? 1 : 0, c[6] += bt.violations;
    local_c_[0] = c[4], local_c_[1] = c[5];
    comm_.sum(c);
    if (c[2] > 0) {
      const std::string e = comm_.agree_on_error(outside_key, outside_message);
      throw RunError(e.empty() ? std::string("a particle left the domain") : e);
    }
    // None lost, none duplicated: the owned counts add up to the total at every sub-iteration.
    if (c[3] != n_global_)
      throw RunError(fmt::format("t = {:.9g} s: {} particles on the ranks after migration, {} "
                                 "expected",
                                 time(), c[3], n_global_));
    if (c[0] == 0 || c[1] > 0)
      break;
    // A fine leaf, on some rank, outran its rows: every rank rolls back and redoes the
    // sub-iteration with twice the skin (OrbScheme's retry; the rows here are always fresh).
    if (skin_ >= skin_cap_)
      throw RunError(fmt::format("t = {:.9g} s: a particle moves more than half the neighbor "
                                 "skin in one sub-iteration even with the largest skin the "
                                 "periodic box allows ({:.4g} m): raise dem.nsubit",
                                 time(), skin_));
    std::copy_n(gx_.begin(), owned_, p_.x.begin()), std::copy_n(gy_.begin(), owned_, p_.y.begin());
    std::copy_n(gz_.begin(), owned_, p_.z.begin()),
        std::copy_n(gvx_.begin(), owned_, p_.vx.begin());
    std::copy_n(gvy_.begin(), owned_, p_.vy.begin()),
        std::copy_n(gvz_.begin(), owned_, p_.vz.begin());
    hprev_ = ghp_;
    skin_ = std::min(2.0 * skin_, skin_cap_);
    dest_.assign(owned_, comm_.rank()); // the particles are where they belong already
    ++retries_;
  }
  if (c[1] > 0) {
    // Faults: every rank raises the one of the smallest particle id.
    std::string message;
    std::int64_t key = std::numeric_limits<std::int64_t>::max();
    for (const Batch& r : batches_) {
      if (r.fault == kNoFault)
        continue;
      const std::size_t i = r.fault_index;
      if (p_.id[i] >= key)
        continue;
      key = p_.id[i];
      message = fmt::format(
          "t = {:.9g} s, sub-iteration {}: particle {} at ({:.6g}, {:.6g}, {:.6g}) m: {} (rank {})",
          time(), subits_, p_.id[i], p_.x[i], p_.y[i], p_.z[i],
          r.fault == kNaN
              ? "position or velocity is not finite (NaN/inf): the step is unstable"
              : fmt::format("left the domain through a wall (coordinate {:.6g} m)", r.fault_value),
          comm_.rank());
    }
    throw RunError(comm_.agree_on_error(key, message));
  }
  for (const Batch& bt : batches_)
    ratio_ = std::max(ratio_, bt.max_ratio);
  for (std::size_t k = 0; k < ids_.size(); ++k) {
    const LeafRun& r = runs_[k];
    leaf_steps_[static_cast<std::size_t>(ids_[k])] += r.K;
    if (cost_weights_)
      for (std::uint32_t i = ranges_[k]; i < ranges_[k + 1]; ++i)
        cost_[i] += static_cast<double>(r.K);
  }
  particle_steps_ += c[4], pair_evaluations_ += c[5], overlap_violations_ += c[6];
  local_particle_steps_ += local_c_[0], local_pair_evaluations_ += local_c_[1];
  fine_count_ += c[7], leaf_subits_ += c[8];
  last_fine_fraction_ = c[8] > 0 ? static_cast<double>(c[7]) / static_cast<double>(c[8]) : 0.0;
  // The largest overlap over the ranks is reduced only when the state is recorded (the loop
  // records the last sub-iteration): one reduction per sub-iteration is the budget.
  if (record)
    max_overlap_ratio_ = std::max(max_overlap_ratio_, comm_.max(ratio_));
  ++subits_;
}

void DistributedOrbScheme::set_external_force(std::span<const double> fx,
                                              std::span<const double> fy,
                                              std::span<const double> fz) {
  // On when any rank passes values (a rank without particles passes empty spans): the columns
  // that travel with the particles must be the same on every rank.
  const bool on = comm_.max(fx.empty() ? 0.0 : 1.0) > 0.0;
  const bool fits = on ? fx.size() == owned_ && fy.size() == owned_ && fz.size() == owned_
                       : fy.empty() && fz.empty();
  if (comm_.max(fits ? 0.0 : 1.0) > 0.0)
    throw std::invalid_argument("set_external_force: one value per owned particle expected");
  ext_on_ = on;
  ex_.assign(fx.begin(), fx.end()), ey_.assign(fy.begin(), fy.end());
  ez_.assign(fz.begin(), fz.end());
}

void DistributedOrbScheme::replace_external_force(std::span<const double> fx,
                                                  std::span<const double> fy,
                                                  std::span<const double> fz) {
  if (fx.size() == owned_ && hprev_.size() >= owned_)
    settle_owed_half_kick(std::span<double>(p_.vx).first(owned_),
                          std::span<double>(p_.vy).first(owned_),
                          std::span<double>(p_.vz).first(owned_), p_.inv_mass,
                          std::span<const double>(hprev_).first(owned_), ex_, ey_, ez_, fx, fy, fz);
  set_external_force(fx, fy, fz); // checks the sizes on every rank
}

LeafStepStats DistributedOrbScheme::take_interval_stats() {
  std::vector<std::int64_t> steps = leaf_steps_;
  comm_.sum(steps);
  std::fill(leaf_steps_.begin(), leaf_steps_.end(), 0);
  LeafStepStats s;
  std::int64_t lo = std::numeric_limits<std::int64_t>::max(), hi = 0, sum = 0, count = 0;
  for (const std::int64_t v : steps)
    if (v > 0)
      lo = std::min(lo, v), hi = std::max(hi, v), sum += v, ++count;
  if (count > 0) {
    s.steps_min = static_cast<double>(lo), s.steps_max = static_cast<double>(hi);
    s.steps_mean = static_cast<double>(sum) / static_cast<double>(count);
  }
  s.fine_fraction =
      leaf_subits_ > 0 ? static_cast<double>(fine_count_) / static_cast<double>(leaf_subits_) : 0.0;
  fine_count_ = leaf_subits_ = 0;
  return s;
}

OrbScheme::State DistributedOrbScheme::save_state() const {
  if (subits_ % nsubit_ != 0)
    throw RunError("orb checkpoint requested between regrid points (internal error)");
  OrbScheme::State s;
  s.hprev = hprev_, s.cost = cost_;
  s.leaf_steps = leaf_steps_;
  comm_.sum(s.leaf_steps);
  s.fine_count = fine_count_, s.leaf_subits = leaf_subits_, s.subits = subits_;
  s.particle_steps = particle_steps_, s.pair_evaluations = pair_evaluations_, s.builds = builds_;
  s.regrids = regrids_, s.overlap_violations = overlap_violations_, s.retries = retries_;
  s.last_fine_fraction = last_fine_fraction_;
  s.max_overlap_ratio = std::max(max_overlap_ratio_, comm_.max(ratio_));
  s.skin = skin_;
  s.pairs_valid = false;
  return s;
}

void DistributedOrbScheme::restore_state(OrbScheme::State s) {
  if (s.hprev.size() != owned_ || s.cost.size() != owned_ || s.subits < 0 ||
      s.subits % nsubit_ != 0 ||
      (!s.leaf_steps.empty() && s.leaf_steps.size() != leaf_steps_.size()))
    throw RunError("checkpoint: the orb state does not fit the particles, dem.nsubit or "
                   "partition.orb_levels");
  hprev_ = std::move(s.hprev), cost_ = std::move(s.cost);
  // The per-leaf steps of the interval are sums over the ranks: rank 0 holds them.
  std::fill(leaf_steps_.begin(), leaf_steps_.end(), 0);
  if (comm_.rank() == 0 && !s.leaf_steps.empty())
    leaf_steps_ = s.leaf_steps;
  fine_count_ = s.fine_count, leaf_subits_ = s.leaf_subits, subits_ = s.subits;
  particle_steps_ = s.particle_steps, pair_evaluations_ = s.pair_evaluations, builds_ = s.builds;
  regrids_ = s.regrids, overlap_violations_ = s.overlap_violations, retries_ = s.retries;
  last_fine_fraction_ = s.last_fine_fraction, max_overlap_ratio_ = s.max_overlap_ratio;
  ratio_ = 0.0;
  if (s.skin > 0.0)
    skin_ = s.skin;
}

} // namespace cfddem::dem
