// The `orb` scheme (dem.scheme = "orb"): the explicit adaptive time stepping of Sitaraman & Grout
// (Algorithm 2). Every dem.regrid_interval (dt_f) the particles are split by an ORB into
// 2^partition.orb_levels leaves and the store is permuted so that each leaf is a contiguous
// range; time advances in sub-iterations of dt_sp = dt_f / dem.nsubit, in each of which every
// leaf picks its own step (the fine step tau_p * dt_factor if one of its particles has a close
// partner or wall, else one step of dt_sp) and takes K = ceil(dt_sp / dt_local) velocity-Verlet
// steps with the explicit scheme's contact law, reading the particles of other leaves frozen at
// the sub-iteration's start. Leaves with the same step run together as TBB tasks. Where nearly
// every leaf would step finely, one rank without friction takes the sub-iteration as global
// steps through the explicit scheme's passes instead (kGlobalFraction, the global mode).
// Velocities are kept at half steps with the half step's length per particle (variable-step
// leapfrog: a constant step is the explicit update exactly). An overlap beyond dem.max_overlap is
// counted, not fatal; NaN or a particle leaving through a wall stops the run.
//
// One class for one rank and R ranks (its rank steps: dem/orb_rank_part.cpp): the leaves of the
// parallel ORB are dealt to ranks by the knapsack, and every particle's position and velocity
// equal the one-rank leaf steps' bit for bit on any rank and thread count. The rule, the
// implementation (candidate pairs, rows, batches, roll-back, friction's history, the rank steps)
// and what each costs: docs/schemes.md, "orb"; the paper's rule: docs/theory.md §8.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_exchange.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/cell_list.hpp"
#include "dem/contact_history.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/external_force.hpp"
#include "dem/global_pairs.hpp"
#include "dem/interval_clock.hpp"
#include "dem/pair_contacts.hpp"
#include "dem/pair_stream.hpp"
#include "dem/travel_bound.hpp"
#include "partition/orb_tree.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::dem {

struct FineSteps; // dem/scheme_support.hpp

// Local steps per leaf over an output interval (non-empty leaves only), and the fraction of
// (leaf, sub-iteration) pairs that took the fine step.
struct LeafStepStats {
  double steps_min = 0.0, steps_mean = 0.0, steps_max = 0.0, fine_fraction = 0.0;
};

struct LeafLive;
struct LeafFrozen;
struct LeafSpin;
struct LeafRows;
struct LeafStep;
struct OverlapTally;

class OrbScheme {
public:
  // One rank: the step model from `particles` (every particle of the scene).
  OrbScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer);
  // Any rank count: `particles` is this rank's share (any split: the first sub-iteration moves
  // each to its owner); `model`: make_step_model over all particles, the same on every rank;
  // `comm` nullptr or of one rank: the one-rank path. With friction the store gets rotation.
  OrbScheme(const Scene& scene, ParticleStore& particles, const StepModel& model,
            const Communicator* comm, PhaseTimer& timer);
  ~OrbScheme();
  OrbScheme(const OrbScheme&) = delete;
  OrbScheme& operator=(const OrbScheme&) = delete;

  // h_prev = 0 (velocities are the synchronised v(0)); evaluates nothing.
  void start();
  // One sub-iteration t -> t + dt_sp (collective). With record = true the state at t (x and the
  // synchronised v(t) = v(t-h_prev) + a(t) h_prev, with a(t) from the first local step) is kept.
  // On a fault every rank throws the same RunError.
  void subiterate(bool record = false);

  double dt_fine() const { return model_.dt; }
  double dt_sub() const { return cfg_.dt_sp; }
  std::int64_t nsubit() const { return cfg_.nsubit; }
  std::int64_t subiterations() const { return stats_.subits; }
  double time() const { return clock_.time(stats_.subits, cfg_.dt_sp); }
  // An adaptive fluid.dt: the next fluid step's length, taken from here on in dem.nsubit
  // sub-iterations of interval / nsubit. Only at a regrid point (subiterations() a multiple of
  // nsubit); throws RunError if `interval` is not a positive finite length.
  void set_interval(double interval);
  // Over all ranks (the same value on every rank).
  std::int64_t particle_steps() const { return stats_.particle_steps; }
  // Per local step, own-leaf pairs once plus other-leaf pairs once per side, over the rows (on R
  // ranks the rows are rebuilt at every sub-iteration, so the count differs from one rank's).
  std::int64_t pair_evaluations() const { return stats_.pair_evaluations; }
  // This rank's share since this process started (run.json's rank_counts; not in checkpoints).
  std::int64_t local_particle_steps() const { return stats_.local_particle_steps; }
  std::int64_t local_pair_evaluations() const { return stats_.local_pair_evaluations; }
  std::int64_t neighbor_builds() const { return stats_.builds; }
  std::int64_t regrids() const { return stats_.regrids; }
  // Sub-iterations redone with a larger skin because a fine leaf outran its rows.
  std::int64_t retries() const { return stats_.retries; }
  // Sub-iterations run in the global mode (kGlobalFraction).
  std::int64_t global_subiterations() const { return stats_.global_subits; }
  // The global mode (no friction, dem.orb_global): a sub-iteration at whose start the
  // leaves that would take the fine step hold more than this fraction of the particles runs as
  // global steps: every particle takes the K fine steps together through the explicit scheme's
  // pair pass and scatter over the candidate pairs (each pair once, every partner live: no
  // frozen copies, no rows, no batches). The cost argument: with a fraction f of the particles
  // in fine leaves a sub-iteration costs about N (f K c_leaf + (1 - f)) against N K c_global
  // in the global mode, where c_leaf is a fine leaf particle's step (its rows' pairs, a pair
  // across leaves evaluated from both sides, the batch loop) and c_global a global particle step
  // (each pair once, flat streams). On HCS 1222 (1% solids, 64 leaves, nsubit 15, K = 47, 90% of
  // the leaves fine) the force phase per particle step measured 2.62 ns in the leaf steps and
  // 1.87 ns in the global mode (best of three runs each, dem.orb_global false and true; single
  // runs on this shared machine spread c_leaf / c_global over 1.15-1.75), c_leaf = 1.4 c_global,
  // so the global mode is the cheaper from f = 1 / 1.4 = 0.71 on (a coarse step, 1 / K of a fine
  // particle's, barely moves it). 3/4 keeps a margin above that break-even for the spread (between
  // 0.71 and 0.75 the leaf steps cost at most 5% more than the global ones), and where the two
  // cost about the same the global mode is the more accurate (no frozen partners). Below it (a
  // bed whose leaves differ, a settling or wall-bounded flow) the sub-iteration is the paper's
  // leaf steps, bit for bit. On R ranks every rank takes the choice one rank takes (the fine
  // particles summed over the ranks); the global steps there run over the rank's rows (each
  // owned pair once, a pair with a ghost on both its ranks, the ghosts' x and v refreshed before
  // every step) and agree with one rank's to round-off (the sums run in another order); a
  // particle that moves more than skin/2 redoes the sub-iteration with twice the skin, as a
  // fine leaf that outruns its rows. A regrid point's choice of the global mode holds to the
  // next regrid point (Global::hold: the global steps are never less accurate than the leaf
  // steps, and choosing at every sub-iteration took the proximity candidates and a re-sort
  // each time); that point decides on the leaves as they are and cuts a new ORB only when the
  // leaf steps follow (docs/schemes.md, "Global mode").
  static constexpr double kGlobalFraction = 0.75;
  double skin() const { return skin_; }
  // On R ranks: over all ranks as of the last recorded sub-iteration (subiterate(true)).
  double max_overlap_ratio() const { return stats_.max_overlap_ratio; }
  std::int64_t overlap_violations() const { return stats_.overlap_violations; }
  // Fraction of non-empty leaves on the fine step in the last sub-iteration.
  double last_fine_fraction() const { return stats_.last_fine_fraction; }
  const StepModel& model() const { return model_; }
  int leaf_count() const { return 1 << cfg_.levels; }
  std::int64_t global_count() const { return cfg_.n_global; }
  // The decomposition of the last regrid (one rank: every leaf on rank 0) and its ORB.
  const partition::RankDecomposition& decomposition() const { return decomp_; }
  const partition::OrbTree& tree() const { return decomp_.tree; }
  // Per regrid: max over ranks / mean of the knapsack load (empty on one rank).
  const std::vector<double>& imbalances() const { return imbalances_; }
  // This rank: owned particles are [0, owned()) of the store, ghosts after them (none on one
  // rank).
  std::size_t owned() const { return owned_; }
  std::size_t ghosts() const { return p_.size() - owned_; }

  // Benchmark hooks (perf/dem, one rank, dem.orb_global = false: the leaf steps' rows): after
  // at least one subiterate(), run leaf `leaf`'s fine-step sub-iteration alone (the batch of
  // that one leaf, from the current state), and refresh the ghosts (frozen copies and the rows'
  // own/other-leaf split, as after a re-sort).
  void benchmark_leaf_subiteration(int leaf);
  void benchmark_ghost_refresh();

  // Collective. Per-particle external force [N] (the gas's drag and pressure), one value per
  // owned particle in the store's current order: held fixed until set again, follows its
  // particle through regrids, re-sorts and migrations; empty spans (on every rank) remove it.
  void set_external_force(std::span<const double> fx, std::span<const double> fy,
                          std::span<const double> fz);
  // The force held now, in the store's order (empty: none).
  [[nodiscard]] const ExternalForce& external_force() const { return ext_; }
  // At a fluid-step boundary (the coupled loops' gas step): the owed half kick settled with the
  // force held so far (settle_owed_half_kick, dem/external_force.hpp), then set_external_force.
  // set_external_force alone is for a restart (the held force as it was).
  void replace_external_force(std::span<const double> fx, std::span<const double> fy,
                              std::span<const double> fz);

  // Collective: statistics over all ranks since the last call (then reset).
  LeafStepStats take_interval_stats();

  // The owned particles' recorded state, with the identity, radius, ORB leaf and local step
  // (dt_sp / the leaf's step count) of each, in the same order (snapshots).
  struct Synchronised {
    std::span<const double> x, y, z, vx, vy, vz, mass;
    std::span<const std::int64_t> id, leaf;
    std::span<const double> radius, local_dt;
  };
  Synchronised synchronised_previous() const {
    return {rec_.x,    rec_.y,  rec_.z,    rec_.vx,     rec_.vy, rec_.vz,
            rec_.mass, rec_.id, rec_.leaf, rec_.radius, rec_.dt};
  }

  // Checkpoint/restart at a regrid point (subiterations() a multiple of dem.nsubit): the ORB,
  // the leaf ranges, the rows and the batches are rebuilt from the particle store by the next
  // sub-iteration exactly as they would have been. Saved: the owned particles' half step and
  // cost weights (store order), the counters over all ranks and the interval statistics, and on
  // one rank the candidate pairs with their reference positions (global indices in the store's
  // order, which the checkpoint keeps). restore_state() replaces start(); on R ranks each rank
  // passes the h_prev and cost of its share of the checkpoint's particles.
  struct State {
    std::vector<double> hprev, cost;
    std::vector<std::int64_t> leaf_steps;
    std::int64_t fine_count = 0, leaf_subits = 0, subits = 0, particle_steps = 0,
                 pair_evaluations = 0, builds = 0, regrids = 0, overlap_violations = 0, retries = 0;
    std::int64_t global_subits = 0; // absent from older checkpoints: 0
    double last_fine_fraction = 0.0, max_overlap_ratio = 0.0, skin = 0.0;
    // Candidate pairs: contact (ca, cb) and proximity (pa, pb); references x_ref..z_ref.
    bool pairs_valid = false, prox_from_pairs = true;
    bool pairs_contact_only = false; // absent from older checkpoints: false
    std::vector<std::uint32_t> ca, cb, pa, pb;
    std::vector<double> x_ref, y_ref, z_ref;
    ContactHistory history; // friction: the tangential history by particle ids
    std::vector<double> clock; // IntervalClock::saved(): empty unless dt_sp has changed
    // A held global interval (Global::hold; absent from older checkpoints: none): the ORB the
    // next regrid point decides on (its cuts, in heap order) and the leaves' ranks.
    bool global_hold = false;
    std::vector<std::int64_t> cut_axis, leaf_owner;
    std::vector<double> cut_position;
  };
  State save_state() const;    // collective
  void restore_state(State s); // throws RunError if it does not fit the store

private:
  struct Batch;
  struct RankPart;
  // Constants of the run.
  struct Config {
    double dt_sp = 0.0, r_max = 0.0, skin_cap = 0.0, prox = 0.0; // prox: proximity_radii / 2
    std::int64_t nsubit = 1, n_global = 0;
    int levels = 0;
    bool cost_weights = false, time_to_contact = false;
    bool global = false; // the global mode may be taken (kGlobalFraction)
    std::int64_t global_min_per_rank = 0; // R ranks: dem.orb_global_min_per_rank
  };
  // The leaves this rank advances: leaf id[k] owns [range[k], range[k+1]) of the store (one
  // rank: every leaf, empty ones included, id[k] = k; R ranks: the non-empty owned ones).
  struct Leaves {
    std::vector<int> id;
    std::vector<std::uint32_t> range;
    std::vector<std::uint32_t> of; // per owned particle: its leaf
    std::vector<unsigned char> fine;
  };
  // One rank's persistent candidate pairs (a, b), global indices, valid while every particle
  // stays within skin/2 of its reference position: contact candidates (centres within
  // r_a + r_b + skin) and proximity candidates (within prox (r_a + r_b) + skin), and the cell
  // list that builds them. contact_only: built in a held global interval (Global::hold), with
  // no proximity candidates; the next sub-iteration that decides its mode builds them again.
  struct Pairs {
    std::vector<std::uint32_t> ca, cb, pa, pb;
    std::vector<double> xr, yr, zr;
    bool valid = false, prox_from_pairs = true, contact_only = false;
    CellList cells;
    std::array<std::vector<double>, 4> sorted; // x, y, z, radius in cell order
  };
  // Rows (one rank: derived from the contact candidates; R ranks: OrbLocalRows'): particle i's
  // own-leaf partners [off[i], mid[i]), others up to off[i+1]; own_before[i]: own-leaf entries
  // of the particles [0, i); near: a partner or wall within the proximity (or reach) distance.
  struct Rows {
    std::vector<std::uint32_t> off, mid, nb, active, own_before;
    std::vector<unsigned char> near;
  };
  // The state at the start of the sub-iteration: what other leaves read, and the rollback point
  // (with friction: the spins and the history per row entry too).
  struct Frozen {
    std::vector<double> x, y, z, vx, vy, vz, hp;
    std::vector<double> wx, wy, wz, hx, hy, hz;
  };
  // Friction: the tangential history per entry of rows_.nb, the ids of the store's slots when the
  // rows were derived (the rows' indices name slots of that order), and records waiting for the
  // next derivation (collected when the rows were dropped, or handed in by a restore).
  struct History {
    std::vector<double> hx, hy, hz;
    std::vector<std::int64_t> ids;
    ContactHistory pending;
  };
  // The recorded state (subiterate(true)).
  struct Record {
    std::vector<double> x, y, z, vx, vy, vz, mass, radius, dt;
    std::vector<std::int64_t> id, leaf;
  };
  // Counters (over all ranks unless local_) and the interval statistics.
  struct Stats {
    std::vector<std::int64_t> leaf_steps; // per leaf, this rank's part, this interval
    std::int64_t fine_count = 0, leaf_subits = 0;
    double last_fine_fraction = 0.0, max_overlap_ratio = 0.0;
    double ratio = 0.0; // this rank's largest overlap ratio (max_overlap_ratio: over the ranks)
    std::int64_t subits = 0, particle_steps = 0, pair_evaluations = 0, builds = 0, regrids = 0,
                 overlap_violations = 0, retries = 0, global_subits = 0;
    std::int64_t local_particle_steps = 0, local_pair_evaluations = 0;
  };

  // The global mode's state: the candidate contact pairs (R ranks: the rows' pairs) through the
  // explicit scheme's pair pass (stale after a build, or on one rank a re-sort), ordered by their
  // lower particle index; `on`: this sub-iteration is global; `hold`: the regrid's sub-iteration
  // chose the global mode, which then holds until the next regrid (kGlobalFraction); `moved`
  // (one rank): the last global step left a particle more than skin/2 from the pairs' build.
  // first: the counting sort's offsets per particle (one rank).
  struct Global {
    GlobalPairs pairs;
    std::vector<std::uint32_t> first;
    std::vector<std::uint64_t> still; // per block of the update: sign bit set while within skin/2
    std::int64_t once = 0; // R ranks: the pairs counted per step (a pair with a ghost on one rank)
    bool stale = true, on = false, hold = false, moved = false;
    TravelBound travel; // one rank: how far the particles can be from the pairs' build
  };

  // The sub-iteration's steps (orb_scheme.cpp).
  bool build_rows(bool force);
  void freeze();
  void plan(bool record);
  bool attempt(bool record);
  void run_batch(Batch& b, bool record);
  template <bool Column> void find_batch_fault(Batch& bt, const LeafLive& p) const;
  bool choose_global();
  bool held_global_decision();
  std::int64_t measure_travel();
  bool global_allowed() const;
  void mark_fine_leaves(std::span<const unsigned char> near);
  void plan_leaf_batches(const FineSteps& steps);
  void record_start();
  void global_stream();
  void run_global(Batch& b, bool record);
  template <bool External, bool Column> void run_global_impl(Batch& b, bool record);
  template <bool External, bool Friction, bool Column> void run_batch_impl(Batch& b, bool record);
  void roll_back();
  [[noreturn]] void raise_fault();
  LeafLive live(bool external);
  LeafFrozen frozen() const;
  LeafSpin spin();
  LeafRows rows_view() const;
  double all_max(double v) const;
  bool time_to_contact_speeds();
  void mark_walls(std::span<unsigned char> near) const;
  // One rank's steps (orb_rows.cpp).
  void wrap_positions();
  void restore_held_tree(State& s);
  std::uint32_t leaf_holding(std::size_t i) const;
  double separation2(std::uint32_t a, std::uint32_t c) const;
  void regrid();
  void resort();
  void sort_into_leaves();
  void apply_permutation(std::span<const std::uint32_t> order);
  void relabel_pairs(std::span<const std::uint32_t> old_slot);
  // Whether one of the first n particles may move more than skin/2 from `ref` (x, y, z) within
  // this sub-iteration: |x - ref| + |v| dt_sp > skin/2 (or not finite).
  bool rows_expire(std::size_t n, const std::array<const double*, 3>& ref) const;
  // contact_only: without the proximity candidates (a held global interval needs none).
  void rebuild_pairs(bool contact_only = false);
  void derive_rows();
  void drop_rows();
  ContactHistory current_history() const;
  void mark_near(bool contact_bound = false);
  // R ranks' steps (orb_rank_part.cpp).
  void rank_regrid();
  std::int64_t rank_locate(bool regridding, std::string& message, std::int64_t& key);
  void rank_exchange_and_rows();
  double rank_reach(bool keep) const;
  int short_periodic_axis(double cutoff) const;
  double rank_cutoff(bool keep) const;
  bool rank_rows_keepable() const;
  bool rank_keep_rows();
  std::vector<ParticleExchange::Copy> rank_halo_copies(double cutoff);
  void rank_rows(double cutoff, bool keep);
  bool rank_choose_global();
  void rank_global_stream();
  void run_global_ranks(Batch& b, bool record);
  template <bool External, bool Column>
  bool global_step(Batch& bt, LeafStep& st, const LeafLive& p, const LeafFrozen& ref,
                   OverlapTally& tally, std::int64_t evals, bool record);
  template <bool External, bool Column> void run_global_ranks_impl(Batch& b, bool record);

  const Scene& scene_;
  ParticleStore& p_;
  PhaseTimer& timer_;
  DomainGeometry geom_;
  StepModel model_;
  partition::Aabb domain_;
  Config cfg_;
  double skin_ = 0.0;     // grows by retries and time_to_contact until the next regrid
  double reach_ = 0.0;    // time_to_contact: the largest speed bound x dt_sp (over the ranks)
  std::size_t owned_ = 0; // this rank's particles: [0, owned_) of the store
  partition::RankDecomposition decomp_;
  std::vector<double> imbalances_;
  // Per owned particle: half of its last step, local steps since the regrid, the external force;
  // with time_to_contact, the speed bound (owned and ghosts).
  std::vector<double> hprev_, cost_, speed_;
  ExternalForce ext_;
  Leaves leaves_;
  Pairs pairs_;
  Rows rows_;
  Frozen frozen_;
  History hist_;
  Global global_;
  Record rec_;
  Stats stats_;
  IntervalClock clock_;
  std::vector<Batch> batches_;
  std::vector<std::uint32_t> scratch_, fill_; // index scratch (one rank)
  std::vector<double> dscratch_;
  std::unique_ptr<RankPart> rank_; // null on one rank
};

} // namespace cfddem::dem
