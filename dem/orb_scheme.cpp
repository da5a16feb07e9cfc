#include "dem/orb_scheme.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

#include "core/error.hpp"
#include "dem/flag_dispatch.hpp"
#include "dem/orb_leaf_kernels.hpp"
#include "dem/orb_rank_part.hpp"
#include "dem/scheme_support.hpp"
#include "dem/task_blocks.hpp"
#include "dem/verlet_passes.hpp"

namespace cfddem::dem {

namespace {
enum class Fault { none = 0, nan, left_domain };
} // namespace

// A run of consecutive leaves with the same local step, advanced in lockstep as one TBB task:
// [b, e) in the store, rows active[a0, a1). Leaves never read each other's live state (partners
// in other leaves are read from the frozen copies), so the grouping changes nothing in the
// arithmetic: it only amortises the per-step loop overhead of small leaves.
struct OrbScheme::Batch {
  std::uint32_t b = 0, e = 0, a0 = 0, a1 = 0;
  std::int64_t K = 1, evals_per_step = 0;
  std::int64_t evals = 0; // force evaluations of the last attempt
  double h = 0.0, h_last = 0.0;
  // Results of the last attempt.
  std::int64_t violations = 0;
  double max_ratio = 0.0;
  bool outran = false; // a particle moved more than skin/2 with force evaluations still to do
  Fault fault = Fault::none;
  std::uint32_t fault_index = 0;
  double fault_value = 0.0;
};

OrbScheme::~OrbScheme() = default;

OrbScheme::OrbScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer)
    : OrbScheme(scene, particles, make_step_model(scene, particles), nullptr, timer) {}

OrbScheme::OrbScheme(const Scene& scene, ParticleStore& particles, const StepModel& model,
                     const Communicator* comm, PhaseTimer& timer)
    : scene_(scene), p_(particles), timer_(timer), geom_(scene.domain), model_(model) {
  if (comm != nullptr && comm->size() > 1)
    rank_ = std::make_unique<RankPart>(*comm);
  if (model_.friction)
    p_.enable_rotation();
  domain_ = partition::Aabb{scene.domain.lo, scene.domain.hi};
  cfg_.levels = scene.partition.orb_levels;
  double r_max = 0.0;
  for (const double r : p_.radius)
    r_max = std::max(r_max, r);
  cfg_.n_global = static_cast<std::int64_t>(p_.size());
  if (rank_)
    r_max = rank_->comm.max(r_max), cfg_.n_global = rank_->comm.sum(cfg_.n_global);
  cfg_.r_max = cfg_.n_global > 0 ? r_max : model_.r_min;
  cfg_.nsubit = scene.dem.nsubit;
  cfg_.dt_sp = model_.interval / static_cast<double>(cfg_.nsubit);
  cfg_.prox = 0.5 * scene.dem.proximity_radii;
  cfg_.cost_weights = scene.partition.weights == "cost";
  cfg_.time_to_contact = scene.dem.local_dt == "time_to_contact";
  cfg_.global = scene.dem.orb_global && !model_.friction;
  cfg_.global_min_per_rank = scene.dem.orb_global_min_per_rank;
  skin_ = model_.skin;
  // The skin may grow (after a retry) while the contact cutoff stays below half of every
  // periodic length (minimum image).
  for (int a = 0; a < 3; ++a) // no particles: nothing to list (a gas-only or empty scene)
    if (cfg_.n_global > 0 && geom_.periodic[a] &&
        geom_.length[a] <= 2.0 * (2.0 * cfg_.r_max + model_.skin))
      throw RunError(fmt::format("periodic axis {} is {:.4g} m long, not more than twice the "
                                 "neighbor cutoff {:.4g} m",
                                 a, geom_.length[a], 2.0 * cfg_.r_max + model_.skin));
  cfg_.skin_cap = periodic_skin_cap(geom_, cfg_.r_max);
  owned_ = p_.size();
  hprev_.assign(owned_, 0.0);
  cost_.assign(owned_, 0.0);
  stats_.leaf_steps.assign(std::size_t{1} << cfg_.levels, 0);
}

void OrbScheme::start() {
  // v holds the synchronised v(0): the first kick is a(0) (0 + h/2), velocity Verlet's.
  hprev_.assign(owned_, 0.0);
  stats_.subits = 0;
}

double OrbScheme::all_max(double v) const {
  return rank_ ? rank_->comm.max(v) : v;
}

// With dem.local_dt = "time_to_contact": each owned particle's speed bound (its speed plus what
// gravity and its external force add over h_prev + dt_sp), the largest reach over the ranks, and
// a skin covering two reaches (so that every pair able to touch within dt_sp is a candidate; it
// returns to the scene's at the regrid). Returns whether the skin grew.
bool OrbScheme::time_to_contact_speeds() {
  speed_.resize(owned_);
  double reach = 0.0;
  for (std::size_t i = 0; i < owned_; ++i) {
    double ax = model_.gravity[0], ay = model_.gravity[1], az = model_.gravity[2];
    if (ext_.active())
      ax += ext_.x[i] * p_.inv_mass[i], ay += ext_.y[i] * p_.inv_mass[i],
          az += ext_.z[i] * p_.inv_mass[i];
    speed_[i] = std::sqrt(p_.vx[i] * p_.vx[i] + p_.vy[i] * p_.vy[i] + p_.vz[i] * p_.vz[i]) +
                std::sqrt(ax * ax + ay * ay + az * az) * (hprev_[i] + cfg_.dt_sp);
    reach = std::max(reach, speed_[i] * cfg_.dt_sp);
  }
  reach_ = all_max(reach);
  if (2.1 * reach_ > skin_ && skin_ < cfg_.skin_cap) {
    skin_ = std::min(2.1 * reach_, cfg_.skin_cap);
    return true;
  }
  return false;
}

// A wall is a partner too: an owned particle whose centre is closer than proximity_radii radii
// to a wall (with time_to_contact: whose gap to it could close within dt_sp) is near (without
// this, a leaf near a floor took coarse steps straight into it). The curved wall of a cylinder
// too, by its centre's distance R - rho to it.
void OrbScheme::mark_walls(std::span<unsigned char> near) const {
  auto reach = [&](std::size_t i) {
    return cfg_.time_to_contact ? p_.radius[i] + speed_[i] * cfg_.dt_sp
                                : 2.0 * cfg_.prox * p_.radius[i];
  };
  for (int a = 0; a < 3; ++a) {
    if (geom_.periodic[a])
      continue;
    const std::vector<double>& pos = a == 0 ? p_.x : a == 1 ? p_.y : p_.z;
    for (std::size_t i = 0; i < owned_; ++i) {
      const double d = reach(i);
      near[i] |= pos[i] - geom_.lo[a] < d || geom_.hi[a] - pos[i] < d;
    }
  }
  if (geom_.cylinder)
    for (std::size_t i = 0; i < owned_; ++i)
      near[i] |= cylinder_gap(geom_, p_.x[i], p_.y[i], p_.z[i], 0.0) < reach(i);
}

// The rows of this sub-iteration; true if built now. One rank: the candidate pairs are rebuilt
// when forced (a retry), invalid or about to be outrun, and the rows derived after a re-sort. R
// ranks: the exchange of particles and ghosts and fresh rows (at every sub-iteration but those
// that keep the global mode's rows: rank_keep_rows).
bool OrbScheme::build_rows(bool force) {
  if (rank_) {
    rank_exchange_and_rows();
    global_.on = global_.hold || rank_choose_global(); // hold: the same on every rank
    return true;
  }
  bool fresh = false;
  if (cfg_.time_to_contact && time_to_contact_speeds())
    pairs_.valid = false;
  if (force || !pairs_.valid || pairs_.contact_only ||
      rows_expire(p_.size(), {pairs_.xr.data(), pairs_.yr.data(), pairs_.zr.data()}))
    rebuild_pairs(), fresh = true;
  global_.on = choose_global();
  if (!global_.on && rows_.off.size() != p_.size() + 1) {
    PhaseTimer::Scope t(timer_, Phase::neighbor);
    derive_rows();
  }
  return fresh;
}

// Frozen copies (what other leaves and ranks read, and the rollback point of a retry).
void OrbScheme::freeze() {
  frozen_.x = p_.x, frozen_.y = p_.y, frozen_.z = p_.z;
  frozen_.vx = p_.vx, frozen_.vy = p_.vy, frozen_.vz = p_.vz, frozen_.hp = hprev_;
  if (model_.friction) {
    frozen_.wx = p_.wx, frozen_.wy = p_.wy, frozen_.wz = p_.wz;
    frozen_.hx = hist_.hx, frozen_.hy = hist_.hy, frozen_.hz = hist_.hz;
  }
}

void OrbScheme::roll_back() {
  const auto back = [&](const std::vector<double>& from, std::vector<double>& to) {
    std::copy_n(from.begin(), owned_, to.begin());
  };
  back(frozen_.x, p_.x), back(frozen_.y, p_.y), back(frozen_.z, p_.z);
  back(frozen_.vx, p_.vx), back(frozen_.vy, p_.vy), back(frozen_.vz, p_.vz);
  hprev_ = frozen_.hp;
  if (model_.friction) {
    back(frozen_.wx, p_.wx), back(frozen_.wy, p_.wy), back(frozen_.wz, p_.wz);
    hist_.hx = frozen_.hx, hist_.hy = frozen_.hy, hist_.hz = frozen_.hz;
  }
}

LeafLive OrbScheme::live(bool external) {
  LeafLive v{p_.x,  p_.y,   p_.z,      p_.vx,   p_.vy,       p_.vz, p_.fx, p_.fy,
             p_.fz, hprev_, p_.radius, p_.mass, p_.inv_mass, {},    {},    {}};
  if (external)
    v.fex = ext_.x, v.fey = ext_.y, v.fez = ext_.z;
  return v;
}

LeafFrozen OrbScheme::frozen() const {
  return {frozen_.x, frozen_.y, frozen_.z, frozen_.vx, frozen_.vy, frozen_.vz};
}

LeafSpin OrbScheme::spin() {
  return {p_.wx,      p_.wy,      p_.wz,      p_.tx,    p_.ty,    p_.tz,   p_.inv_inertia,
          frozen_.wx, frozen_.wy, frozen_.wz, hist_.hx, hist_.hy, hist_.hz};
}

LeafRows OrbScheme::rows_view() const {
  if (rank_)
    return {rank_->rows.active(), rank_->rows.off(), rank_->rows.mid(), rank_->rows.nb()};
  return {rows_.active, rows_.off, rows_.mid, rows_.nb};
}

// leaves_.fine: 1 for a leaf one of whose particles is near a partner or a wall.
void OrbScheme::mark_fine_leaves(std::span<const unsigned char> near) {
  const std::size_t nl = leaves_.id.size();
  leaves_.fine.assign(nl, 0);
  for (std::size_t k = 0; k < nl; ++k) {
    unsigned char any = 0; // a local: stores through a char pointer would alias everything
    for (std::uint32_t i = leaves_.range[k]; i < leaves_.range[k + 1]; ++i)
      any |= near[i];
    leaves_.fine[k] = any;
  }
}

// The step of each leaf (fine if one of its particles is near a partner or a wall), the batches
// with their rows and force evaluations per local step (own-leaf entries count half a pair,
// other-leaf entries one: see pair_evaluations()), and with `record` the state at t.
void OrbScheme::plan(bool record) {
  const std::size_t n = owned_;
  const FineSteps steps = fine_steps(cfg_.dt_sp, model_.dt);
  batches_.clear();
  if (global_.on) {
    // Every particle on the fine steps (counted as every leaf fine): one batch of all, no rows
    // (the global steps count their pairs).
    std::fill(leaves_.fine.begin(), leaves_.fine.end(), 1);
    Batch bt;
    bt.b = 0, bt.e = static_cast<std::uint32_t>(n), bt.K = steps.K;
    bt.h = steps.h, bt.h_last = steps.h_last;
    batches_.push_back(bt);
  } else {
    plan_leaf_batches(steps);
  }
  if (record)
    record_start();
}

// Batches: runs of consecutive leaves with the same step, cut at about `grain` particles so that
// every thread gets several (the arithmetic does not depend on the cuts), with their rows and
// force evaluations per local step.
void OrbScheme::plan_leaf_batches(const FineSteps& steps) {
  const std::size_t n = owned_, nl = leaves_.id.size();
  const bool can_refine = model_.dt < cfg_.dt_sp;
  const auto threads = static_cast<std::size_t>(tbb::this_task_arena::max_concurrency());
  const std::size_t grain = std::max<std::size_t>(256, n / (4 * std::max<std::size_t>(threads, 1)));
  for (std::size_t k = 0; k < nl; ++k) {
    const bool fine = leaves_.fine[k] && can_refine;
    const std::uint32_t b = leaves_.range[k], e = leaves_.range[k + 1];
    if (b == e)
      continue;
    const std::int64_t K = fine ? steps.K : 1;
    if (batches_.empty() || batches_.back().K != K || batches_.back().e != b ||
        batches_.back().e - batches_.back().b >= grain) {
      Batch bt;
      bt.b = b, bt.K = K;
      bt.h = fine ? steps.h : cfg_.dt_sp;
      bt.h_last = fine ? steps.h_last : cfg_.dt_sp;
      batches_.push_back(bt);
    }
    batches_.back().e = e;
  }
  const LeafRows rows = rows_view();
  const std::span<const std::uint32_t> active = rows.act;
  for (Batch& bt : batches_) {
    bt.a0 = static_cast<std::uint32_t>(std::lower_bound(active.begin(), active.end(), bt.b) -
                                       active.begin());
    bt.a1 = static_cast<std::uint32_t>(std::lower_bound(active.begin(), active.end(), bt.e) -
                                       active.begin());
    const auto own = static_cast<std::int64_t>(rows_.own_before[bt.e] - rows_.own_before[bt.b]);
    const auto all = static_cast<std::int64_t>(rows.off[bt.e] - rows.off[bt.b]);
    bt.evals_per_step = own / 2 + (all - own);
  }
}

// With `record`: the state at t (wrapped positions, the leaf and local step of each particle).
void OrbScheme::record_start() {
  const std::size_t n = owned_, nl = leaves_.id.size();
  rec_.x.resize(n), rec_.y.resize(n), rec_.z.resize(n);
  for_particle_ranges(n, [&](std::size_t a, std::size_t b) {
    for (std::size_t i = a; i < b; ++i)
      rec_.x[i] = geom_.wrap(p_.x[i], 0), rec_.y[i] = geom_.wrap(p_.y[i], 1),
      rec_.z[i] = geom_.wrap(p_.z[i], 2);
  });
  rec_.vx.resize(n), rec_.vy.resize(n), rec_.vz.resize(n);
  const auto first = [n](const auto& v) {
    return std::vector(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(n));
  };
  rec_.mass = first(p_.mass), rec_.id = first(p_.id), rec_.radius = first(p_.radius);
  rec_.leaf.resize(n), rec_.dt.resize(n);
  for (std::size_t k = 0; k < nl; ++k)
    for (std::uint32_t i = leaves_.range[k]; i < leaves_.range[k + 1]; ++i)
      rec_.leaf[i] = leaves_.id[k];
  for (const Batch& bt : batches_)
    for (std::uint32_t i = bt.b; i < bt.e; ++i)
      rec_.dt[i] = cfg_.dt_sp / static_cast<double>(bt.K);
}

void OrbScheme::run_batch(Batch& bt, bool record) {
  // Column: a cylinder's walls (add_column_wall_forces), chosen here so a box's loop is as it was.
  with_flags([&](auto ext, auto fr, auto col) { run_batch_impl<ext, fr, col>(bt, record); },
             ext_.active(), model_.friction, geom_.cylinder);
}

// The batch's K local steps. With External, the per-particle external force is added to the
// contact force in every kick and in the synchronised velocity ((F + F_ext) / m + g, the
// explicit scheme's arithmetic).
template <bool External, bool Friction, bool Column>
void OrbScheme::run_batch_impl(Batch& bt, bool record) {
  bt.violations = 0;
  bt.max_ratio = 0.0;
  bt.outran = false;
  bt.fault = Fault::none;
  bt.evals = bt.evals_per_step * bt.K;
  if (bt.e == bt.b)
    return;
  const DomainGeometry g = geom_;
  const StepModel m = model_;
  const LeafLive p = live(External);
  const LeafFrozen frozen_state = frozen();
  // The reference of the skin test: one rank, the positions of the pair build; R ranks, those at
  // the sub-iteration start (the rows are built there).
  const LeafFrozen ref =
      rank_ ? frozen_state : LeafFrozen{pairs_.xr, pairs_.yr, pairs_.zr, {}, {}, {}};
  const LeafRows rows = rows_view();
  [[maybe_unused]] const LeafSpin w = Friction ? spin() : LeafSpin{};
  const bool walls = !(g.periodic[0] && g.periodic[1] && g.periodic[2]);
  const std::uint32_t b = bt.b, e = bt.e;
  OverlapTally tally;
  LeafStep st;
  st.K = bt.K;
  st.half_skin2 = 0.25 * skin_ * skin_;
  for (std::int64_t k = 0; k < bt.K; ++k) {
    st.k = k;
    st.hk = k + 1 == bt.K ? bt.h_last : bt.h;
    // Contact pass: the explicit scheme's pair arithmetic; partners of the own leaf read live,
    // partners of other leaves read frozen at the start of the sub-iteration.
    if constexpr (Friction) {
      leaf_frictional_contact_pass(bt.a0, bt.a1, rows, p, frozen_state, w, st.hk, g, m, tally);
      if (walls && !Column)
        add_frictional_wall_forces(b, e, rows.off.data(), p, w, g, m, tally);
    } else {
      leaf_contact_pass(bt.a0, bt.a1, rows, p, frozen_state, g, m, tally);
      if (walls && !Column)
        add_wall_forces(b, e, rows.off.data(), p, g, m.wall, m.max_overlap, tally);
    }
    if constexpr (Column) // the column's walls replace the planar ones across it
      add_column_wall_forces<Friction>(b, e, rows.off.data(), p, w, g, m, tally);
    if (record && k == 0)
      synchronised_velocities<External>(b, e, p, m.gravity, rec_.vx.data(), rec_.vy.data(),
                                        rec_.vz.data());
    if constexpr (Friction)
      leaf_spin_kick(b, e, p, w, k, st.h_before, st.hk);
    // v(n+1/2) = v(n-1/2) + a(n) (h_prev + h/2), x(n+1) = x(n) + v(n+1/2) h (leaf_kick_drift).
    // Sign-bit AND instead of a max: vectorizes (see integrate_range in explicit_scheme.cpp).
    std::uint64_t still = ~std::uint64_t{0};
    leaf_kick_drift<External>(b, e, p, ref, st, m.gravity, still);
    st.h_before = st.hk;
    // Frozen partners do not move and were within skin/2 of their reference: own particles may
    // use the other half. Beyond it a pair could be missing from the rows: stop, the
    // sub-iteration is redone with a larger skin (NaN-safe: a NaN compares false here, fails
    // below and is reported as such).
    if (k + 1 < bt.K && !(still >> 63)) {
      bt.outran = true;
      break;
    }
  }
  bt.max_ratio = tally.max_ratio;
  bt.violations = tally.violations;
  find_batch_fault<Column>(bt, p);
}

// A NaN or a particle outside a wall among the batch's particles, into bt.fault.
template <bool Column> void OrbScheme::find_batch_fault(Batch& bt, const LeafLive& p) const {
  const DomainGeometry& g = geom_;
  const std::uint32_t b = bt.b, e = bt.e;
  // Faults are rare: a branch-free pass (it vectorizes) says whether to look for one. The sum
  // v2 + x + y + z is NaN or inf if any term is; a coordinate outside a wall's closed interval,
  // or NaN, fails the comparison (periodic axes get an infinite interval).
  const WallBounds wb(g);
  {
    const double inf = std::numeric_limits<double>::infinity();
    std::uint64_t bad = 0;
    for (std::uint32_t i = b; i < e; ++i) {
      const double v2 = p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
      const double t = v2 + p.x[i] + p.y[i] + p.z[i];
      bad |= sign_unless(t > -inf) | sign_unless(t < inf) | sign_unless(p.x[i] >= wb.lo[0]) |
             sign_unless(p.x[i] <= wb.hi[0]) | sign_unless(p.y[i] >= wb.lo[1]) |
             sign_unless(p.y[i] <= wb.hi[1]) | sign_unless(p.z[i] >= wb.lo[2]) |
             sign_unless(p.z[i] <= wb.hi[2]);
    }
    if constexpr (Column) // a centre beyond the curved wall (or NaN)
      for (std::uint32_t i = b; i < e; ++i)
        bad |= sign_unless(cylinder_gap(g, p.x[i], p.y[i], p.z[i], 0.0) >= 0.0);
    if (!(bad >> 63))
      return;
  }
  for (std::uint32_t i = b; i < e && bt.fault == Fault::none; ++i) {
    const double q[3] = {p.x[i], p.y[i], p.z[i]};
    const double v2 = p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
    if (!std::isfinite(v2 + q[0] + q[1] + q[2])) {
      bt.fault = Fault::nan, bt.fault_index = i, bt.fault_value = v2;
      break;
    }
    for (int a = 0; a < 3; ++a)
      if (!(q[a] >= wb.lo[a] && q[a] <= wb.hi[a])) {
        bt.fault = Fault::left_domain, bt.fault_index = i, bt.fault_value = q[a];
        break;
      }
    if (Column && bt.fault == Fault::none && !(cylinder_gap(g, q, 0.0) >= 0.0))
      bt.fault = Fault::left_domain, bt.fault_index = i, bt.fault_value = q[g.u];
  }
}

// Whether a sub-iteration may be global at all: dem.orb_global without friction, and a fine step
// shorter than the sub-iteration; on R ranks also dem.orb_global_min_per_rank particles per rank
// on average (the global steps' ghost refresh before every fine step is a wait between the ranks
// that the leaf steps take once per sub-iteration: docs/schemes.md, "Global mode"). The same on
// every rank.
bool OrbScheme::global_allowed() const {
  if (!cfg_.global || !(model_.dt < cfg_.dt_sp))
    return false;
  return !rank_ ||
         cfg_.n_global >= cfg_.global_min_per_rank * static_cast<std::int64_t>(rank_->comm.size());
}

// One rank, at the sub-iteration's start: which particles are near a partner or a wall
// (mark_near), and whether the sub-iteration runs in the global mode: the leaves that would step
// finely hold more than kGlobalFraction of the particles (orb_scheme.hpp gives the cost
// argument). A decision from the state alone, so a rerun, a thread count and a restart take it
// alike.
bool OrbScheme::choose_global() {
  mark_near();
  mark_fine_leaves(rows_.near);
  if (!global_allowed())
    return false;
  std::size_t fine = 0;
  for (std::size_t k = 0; k < leaves_.fine.size(); ++k)
    fine += leaves_.fine[k] ? leaves_.range[k + 1] - leaves_.range[k] : 0;
  return static_cast<double>(fine) > kGlobalFraction * static_cast<double>(owned_);
}

// The candidate contact pairs as the pair pass's streams (GlobalPairs::split, in blocks of
// 2 kPairBlock pairs: the explicit scheme's blocks of 256 rows hold about as many in a dense
// gas), and the particles that can reach a wall before the pairs expire. Until then each
// particle moves at most a skin from here (up to skin/2 from its reference now, skin/2 more).
void OrbScheme::global_stream() {
  // The pairs in the order of their lower particle index (a stable counting sort), as the
  // explicit scheme's rows give them: a block of the stream then reads a compact range of the
  // store. In the cell order they are found in, every block read particles from all over it,
  // and on two threads each pair took about 1.5x the CPU time of one thread's (the 1e5 bed).
  const std::size_t np = pairs_.ca.size();
  std::vector<std::uint32_t>& start = global_.first;
  start.assign(p_.size() + 1, 0);
  for (std::size_t q = 0; q < np; ++q)
    ++start[std::min(pairs_.ca[q], pairs_.cb[q]) + 1];
  for (std::size_t i = 0; i + 1 < start.size(); ++i)
    start[i + 1] += start[i];
  GlobalPairs& gp = global_.pairs;
  gp.a.resize(np), gp.b.resize(np);
  for (std::size_t q = 0; q < np; ++q) {
    const std::uint32_t at = start[std::min(pairs_.ca[q], pairs_.cb[q])]++;
    gp.a[at] = pairs_.ca[q], gp.b[at] = pairs_.cb[q];
  }
  gp.split(p_, owned_, {pairs_.xr, pairs_.yr, pairs_.zr}, geom_, skin_);
  global_.stale = false;
}

// One global step of every owned particle, on any rank count: each stream pair once through the
// pair pass, its contacts scattered to both particles in the streams' order, the walls of the
// particles near one, the synchronised velocities of a recorded first step, and orb's
// variable-step leapfrog (leaf_kick_drift) in blocks. `evals`: the pairs this step counts.
// Returns true while every particle is within skin/2 of `ref`. One rank leaves the skin test out
// while the travel bound (Global::travel, the explicit scheme's TravelBound) shows that no
// particle can be that far, and measures exactly when a speed passed its cap: the same answer.
template <bool External, bool Column>
bool OrbScheme::global_step(Batch& bt, LeafStep& st, const LeafLive& p, const LeafFrozen& ref,
                            OverlapTally& tally, std::int64_t evals, bool record) {
  const std::size_t n = owned_;
  StepReport rep;
  global_.pairs.pass(p_, geom_, model_, st.hk, rep);
  tally.max_ratio = std::max(tally.max_ratio, rep.max_ratio);
  tally.violations += rep.overlaps;
  // The walls over the scatter's particle ranges (each particle stays with one thread); the
  // tallies are a maximum and a count, whatever the order of the ranges.
  tally.join(reduce_particle_ranges<OverlapTally>(n, [&](std::size_t a, std::size_t b) {
    OverlapTally t;
    add_listed_wall_forces<Column>(listed_in(global_.pairs.near_wall(), a, b), p, geom_, model_, t);
    return t;
  }));
  bt.evals += evals;
  if (record && st.k == 0)
    for_particle_ranges(n, [&](std::size_t a, std::size_t b) {
      synchronised_velocities<External>(static_cast<std::uint32_t>(a),
                                        static_cast<std::uint32_t>(b), p, model_.gravity,
                                        rec_.vx.data(), rec_.vy.data(), rec_.vz.data());
    });
  constexpr std::size_t kBlock = 4096;
  const std::size_t nblocks = (n + kBlock - 1) / kBlock;
  std::vector<std::uint64_t>& still_of = global_.still;
  still_of.assign(nblocks, ~std::uint64_t{0});
  TravelBound& travel = global_.travel;
  const bool exact = rank_ || !travel.may_skip(geom_, skin_, st.hk);
  const double cap2 = travel.cap * travel.cap;
  auto kick_drift = [&](std::size_t q) {
    std::uint64_t still = ~std::uint64_t{0};
    const auto b = static_cast<std::uint32_t>(q * kBlock);
    const auto e = static_cast<std::uint32_t>(std::min(n, (q + 1) * kBlock));
    if (exact)
      leaf_kick_drift<External>(b, e, p, ref, st, model_.gravity, still);
    else
      leaf_kick_drift<External, false>(b, e, p, ref, st, model_.gravity, still, cap2);
    still_of[q] = still;
  };
  if (nblocks <= 2) {
    for (std::size_t q = 0; q < nblocks; ++q)
      kick_drift(q);
  } else {
    for_particle_blocks(nblocks, kick_drift);
  }
  st.h_before = st.hk;
  std::uint64_t still = ~std::uint64_t{0};
  for (const std::uint64_t b : still_of)
    still &= b;
  // `still`: within skin/2 (the exact test), or without it every new speed within the cap.
  const bool within = (still >> 63) != 0;
  if (rank_)
    return within;
  const std::int64_t far = travel.close_pass(exact, within, st.hk, [&] { return measure_travel(); });
  return exact ? within : far == 0;
}

// One rank: the particles farther than skin/2 from the pairs' build, exactly, with the travel
// bound restarted from the largest displacement and speed (TravelBound::measure).
std::int64_t OrbScheme::measure_travel() {
  const std::size_t n = owned_;
  KickDriftColumns c;
  c.x = p_.x, c.y = p_.y, c.z = p_.z, c.vx = p_.vx, c.vy = p_.vy, c.vz = p_.vz;
  c.xr = pairs_.xr, c.yr = pairs_.yr, c.zr = pairs_.zr;
  return global_.travel.measure(c, n, 0.25 * skin_ * skin_);
}

void OrbScheme::run_global(Batch& bt, bool record) {
  with_flags([&](auto ext, auto col) { run_global_impl<ext, col>(bt, record); }, ext_.active(),
             geom_.cylinder);
}

// The global mode's K fine steps of every particle: the explicit scheme's passes (each
// candidate pair once through pair_pass, through the minimum image, its contacts scattered to
// both particles in the stream's order, so the sums do not depend on the thread count), the
// walls of the particles near one, and the orb's variable-step leapfrog (leaf_kick_drift: the
// first kick spans each particle's own h_prev + h/2). As the explicit scheme, the pairs are
// checked after every step and rebuilt when some particle moved more than skin/2 since their
// build (no partner is frozen, so nothing is rolled back).
template <bool External, bool Column>
void OrbScheme::run_global_impl(Batch& bt, bool record) {
  bt.violations = 0, bt.max_ratio = 0.0, bt.outran = false, bt.fault = Fault::none, bt.evals = 0;
  const std::size_t n = owned_;
  const LeafLive p = live(External);
  if (global_.stale)
    global_stream();
  // The leaf steps left forces behind: every particle's from zero at the first step, then those
  // of the last step's contacts and of the particles near a wall (as the explicit scheme).
  for (std::vector<double>* c : {&p_.fx, &p_.fy, &p_.fz})
    std::fill(c->begin(), c->begin() + static_cast<std::ptrdiff_t>(n), 0.0);
  OverlapTally tally;
  LeafStep st;
  st.K = bt.K;
  st.half_skin2 = 0.25 * skin_ * skin_;
  bool still = true;
  for (std::int64_t k = 0; k < bt.K; ++k) {
    st.k = k;
    st.hk = k + 1 == bt.K ? bt.h_last : bt.h;
    if (k > 0) {
      global_.pairs.clear_forces(p_);
      if (!still) { // some particle moved more than skin/2 since the build
        rebuild_pairs(global_.hold);
        global_stream();
      }
    }
    const LeafFrozen ref{pairs_.xr, pairs_.yr, pairs_.zr, {}, {}, {}};
    const auto evals = static_cast<std::int64_t>(global_.pairs.size());
    still = global_step<External, Column>(bt, st, p, ref, tally, evals, record);
  }
  global_.moved = !still;
  bt.max_ratio = tally.max_ratio;
  bt.violations = tally.violations;
  find_batch_fault<Column>(bt, p);
}

// R ranks: the rows' pairs as the pair pass's streams, each pair once (of two owned particles
// the lower index's entry, with a ghost the owned one's: a pair across ranks is evaluated on
// both, each rank keeping its own particle's force), ordered by their lower index as the rows
// are; the pairs counted once over the ranks (with a ghost, on the rank of the lower id); the
// owned particles near a wall. Rows and ghosts hold while no particle moves skin/2 from the
// build (rank_keep_rows), so the raw separations split into head and tail as one rank's.
void OrbScheme::rank_global_stream() {
  global_.once = global_.pairs.from_rows(rank_->rows.off(), rank_->rows.nb(), owned_, p_.id);
  global_.pairs.split(p_, owned_, {rank_->ref[0], rank_->ref[1], rank_->ref[2]}, geom_, skin_);
}

void OrbScheme::run_global_ranks(Batch& bt, bool record) {
  with_flags([&](auto ext, auto col) { run_global_ranks_impl<ext, col>(bt, record); },
             ext_.active(), geom_.cylinder);
}

// The global mode's K fine steps on R ranks: one rank's passes over the rows' pairs
// (rank_global_stream, once per build of the rows), the ghosts' x and v from their owners before
// every step but the first (before the first: at the build, or rank_keep_rows).
// A particle that moved more than skin/2 from the build with steps still to take sets outran:
// this rank computes no more, but takes part in every refresh, and every rank redoes the
// sub-iteration (subiterate's reduction).
template <bool External, bool Column>
void OrbScheme::run_global_ranks_impl(Batch& bt, bool record) {
  bt.violations = 0, bt.max_ratio = 0.0, bt.outran = false, bt.fault = Fault::none, bt.evals = 0;
  const LeafLive p = live(External);
  if (global_.stale)
    rank_global_stream(), global_.stale = false;
  OverlapTally tally;
  LeafStep st;
  st.K = bt.K;
  st.half_skin2 = 0.25 * skin_ * skin_;
  const LeafFrozen ref{rank_->ref[0], rank_->ref[1], rank_->ref[2], {}, {}, {}};
  for (std::int64_t k = 0; k < bt.K; ++k) {
    st.k = k;
    st.hk = k + 1 == bt.K ? bt.h_last : bt.h;
    if (k > 0) {
      rank_->exchange.forward(p_);
      if (bt.outran)
        continue;
      global_.pairs.clear_forces(p_);
    }
    const bool still = global_step<External, Column>(bt, st, p, ref, tally, global_.once, record);
    if (k + 1 < bt.K && !still)
      bt.outran = true; // the rows may miss a pair from the next step on
  }
  bt.max_ratio = tally.max_ratio;
  bt.violations = tally.violations;
  find_batch_fault<Column>(bt, p); // a fault before the rows ran out stops the run, as a leaf's
}

// One try at the sub-iteration with the current rows (one TBB task per batch); true if some
// batch outran its rows.
bool OrbScheme::attempt(bool record) {
  if (global_.on && rank_) {
    run_global_ranks(batches_.front(), record);
    return batches_.front().outran && batches_.front().fault == Fault::none;
  }
  if (global_.on) {
    run_global(batches_.front(), record);
    return false; // the global steps rebuild their pairs as they go: nothing to redo
  }
  const int nb = static_cast<int>(batches_.size());
  tbb::parallel_for(
      tbb::blocked_range<int>(0, nb, 1),
      [&](const tbb::blocked_range<int>& r) {
        for (int q = r.begin(); q != r.end(); ++q)
          run_batch(batches_[static_cast<std::size_t>(q)], record);
      },
      tbb::simple_partitioner{});
  for (const Batch& bt : batches_)
    if (bt.outran && bt.fault == Fault::none)
      return true;
  return false;
}

// A NaN or a particle through a wall: every rank raises the fault of the smallest particle id.
void OrbScheme::raise_fault() {
  std::string message;
  std::int64_t key = std::numeric_limits<std::int64_t>::max();
  for (const Batch& bt : batches_) {
    if (bt.fault == Fault::none)
      continue;
    const std::size_t i = bt.fault_index;
    if (p_.id[i] >= key)
      continue;
    key = p_.id[i];
    message = fmt::format(
        "t = {:.9g} s, sub-iteration {}: particle {} at ({:.6g}, {:.6g}, {:.6g}) m: {}{}", time(),
        stats_.subits, p_.id[i], p_.x[i], p_.y[i], p_.z[i],
        bt.fault == Fault::nan
            ? "position or velocity is not finite (NaN/inf): the step is unstable"
            : fmt::format("left the domain through a wall (coordinate {:.6g} m){}", bt.fault_value,
                          wall_passage(p_, i, model_)),
        rank_ ? fmt::format(" (rank {})", rank_->comm.rank()) : std::string());
  }
  throw RunError(rank_ ? rank_->comm.agree_on_error(key, message) : message);
}

void OrbScheme::subiterate(bool record) {
  // A regrid point decides the interval's mode afresh. After a held global interval (`held`) it
  // decides on the leaves as they are, and the ORB is cut again only if the leaf steps follow:
  // the global steps do not use the leaves, so the tree is the leaf steps' (kGlobalFraction).
  const bool regridding = stats_.subits % cfg_.nsubit == 0;
  const bool held = regridding && global_.hold;
  if (regridding)
    global_.hold = false;
  std::string outside_message;
  std::int64_t outside_key = std::numeric_limits<std::int64_t>::max();
  std::int64_t outside = 0;
  // R ranks: the global mode may keep the last sub-iteration's rows and ghosts (rank_keep_rows)
  // within an interval; a regrid point and a recorded sub-iteration rebuild them.
  const bool keep = rank_ && global_.on && rank_->keepable && !regridding && !record;
  const auto cut_again = [&] {
    if (rank_) {
      PhaseTimer::Scope t(timer_, Phase::neighbor);
      p_.resize(owned_); // the last sub-iteration's ghosts go
      rank_regrid();
      outside = rank_locate(true, outside_message, outside_key);
    } else {
      regrid();
    }
  };
  if (regridding && !held) {
    cut_again();
  } else if (rank_) {
    if (!keep)
      p_.resize(owned_);
    PhaseTimer::Scope t(timer_, Phase::neighbor);
    if (held)
      wrap_positions();
    outside = rank_locate(held, outside_message, outside_key); // held: leaves_.of may be unset
  } else if (held) {
    PhaseTimer::Scope t(timer_, Phase::regrid);
    wrap_positions();
    sort_into_leaves(); // into the leaves that hold them now
  }
  bool fresh = false;
  if (!rank_ && global_.hold) {
    // One rank, a held global interval: no mode to decide, so neither the proximity candidates
    // nor the leaves' membership are needed; the contact pairs are rebuilt as the explicit
    // scheme's list, when the last step left a particle skin/2 from their build. A recorded
    // sub-iteration re-sorts first: its state names each particle's leaf.
    if (record)
      sort_into_leaves();
    global_.on = true;
  } else if (!rank_ && regridding && pairs_.valid && pairs_.contact_only && !cfg_.time_to_contact &&
             held_global_decision()) {
    // One rank, the regrid point after a held global interval, whose pairs are the contact
    // candidates alone: the mode is decided without the proximity candidates, and if it stays
    // global those pairs hold while no particle has moved skin/2 since their build (the held
    // steps' rule, measured on the state by wrap_positions, as a restart has it).
    global_.on = true;
  } else {
    global_.moved = false; // the build's expiry test (rows_expire) covers the last steps
    fresh = keep && rank_keep_rows() ? false : build_rows(false);
  }
  if (held && !global_.on) { // the leaf steps follow: on the leaves of a new ORB
    cut_again();
    fresh = build_rows(false) || fresh;
  }
  // The regrid point's choice of the global mode holds to the next one (kGlobalFraction).
  if (regridding && global_.on)
    global_.hold = true;
  // One rank, held: the last step outran the contact candidates, which are built again.
  if (!rank_ && global_.hold && global_.moved) {
    rebuild_pairs(true);
    global_.moved = false;
  }
  // One reduction closes the sub-iteration (on R ranks): {outran, faults, outside, owned,
  // particle steps, force evaluations, overlaps beyond the bound, fine leaves, non-empty leaves}.
  std::array<std::int64_t, 9> c{};
  std::int64_t local_steps = 0, local_evals = 0;
  while (true) {
    PhaseTimer::Scope t(timer_, Phase::force);
    // One rank's global steps have no frozen partners and never roll back; on R ranks they are
    // redone when a particle outruns the rows (the state at the start is the rollback point).
    if (!global_.on || rank_)
      freeze();
    plan(record);
    c = {};
    c[0] = attempt(record) ? 1 : 0;
    c[2] = outside;
    c[3] = static_cast<std::int64_t>(owned_);
    for (const Batch& bt : batches_) {
      c[1] += bt.fault != Fault::none ? 1 : 0;
      c[4] += static_cast<std::int64_t>(bt.e - bt.b) * bt.K;
      c[5] += bt.evals;
      c[6] += bt.violations;
    }
    if (rank_ && rank_->kept) { // the store is not in leaf order: this rank's leaves
      c[7] += static_cast<std::int64_t>(rank_->kept_leaves.size());
      c[8] += static_cast<std::int64_t>(rank_->kept_leaves.size());
    } else {
      for (std::size_t k = 0; k < leaves_.id.size(); ++k)
        if (leaves_.range[k + 1] > leaves_.range[k])
          c[7] += leaves_.fine[k], c[8] += 1;
    }
    local_steps = c[4], local_evals = c[5];
    if (rank_) {
      rank_->comm.sum(c);
      if (c[2] > 0) {
        const std::string e = rank_->comm.agree_on_error(outside_key, outside_message);
        throw RunError(e.empty() ? std::string("a particle left the domain") : e);
      }
      // None lost, none duplicated: the owned counts add up to the total at every sub-iteration.
      if (c[3] != cfg_.n_global)
        throw RunError(fmt::format("t = {:.9g} s: {} particles on the ranks after migration, {} "
                                   "expected",
                                   time(), c[3], cfg_.n_global));
    }
    if (c[0] == 0 || c[1] > 0)
      break;
    // A fine leaf (on some rank) outran its rows (a collision sped a particle up): roll back,
    // rebuild, redo; if the rows were already fresh, with twice the skin (until the regrid).
    if (fresh && skin_ >= cfg_.skin_cap)
      throw RunError(outran_skin_cap(time(), skin_, "raise dem.nsubit"));
    roll_back();
    if (fresh)
      skin_ = std::min(2.0 * skin_, cfg_.skin_cap);
    ++stats_.retries;
    if (rank_)
      rank_->dest.assign(owned_, rank_->comm.rank()); // the particles are where they belong
    fresh = build_rows(true);
  }
  if (c[1] > 0)
    raise_fault();
  // Counters, reduced in batch order.
  for (const Batch& bt : batches_) {
    stats_.ratio = std::max(stats_.ratio, bt.max_ratio);
    if (cfg_.cost_weights)
      for (std::uint32_t i = bt.b; i < bt.e; ++i)
        cost_[i] += static_cast<double>(bt.K);
  }
  const bool can_refine = model_.dt < cfg_.dt_sp;
  const std::int64_t K_fine = fine_steps(cfg_.dt_sp, model_.dt).K;
  if (rank_ && rank_->kept) {
    for (const int l : rank_->kept_leaves) // every leaf fine (the global mode), by its owner
      stats_.leaf_steps[static_cast<std::size_t>(l)] += K_fine;
  } else {
    for (std::size_t k = 0; k < leaves_.id.size(); ++k)
      if (leaves_.range[k + 1] > leaves_.range[k])
        stats_.leaf_steps[static_cast<std::size_t>(leaves_.id[k])] +=
            leaves_.fine[k] && can_refine ? K_fine : 1;
  }
  stats_.particle_steps += c[4], stats_.pair_evaluations += c[5];
  stats_.overlap_violations += c[6];
  stats_.local_particle_steps += local_steps, stats_.local_pair_evaluations += local_evals;
  stats_.fine_count += c[7], stats_.leaf_subits += c[8];
  stats_.last_fine_fraction =
      c[8] > 0 ? static_cast<double>(c[7]) / static_cast<double>(c[8]) : 0.0;
  // On R ranks the largest overlap over the ranks is reduced only when the state is recorded
  // (the loop records the last sub-iteration): one reduction per sub-iteration is the budget.
  if (!rank_ || record)
    stats_.max_overlap_ratio = std::max(stats_.max_overlap_ratio, all_max(stats_.ratio));
  ++stats_.subits;
  if (global_.on) {
    ++stats_.global_subits;
    // The leaf steps rewrite the force of the particles with rows only: derive_rows clears the
    // rest (the global steps left theirs behind).
    drop_rows();
  }
  if (!rank_ && !global_.hold)
    resort(); // a held interval's store is re-sorted by the next regrid
}

void OrbScheme::benchmark_leaf_subiteration(int leaf) {
  const auto l = static_cast<std::size_t>(leaf);
  Batch bt;
  bt.b = leaves_.range[l], bt.e = leaves_.range[l + 1];
  const FineSteps steps = fine_steps(cfg_.dt_sp, model_.dt);
  bt.K = steps.K;
  bt.h = steps.h;
  bt.h_last = steps.h_last;
  const auto& active = rows_.active;
  bt.a0 = static_cast<std::uint32_t>(std::lower_bound(active.begin(), active.end(), bt.b) -
                                     active.begin());
  bt.a1 = static_cast<std::uint32_t>(std::lower_bound(active.begin(), active.end(), bt.e) -
                                     active.begin());
  run_batch(bt, false);
}

void OrbScheme::benchmark_ghost_refresh() {
  freeze();
  derive_rows();
}

void OrbScheme::set_external_force(std::span<const double> fx, std::span<const double> fy,
                                   std::span<const double> fz) {
  if (!rank_) {
    ext_.set(fx, fy, fz, owned_);
    return;
  }
  // On when any rank passes values (a rank without particles passes empty spans): the columns
  // that travel with the particles must be the same on every rank.
  const Communicator& comm = rank_->comm;
  const bool on = comm.max(fx.empty() ? 0.0 : 1.0) > 0.0;
  const bool fits = on ? fx.size() == owned_ && fy.size() == owned_ && fz.size() == owned_
                       : fy.empty() && fz.empty();
  if (comm.max(fits ? 0.0 : 1.0) > 0.0)
    throw std::invalid_argument("set_external_force: one value per owned particle expected");
  rank_->ext_on = on;
  ext_.x.assign(fx.begin(), fx.end()), ext_.y.assign(fy.begin(), fy.end());
  ext_.z.assign(fz.begin(), fz.end());
}

void OrbScheme::replace_external_force(std::span<const double> fx, std::span<const double> fy,
                                       std::span<const double> fz) {
  // hprev_ was sized at construction; after a checkpoint restore it is the saved one. A force
  // of the wrong size is refused by set_external_force below.
  const bool fits =
      (fx.empty() || (fx.size() == owned_ && fy.size() == owned_ && fz.size() == owned_)) &&
      (!ext_.active() || ext_.x.size() == owned_);
  if ((ext_.active() || !fx.empty()) && fits)
    settle_owed_half_kick(
        std::span<double>(p_.vx).first(owned_), std::span<double>(p_.vy).first(owned_),
        std::span<double>(p_.vz).first(owned_), p_.inv_mass,
        std::span<const double>(hprev_).first(owned_), ext_.x, ext_.y, ext_.z, fx, fy, fz);
  set_external_force(fx, fy, fz);
}

void OrbScheme::set_interval(double interval) {
  if (stats_.subits % cfg_.nsubit != 0)
    throw RunError("orb: the sub-iteration length changed between regrid points (internal error)");
  IntervalClock::check_interval(interval, "orb");
  clock_.set_length(stats_.subits, cfg_.dt_sp, interval / static_cast<double>(cfg_.nsubit));
}

OrbScheme::State OrbScheme::save_state() const {
  if (stats_.subits % cfg_.nsubit != 0)
    throw RunError("orb checkpoint requested between regrid points (internal error)");
  State s;
  s.hprev = hprev_, s.cost = cost_, s.leaf_steps = stats_.leaf_steps;
  if (rank_)
    rank_->comm.sum(s.leaf_steps);
  s.fine_count = stats_.fine_count, s.leaf_subits = stats_.leaf_subits, s.subits = stats_.subits;
  s.particle_steps = stats_.particle_steps, s.pair_evaluations = stats_.pair_evaluations;
  s.builds = stats_.builds, s.regrids = stats_.regrids;
  s.overlap_violations = stats_.overlap_violations, s.retries = stats_.retries;
  s.global_subits = stats_.global_subits;
  s.last_fine_fraction = stats_.last_fine_fraction;
  s.max_overlap_ratio = std::max(stats_.max_overlap_ratio, all_max(stats_.ratio));
  s.skin = skin_;
  // One rank: the candidate pairs survive the regrid (R ranks rebuild rows every sub-iteration),
  // a held global interval's contact candidates alone too.
  s.pairs_valid = !rank_ && pairs_.valid, s.prox_from_pairs = pairs_.prox_from_pairs;
  s.pairs_contact_only = s.pairs_valid && pairs_.contact_only;
  s.global_hold = global_.hold;
  if (global_.hold) {
    for (const partition::OrbCut& c : decomp_.tree.cuts())
      s.cut_axis.push_back(c.axis), s.cut_position.push_back(c.position);
    s.leaf_owner.assign(decomp_.owner.begin(), decomp_.owner.end());
  }
  if (s.pairs_valid) {
    s.ca = pairs_.ca, s.cb = pairs_.cb, s.pa = pairs_.pa, s.pb = pairs_.pb;
    s.x_ref = pairs_.xr, s.y_ref = pairs_.yr, s.z_ref = pairs_.zr;
  }
  if (model_.friction)
    s.history = current_history();
  s.clock = clock_.saved(stats_.subits, cfg_.dt_sp);
  return s;
}

void OrbScheme::restore_state(State s) {
  const std::size_t n = owned_;
  if (s.hprev.size() != n || s.cost.size() != n || s.subits < 0 || s.subits % cfg_.nsubit != 0 ||
      (!s.leaf_steps.empty() && s.leaf_steps.size() != stats_.leaf_steps.size()))
    throw RunError("checkpoint: the orb state does not fit the particles, dem.nsubit or "
                   "partition.orb_levels");
  if (rank_)
    s.pairs_valid = false; // R ranks build their rows from the particles
  if (s.pairs_valid) {
    bool ok = s.ca.size() == s.cb.size() && s.pa.size() == s.pb.size() && s.x_ref.size() == n &&
              s.y_ref.size() == n && s.z_ref.size() == n;
    for (const auto* v : {&s.ca, &s.cb, &s.pa, &s.pb})
      for (std::uint32_t i : *v)
        ok = ok && i < n;
    if (!ok)
      throw RunError("checkpoint: the orb candidate pairs do not fit the particles");
  }
  if (!clock_.restore(s.clock))
    throw RunError("checkpoint: the orb scheme's interval clock is not a time and a count");
  hprev_ = std::move(s.hprev), cost_ = std::move(s.cost);
  // The per-leaf steps of the interval are sums over the ranks: rank 0 holds them.
  std::fill(stats_.leaf_steps.begin(), stats_.leaf_steps.end(), 0);
  if (!s.leaf_steps.empty() && (!rank_ || rank_->comm.rank() == 0))
    stats_.leaf_steps = std::move(s.leaf_steps);
  stats_.fine_count = s.fine_count, stats_.leaf_subits = s.leaf_subits, stats_.subits = s.subits;
  stats_.particle_steps = s.particle_steps, stats_.pair_evaluations = s.pair_evaluations;
  stats_.builds = s.builds, stats_.regrids = s.regrids;
  stats_.overlap_violations = s.overlap_violations, stats_.retries = s.retries;
  stats_.global_subits = s.global_subits;
  stats_.last_fine_fraction = s.last_fine_fraction, stats_.max_overlap_ratio = s.max_overlap_ratio;
  stats_.ratio = 0.0;
  if (s.skin > 0.0)
    skin_ = s.skin;
  pairs_.valid = s.pairs_valid, pairs_.prox_from_pairs = s.prox_from_pairs;
  pairs_.contact_only = s.pairs_valid && s.pairs_contact_only;
  global_.hold = false, global_.moved = false;
  pairs_.ca = std::move(s.ca), pairs_.cb = std::move(s.cb);
  pairs_.pa = std::move(s.pa), pairs_.pb = std::move(s.pb);
  pairs_.xr = std::move(s.x_ref), pairs_.yr = std::move(s.y_ref), pairs_.zr = std::move(s.z_ref);
  if (!pairs_.valid)
    pairs_.ca.clear(), pairs_.cb.clear(), pairs_.pa.clear(), pairs_.pb.clear(), pairs_.xr.clear(),
        pairs_.yr.clear(), pairs_.zr.clear();
  rows_.off.clear(); // rows are derived again, the history attached to them by ids
  global_.stale = true;
  hist_.hx.clear(), hist_.hy.clear(), hist_.hz.clear(), hist_.ids.clear();
  hist_.pending = std::move(s.history);
  if (s.global_hold)
    restore_held_tree(s);
}

// A held global interval's ORB (State::global_hold), which the next regrid point decides on
// instead of a new one, after sorting the store into its leaves (sort_into_leaves). The cuts are
// the tree on any rank count; the leaves' ranks are the saved ones where they fit this rank
// count, else contiguous blocks of leaves (where the particles are stepped, not how).
void OrbScheme::restore_held_tree(State& s) {
  const std::size_t nl = std::size_t{1} << cfg_.levels;
  bool ok = s.cut_axis.size() == nl - 1 && s.cut_position.size() == nl - 1;
  std::vector<partition::OrbCut> cuts(nl - 1);
  for (std::size_t k = 0; ok && k + 1 < nl; ++k) {
    ok = s.cut_axis[k] >= 0 && s.cut_axis[k] < 3 && std::isfinite(s.cut_position[k]);
    cuts[k] = {static_cast<int>(s.cut_axis[k]), s.cut_position[k]};
  }
  if (!ok)
    throw RunError("checkpoint: the orb scheme's held ORB does not fit partition.orb_levels");
  decomp_.tree = partition::OrbTree::from_cuts({}, {}, {}, domain_, cfg_.levels, std::move(cuts));
  const int ranks = rank_ ? rank_->comm.size() : 1;
  bool owners_fit = s.leaf_owner.size() == nl;
  for (const std::int64_t r : s.leaf_owner)
    owners_fit = owners_fit && r >= 0 && r < ranks;
  decomp_.owner.resize(nl);
  for (std::size_t l = 0; l < nl; ++l)
    decomp_.owner[l] = owners_fit ? static_cast<int>(s.leaf_owner[l])
                                  : static_cast<int>(l * static_cast<std::size_t>(ranks) / nl);
  global_.hold = true;
  if (!rank_) {
    leaves_.id.resize(nl);
    std::iota(leaves_.id.begin(), leaves_.id.end(), 0);
    leaves_.range.assign(nl + 1, 0);
    decomp_.load.assign(1, static_cast<double>(p_.size()));
  }
}

LeafStepStats OrbScheme::take_interval_stats() {
  std::vector<std::int64_t> steps = stats_.leaf_steps;
  if (rank_)
    rank_->comm.sum(steps);
  std::fill(stats_.leaf_steps.begin(), stats_.leaf_steps.end(), 0);
  LeafStepStats s;
  std::int64_t lo = std::numeric_limits<std::int64_t>::max(), hi = 0, sum = 0, count = 0;
  for (const std::int64_t v : steps)
    if (v > 0)
      lo = std::min(lo, v), hi = std::max(hi, v), sum += v, ++count;
  if (count > 0) {
    s.steps_min = static_cast<double>(lo), s.steps_max = static_cast<double>(hi);
    s.steps_mean = static_cast<double>(sum) / static_cast<double>(count);
  }
  s.fine_fraction = stats_.leaf_subits > 0 ? static_cast<double>(stats_.fine_count) /
                                                 static_cast<double>(stats_.leaf_subits)
                                           : 0.0;
  stats_.fine_count = stats_.leaf_subits = 0;
  return s;
}

} // namespace cfddem::dem
