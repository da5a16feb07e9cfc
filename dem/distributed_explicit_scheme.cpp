#include "dem/distributed_explicit_scheme.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_map>

#include <fmt/format.h>

#include "core/error.hpp"
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

DistributedExplicitScheme::DistributedExplicitScheme(const Scene& scene, ParticleStore& particles,
                                                     const StepModel& model,
                                                     const Communicator& comm, PhaseTimer& timer)
    : scene_(scene), p_(particles), comm_(comm), timer_(timer), geom_(scene.domain), model_(model),
      exchange_(comm) {
  if (model_.friction)
    p_.enable_rotation();
  // Enough boxes that the knapsack can balance: at least 4 per rank (partition.orb_levels when
  // that is more).
  levels_ = std::min(20, std::max(scene.partition.orb_levels, ceil_log2(comm.size()) + 2));
  double r_max = 0.0;
  for (const double r : p_.radius)
    r_max = std::max(r_max, r);
  r_max = comm_.max(r_max);
  halo_ = 2.0 * r_max + model_.skin; // the Verlet cutoff: every pair the list can hold
  n_global_ = comm_.sum(static_cast<std::int64_t>(p_.size()));
  for (int a = 0; a < 3; ++a)
    // As VerletList::build: one image of a neighbour within reach at most.
    if (n_global_ > 0 && geom_.periodic[a] && geom_.length[a] <= 2.0 * (halo_ + model_.skin))
      throw RunError(fmt::format(
          "periodic axis {} is {:.6g} m long, not more than twice the neighbor cutoff plus skin "
          "{:.6g} m (largest diameter + 2 skins): enlarge the domain or reduce dem.neighbor_skin",
          a, geom_.length[a], halo_ + model_.skin));
  // Regrid at the first neighbor rebuild after dem.regrid_interval (simulated seconds).
  regrid_every_ = std::max<std::int64_t>(
      1, std::llround(scene.dem.regrid_interval / std::max(model_.dt, 1e-300)));
  owned_ = p_.size();
}

void DistributedExplicitScheme::canonicalize() {
  last_regrid_ = -1; // regrid now
  rebuild();
}

ContactHistory DistributedExplicitScheme::contact_history() const {
  return collect_history(p_, list_, owned_, hx_, hy_, hz_);
}

void DistributedExplicitScheme::restore(const Counters& c, const ContactHistory& history) {
  steps_ = c.steps;
  pending_ = history;
  canonicalize();
  particle_steps_ = c.particle_steps, pair_evaluations_ = c.pair_evaluations, builds_ = c.builds;
}

void DistributedExplicitScheme::ghost_copies(std::vector<ParticleExchange::Copy>& out) const {
  out.clear();
  const partition::OrbTree& tree = decomposition_.tree;
  const int me = comm_.rank();
  std::vector<std::pair<int, std::array<int, 3>>> seen;
  for (std::size_t i = 0; i < owned_; ++i) {
    const partition::Aabb q{{p_.x[i] - halo_, p_.y[i] - halo_, p_.z[i] - halo_},
                            {p_.x[i] + halo_, p_.y[i] + halo_, p_.z[i] + halo_}};
    // Fast path: a halo strictly inside the particle's own box reaches no other box and no
    // periodic image (most particles of a large box).
    const int own = tree.locate(p_.x[i], p_.y[i], p_.z[i]);
    if (own >= 0) {
      const partition::Aabb& b = tree.leaves()[static_cast<std::size_t>(own)].box;
      bool inside = true;
      for (int a = 0; a < 3; ++a)
        inside = inside && q.lo[a] > b.lo[a] && q.hi[a] < b.hi[a];
      if (inside)
        continue;
    }
    seen.clear();
    // (leaf, s): the particle's image p + s L lies within the halo of the leaf.
    for (const partition::LeafImage& li : tree.leaf_images_overlapping(q, geom_.periodic)) {
      const int r = decomposition_.owner[static_cast<std::size_t>(li.leaf)];
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
        c.shift[a] = li.shift[a] * geom_.length[a];
      out.push_back(c);
    }
  }
}

DistributedExplicitScheme::~DistributedExplicitScheme() {
  finish_forward();
}

void DistributedExplicitScheme::finish_forward() {
  if (!forward_pending_)
    return;
  exchange_.forward_end(p_);
  forward_pending_ = false;
}

template <bool Friction>
void DistributedExplicitScheme::contact_rows(std::span<const std::uint32_t> rows, double dt,
                                             StepReport& rep) {
  contact_pass<Friction>(p_, list_, local_, model_, hx_.data(), hy_.data(), hz_.data(), dt, rows,
                         rep);
}

void DistributedExplicitScheme::contact(double dt, StepReport& rep) {
  PhaseTimer::Scope t(timer_, Phase::force);
  const bool fr = model_.friction;
  if (!forward_pending_) {
    fr ? contact_rows<true>(list_.active(), dt, rep) : contact_rows<false>(list_.active(), dt, rep);
    return;
  }
  fr ? contact_rows<true>(list_.interior(), dt, rep)
     : contact_rows<false>(list_.interior(), dt, rep);
  finish_forward();
  fr ? contact_rows<true>(list_.boundary(), dt, rep)
     : contact_rows<false>(list_.boundary(), dt, rep);
}

void DistributedExplicitScheme::rebuild() {
  finish_forward(); // its ghosts are about to be replaced; the messages must land first
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  // The owned rows' history by ids (partners may be ghosts, about to go), with any records a
  // restart handed in.
  ContactHistory held;
  if (model_.friction) {
    held = collect_history(p_, list_, owned_, hx_, hy_, hz_);
    held.append(pending_);
    pending_ = ContactHistory{};
  }
  p_.resize(owned_); // the ghosts go; they come back from their owners below
  for (std::size_t i = 0; i < owned_; ++i)
    p_.x[i] = geom_.wrap(p_.x[i], 0), p_.y[i] = geom_.wrap(p_.y[i], 1),
    p_.z[i] = geom_.wrap(p_.z[i], 2);
  // A fixed decomposition is never redone, but the first build sorts as a regrid does.
  const bool regrid =
      last_regrid_ < 0 || (!fixed_decomposition_ && steps_ - last_regrid_ >= regrid_every_);
  if (regrid && !fixed_decomposition_) {
    const partition::Aabb domain{scene_.domain.lo, scene_.domain.hi};
    decomposition_ = partition::decompose(comm_, p_.x, p_.y, p_.z, domain, levels_);
    regrids_.push_back({steps_, decomposition_.imbalance});
  }
  if (regrid) {
    last_regrid_ = steps_;
  }
  std::vector<int> dest(owned_);
  std::string outside; // the update's checks stop such a particle first; agreed on all ranks
  std::int64_t outside_id = 0;
  for (std::size_t i = 0; i < owned_; ++i) {
    dest[i] = decomposition_.owner_of(p_.x[i], p_.y[i], p_.z[i]);
    if (dest[i] < 0 && outside.empty()) {
      outside_id = p_.id[i];
      outside = fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m is outside "
                            "the domain (rank {})",
                            time(), p_.id[i], p_.x[i], p_.y[i], p_.z[i], comm_.rank());
    }
  }
  if (const std::string e = comm_.agree_on_error(outside_id, outside); !e.empty())
    throw RunError(e);
  ContactHistory arrived;
  std::int64_t moved_history = 0;
  if (model_.friction) {
    // Each record follows its owner particle; records of particles this rank does not hold
    // (a restart's, of other ranks' shares) are dropped here: their holder routes them.
    std::unordered_map<std::int64_t, std::uint32_t> index;
    index.reserve(owned_);
    for (std::size_t i = 0; i < owned_; ++i)
      index.emplace(p_.id[i], static_cast<std::uint32_t>(i));
    ContactHistory mine;
    std::vector<int> to;
    for (std::size_t q = 0; q < held.size(); ++q) {
      const auto it = index.find(held.owner[q]);
      if (it == index.end())
        continue;
      mine.add(held.owner[q], held.partner[q], held.hx[q], held.hy[q], held.hz[q]);
      to.push_back(dest[it->second]);
      moved_history += to.back() != comm_.rank() ? 1 : 0;
    }
    arrived = ContactHistory::unpack(exchange_.route(to, mine.pack(), ContactHistory::kStride));
  }
  if (ext_on_) {
    // Every rank alike (the record sizes must agree), a rank without particles included.
    std::vector<double>* force[3] = {&ext_.x, &ext_.y, &ext_.z};
    exchange_.migrate(p_, dest, force);
  } else {
    exchange_.migrate(p_, dest);
  }
  owned_ = p_.size();
  if (regrid) {
    // Locality: owned particles in cell order (cells of the halo width), as the serial list
    // sorts its store; then rows and their neighbours are near in memory.
    std::vector<std::uint64_t> key(owned_);
    for (std::size_t i = 0; i < owned_; ++i) {
      const double q[3] = {p_.x[i], p_.y[i], p_.z[i]};
      std::uint64_t k = 0;
      for (int a = 2; a >= 0; --a)
        k = k * (std::uint64_t{1} << 20) +
            static_cast<std::uint64_t>(std::clamp((q[a] - geom_.lo[a]) / halo_, 0.0, 1048575.0));
      key[i] = k;
    }
    std::vector<std::uint32_t> order(owned_);
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
  ghost_copies(copies);
  exchange_.build_ghosts(p_, owned_, std::move(copies));
  list_.build_local(p_, owned_, model_.skin);
  if (model_.friction)
    attach_history(std::move(arrived), p_, list_, owned_, hx_, hy_, hz_);
  // Only rows get their force (torque) rewritten each step: clear the rest, as the serial build.
  std::fill(p_.fx.begin(), p_.fx.end(), 0.0);
  std::fill(p_.fy.begin(), p_.fy.end(), 0.0);
  std::fill(p_.fz.begin(), p_.fz.end(), 0.0);
  if (p_.rotation) {
    std::fill(p_.tx.begin(), p_.tx.end(), 0.0);
    std::fill(p_.ty.begin(), p_.ty.end(), 0.0);
    std::fill(p_.tz.begin(), p_.tz.end(), 0.0);
  }
  // No particle lost: the owned counts add up to the initial total (and the pair count).
  std::array<std::int64_t, 3> totals{static_cast<std::int64_t>(owned_),
                                     static_cast<std::int64_t>(list_.neighbors().size()),
                                     moved_history};
  comm_.sum(totals);
  if (totals[0] != n_global_)
    throw RunError(fmt::format("t = {:.9g} s: {} particles on the ranks after migration, {} "
                               "expected",
                               time(), totals[0], n_global_));
  global_pairs_ = totals[1] / 2;
  history_migrations_ += totals[2];
  ++builds_;
  need_rebuild_ = false;
}

template <bool Walls, bool Friction>
void DistributedExplicitScheme::update(double dt, StepReport& rep) {
  if (ext_.active()) {
    update_pass<Walls, Friction, true>(p_, owned_, list_, ext_, geom_, model_, dt, rep);
  } else {
    update_pass<Walls, Friction, false>(p_, owned_, list_, ext_, geom_, model_, dt, rep);
  }
}

void DistributedExplicitScheme::set_decomposition(partition::RankDecomposition d) {
  decomposition_ = std::move(d);
  fixed_decomposition_ = true;
  last_regrid_ = -1;
  need_rebuild_ = true;
}

void DistributedExplicitScheme::set_external_force(std::span<const double> fx,
                                                   std::span<const double> fy,
                                                   std::span<const double> fz) {
  ext_.set(fx, fy, fz, owned_);
  // On when any rank holds a force: then every rank carries one per particle when particles
  // migrate (a rank without particles, whose spans are empty, too).
  ext_on_ = comm_.max(fx.empty() ? 0.0 : 1.0) > 0.0;
}

void DistributedExplicitScheme::evaluate_and_update(double dt, StepReport& rep) {
  const bool walls = !(geom_.periodic[0] && geom_.periodic[1] && geom_.periodic[2]);
  contact(dt, rep);
  PhaseTimer::Scope t(timer_, Phase::integrate);
  if (model_.friction)
    walls ? update<true, true>(dt, rep) : update<false, true>(dt, rep);
  else
    walls ? update<true, false>(dt, rep) : update<false, false>(dt, rep);
}

void DistributedExplicitScheme::agree(const StepReport& rep, double t) const {
  std::string message;
  std::int64_t key = std::numeric_limits<std::int64_t>::max();
  if (rep.bad != kNoParticle) {
    message = fmt::format("t = {:.9g} s, step {}: {} (rank {})", t, steps_,
                          describe_fault(p_, rep, model_), comm_.rank());
    key = p_.id[rep.bad];
  }
  const std::string agreed = comm_.agree_on_error(key, message);
  if (!agreed.empty())
    throw RunError(agreed);
}

void DistributedExplicitScheme::start() {
  rebuild();
  StepReport rep;
  evaluate_and_update(0.0, rep); // dt = 0: forces at t = 0, x and v unchanged
  if (rep.fault != StepFault::overlap)
    rep = StepReport{}; // as the serial start: overlaps only
  agree(rep, 0.0);
  const double h = 0.5 * model_.dt;
  for (std::size_t i = 0; i < owned_; ++i) {
    const double e[3] = {ext_.active() ? ext_.x[i] : 0.0, ext_.active() ? ext_.y[i] : 0.0,
                         ext_.active() ? ext_.z[i] : 0.0};
    p_.vx[i] -= ((p_.fx[i] + e[0]) * p_.inv_mass[i] + model_.gravity[0]) * h;
    p_.vy[i] -= ((p_.fy[i] + e[1]) * p_.inv_mass[i] + model_.gravity[1]) * h;
    p_.vz[i] -= ((p_.fz[i] + e[2]) * p_.inv_mass[i] + model_.gravity[2]) * h;
    if (model_.friction) {
      p_.wx[i] -= p_.tx[i] * p_.inv_inertia[i] * h;
      p_.wy[i] -= p_.ty[i] * p_.inv_inertia[i] * h;
      p_.wz[i] -= p_.tz[i] * p_.inv_inertia[i] * h;
    }
  }
  exchange_.forward(p_);
}

void DistributedExplicitScheme::record_synchronised() {
  const std::size_t n = owned_;
  sx_.assign(p_.x.begin(), p_.x.begin() + static_cast<std::ptrdiff_t>(n));
  sy_.assign(p_.y.begin(), p_.y.begin() + static_cast<std::ptrdiff_t>(n));
  sz_.assign(p_.z.begin(), p_.z.begin() + static_cast<std::ptrdiff_t>(n));
  svx_.resize(n), svy_.resize(n), svz_.resize(n);
  const double h = 0.5 * model_.dt;
  for (std::size_t i = 0; i < n; ++i) {
    const double e[3] = {ext_.active() ? ext_.x[i] : 0.0, ext_.active() ? ext_.y[i] : 0.0,
                         ext_.active() ? ext_.z[i] : 0.0};
    svx_[i] = p_.vx[i] + ((p_.fx[i] + e[0]) * p_.inv_mass[i] + model_.gravity[0]) * h;
    svy_[i] = p_.vy[i] + ((p_.fy[i] + e[1]) * p_.inv_mass[i] + model_.gravity[1]) * h;
    svz_[i] = p_.vz[i] + ((p_.fz[i] + e[2]) * p_.inv_mass[i] + model_.gravity[2]) * h;
  }
}

void DistributedExplicitScheme::step(bool record) {
  if (need_rebuild_)
    rebuild();
  StepReport rep;
  if (!record) {
    evaluate_and_update(model_.dt, rep);
  } else {
    // As ExplicitScheme::step: record x(n), v(n) between the forces and the update.
    const bool walls = !(geom_.periodic[0] && geom_.periodic[1] && geom_.periodic[2]);
    contact(model_.dt, rep);
    PhaseTimer::Scope t(timer_, Phase::integrate);
    const bool fr = model_.friction;
    if (walls) // wall forces into f, x and v unchanged
      fr ? update<true, true>(0.0, rep) : update<true, false>(0.0, rep);
    record_synchronised();
    fr ? update<false, true>(model_.dt, rep) : update<false, false>(model_.dt, rep);
  }
  // One reduction: did any particle anywhere move past skin/2, and did any rank fail a check;
  // in flight together with the ghost forward (wasted, and overwritten, before a rebuild).
  std::array<std::int64_t, 2> flags{rep.moved > 0 ? 1 : 0, rep.bad != kNoParticle ? 1 : 0};
  comm_.max_begin(flags);
  exchange_.forward_begin(p_);
  forward_pending_ = true;
  comm_.max_wait();
  if (flags[1] != 0) {
    finish_forward();
    agree(rep, time());
  }
  ++steps_;
  particle_steps_ += n_global_;
  pair_evaluations_ += global_pairs_;
  local_particle_steps_ += static_cast<std::int64_t>(owned_);
  local_pair_evaluations_ += static_cast<std::int64_t>(list_.neighbors().size() / 2);
  if (flags[0] != 0)
    need_rebuild_ = true;
}

} // namespace cfddem::dem
