#include "dem/islands_scheme.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <numeric>
#include <span>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.hpp"
#include "dem/contact_history.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/flag_dispatch.hpp"
#include "dem/islands_rank_part.hpp"
#include "dem/kick_drift_range.hpp"
#include "dem/scheme_support.hpp"
#include "dem/subiteration_length.hpp"
#include "dem/task_blocks.hpp"
#include "dem/verlet_passes.hpp"

namespace cfddem::dem {

IslandsScheme::IslandsScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer)
    : IslandsScheme(scene, particles, make_step_model(scene, particles), nullptr, timer) {}

IslandsScheme::IslandsScheme(const Scene& scene, ParticleStore& particles, const StepModel& model,
                             const Communicator* comm, PhaseTimer& timer)
    : scene_(scene), p_(particles), timer_(timer), geom_(scene.domain), model_(model) {
  if (model_.friction)
    p_.enable_rotation();
  nsubit_ = scene.dem.nsubit;
  auto_.on = scene.dem.nsubit_auto;
  if (auto_.on) {
    // The first interval's count: dem.nsubit's integer, at most the fine step's.
    auto_.interval = model_.interval;
    nsubit_ = std::min(nsubit_, length::most_subiterations(auto_.interval, model_.dt));
    auto_.next = nsubit_;
  }
  dt_sp_ = model_.interval / static_cast<double>(nsubit_);
  // The list only finds links and island members (cheap per entry) while its builds are the
  // scheme's largest cost: without dem.neighbor_skin, three times the explicit scheme's skin to
  // start with (measured on HCS 1222: 3.2x fewer builds, 30% less wall time than with the same
  // skin), then on one rank the one choose_skin() prices lowest at each expiry.
  one_.islands_skin = scene.dem.neighbor_skin > 0.0 ? model_.skin : 3.0 * model_.skin;
  one_.adapt_skin = !(scene.dem.neighbor_skin > 0.0);
  one_.nominal_skin = one_.islands_skin;
  one_.global_skin = model_.skin;
  skin_ = one_.islands_skin;
  // A link margin far above rounding and far below any gap that matters.
  margin_ = 1e-3 * model_.r_min;
  owned_ = p_.size();
  n_global_ = static_cast<std::int64_t>(owned_);
  hprev_.assign(owned_, 0.0);
  fine_.assign(owned_, 0.0);
  if (comm != nullptr && comm->size() > 1) {
    rank_ = std::make_unique<RankPart>(*comm);
    init_ranks();
  } else {
    double r_max = 0.0;
    for (double r : p_.radius)
      r_max = std::max(r_max, r);
    skin_cap_ = periodic_skin_cap(geom_, r_max);
    one_.d_max = 2.0 * r_max;
    one_.with_comm = comm != nullptr;
  }
}

IslandsScheme::~IslandsScheme() = default;

void IslandsScheme::start() {
  hprev_.assign(owned_, 0.0);
  fine_.assign(owned_, 0.0);
  st_.subits = 0;
  if (rank_)
    return;
  ln_.island_of.assign(p_.size(), kAlone);
  ln_.busy.clear();
  rebuild();
}

IslandsScheme::State IslandsScheme::save_state() {
  State s;
  if (rank_) {
    canonicalize();
    if (model_.friction)
      s.history = rank_->pending;
  } else if (one_.with_comm) { // an R-rank loop on one rank: no list, the canonical state
    if (model_.friction) {     // the history by ids, attached again at the next build
      if (one_.built)
        one_.pending.append(collect_history(p_, one_.list, p_.size(), hx_, hy_, hz_));
      hx_.clear(), hy_.clear(), hz_.clear();
      s.history = one_.pending;
    }
    one_.canonical = true, one_.built = false;
  }
  if (!rank_ && one_.built) {
    const VerletList& l = one_.list;
    s.offsets.assign(l.offsets().begin(), l.offsets().end());
    s.neighbors.assign(l.neighbors().begin(), l.neighbors().end());
    s.x_ref.assign(l.x_ref().begin(), l.x_ref().end());
    s.y_ref.assign(l.y_ref().begin(), l.y_ref().end());
    s.z_ref.assign(l.z_ref().begin(), l.z_ref().end());
    if (model_.friction)
      s.hx = hx_, s.hy = hy_, s.hz = hz_;
  }
  s.skin = skin_;
  if (!rank_)
    s.skin_choice = {one_.islands_skin, static_cast<double>(one_.build_subits),
                     static_cast<double>(one_.build_pairs), one_.measured ? 1.0 : 0.0};
  s.hprev.assign(hprev_.begin(), hprev_.begin() + static_cast<std::ptrdiff_t>(owned_));
  s.fine_subits.resize(owned_);
  for (std::size_t i = 0; i < owned_; ++i)
    s.fine_subits[i] = static_cast<std::int64_t>(fine_[i]);
  if (!rank_)
    s.size_hist = st_.size_hist;
  s.counters = st_.counters();
  s.max_overlap_ratio = st_.max_overlap_ratio;
  s.last_fine_fraction = st_.last_fine_fraction;
  if (rank_) {
    s.rank_counters = {st_.regrids,     st_.retries,        st_.expired_builds,
                       st_.span_subits, st_.span_particles, st_.span_parts};
    s.rank_values = {rank_->max_ratio_local};
  }
  if (auto_.on) {
    const AutoLength& a = auto_;
    s.length_counters = {nsubit_, a.next,       a.intervals,  a.subits_base,
                         a.q,     a.fine_count, a.global_now, a.next_global};
    s.length_values = {a.t0,       a.fine_sum, a.gas_dA,      a.gas_aref,   a.gas_ratio_max,
                       a.fine_avg, a.busy_avg, a.members_sum, a.members_avg};
    s.length_values.insert(s.length_values.end(), a.hist_avg.begin(), a.hist_avg.end());
    s.length_log = a.log;
    if (a.variable)
      s.clock = {a.interval, a.actual, a.previous};
  } else {
    s.clock = clock_.saved(st_.subits, dt_sp_);
  }
  return s;
}

void IslandsScheme::restore_state(State s) {
  const std::size_t n = owned_;
  bool fits = s.hprev.size() == n && s.fine_subits.size() == n && s.counters.size() == 12;
  if (rank_) {
    fits = fits && (s.rank_counters.empty() || s.rank_counters.size() == 6) &&
           (s.rank_values.empty() || s.rank_values.size() == 1);
    fits = rank_->comm.max(fits ? 0.0 : 1.0) == 0.0; // every rank throws alike
  } else {
    check_saved_list(n, s.offsets, s.neighbors, s.x_ref, s.y_ref, s.z_ref);
    // An R-rank checkpoint holds no histogram: it counts from the restart on.
    if (s.size_hist.empty())
      s.size_hist.assign(st_.size_hist.size(), 0);
    fits = fits && s.size_hist.size() == st_.size_hist.size() && s.skin > 0.0;
    if (model_.friction && !s.offsets.empty())
      fits = fits && s.hx.size() == s.neighbors.size() && s.hy.size() == s.neighbors.size() &&
             s.hz.size() == s.neighbors.size();
  }
  // dem.nsubit = "auto" needs its choice (the sub-iteration length is state); an integer
  // nsubit ignores one.
  fits = fits && (!auto_.on || ((s.length_counters.size() == 6 || s.length_counters.size() == 8) &&
                                s.length_values.size() >= 7 &&
                                // no choice logged yet only before the first interval (a state
                                // saved at t = 0, as particles entering the run save it)
                                (!s.length_log.empty() || s.length_counters[2] == 0) &&
                                s.length_log.size() % kChoiceColumns.size() == 0 &&
                                s.length_counters[0] >= 1 && s.length_counters[1] >= 1));
  // An adaptive fluid.dt's intervals (none saved: one length).
  if (auto_.on && !s.clock.empty()) {
    const bool ok = s.clock.size() == 3 && s.clock[0] > 0.0 && s.clock[1] > 0.0 && s.clock[2] > 0.0;
    fits = fits && ok;
    if (ok)
      auto_.interval = s.clock[0], auto_.actual = s.clock[1], auto_.previous = s.clock[2];
    auto_.variable = ok;
  } else if (!auto_.on) {
    fits = clock_.restore(s.clock) && fits;
  }
  if (!fits)
    throw RunError(auto_.on && s.length_counters.empty()
                       ? "checkpoint: written without dem.nsubit = \"auto\" (no sub-iteration "
                         "length in it): restart with the integer dem.nsubit it was written with"
                       : "checkpoint: the islands scheme's state does not fit the particles");
  if (auto_.on) {
    const auto& k = s.length_counters;
    const auto& v = s.length_values;
    nsubit_ = k[0], auto_.next = k[1], auto_.intervals = k[2], auto_.subits_base = k[3];
    auto_.q = k[4], auto_.fine_count = k[5];
    // Checkpoints written before the global mode was a choice hold 6 counters.
    auto_.global_now = k.size() > 6 && k[6] != 0, auto_.next_global = k.size() > 7 && k[7] != 0;
    auto_.t0 = v[0], auto_.fine_sum = v[1], auto_.gas_dA = v[2], auto_.gas_aref = v[3];
    auto_.gas_ratio_max = v[4], auto_.fine_avg = v[5], auto_.busy_avg = v[6];
    // The histogram has one entry per count 0 .. m_hi; before the members were measured two
    // values fewer preceded it (their means start from the nominal ones).
    const auto hist =
        static_cast<std::size_t>(length::most_subiterations(auto_.interval, model_.dt) + 1);
    const bool members = v.size() >= 9 + hist;
    auto_.members_sum = members ? v[7] : v[1], auto_.members_avg = members ? v[8] : v[5];
    auto_.hist_avg.assign(v.begin() + (members ? 9 : 7), v.end());
    auto_.log = std::move(s.length_log);
    dt_sp_ = (auto_.variable ? auto_.actual : auto_.interval) / static_cast<double>(nsubit_);
  }
  hprev_ = std::move(s.hprev);
  fine_.assign(s.fine_subits.begin(), s.fine_subits.end());
  st_.set_counters(s.counters);
  st_.max_overlap_ratio = s.max_overlap_ratio;
  st_.last_fine_fraction = s.last_fine_fraction;
  if (rank_) {
    if (!s.rank_counters.empty()) {
      const auto& k = s.rank_counters;
      st_.regrids = k[0], st_.retries = k[1], st_.expired_builds = k[2], st_.span_subits = k[3];
      st_.span_particles = k[4], st_.span_parts = k[5];
    }
    rank_->max_ratio_local = s.rank_values.empty() ? st_.max_overlap_ratio : s.rank_values[0];
    canonicalize();
    // Every rank may be handed every record: each routes those of the particles it holds.
    rank_->pending = model_.friction ? std::move(s.history) : ContactHistory{};
    return;
  }
  one_.built = !s.offsets.empty();
  if (model_.friction) {
    if (one_.built)
      hx_ = std::move(s.hx), hy_ = std::move(s.hy), hz_ = std::move(s.hz);
    else
      hx_.clear(), hy_.clear(), hz_.clear();
    // A canonical state's records (by ids, no list): attached at the next build.
    one_.pending = std::move(s.history);
  }
  if (one_.built)
    one_.list.restore(std::move(s.offsets), std::move(s.neighbors), std::move(s.x_ref),
                      std::move(s.y_ref), std::move(s.z_ref), s.skin, geom_);
  one_.canonical = one_.with_comm;
  one_.half_stale = true;
  one_.moved = std::numeric_limits<double>::infinity(); // unknown until the next build
  skin_ = s.skin;
  if (s.skin_choice.size() == 4 && s.skin_choice[0] > 0.0) {
    one_.islands_skin = s.skin_choice[0];
    one_.build_subits = static_cast<std::int64_t>(s.skin_choice[1]);
    one_.build_pairs = static_cast<std::int64_t>(s.skin_choice[2]);
    one_.measured = s.skin_choice[3] != 0.0;
  } else {
    one_.measured = false; // an older checkpoint: the next list's life is measured afresh
  }
  st_.size_hist = std::move(s.size_hist);
  ln_.island_of.assign(n, kAlone);
  ln_.busy.clear();
}

std::vector<std::int64_t> IslandsScheme::Stats::counters() const {
  return {subits,           particle_steps, pair_evaluations, builds,       overlap_violations,
          bound_violations, global_subits,  iv_fine,          iv_particles, iv_steps,
          iv_min,           iv_max};
}

void IslandsScheme::Stats::set_counters(const std::vector<std::int64_t>& k) {
  subits = k[0], particle_steps = k[1], pair_evaluations = k[2], builds = k[3];
  overlap_violations = k[4], bound_violations = k[5], global_subits = k[6];
  iv_fine = k[7], iv_particles = k[8], iv_steps = k[9], iv_min = k[10], iv_max = k[11];
}

void IslandsScheme::Stats::add_interval(std::int64_t fine, std::int64_t n, std::int64_t K) {
  iv_fine += fine, iv_particles += n, iv_steps += (n - fine) + fine * K;
  iv_min = std::min(iv_min, fine < n ? std::int64_t{1} : K);
  iv_max = std::max(iv_max, fine > 0 ? K : std::int64_t{1});
}

void IslandsScheme::set_external_force(std::span<const double> fx, std::span<const double> fy,
                                       std::span<const double> fz) {
  if (rank_)
    return set_external_force_ranks(fx, fy, fz);
  ext_.set(fx, fy, fz, p_.size());
}

void IslandsScheme::replace_external_force(std::span<const double> fx, std::span<const double> fy,
                                           std::span<const double> fz) {
  if (auto_.on)
    note_gas_change(fx, fy, fz); // collective
  // hprev_ was sized at construction; after a checkpoint restore it is the saved one. A force of
  // the wrong size is refused by set_external_force (on every rank).
  if ((ext_.active() || !fx.empty()) && (fx.empty() || fx.size() == owned_) &&
      hprev_.size() >= owned_)
    settle_owed_half_kick(
        std::span<double>(p_.vx).first(owned_), std::span<double>(p_.vy).first(owned_),
        std::span<double>(p_.vz).first(owned_), p_.inv_mass,
        std::span<const double>(hprev_).first(owned_), ext_.x, ext_.y, ext_.z, fx, fy, fz);
  set_external_force(fx, fy, fz);
}

// The Verlet list sorts the store by cell: the per-particle state follows.
void IslandsScheme::rebuild() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  // With friction the tangential history follows its pairs by particle ids (as the explicit
  // scheme carries it across a rebuild).
  ContactHistory held;
  if (model_.friction) {
    held = std::move(one_.pending);
    one_.pending = ContactHistory{};
    if (one_.built)
      held.append(collect_history(p_, one_.list, p_.size(), hx_, hy_, hz_));
  }
  one_.list.build(p_, geom_, skin_);
  one_.half_stale = true;
  if (model_.friction)
    attach_history(std::move(held), p_, one_.list, p_.size(), hx_, hy_, hz_);
  const auto order = one_.list.order();
  if (!order.empty()) {
    std::vector<double> h(order.size());
    for (std::size_t k = 0; k < order.size(); ++k)
      h[k] = hprev_[order[k]];
    hprev_.swap(h);
    for (std::size_t k = 0; k < order.size(); ++k)
      h[k] = fine_[order[k]];
    fine_.swap(h);
    ext_.permute(order);
  }
  one_.built = true;
  one_.moved = 0.0;
  ++st_.builds;
  one_.measured = !global_;
  one_.build_subits = st_.subits, one_.build_pairs = st_.pair_evaluations;
}

namespace {
// The islands skin's cost model (choose_skin), in instructions (callgrind, HCS 1222 at skins of
// 75 to 150 um, the phi 0.3 gas and the walled box): a build costs about 1000 per particle (the
// binning, the store's sort, the cell pairs) and 370 per list entry; every sub-iteration scans
// each entry (the link rounds, the length choice's histogram) for about 60, and a pair
// evaluation inside an island costs about 30.
constexpr double kBuildPerParticle = 1000.0, kBuildPerEntry = 370.0, kScanPerEntry = 60.0;
constexpr double kPerPairEvaluation = 30.0;
// A new skin must be priced this much below the current one (no flip-flop on noise).
constexpr double kSkinSwitch = 0.95;
} // namespace

// At an islands list's expiry, the skin for the next list (dem.neighbor_skin = "auto", one
// rank). The list lasted `life` sub-iterations at skin s: it expires when the two largest
// reaches (displacement plus bound x dt_sp) add up to s, so at skin s' it lasts about
// life (s' - r_b) / (s - r_b), r_b = 2 b_max dt_sp; its entries and the pair work in islands
// grow as the volume within d_max + s', ((d_max + s') / (d_max + s))^3. Per sub-iteration a
// skin costs (1000 n + 370 E) / life + 60 E + 30 P (E entries, P pair evaluations per
// sub-iteration); the candidates are 1 to 8 explicit skins, each lasting a sub-iteration at
// least and within the list's periodic bound. A dilute gas lengthens the list (builds dominate), a
// dense one shortens it (its entries are evaluated at every fine step). Counts only: the same
// choice on any thread count.
void IslandsScheme::choose_skin() {
  if (!one_.adapt_skin || !one_.measured || global_)
    return;
  const auto life = static_cast<double>(st_.subits - one_.build_subits);
  const double s = skin_, r_b = 2.0 * one_.bound_max * dt_sp_;
  if (!(life >= 1.0) || !(s > r_b))
    return;
  const auto n = static_cast<double>(p_.size());
  const auto E = static_cast<double>(one_.list.neighbors().size());
  const double P = static_cast<double>(st_.pair_evaluations - one_.build_pairs) / life;
  auto cost = [&](double s2) {
    const double g = std::pow((one_.d_max + s2) / (one_.d_max + s), 3.0);
    const double lasts = std::max(1.0, life * (s2 - r_b) / (s - r_b));
    return (kBuildPerParticle * n + kBuildPerEntry * E * g) / lasts + kScanPerEntry * E * g +
           kPerPairEvaluation * P * g;
  };
  double best = s, c_best = kSkinSwitch * cost(s);
  for (const double m : {1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0}) {
    const double s2 = m * one_.global_skin;
    if (!(s2 > 1.1 * r_b) || !(s2 < skin_cap_) ||
        !VerletList::skin_fits(geom_, 0.5 * one_.d_max, s2))
      continue;
    if (const double c = cost(s2); c < c_best)
      best = s2, c_best = c;
  }
  one_.islands_skin = skin_ = best;
}

// The canonical state of a one-rank run with a communicator: the store in id order (the order
// an R-rank checkpoint restores it in), no list, every particle alone.
void IslandsScheme::canonical_order() {
  const std::size_t n = p_.size();
  std::vector<std::uint32_t> order(n);
  std::iota(order.begin(), order.end(), 0U);
  std::sort(order.begin(), order.end(),
            [&](std::uint32_t a, std::uint32_t b) { return p_.id[a] < p_.id[b]; });
  p_.permute(order);
  std::vector<double> h(n);
  for (std::size_t k = 0; k < n; ++k)
    h[k] = hprev_[order[k]];
  hprev_.swap(h);
  for (std::size_t k = 0; k < n; ++k)
    h[k] = fine_[order[k]];
  fine_.swap(h);
  ext_.permute(order);
  for (const std::uint32_t v : ln_.busy)
    ln_.island_of[v] = kAlone;
  ln_.busy.clear();
  one_.built = false;
  one_.canonical = false;
}

void IslandsScheme::speed_bounds() {
  ln_.bound.resize(p_.size());
  islands::speed_bounds(cols(), p_.size(), model_.gravity, dt_sp_, ln_.bound.data());
}

// True when a pair missing from the list could touch within the sub-iteration: a pair outside
// the list was farther apart than r_i + r_j + skin at the build, so it needs the two particles'
// reaches (displacement since the build plus bound over the sub-iteration) to add up to the skin:
// the two largest reaches are checked against it (the list stays valid twice as long as with
// skin/2 per particle when a few particles are fast).
bool IslandsScheme::list_expires() {
  // The cheap bound first: no particle has moved farther than one_.moved since the build, nor
  // can it move farther than bound_max dt_sp in this sub-iteration, so while twice their sum is
  // below the skin the exact pass below cannot expire the list (the same answer, one max over
  // the bounds instead of a square root per particle).
  double b_max = 0.0;
  for (const double b : ln_.bound)
    b_max = std::max(b_max, b);
  one_.bound_max = b_max;
  if (2.0 * (one_.moved + b_max * dt_sp_) < skin_)
    return false;
  const VerletList& l = one_.list;
  const islands::Reaches r = islands::largest_reaches<false>(
      p_.x.data(), p_.y.data(), p_.z.data(), l.x_ref().data(), l.y_ref().data(), l.z_ref().data(),
      ln_.bound.data(), dt_sp_, p_.size());
  return !(r.first + r.second < skin_);
}

// Links with the current bounds, and the islands of the linked and wall-tied particles
// (ln_.busy, increasing); every other particle is alone (ln_.island_of = kAlone).
//
// The first call of a link() scans every row. Later rounds only raise bounds, and a link test
// only grows with the two bounds (floating-point addition, multiplication and comparison are
// monotone), so every link stays and a pair can become linked only if one of its particles had
// its bound raised (ln_.changed): those rows alone are scanned, and the new links are merged into
// the list in scan order (by the pair's position in the lower particle's row, ln_.ek), so the list
// is exactly what a full scan would give.
void IslandsScheme::make_links(bool incremental) {
  const std::size_t n = p_.size();
  const std::uint32_t* __restrict off = one_.list.offsets().data();
  const std::uint32_t* __restrict nb = one_.list.neighbors().data();
  const std::uint32_t* __restrict wrap = one_.list.wrap_begin().data();
  const double* __restrict x = p_.x.data();
  const double* __restrict y = p_.y.data();
  const double* __restrict z = p_.z.data();
  const double* __restrict rad = p_.radius.data();
  const double* __restrict bnd = ln_.bound.data();
  const DomainGeometry& g = geom_;
  const double dt = dt_sp_, margin = margin_;
  // The link test of pair (i, j), i < j. Pairs that do not cross a periodic face (before the
  // row's wrap_begin) need no image: image() returns their separation unchanged.
  auto linked = [&](std::uint32_t i, std::uint32_t j, bool crosses) {
    double dx = x[j] - x[i], dy = y[j] - y[i], dz = z[j] - z[i];
    if (crosses)
      dx = g.image(dx, 0), dy = g.image(dy, 1), dz = g.image(dz, 2);
    return islands::may_touch(dx * dx + dy * dy + dz * dz, bnd[i], bnd[j], rad[i], rad[j], dt,
                              margin);
  };
  auto tied = [&](std::uint32_t i, int a) {
    const double pos = a == 0 ? x[i] : a == 1 ? y[i] : z[i];
    return islands::may_reach_wall(pos, g.lo[a], g.hi[a], rad[i], bnd[i], dt, margin);
  };
  auto tied_to_cylinder = [&](std::uint32_t i) {
    return islands::may_reach_cylinder(g, x[i], y[i], z[i], rad[i], bnd[i], dt, margin);
  };
  unsigned char* __restrict is_link = nullptr;
  if (!incremental) {
    ln_.linked_entry.assign(off[n], 0);
    is_link = ln_.linked_entry.data();
    // Only particles with a non-empty row (increasing): most rows of a dilute scene are empty.
    // Blocks of rows are scanned as tasks (each marks its own entries) and their links joined in
    // block order: the list is the serial scan's for any thread count.
    const std::span<const std::uint32_t> active = one_.list.active();
    constexpr std::size_t kRows = 2048;
    const std::size_t nblocks = (active.size() + kRows - 1) / kRows;
    if (ln_.blocks.size() < nblocks)
      ln_.blocks.resize(nblocks);
    auto scan = [&](std::size_t q) {
      Links::BlockLinks& bl = ln_.blocks[q];
      bl.a.clear(), bl.b.clear(), bl.k.clear();
      const std::size_t r1 = std::min(active.size(), (q + 1) * kRows);
      for (std::size_t r = q * kRows; r < r1; ++r) {
        const std::uint32_t i = active[r];
        const std::uint32_t kw = wrap[i], ke = off[i + 1];
        for (std::uint32_t k = off[i]; k < ke; ++k) {
          const std::uint32_t j = nb[k];
          if (j > i && linked(i, j, k >= kw))
            bl.a.push_back(i), bl.b.push_back(j), bl.k.push_back(k), is_link[k] = 1;
        }
      }
    };
    if (nblocks > 1)
      tbb::parallel_for(std::size_t{0}, nblocks, scan);
    else if (nblocks == 1)
      scan(0);
    std::size_t total = 0;
    for (std::size_t q = 0; q < nblocks; ++q)
      total += ln_.blocks[q].a.size();
    ln_.ea.resize(total), ln_.eb.resize(total), ln_.ek.resize(total);
    for (std::size_t q = 0, at = 0; q < nblocks; ++q) {
      const Links::BlockLinks& bl = ln_.blocks[q];
      const auto to = static_cast<std::ptrdiff_t>(at);
      std::copy(bl.a.begin(), bl.a.end(), ln_.ea.begin() + to);
      std::copy(bl.b.begin(), bl.b.end(), ln_.eb.begin() + to);
      std::copy(bl.k.begin(), bl.k.end(), ln_.ek.begin() + to);
      at += bl.a.size();
    }
    ln_.tied.clear();
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a])
        continue;
      for (std::uint32_t i = 0; i < n; ++i)
        if (tied(i, a))
          ln_.tied.push_back(i);
    }
    if (g.cylinder)
      for (std::uint32_t i = 0; i < n; ++i)
        if (tied_to_cylinder(i))
          ln_.tied.push_back(i);
  } else {
    // New links from the rows of the raised particles, keyed by their position in the lower
    // particle's row. A key already linked (before or earlier in this scan: a pair both of whose
    // particles were raised is met twice) is skipped, so new_k holds each new link once and its
    // sort is over the new links alone (in a dense bed the raised rows hold mostly old links).
    // A pair of two raised particles is tested from the lower one's row only: the search for
    // its position in the lower row is left to the pairs with an unraised lower particle.
    is_link = ln_.linked_entry.data();
    ln_.mark.resize(n, 0);
    for (const std::uint32_t c : ln_.changed)
      ln_.mark[c] = 1;
    ln_.new_k.clear();
    for (const std::uint32_t c : ln_.changed)
      for (std::uint32_t k = off[c]; k < off[c + 1]; ++k) {
        const std::uint32_t j = nb[k];
        if (j > c) {
          if (!is_link[k] && linked(c, j, k >= wrap[c]))
            ln_.new_k.push_back(k), is_link[k] = 3; // 2: new in this round
        } else if (!ln_.mark[j]) {
          // The pair's position in row j (rows hold both directions).
          std::uint32_t kj = off[j];
          while (nb[kj] != c)
            ++kj;
          if (!is_link[kj] && linked(j, c, kj >= wrap[j]))
            ln_.new_k.push_back(kj), is_link[kj] = 3;
        }
      }
    for (const std::uint32_t c : ln_.changed)
      ln_.mark[c] = 0;
    // Increasing: a sort when the new links are few, else one pass over the entries' marks.
    if (ln_.new_k.size() * 8 > off[n]) {
      ln_.new_k.clear();
      for (std::uint32_t k = 0; k < off[n]; ++k)
        if (is_link[k] & 2)
          ln_.new_k.push_back(k), is_link[k] = 1;
    } else {
      std::sort(ln_.new_k.begin(), ln_.new_k.end());
      for (const std::uint32_t k : ln_.new_k)
        is_link[k] = 1;
    }
    // Merge (ln_.ek increasing): new_k holds no key of ek (linked_entry kept them out).
    std::size_t q = ln_.ek.size();
    std::size_t added = ln_.new_k.size();
    if (added > 0) {
      ln_.ea.resize(q + added), ln_.eb.resize(q + added), ln_.ek.resize(q + added);
      // Back to front: the merged list in place.
      std::size_t w = q + added;
      while (added > 0) {
        const std::uint32_t kn = ln_.new_k[added - 1];
        if (q > 0 && ln_.ek[q - 1] > kn) {
          --q, --w;
          ln_.ea[w] = ln_.ea[q], ln_.eb[w] = ln_.eb[q], ln_.ek[w] = ln_.ek[q];
        } else {
          --added, --w;
          // Owner of position kn: the last row starting at or before it.
          const auto* row = std::upper_bound(off, off + n + 1, kn) - 1;
          ln_.ea[w] = static_cast<std::uint32_t>(row - off), ln_.eb[w] = nb[kn], ln_.ek[w] = kn;
        }
      }
    }
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a])
        continue;
      for (const std::uint32_t c : ln_.changed)
        if (tied(c, a))
          ln_.tied.push_back(c); // duplicates are harmless (ln_.busy is a set)
    }
    if (g.cylinder)
      for (const std::uint32_t c : ln_.changed)
        if (tied_to_cylinder(c))
          ln_.tied.push_back(c);
  }
  ln_.form(n, kGlobalFraction * static_cast<double>(n)); // false: link() goes global
}

// Islands over the busy particles: the ends of the links (ea, eb) and the tied particles, unique
// (marked), increasing; each island's members and each busy particle's island (island_of; the
// others keep kAlone). Both paths form their islands here.
bool IslandsScheme::Links::form(std::size_t n, double limit) {
  for (std::uint32_t v : busy)
    island_of[v] = kAlone; // reset the last sub-iteration's
  busy.clear();
  mark.resize(n, 0);
  for (const auto* list : {&ea, &eb, &tied})
    for (const std::uint32_t v : *list)
      if (!mark[v])
        mark[v] = 1, busy.push_back(v);
  for (const std::uint32_t v : busy)
    mark[v] = 0;
  if (busy.size() > limit)
    return false;
  std::sort(busy.begin(), busy.end());
  for (std::uint32_t k = 0; k < busy.size(); ++k)
    island_of[busy[k]] = k; // local index
  la.resize(ea.size()), lb.resize(eb.size());
  for (std::size_t q = 0; q < ea.size(); ++q)
    la[q] = island_of[ea[q]], lb[q] = island_of[eb[q]];
  partition::connected_components(busy.size(), la, lb, islands, uf_scratch);
  for (std::uint32_t k = 0; k < busy.size(); ++k)
    island_of[busy[k]] = islands.label[k];
  return true;
}

// Per island: the springs' potential energy of current overlaps (links, then walls), the
// members' kinetic energy at their own bounds, the lightest mass, the largest external
// acceleration and half step, over the owned members (busy particles below `owned`). Both paths
// sum here.
void IslandsScheme::island_sums(std::size_t owned) {
  with_flags([&](auto ext, auto fr) { island_sums_of<ext, fr>(owned); }, ext_.active(),
             model_.friction);
}

template <bool External, bool Friction> void IslandsScheme::island_sums_of(std::size_t owned) {
  const DomainGeometry& g = geom_;
  const std::uint32_t nc = ln_.islands.count();
  ln_.energy.assign(nc, 0.0);
  ln_.m_min.assign(nc, std::numeric_limits<double>::infinity());
  ln_.a_max.assign(nc, 0.0);
  ln_.hp_max.assign(nc, 0.0);
  for (std::size_t q = 0; q < ln_.ea.size(); ++q) {
    const std::uint32_t i = ln_.ea[q], j = ln_.eb[q];
    const double dx = g.image(p_.x[j] - p_.x[i], 0), dy = g.image(p_.y[j] - p_.y[i], 1),
                 dz = g.image(p_.z[j] - p_.z[i], 2);
    const double delta = p_.radius[i] + p_.radius[j] - std::sqrt(dx * dx + dy * dy + dz * dz);
    if (delta > 0.0)
      ln_.energy[ln_.island_of[i]] += 0.5 * model_.pair.k * delta * delta;
    if constexpr (Friction) {
      // The tangential spring of the pair (i's entry; j's holds the same vector negated): what a
      // sticking contact has stored and can give back.
      const std::uint32_t k = ln_.ek[q];
      const double xi2 = hx_[k] * hx_[k] + hy_[k] * hy_[k] + hz_[k] * hz_[k];
      ln_.energy[ln_.island_of[i]] += 0.5 * model_.pair_t.k_t * xi2;
    }
  }
  const islands::Columns c = cols();
  for (const std::uint32_t i : ln_.busy) {
    if (i >= owned)
      break; // busy is increasing: ghosts come last
    const std::uint32_t q = ln_.island_of[i];
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a])
        continue;
      const double pos = a == 0 ? p_.x[i] : a == 1 ? p_.y[i] : p_.z[i];
      const double delta = p_.radius[i] - std::min(pos - g.lo[a], g.hi[a] - pos);
      if (delta > 0.0)
        ln_.energy[q] += 0.5 * model_.wall.k * delta * delta;
    }
    ln_.energy[q] += 0.5 * p_.mass[i] * ln_.own_bound[i] * ln_.own_bound[i];
    if constexpr (Friction) // rotational energy I |w|^2 / 2, I = 1 / inv_inertia
      ln_.energy[q] += 0.5 * (p_.wx[i] * p_.wx[i] + p_.wy[i] * p_.wy[i] + p_.wz[i] * p_.wz[i]) /
                       p_.inv_inertia[i];
    ln_.m_min[q] = std::min(ln_.m_min[q], p_.mass[i]);
    ln_.a_max[q] = std::max(ln_.a_max[q], islands::acceleration<External>(c, model_.gravity, i));
    ln_.hp_max[q] = std::max(ln_.hp_max[q], hprev_[i]);
  }
  if (g.cylinder) // the curved wall's spring, as the planar walls' above
    for (const std::uint32_t i : ln_.busy) {
      if (i >= owned)
        break;
      const double delta = -cylinder_gap(g, p_.x[i], p_.y[i], p_.z[i], p_.radius[i]);
      if (delta > 0.0)
        ln_.energy[ln_.island_of[i]] += 0.5 * model_.wall.k * delta * delta;
    }
}

// Islands whose bounds account for the energy contacts can move inside them: link with the
// particles' own bounds, raise every member of an island to the island's s_max (from the
// members' own bounds and the springs' energy), link again, until the islands stop changing.
// Islands only merge from round to round (bounds only grow), so this ends.
void IslandsScheme::link() {
  const std::size_t n = p_.size();
  // Own bounds are kept only for busy particles (the only ones raised), saved the first time a
  // particle is busy in this call: busy sets only grow from round to round, so ln_.bound still
  // holds its own bound then. A stamp per call marks the saved ones (no O(N) copy or reset).
  ln_.own_bound.resize(n);
  ln_.own_stamp.resize(n, 0);
  if (++ln_.stamp == 0)
    std::fill(ln_.own_stamp.begin(), ln_.own_stamp.end(), 0u), ln_.stamp = 1;
  global_ = false;
  for (int round = 0;; ++round) {
    make_links(round > 0 && one_.incremental);
    if (ln_.busy.size() > kGlobalFraction * static_cast<double>(n)) {
      // A dense bed: most particles are linked, the energy bounds of a large island are loose,
      // and the islands would cost more than they save. Step everyone finely instead.
      global_ = true;
      return;
    }
    if (round > 0 && ln_.busy == ln_.busy_before && ln_.islands.label == ln_.label_before)
      break;
    for (const std::uint32_t i : ln_.busy)
      if (ln_.own_stamp[i] != ln_.stamp)
        ln_.own_stamp[i] = ln_.stamp, ln_.own_bound[i] = ln_.bound[i];
    island_sums(n);
    ln_.changed.clear();
    for (const std::uint32_t i : ln_.busy) {
      const std::uint32_t c = ln_.island_of[i];
      const double b =
          std::max(ln_.own_bound[i], islands::island_speed(ln_.energy[c], ln_.m_min[c],
                                                           ln_.a_max[c], ln_.hp_max[c], dt_sp_));
      if (b != ln_.bound[i])
        ln_.changed.push_back(i);
      ln_.bound[i] = b;
    }
    if (ln_.changed.empty())
      break;
    ln_.busy_before = ln_.busy;
    ln_.label_before = ln_.islands.label;
  }
}

// The Verlet list's part of a sub-iteration: speed bounds and link rounds over a list that
// holds every pair that can link (else a build, with the skin chosen or grown), or the global
// mode with the explicit scheme's skin.
void IslandsScheme::find_islands_one() {
  if (one_.canonical)
    canonical_order();
  if (!one_.built)
    rebuild();
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  bool fresh = false;
  for (;;) {
    // "auto" chose the global mode for this interval: no bounds or links. Else link() says.
    global_ = auto_.global_now;
    if (!global_) {
      speed_bounds();
      link();
    }
    if (global_) {
      // The explicit scheme's skin: the list then holds what the explicit list holds.
      if (skin_ != one_.global_skin)
        skin_ = one_.global_skin, rebuild();
      break;
    }
    if (skin_ < one_.islands_skin) {
      skin_ = one_.islands_skin;
      rebuild();
      fresh = true;
      continue;
    }
    if (!list_expires())
      break;
    if (!fresh) {
      choose_skin();
    } else {
      // Even a fresh list is too short for these bounds: grow the skin (kept for the run).
      double need = 0.0;
      for (double b : ln_.bound)
        need = std::max(need, 2.2 * b * dt_sp_);
      if (!(need < skin_cap_))
        throw RunError(travel_beyond_skin_cap(time(), 0.5 * need, skin_cap_, "raise dem.nsubit"));
      skin_ = std::max(need, 2.0 * skin_ < skin_cap_ ? 2.0 * skin_ : need);
    }
    rebuild();
    fresh = true;
  }
}

islands::ContactView IslandsScheme::contact_view() {
  // R ranks: rows over owned + ghosts, separations by the minimum image (no wrap part).
  const islands::Rows rows =
      rank_ ? islands::Rows{rank_->rows.off(), rank_->rows.nb(), {}}
            : islands::Rows{one_.list.offsets(), one_.list.neighbors(), one_.list.wrap_begin()};
  islands::ContactView v{cols(), rows, ln_.island_of, &geom_, &model_, {}, {}, {}};
  if (model_.friction)
    v.hx = hx_, v.hy = hy_, v.hz = hz_;
  return v;
}

// A sub-iteration where a large part of the particles is linked (a dense bed): every particle
// takes the K fine steps together, as the explicit scheme would, all partners read live (no
// bound is needed: nothing flies free). The list is checked after every step, as the explicit
// scheme checks it, and rebuilt when some particle moved more than skin/2.
void IslandsScheme::global_steps(bool record) {
  with_flags([&](auto ext, auto fr) { run_global_steps<ext, fr>(record); }, ext_.active(),
             model_.friction);
}

template <bool External> void IslandsScheme::record_start_velocities(std::size_t n) {
  const StepModel& m = model_;
  // Each particle on its own: ranges of the static partition (the same values on any threads).
  for_particle_ranges(n, [&](std::size_t a, std::size_t b) {
    for (std::size_t i = a; i < b; ++i) {
      double ex = 0.0, ey = 0.0, ez = 0.0;
      if constexpr (External)
        ex = ext_.x[i], ey = ext_.y[i], ez = ext_.z[i];
      rec_.vx[i] = p_.vx[i] + ((p_.fx[i] + ex) * p_.inv_mass[i] + m.gravity[0]) * hprev_[i];
      rec_.vy[i] = p_.vy[i] + ((p_.fy[i] + ey) * p_.inv_mass[i] + m.gravity[1]) * hprev_[i];
      rec_.vz[i] = p_.vz[i] + ((p_.fz[i] + ez) * p_.inv_mass[i] + m.gravity[2]) * hprev_[i];
    }
  });
}
template void IslandsScheme::record_start_velocities<false>(std::size_t);
template void IslandsScheme::record_start_velocities<true>(std::size_t);

template <bool External, bool Friction> void IslandsScheme::run_global_steps(bool record) {
  const std::size_t n = p_.size();
  const StepModel& m = model_;
  constexpr std::size_t kBlock = 1024;
  const std::size_t blocks = (n + kBlock - 1) / kBlock;
  // Per block of the update: the sign bit set when some particle moved beyond skin/2.
  std::vector<std::uint64_t> moved_of(blocks, 0);
  double h_before = 0.0;
  one_.clear_all = true; // the islands' steps since the last global step left forces behind
  {
    // The check after each step below serves the next one: the last global sub-iteration's last
    // step is checked here (an islands' sub-iteration before this one checked its own reaches).
    const auto xr = one_.list.x_ref(), yr = one_.list.y_ref(), zr = one_.list.z_ref();
    const double half_skin2 = 0.25 * skin_ * skin_;
    bool expired = false;
    for (std::size_t i = 0; i < n; ++i) {
      const double dx = p_.x[i] - xr[i], dy = p_.y[i] - yr[i], dz = p_.z[i] - zr[i];
      expired = expired || !(dx * dx + dy * dy + dz * dz <= half_skin2);
    }
    if (expired)
      rebuild();
  }
  for (std::int64_t k = 0; k < steps_.K; ++k) {
    const double hk = k + 1 == steps_.K ? steps_.h_last : steps_.h;
    if (k > 0) {
      std::uint64_t moved = 0;
      for (const std::uint64_t b : moved_of)
        moved |= b;
      if (moved >> 63) {
        if constexpr (Friction)
          mirror_history();
        rebuild();
      }
    }
    global_contacts<Friction>(hk);
    if (record && k == 0)
      record_start_velocities<External>(n);
    const double half = 0.5 * hk;
    const double s_common = 0.5 * h_before + half;
    const auto xr = one_.list.x_ref(), yr = one_.list.y_ref(), zr = one_.list.z_ref();
    const double half_skin2 = 0.25 * skin_ * skin_;
    const KickDriftColumns columns =
        kick_drift_columns(p_, xr, yr, zr, External ? &ext_ : nullptr, hprev_);
    KickDriftStep st;
    st.s = s_common, st.h = hk, st.g = m.gravity, st.half_skin2 = half_skin2;
    for_particle_blocks(blocks, [&](std::size_t b) {
      const std::size_t i0 = b * kBlock, i1 = std::min(n, (b + 1) * kBlock);
      if constexpr (Friction) // the spin's kick over the same span (before h_prev changes)
        for (std::size_t i = i0; i < i1; ++i) {
          const double si = p_.inv_inertia[i] * (k == 0 ? hprev_[i] + half : s_common);
          p_.wx[i] += p_.tx[i] * si, p_.wy[i] += p_.ty[i] * si, p_.wz[i] += p_.tz[i] * si;
        }
      KickDriftFlags flags;
      if (k == 0) // each particle's own first kick h_prev + h/2 (st.s unused)
        kick_drift_range<External, true>(columns.range(i0, i1), st, flags);
      else
        kick_drift_range<External>(columns.range(i0, i1), st, flags);
      const std::uint64_t still = flags.still;
      moved_of[b] = ~still; // sign bit set: some particle beyond skin/2
    });
    // The orb kernel leaves h_prev alone after the first step: the last step's half step.
    if (k > 0 && k + 1 == steps_.K)
      for (double& h : hprev_)
        h = half;
    h_before = hk;
  }
  if constexpr (Friction)
    mirror_history();
}

// The global steps' contact and wall forces, as the explicit scheme computes them: each pair of
// the list once (the full rows' partners of higher index, laid out flat after every build)
// through its pair passes (dem/verlet_passes.hpp), then the walls of the particles that can reach
// one before the next build. The scatter sums each particle's contacts in its full row's order,
// so the forces are those of a pass over full rows, bit for bit. With friction the tangential
// spring of a pair lives in both its rows' entries (the islands' steps read it from either end):
// the pass advances the upper entry, and the lower one later takes its negative (mirror_history:
// the same arithmetic from the other end gives exactly that, every term changes sign). Adds to
// the counters.
template <bool Friction> void IslandsScheme::global_contacts(double hk) {
  OneRank& o = one_;
  const std::size_t n = p_.size();
  if (o.half_stale) {
    o.head_pairs.build<false, true>(o.list, o.list.active(), kPairBlock, Friction);
    o.tail_pairs.build<true, true>(o.list, o.list.tail_rows(), kPairBlock, Friction);
    if constexpr (Friction) {
      mirror_entries(o.list, o.head_pairs, o.head_mirror);
      mirror_entries(o.list, o.tail_pairs, o.tail_mirror);
    }
    near_walls(p_, n, o.list, geom_, o.list.skin(), o.near_wall);
    o.half_stale = false;
    o.clear_all = true;
  }
  // Clear the forces that are not zero, as the explicit scheme does: after a build or at a
  // sub-iteration's first step (the islands' steps leave forces behind) every particle's, else
  // those of the last step's contacts and of the particles near a wall.
  if (o.clear_all) {
    const auto nn = static_cast<std::ptrdiff_t>(n);
    for (std::vector<double>* c : {&p_.fx, &p_.fy, &p_.fz})
      std::fill(c->begin(), c->begin() + nn, 0.0);
    if constexpr (Friction)
      for (std::vector<double>* c : {&p_.tx, &p_.ty, &p_.tz})
        std::fill(c->begin(), c->begin() + nn, 0.0);
    o.clear_all = false;
  } else {
    clear_contact_forces<Friction>(p_, n, std::span<const PairContacts>(o.head).first(o.nh),
                                   std::span<const PairContacts>(o.tail).first(o.nt), o.near_wall);
  }
  StepReport rep;
  const HistoryColumns h{hx_, hy_, hz_};
  const std::size_t nh =
      pair_pass<Friction, false, true>(p_, o.head_pairs, h, geom_, model_, hk, o.head, rep);
  const std::size_t nt =
      pair_pass<Friction, true, true>(p_, o.tail_pairs, h, geom_, model_, hk, o.tail, rep);
  scatter_contacts<Friction>(p_, n, std::span<const PairContacts>(o.head).first(nh),
                             std::span<const PairContacts>(o.tail).first(nt));
  o.nh = nh, o.nt = nt;
  // The walls over the same particle ranges as the scatter (the particles' lines stay with the
  // thread that summed their contacts), tallied into the pair passes' report (a maximum and a
  // count, whatever the order of the ranges).
  const islands::ContactView view = contact_view();
  rep.join(reduce_particle_ranges<StepReport>(n, [&](std::size_t a, std::size_t b) {
    StepReport t;
    with_flags(
        [&](auto cyl) {
          constexpr bool Cylinder = decltype(cyl)::value;
          for (const std::uint32_t i : listed_in(o.near_wall, a, b)) {
            double w[3] = {0.0, 0.0, 0.0}, tq[3] = {0.0, 0.0, 0.0};
            if constexpr (Friction) {
              w[0] = p_.wx[i], w[1] = p_.wy[i], w[2] = p_.wz[i];
              tq[0] = p_.tx[i], tq[1] = p_.ty[i], tq[2] = p_.tz[i];
            }
            islands::add_member_walls<Friction, Cylinder>(view, i, p_.fx[i], p_.fy[i], p_.fz[i], w,
                                                          tq, t.max_ratio, t.overlaps);
            if constexpr (Friction)
              p_.tx[i] = tq[0], p_.ty[i] = tq[1], p_.tz[i] = tq[2];
          }
        },
        geom_.cylinder);
    return t;
  }));
  st_.pair_evaluations += static_cast<std::int64_t>(o.head_pairs.i.size() + o.tail_pairs.i.size());
  st_.overlap_violations += rep.overlaps;
  st_.max_overlap_ratio = std::max(st_.max_overlap_ratio, rep.max_ratio);
}

// Friction: the lower entry of every pair the global steps advanced takes 0 - h of the upper one
// (a pair apart has +0 at both ends, as the rows' own pass leaves it). Only the islands' steps,
// a rebuild's history collection and a checkpoint read the lower entries, so the global steps
// mirror before a rebuild and at their end, not after every step.
void IslandsScheme::mirror_history() {
  const OneRank& o = one_;
  const std::pair<const PairStream*, const std::vector<std::uint32_t>*> parts[] = {
      {&o.head_pairs, &o.head_mirror}, {&o.tail_pairs, &o.tail_mirror}};
  for (const auto& [stream, mirror] : parts)
    for (std::size_t e = 0; e < mirror->size(); ++e) {
      const std::uint32_t k = stream->k[e], q = (*mirror)[e];
      hx_[q] = 0.0 - hx_[k], hy_[q] = 0.0 - hy_[k], hz_[q] = 0.0 - hz_[k];
    }
}

// For every pair of `stream` (a full list's upper entries), the list entry of the same pair in
// its partner's row: rows list their partners in increasing index within each part (in-box,
// then across a face), and a pair's two entries lie in the same part.
void IslandsScheme::mirror_entries(const VerletList& list, const PairStream& stream,
                                   std::vector<std::uint32_t>& mirror) {
  const std::uint32_t* off = list.offsets().data();
  const std::uint32_t* wrap = list.wrap_begin().data();
  const std::uint32_t* nb = list.neighbors().data();
  mirror.resize(stream.i.size());
  for (std::size_t e = 0; e < mirror.size(); ++e) {
    const std::uint32_t i = stream.i[e], j = stream.j[e], k = stream.k[e];
    const bool tail = k >= wrap[i];
    const std::uint32_t* b = nb + (tail ? wrap[j] : off[j]);
    const std::uint32_t* end = nb + (tail ? off[j + 1] : wrap[j]);
    const std::uint32_t* at = std::lower_bound(b, end, i);
    if (at == end || *at != i)
      throw std::logic_error("islands: a full list's pair is missing from its partner's row");
    mirror[e] = static_cast<std::uint32_t>(at - nb);
  }
}

// The fine steps of every island that does not span ranks (`spans` null on one rank), one
// result per island in results_: TBB tasks when they hold many particles. Here, beside the
// contact kernels' other callers: compiled in a smaller unit, GCC inlines the pair kernel
// differently and the dilute gas costs ~2% more instructions (callgrind, HCS 1222).
void IslandsScheme::run_islands(bool record, const unsigned char* spans) {
  const std::uint32_t nc = ln_.islands.count();
  results_.assign(nc, islands::IslandResult{});
  const islands::ContactView view = contact_view();
  with_flags(
      [&](auto ext, auto ranks, auto fr) {
        auto range = [&](std::size_t b, std::size_t e) {
          for (std::size_t q = b; q != e; ++q)
            if (spans == nullptr || !spans[q])
              run_island<ext, ranks, fr>(static_cast<std::uint32_t>(q), record, view);
        };
        if (ln_.busy.size() < 256) {
          range(0, nc); // few fine particles: no task overhead
        } else {
          tbb::parallel_for(
              tbb::blocked_range<std::size_t>(0, nc, 1),
              [&](const tbb::blocked_range<std::size_t>& r) { range(r.begin(), r.end()); });
        }
      },
      ext_.active(), rank_ != nullptr, model_.friction);
}

// The K fine steps of island c (every island has a link or a wall): contact forces from members
// only (no other particle can reach them within dt_sp), walls, and the variable-step leapfrog.
// On R ranks a local island's (all its members owned), over the rank's rows.
template <bool External, bool Ranks, bool Friction>
void IslandsScheme::run_island(std::uint32_t c, bool record, const islands::ContactView& view) {
  const std::uint32_t first = ln_.islands.first[c];
  const std::uint32_t size = ln_.islands.size(c);
  const auto part = [first, size](const auto& v) { return std::span(v).subspan(first, size); };
  islands::Members mb{part(ln_.members), part(x0_), part(y0_), part(z0_), ln_.bound, margin_, 0.0};
  // No member touches anything before the island's entry time: its leading steps are one.
  mb.lead = islands::entry_lead(islands::entry_time<!Ranks>(view, mb, ln_.own_bound.data(), c),
                                dt_sp_, steps_);
  // After the lead, and between contacts, the steps the island flies free through are one.
  auto free_time = [&] {
    return islands::free_time<!Ranks, External>(view, mb, c, model_.gravity);
  };
  if constexpr (!Ranks && !Friction) {
    // The common island of a dilute gas: its one pair, evaluated once. A step_island of its own
    // (one forces callback with a branch on this case cost 11% more instructions on HCS 1222).
    if (mb.count() == 2) {
      const std::uint32_t i = mb.mem[0], j = mb.mem[1];
      bool across = false;
      for (std::uint32_t k = view.rows.wrap[i]; k < view.rows.off[i + 1]; ++k)
        across = across || view.rows.nb[k] == j;
      results_[c] = islands::step_island<External, true>(
          view.c, mb, steps_, model_.gravity, record ? rec_.vx.data() : nullptr,
          record ? rec_.vy.data() : nullptr, record ? rec_.vz.data() : nullptr,
          [&](std::uint32_t, std::uint32_t, double& max_ratio, std::int64_t& violations) {
            return islands::pair_island_forces(view, i, j, across, max_ratio, violations);
          },
          [] {}, islands::SerialBlocks{}, free_time); // two members: never a giant island
      return;
    }
  }
  // The curved wall of a cylinder (Cylinder) chosen once per island, outside its steps.
  results_[c] = with_flags(
      [&](auto cyl) {
        constexpr bool Cylinder = decltype(cyl)::value;
        return islands::step_island<External, true, Friction>(
            view.c, mb, steps_, model_.gravity, record ? rec_.vx.data() : nullptr,
            record ? rec_.vy.data() : nullptr, record ? rec_.vz.data() : nullptr,
            [&](std::uint32_t u0, std::uint32_t u1, double& max_ratio, std::int64_t& violations,
                auto... hk) {
              return islands::contact_forces_of<true, true, !Ranks, Ranks, Friction, Cylinder>(
                  view, mb.mem.data(), u0, u1, c, max_ratio, violations, hk...);
            },
            [] {}, TaskBlocks{},
            [&] {
              return islands::free_time_of<!Ranks, External, Cylinder>(view, mb, c, model_.gravity);
            });
      },
      geom_.cylinder);
}

// The recorded state at the sub-iteration's start: positions wrapped into the box, each
// particle's island (-1 alone, 0 for all in the global mode) and local step.
void IslandsScheme::record_state() {
  const std::size_t n = owned_;
  rec_.x.resize(n), rec_.y.resize(n), rec_.z.resize(n), rec_.vx.resize(n), rec_.vy.resize(n);
  rec_.vz.resize(n), rec_.dt.resize(n), rec_.island.resize(n);
  for_particle_ranges(n, [&](std::size_t a, std::size_t b) {
    for (std::size_t i = a; i < b; ++i) {
      rec_.x[i] = geom_.wrap(p_.x[i], 0), rec_.y[i] = geom_.wrap(p_.y[i], 1),
      rec_.z[i] = geom_.wrap(p_.z[i], 2);
      const bool fine = global_ || ln_.island_of[i] != kAlone;
      rec_.island[i] = global_ ? 0 : fine ? static_cast<std::int64_t>(ln_.island_of[i]) : -1;
      rec_.dt[i] = fine ? dt_sp_ / static_cast<double>(steps_.K) : dt_sp_;
    }
  });
  const auto end = static_cast<std::ptrdiff_t>(n);
  rec_.mass.assign(p_.mass.begin(), p_.mass.begin() + end);
  rec_.radius.assign(p_.radius.begin(), p_.radius.begin() + end);
  rec_.id.assign(p_.id.begin(), p_.id.begin() + end);
}

namespace islands {

std::optional<Fault> find_fault(const ParticleStore& p, std::size_t n, const DomainGeometry& g) {
  {
    const WallBounds wb(g);
    const double(&lo)[3] = wb.lo;
    const double(&hi)[3] = wb.hi;
    const double inf = std::numeric_limits<double>::infinity();
    const double* __restrict x = p.x.data();
    const double* __restrict y = p.y.data();
    const double* __restrict z = p.z.data();
    const double* __restrict vx = p.vx.data();
    const double* __restrict vy = p.vy.data();
    const double* __restrict vz = p.vz.data();
    std::uint64_t bad = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const double q = vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i] + x[i] + y[i] + z[i];
      bad |= sign_unless(q > -inf) | sign_unless(q < inf) | sign_unless(x[i] >= lo[0]) |
             sign_unless(x[i] <= hi[0]) | sign_unless(y[i] >= lo[1]) | sign_unless(y[i] <= hi[1]) |
             sign_unless(z[i] >= lo[2]) | sign_unless(z[i] <= hi[2]);
    }
    if (g.cylinder) // a centre beyond the curved wall (or NaN)
      for (std::size_t i = 0; i < n; ++i)
        bad |= sign_unless(cylinder_gap(g, x[i], y[i], z[i], 0.0) >= 0.0);
    if (!(bad >> 63))
      return std::nullopt;
  }
  for (std::size_t i = 0; i < n; ++i) {
    const double q[3] = {p.x[i], p.y[i], p.z[i]};
    const double v2 = p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
    if (!std::isfinite(v2 + q[0] + q[1] + q[2]))
      return Fault{i, true};
    for (int a = 0; a < 3; ++a)
      if (!g.periodic[a] && !(q[a] >= g.lo[a] && q[a] <= g.hi[a]))
        return Fault{i, false};
    if (g.cylinder && !(cylinder_gap(g, q, 0.0) >= 0.0))
      return Fault{i, false};
  }
  return std::nullopt;
}

std::string fault_message(const ParticleStore& p, const Fault& f, double t, std::int64_t subit,
                          const StepModel& m) {
  const std::size_t i = f.index;
  return fmt::format(
      "t = {:.9g} s, sub-iteration {}: particle {} at ({:.6g}, {:.6g}, {:.6g}) m: {}", t, subit,
      p.id[i], p.x[i], p.y[i], p.z[i],
      f.nonfinite ? "position or velocity is not finite (NaN/inf): the step is unstable"
                  : "left the domain through a wall" + wall_passage(p, i, m));
}

} // namespace islands

LeafStepStats IslandsScheme::take_interval_stats() {
  LeafStepStats s;
  if (st_.iv_particles > 0) {
    s.steps_min = static_cast<double>(st_.iv_min);
    s.steps_max = static_cast<double>(st_.iv_max);
    s.steps_mean = static_cast<double>(st_.iv_steps) / static_cast<double>(st_.iv_particles);
    s.fine_fraction = static_cast<double>(st_.iv_fine) / static_cast<double>(st_.iv_particles);
  }
  st_.iv_fine = st_.iv_particles = st_.iv_steps = 0;
  st_.iv_min = std::numeric_limits<std::int64_t>::max();
  st_.iv_max = 0;
  return s;
}

std::array<double, 7> IslandsScheme::fine_fraction_distribution() const {
  std::array<double, 7> d{};
  const std::size_t n = std::min(owned_, fine_.size());
  if (st_.subits == 0 || n == 0)
    return d;
  std::vector<double> f(n);
  double sum = 0.0;
  for (std::size_t i = 0; i < n; ++i)
    f[i] = fine_[i] / static_cast<double>(st_.subits), sum += f[i];
  std::sort(f.begin(), f.end());
  auto rank = [&](double q) {
    const auto k = static_cast<std::size_t>(std::ceil(q * static_cast<double>(f.size())));
    return f[std::min(f.size() - 1, k > 0 ? k - 1 : 0)];
  };
  d = {sum / static_cast<double>(f.size()),
       f.front(),
       rank(0.1),
       rank(0.5),
       rank(0.9),
       rank(0.99),
       f.back()};
  return d;
}

} // namespace cfddem::dem
