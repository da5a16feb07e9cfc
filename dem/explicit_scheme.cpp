#include "dem/explicit_scheme.hpp"

#include <algorithm>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>

#include <fmt/format.h>

#include "core/error.hpp"
#include "dem/explicit_ranks.hpp"
#include "dem/verlet_passes.hpp"

namespace cfddem::dem {

ExplicitScheme::ExplicitScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer)
    : ExplicitScheme(scene, particles, make_step_model(scene, particles), nullptr, timer) {}

ExplicitScheme::ExplicitScheme(const Scene& scene, ParticleStore& particles, const StepModel& model,
                               const Communicator* comm, PhaseTimer& timer)
    : scene_(scene), p_(particles), timer_(timer), geom_(scene.domain), model_(model) {
  if (model_.friction)
    p_.enable_rotation();
  if (comm != nullptr && comm->size() > 1)
    rank_ = std::make_unique<RankPart>(scene, p_, model_, *comm);
}

ExplicitScheme::~ExplicitScheme() {
  finish_forward();
}

std::size_t ExplicitScheme::owned() const {
  return rank_ ? rank_->owned : p_.size();
}
std::int64_t ExplicitScheme::global_count() const {
  return rank_ ? rank_->n_global : static_cast<std::int64_t>(p_.size());
}
std::int64_t ExplicitScheme::history_migrations() const {
  return rank_ ? rank_->history_migrations : 0;
}
int ExplicitScheme::levels() const {
  return rank_ ? rank_->levels : 0;
}
const std::vector<ExplicitScheme::Regrid>& ExplicitScheme::regrids() const {
  static const std::vector<Regrid> none;
  return rank_ ? rank_->regrids : none;
}
const partition::RankDecomposition& ExplicitScheme::decomposition() const {
  static const partition::RankDecomposition none;
  return rank_ ? rank_->decomposition : none;
}

void ExplicitScheme::set_decomposition(partition::RankDecomposition d) {
  if (!rank_)
    return;
  rank_->decomposition = std::move(d);
  rank_->fixed_decomposition = true;
  rank_->last_regrid = -1;
  rows_.need_rebuild = true;
}

void ExplicitScheme::redistribute_now() {
  if (rank_ && rows_.need_rebuild)
    rebuild();
}

void ExplicitScheme::set_external_force(std::span<const double> fx, std::span<const double> fy,
                                        std::span<const double> fz) {
  ext_.set(fx, fy, fz, owned());
  // On R ranks: on when any rank holds a force; then every rank carries one per particle when
  // particles migrate (a rank without particles, whose spans are empty, too).
  if (rank_)
    rank_->ext_on = rank_->comm.max(fx.empty() ? 0.0 : 1.0) > 0.0;
}

void ExplicitScheme::rebuild_one_rank() {
  // Carry the tangential history of each pair across the rebuild, keyed by particle ids (with
  // any records a restart handed in).
  ContactHistory held;
  if (model_.friction) {
    held = collect_history(p_, rows_.list, p_.size(), rows_.hx, rows_.hy, rows_.hz);
    held.append(rows_.pending);
    rows_.pending = ContactHistory{};
  }
  rows_.list.build(p_, geom_, model_.skin, RowKind::half);
  if (model_.friction)
    attach_history(std::move(held), p_, rows_.list, p_.size(), rows_.hx, rows_.hy, rows_.hz);
  ext_.permute(rows_.list.order()); // the build permuted the store: external forces follow
}

void ExplicitScheme::rebuild() {
  finish_forward(); // its ghosts are about to be replaced; the messages must land first
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  rank_ ? rebuild_ranks() : rebuild_one_rank();
  // Only particles with a row get their contact force rewritten each step: clear the rest.
  std::fill(p_.fx.begin(), p_.fx.end(), 0.0);
  std::fill(p_.fy.begin(), p_.fy.end(), 0.0);
  std::fill(p_.fz.begin(), p_.fz.end(), 0.0);
  if (p_.rotation) {
    std::fill(p_.tx.begin(), p_.tx.end(), 0.0);
    std::fill(p_.ty.begin(), p_.ty.end(), 0.0);
    std::fill(p_.tz.begin(), p_.tz.end(), 0.0);
  }
  ++stats_.builds;
  rows_.need_rebuild = false;
  rows_.travel.reset(); // the build's reference positions are the particles' positions
  lay_out_pairs();
}

void ExplicitScheme::lay_out_pairs() {
  const VerletList& list = rows_.list;
  rows_.head_pairs.build<false>(list, list.active(), kPairBlock, model_.friction);
  rows_.tail_pairs.build<true>(list, list.tail_rows(), kPairBlock, model_.friction);
  near_walls(p_, owned(), list, geom_, model_.skin, rows_.near_wall);
  // The last contacts' indices no longer name the same particles: clear every listed force next.
  rows_.clear_all = true;
  rows_.nh = rows_.nt = 0;
}

template <bool Friction>
void ExplicitScheme::contact_pairs(const DomainGeometry& frame, double dt, StepReport& rep) {
  const VerletList& list = rows_.list;
  const HistoryColumns h{rows_.hx, rows_.hy, rows_.hz};
  // Clear the forces that are not zero: those of the particles the update pass may have given a
  // wall force, and after a new layout of the list (a build, a restart) every listed particle's,
  // else those of the last step's contacts (the blocks still hold them).
  if (rows_.clear_all) {
    clear_forces<Friction>(p_, rows_.near_wall);
    clear_forces<Friction>(p_, list.listed_index());
    rows_.clear_all = false;
  } else {
    clear_contact_forces<Friction>(
        p_, p_.size(), std::span<const PairContacts>(rows_.head).first(rows_.nh),
        std::span<const PairContacts>(rows_.tail).first(rows_.nt), rows_.near_wall);
  }
  // Pairs whose separation is ready first (in-box; on R ranks two owned particles), then, once a
  // ghost forward in flight has landed, the rest (across a periodic face; with a ghost).
  rows_.nh =
      pair_pass<Friction, false>(p_, rows_.head_pairs, h, frame, model_, dt, rows_.head, rep);
  if (rank_ && rank_->forward_pending) {
    PhaseTimer::Scope t(timer_, Phase::comm); // the ghosts' positions land
    finish_forward();
  }
  rows_.nt = pair_pass<Friction, true>(p_, rows_.tail_pairs, h, frame, model_, dt, rows_.tail, rep);
  scatter_contacts<Friction>(p_, p_.size(),
                             std::span<const PairContacts>(rows_.head).first(rows_.nh),
                             std::span<const PairContacts>(rows_.tail).first(rows_.nt));
}

void ExplicitScheme::contact(double dt, StepReport& rep) {
  PhaseTimer::Scope t(timer_, Phase::force);
  // One rank: minimum image through the whole domain. R ranks: the local frame (ghosts sit at
  // their images).
  const DomainGeometry& frame = rank_ ? rank_->local : geom_;
  model_.friction ? contact_pairs<true>(frame, dt, rep) : contact_pairs<false>(frame, dt, rep);
}

std::int64_t ExplicitScheme::local_pair_entries2() const {
  return 2 * static_cast<std::int64_t>(rows_.list.neighbors().size()) -
         static_cast<std::int64_t>(rows_.list.ghost_entries());
}

template <bool Walls, bool Friction, bool External>
void ExplicitScheme::update_owned(double dt, StepReport& rep) {
  update_pass<Walls, Friction, External>(p_, owned(), rows_.list, rows_.near_wall, ext_, geom_,
                                         model_, dt, rep, rows_.travel);
}

template <bool Walls> void ExplicitScheme::update(double dt, StepReport& rep) {
  if (model_.friction) {
    ext_.active() ? update_owned<Walls, true, true>(dt, rep)
                  : update_owned<Walls, true, false>(dt, rep);
  } else {
    ext_.active() ? update_owned<Walls, false, true>(dt, rep)
                  : update_owned<Walls, false, false>(dt, rep);
  }
}

void ExplicitScheme::evaluate_and_update(double dt, StepReport& rep) {
  const bool walls = !(geom_.periodic[0] && geom_.periodic[1] && geom_.periodic[2]);
  contact(dt, rep);
  // Wall forces are evaluated inside the update pass and timed with it.
  PhaseTimer::Scope t(timer_, Phase::integrate);
  walls ? update<true>(dt, rep) : update<false>(dt, rep);
}

void ExplicitScheme::report_fault(const StepReport& rep, double t) const {
  std::string message;
  std::int64_t key = std::numeric_limits<std::int64_t>::max();
  if (rep.bad != kNoParticle) {
    message =
        fmt::format("t = {:.9g} s, step {}: {}", t, stats_.steps, describe_fault(p_, rep, model_));
    if (rank_)
      message += fmt::format(" (rank {})", rank_->comm.rank());
    key = p_.id[rep.bad];
  }
  if (!rank_) {
    if (!message.empty())
      throw RunError(message);
    return;
  }
  // Every rank learns whether any has a fault, and all throw the same error.
  const std::string agreed = rank_->comm.agree_on_error(key, message);
  if (!agreed.empty())
    throw RunError(agreed);
}

void ExplicitScheme::half_kick_start() {
  const double h = 0.5 * model_.dt;
  for (std::size_t i = 0, n = owned(); i < n; ++i) {
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
}

void ExplicitScheme::start() {
  rebuild();
  // Forces at t = 0 with v(0) (dt = 0 leaves x and v unchanged), then v(-dt/2) = v(0) - a(0) dt/2.
  StepReport rep;
  evaluate_and_update(0.0, rep);
  if (rep.fault != StepFault::overlap)
    rep = StepReport{}; // at t = 0 only an overlap is a fault
  report_fault(rep, 0.0);
  half_kick_start();
  if (rank_)
    rank_->exchange.forward(p_);
}

void ExplicitScheme::record_synchronised() {
  // x(n) and v(n) = v(n-1/2) + a(n) dt/2, with a(n) from the forces just evaluated.
  const std::size_t n = owned();
  const auto first = static_cast<std::ptrdiff_t>(n);
  Recorded& s = recorded_;
  s.x.assign(p_.x.begin(), p_.x.begin() + first);
  s.y.assign(p_.y.begin(), p_.y.begin() + first);
  s.z.assign(p_.z.begin(), p_.z.begin() + first);
  s.vx.resize(n), s.vy.resize(n), s.vz.resize(n);
  const double h = 0.5 * model_.dt;
  for (std::size_t i = 0; i < n; ++i) {
    const double e[3] = {ext_.active() ? ext_.x[i] : 0.0, ext_.active() ? ext_.y[i] : 0.0,
                         ext_.active() ? ext_.z[i] : 0.0};
    s.vx[i] = p_.vx[i] + ((p_.fx[i] + e[0]) * p_.inv_mass[i] + model_.gravity[0]) * h;
    s.vy[i] = p_.vy[i] + ((p_.fy[i] + e[1]) * p_.inv_mass[i] + model_.gravity[1]) * h;
    s.vz[i] = p_.vz[i] + ((p_.fz[i] + e[2]) * p_.inv_mass[i] + model_.gravity[2]) * h;
  }
}

void ExplicitScheme::step(bool record) {
  if (rows_.need_rebuild)
    rebuild();
  StepReport rep;
  if (!record) {
    evaluate_and_update(model_.dt, rep);
  } else {
    // Split so the state at time n can be recorded between the force and the update.
    const bool walls = !(geom_.periodic[0] && geom_.periodic[1] && geom_.periodic[2]);
    const bool fr = model_.friction;
    contact(model_.dt, rep);
    PhaseTimer::Scope t(timer_, Phase::integrate);
    if (walls) {
      // Wall forces are added inside the update pass; record after a force-only wall pass would
      // double count, so record with the wall forces applied by a dt = 0 update (x, v unchanged).
      fr ? update_owned<true, true, false>(0.0, rep) : update_owned<true, false, false>(0.0, rep);
    }
    record_synchronised();
    // F now includes the walls: finish with a pure update.
    update<false>(model_.dt, rep);
  }
  bool moved = rep.moved > 0, failed = rep.bad != kNoParticle;
  if (rank_) {
    PhaseTimer::Scope t(timer_, Phase::comm);
    exchange_after_step(moved, failed);
  }
  if (failed)
    report_fault(rep, time());
  ++stats_.steps;
  const std::int64_t pairs = local_pair_entries2() / 2;
  stats_.particle_steps += global_count();
  stats_.pair_evaluations += rank_ ? rank_->global_pairs : pairs;
  stats_.local_particle_steps += static_cast<std::int64_t>(owned());
  stats_.local_pair_evaluations += pairs;
  if (moved)
    rows_.need_rebuild = true;
}

void ExplicitScheme::canonicalize() {
  if (rank_) {
    rank_->last_regrid = -1; // regrid now
    rebuild();
    return;
  }
  // One rank: the list build sorts the store by cell, ties kept in their order; start it from id
  // order, so that the order is (cell, id) however the particles come back (a checkpoint's).
  if (model_.friction)
    rows_.pending.append(contact_history());
  std::vector<std::uint32_t> order(p_.size());
  std::iota(order.begin(), order.end(), 0U);
  std::sort(order.begin(), order.end(),
            [&](std::uint32_t a, std::uint32_t b) { return p_.id[a] < p_.id[b]; });
  p_.permute(order);
  ext_.permute(order);
  ContactHistory pending = std::move(rows_.pending);
  rows_ = Rows{}; // the rows indexed the old order
  rows_.pending = std::move(pending);
  rebuild();
}

ContactHistory ExplicitScheme::contact_history() const {
  return collect_history(p_, rows_.list, owned(), rows_.hx, rows_.hy, rows_.hz);
}

void ExplicitScheme::restore(const Counters& c, const ContactHistory& history) {
  stats_.steps = c.steps;
  rows_.pending = history;
  // A one-rank checkpoint's half rows hold each pair's record once: its partner's is the negated
  // spring (a full list's row would hold it).
  rows_.pending.add_mirrors();
  canonicalize();
  stats_.particle_steps = c.particle_steps, stats_.pair_evaluations = c.pair_evaluations;
  stats_.builds = c.builds;
}

namespace {
// A full list's rows reduced to the half list's (each row's partners of higher index, in their
// order), history entries with them: what a build of the same list gives.
void keep_upper_pairs(ExplicitScheme::State& s) {
  const std::size_t n = s.offsets.size() - 1;
  const bool history = !s.hx.empty();
  std::size_t w = 0, k = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint32_t end = s.offsets[i + 1];
    s.offsets[i] = static_cast<std::uint32_t>(w);
    for (; k < end; ++k) {
      if (s.neighbors[k] <= i)
        continue;
      s.neighbors[w] = s.neighbors[k];
      if (history)
        s.hx[w] = s.hx[k], s.hy[w] = s.hy[k], s.hz[w] = s.hz[k];
      ++w;
    }
  }
  s.offsets[n] = static_cast<std::uint32_t>(w);
  s.neighbors.resize(w);
  if (history)
    s.hx.resize(w), s.hy.resize(w), s.hz.resize(w);
}
} // namespace

ExplicitScheme::State ExplicitScheme::save_state() const {
  if (rank_)
    throw std::logic_error("ExplicitScheme::save_state is the one-rank checkpoint; on R ranks "
                           "use canonicalize(), counters() and contact_history()");
  const VerletList& list = rows_.list;
  State s;
  s.offsets.assign(list.offsets().begin(), list.offsets().end());
  s.neighbors.assign(list.neighbors().begin(), list.neighbors().end());
  s.x_ref.assign(list.x_ref().begin(), list.x_ref().end());
  s.y_ref.assign(list.y_ref().begin(), list.y_ref().end());
  s.z_ref.assign(list.z_ref().begin(), list.z_ref().end());
  s.hx = rows_.hx, s.hy = rows_.hy, s.hz = rows_.hz;
  s.skin = list.skin();
  s.need_rebuild = rows_.need_rebuild;
  s.steps = stats_.steps, s.particle_steps = stats_.particle_steps;
  s.pair_evaluations = stats_.pair_evaluations, s.builds = stats_.builds;
  return s;
}

void ExplicitScheme::restore_state(State s) {
  if (rank_)
    throw std::logic_error("ExplicitScheme::restore_state is the one-rank restart; on R ranks "
                           "use restore()");
  const std::size_t n = p_.size();
  const bool listed = !s.offsets.empty();
  check_saved_list(n, s.offsets, s.neighbors, s.x_ref, s.y_ref, s.z_ref);
  if (model_.friction && (s.hx.size() != s.neighbors.size() || s.hy.size() != s.neighbors.size() ||
                          s.hz.size() != s.neighbors.size()))
    throw RunError("checkpoint: the tangential history does not fit the neighbor list");
  if (listed)
    keep_upper_pairs(s); // a checkpoint of an older version holds full rows
  rows_.list.restore(std::move(s.offsets), std::move(s.neighbors), std::move(s.x_ref),
                     std::move(s.y_ref), std::move(s.z_ref), s.skin, geom_);
  rows_.hx = std::move(s.hx), rows_.hy = std::move(s.hy), rows_.hz = std::move(s.hz);
  rows_.need_rebuild = s.need_rebuild || !listed;
  rows_.travel.forget(); // the restored positions may lie anywhere within skin/2 of the build's
  // A state without a list (an R-rank checkpoint's canonical state) has nothing to lay out, nor
  // build positions to judge the walls by: its first step builds and lays the pairs out.
  if (listed)
    lay_out_pairs();
  stats_.steps = s.steps, stats_.particle_steps = s.particle_steps;
  stats_.pair_evaluations = s.pair_evaluations, stats_.builds = s.builds;
}

} // namespace cfddem::dem
