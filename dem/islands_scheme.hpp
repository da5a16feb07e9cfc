// The `islands` scheme (dem.scheme = "islands"): adaptive steps that miss no collision. Time
// advances in sub-iterations of dt_sp, as in `orb`. At the start of each one every particle gets
// a speed bound over the sub-iteration; pairs whose gap could close within dt_sp are linked (and
// particles tied to walls likewise), the connected components are the contact islands, and the
// members' bounds are raised to what the island's energy allows until no island grows (the rule
// and its energy argument: docs/theory.md §8; the implementation: docs/schemes.md, "islands").
// Lone particles take one step of dt_sp; an island takes the explicit scheme's fine steps as a
// TBB task, its leading contact-free steps folded into one; a dense sub-iteration steps everyone
// together with the explicit scheme's passes (the global mode). The bound is checked at every
// step (bound_violations(); the tests require none); NaN or a particle leaving through a wall
// stops the run. The Verlet list is rebuilt when some particle's displacement since the build
// plus its bound over the next sub-iteration would exceed skin/2.
//
// One class for one rank and R ranks: the bound, links, islands, forces, fine steps and free
// flight are one code (dem/islands_kernels.hpp), and so is the sub-iteration's driver
// (dem/islands_subiteration.cpp); what R ranks add (ghosts, rows, reductions, an island spanning
// ranks) is dem/islands_ranks.cpp. Results are bitwise independent of the thread count; R ranks
// agree with one rank to round-off. Checkpoints: with a communicator save_state() leaves a
// canonical state that restore_state() recreates on any rank count; without one the state holds
// the Verlet list as built.
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/contact_history.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/external_force.hpp"
#include "dem/interval_clock.hpp"
#include "dem/islands_counts.hpp"
#include "dem/islands_kernels.hpp"
#include "dem/orb_scheme.hpp"
#include "dem/pair_contacts.hpp"
#include "dem/pair_stream.hpp"
#include "dem/scheme_support.hpp"
#include "dem/subiteration_length.hpp"
#include "dem/verlet_list.hpp"
#include "partition/contact_islands.hpp"

namespace cfddem::dem {

class IslandsScheme {
public:
  // Above this fraction of particles linked or tied, a sub-iteration steps everyone finely (over
  // all ranks on R ranks).
  static constexpr double kGlobalFraction = length::kGlobalFraction;

  // One rank: the model from these particles.
  IslandsScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer);
  // `comm` null or of size 1: one rank. Else `particles` is this rank's share (any split) and
  // `model` make_step_model over all particles, the same on every rank. With friction the store
  // gets rotation.
  IslandsScheme(const Scene& scene, ParticleStore& particles, const StepModel& model,
                const Communicator* comm, PhaseTimer& timer);
  IslandsScheme(const IslandsScheme&) = delete;
  IslandsScheme& operator=(const IslandsScheme&) = delete;
  ~IslandsScheme();

  // h_prev = 0 (velocities are the synchronised v(0)); on one rank builds the Verlet list.
  void start();
  // One sub-iteration t -> t + dt_sp; collective on R ranks (every rank throws the same RunError
  // on a fault). With record = true the state at t is kept (synchronised_previous()).
  void subiterate(bool record = false);

  double dt_fine() const { return model_.dt; }
  double dt_sub() const { return dt_sp_; }
  std::int64_t nsubit() const { return nsubit_; }
  std::int64_t subiterations() const { return st_.subits; }
  double time() const {
    return auto_.on ? auto_.t0 + static_cast<double>(st_.subits - auto_.subits_base) * dt_sp_
                    : clock_.time(st_.subits, dt_sp_);
  }
  // An adaptive fluid.dt: the next fluid step's length, before its sub-iterations (and, with
  // "auto", before begin_interval()). An integer dem.nsubit takes it in nsubit sub-iterations
  // of interval / nsubit; "auto" keeps the length it chose for its reference interval (the first
  // fluid step) and takes as many as cover this one (length::subiterations_over). Throws
  // RunError if `interval` is not a positive finite length.
  void set_interval(double interval);

  // dem.nsubit = "auto" (dem/subiteration_length.hpp): the caller runs the loop in control
  // intervals of interval() (dem.regrid_interval; with a gas fluid.dt), each opened by
  // begin_interval(), which sets dt_sp to the length chosen at the end of the last interval and
  // returns its sub-iterations. Without "auto" begin_interval() only returns nsubit().
  bool auto_length() const { return auto_.on; }
  double interval() const { return auto_.interval; }
  std::int64_t begin_interval();
  // After the last interval, the sub-iteration that only completes the last row (the time
  // loop's step past the end) is the shortest "auto" allows, dt_sp about the fine step, not a
  // whole interval of work no output reads. Nothing without "auto".
  void begin_completion();
  // "auto": the count chosen for the next interval (the last choice).
  std::int64_t next_nsubit() const { return auto_.next; }
  // The choices so far: rows of kChoiceColumns (a row per change of nsubit; `intervals` counts
  // the intervals it was kept for).
  static constexpr std::array<const char*, 10> kChoiceColumns = {
      "t",          "nsubit",        "dt_sp", "intervals",  "nsubit_min",
      "nsubit_max", "fine_estimate", "rho",   "cost_ratio", "reason"};
  const std::vector<double>& choices() const { return auto_.log; }
  // With a gas: the largest ratio of a held acceleration's change over one sub-iteration (at
  // the last fluid step's rate) to the largest held acceleration (or |g|), over the run; the
  // bound is length::kGasChangeBound.
  double gas_change_ratio_max() const { return auto_.gas_ratio_max; }
  // Counters over all ranks (the same value on every rank).
  std::int64_t particle_steps() const { return st_.particle_steps; }
  // Pairs of an island evaluated per local step (each pair once), summed over steps.
  std::int64_t pair_evaluations() const { return st_.pair_evaluations; }
  // This rank's share of the work since this process started (run.json's rank_counts; not in
  // checkpoints): owned particle steps and the pair evaluations of its rows.
  std::int64_t local_particle_steps() const {
    return rank_ ? st_.local_particle_steps : st_.particle_steps;
  }
  std::int64_t local_pair_evaluations() const {
    return rank_ ? st_.local_pair_evaluations : st_.pair_evaluations;
  }
  std::int64_t neighbor_builds() const { return st_.builds; }
  // R ranks: decompositions, rolled-back sub-iterations (the dense mode outran its rows), and
  // builds made inside a sub-iteration because the rows ran short (0 on one rank).
  std::int64_t regrids() const { return st_.regrids; }
  std::int64_t retries() const { return st_.retries; }
  std::int64_t expired_builds() const { return st_.expired_builds; }
  double skin() const { return skin_; }
  double max_overlap_ratio() const { return st_.max_overlap_ratio; }
  std::int64_t overlap_violations() const { return st_.overlap_violations; }
  // Particles that moved farther than their speed bound allowed (a collision could then have
  // been missed): zero unless the bound is wrong.
  std::int64_t bound_violations() const { return st_.bound_violations; }
  // Sub-iterations taken with every particle on the fine step (a dense bed: see kGlobalFraction).
  std::int64_t global_subiterations() const { return st_.global_subits; }
  // R ranks: sub-iterations in which some island spanned ranks; spanning particles summed over
  // sub-iterations; spanning islands summed over ranks and sub-iterations (an island over two
  // ranks counts twice: each rank sees its part). 0 on one rank.
  std::int64_t spanning_subiterations() const { return st_.span_subits; }
  // R ranks: the link rounds after the first that tested only the changed particles' pairs; off
  // (tests): every round scans every row, which must give the same links.
  std::int64_t incremental_link_rounds() const;
  void use_incremental_links(bool on);
  std::int64_t spanning_particles() const { return st_.span_particles; }
  std::int64_t spanning_island_parts() const { return st_.span_parts; }
  std::int64_t global_count() const { return n_global_; }
  const StepModel& model() const { return model_; }
  // The fraction of particles in an island (on the fine step) in the last sub-iteration.
  double last_fine_fraction() const { return st_.last_fine_fraction; }
  // Island sizes over the run (one rank; an R-rank run counts none): bin b counts islands (fine
  // or not) with 2^(b-1) < size <= 2^b members (bin 0: single particles), one count per island
  // per sub-iteration.
  std::span<const std::int64_t> island_size_histogram() const { return st_.size_hist; }
  // Per particle, the fraction of sub-iterations it spent in a fine island: its distribution over
  // this rank's particles as {mean, min, p10, p50, p90, p99, max} (nearest-rank percentiles).
  std::array<double, 7> fine_fraction_distribution() const;
  // Per regrid: max over ranks / mean of the particles per rank (empty on one rank).
  const std::vector<double>& imbalances() const { return imbalances_; }
  // The particles this rank owns (the first owned() of the store) and the ghosts after them.
  std::size_t owned() const { return owned_; }
  std::size_t ghosts() const { return p_.size() - owned_; }

  // Collective. External force [N] per owned particle in the store's current order, held until
  // set again and carried with its particle; empty spans (on every rank) remove it.
  void set_external_force(std::span<const double> fx, std::span<const double> fy,
                          std::span<const double> fz);
  // The force held now, in the store's order (empty: none).
  [[nodiscard]] const ExternalForce& external_force() const { return ext_; }
  // With false, every link round rescans all rows instead of the raised particles' rows only
  // (one rank; the reference the tests hold the incremental rounds to: the same links in the
  // same order, hence bitwise the same run).
  void set_incremental_links(bool on) { one_.incremental = on; }
  // At a fluid-step boundary (the coupled loops' gas step): the owed half kick settled with the
  // force held so far (settle_owed_half_kick, dem/external_force.hpp), then set_external_force.
  // set_external_force alone is for a restart (the held force as it was).
  void replace_external_force(std::span<const double> fx, std::span<const double> fy,
                              std::span<const double> fz);

  // Per output interval: local steps per particle per sub-iteration (min/mean/max over particles
  // and sub-iterations) and the fraction of particle sub-iterations on the fine step.
  LeafStepStats take_interval_stats();

  // The recorded state of the owned particles, with each particle's island (-1: alone, free
  // flight) and local step.
  OrbScheme::Synchronised synchronised_previous() const {
    return {rec_.x,    rec_.y,  rec_.z,      rec_.vx,     rec_.vy, rec_.vz,
            rec_.mass, rec_.id, rec_.island, rec_.radius, rec_.dt};
  }

  // Checkpoint/restart between sub-iterations: what a sub-iteration reads that it did not compute
  // itself -- on one rank without a communicator the Verlet list exactly as built (rows in order,
  // reference positions, skin; the store's order is the list's, which the checkpoint keeps); per
  // owned particle the half step and fine-sub-iteration count; the counters, the island-size
  // histogram and the interval statistics. Speed bounds, links and islands are remade at the
  // start of every sub-iteration. A gas force held over the sub-cycle is the caller's
  // (set_external_force after restore). restore_state() replaces start(). With a communicator
  // both are collective and save_state() puts the scheme in its canonical state (header).
  struct State {
    std::vector<std::uint32_t> offsets, neighbors;
    std::vector<double> x_ref, y_ref, z_ref;
    double skin = 0.0;
    std::vector<double> hprev;
    std::vector<std::int64_t> fine_subits, size_hist;
    // subits, particle_steps, pair_evaluations, builds, overlap_violations, bound_violations,
    // global_subits, iv_fine, iv_particles, iv_steps, iv_min, iv_max
    std::vector<std::int64_t> counters;
    double max_overlap_ratio = 0.0, last_fine_fraction = 0.0;
    // Written on R ranks only (empty from one rank, ignored by it): regrids, retries, expired
    // builds, spanning sub-iterations, spanning particles, spanning island parts; and the overlap
    // ratio not yet recorded.
    std::vector<std::int64_t> rank_counters;
    std::vector<double> rank_values;
    // dem.nsubit = "auto" (empty otherwise): nsubit, next, intervals, subits_base, q,
    // fine_count; t0, fine_sum, gas_dA, gas_aref, gas_ratio_max, fine_avg, busy_avg,
    // members_sum, members_avg (not in checkpoints written before the members were measured)
    // and hist_avg; the choices' rows.
    std::vector<std::int64_t> length_counters;
    std::vector<double> length_values, length_log;
    // One rank: the islands skin and its choice's counters (islands_skin, build_subits,
    // build_pairs, measured); empty in checkpoints written before the skin was chosen.
    std::vector<double> skin_choice;
    // Friction: the tangential history per entry of the list (neighbors' indexing); with a
    // communicator (the canonical state, no list) the records by particle ids instead.
    std::vector<double> hx, hy, hz;
    ContactHistory history;
    // An adaptive fluid.dt (empty otherwise): an integer dem.nsubit's IntervalClock::saved();
    // "auto": its reference interval, the interval in force and the one before.
    std::vector<double> clock;
  };
  State save_state();
  // Throws RunError (on every rank) if the state does not fit the store.
  void restore_state(State s);

private:
  // Links and islands of the current sub-iteration (both paths).
  struct Links {
    std::vector<double> bound;            // per local particle: speed bound s_i [m/s]
    std::vector<double> own_bound;        // ... from its own velocity (busy particles only)
    std::vector<std::uint32_t> own_stamp; // own_bound[i] is this round set's when == stamp
    std::uint32_t stamp = 0;
    std::vector<std::uint32_t> ea, eb;         // links (one rank: ea < eb), in row-scan order
    std::vector<std::uint32_t> ek;             // one rank: each one's position in ea's row
    std::vector<std::uint32_t> changed, new_k; // one rank: particles raised by the last round
    // One rank: per entry of the Verlet list, 1 when it is the key of a link (ek), so that a
    // round's scan of the raised rows tests and collects only the pairs not yet linked.
    std::vector<unsigned char> linked_entry;
    // One rank's first link scan, per block of rows (tasks): the links each block found, joined
    // in block order (the serial scan's order).
    struct BlockLinks {
      std::vector<std::uint32_t> a, b, k;
    };
    std::vector<BlockLinks> blocks;
    std::vector<std::uint32_t> tied;           // particles tied to a wall
    // Busy particles (linked or tied), increasing; the islands over them (local indices), each
    // island's members as particle indices, and per particle its island or kAlone.
    std::vector<std::uint32_t> busy, la, lb, members, island_of;
    std::vector<std::uint32_t> busy_before, label_before;
    std::vector<unsigned char> mark; // all zero between calls
    partition::Islands islands;
    std::vector<std::uint32_t> uf_scratch;
    // Per island: energy, lightest mass, largest external acceleration and half step.
    std::vector<double> energy, m_min, a_max, hp_max;
    // Islands over the busy particles (busy from ea, eb, tied); false, with no islands made,
    // when more than `limit` particles are busy.
    bool form(std::size_t n, double limit);
  };
  // One rank: the Verlet list and its skins.
  struct OneRank {
    VerletList list;
    // Skins of the two modes: islands (a longer list: fewer builds) and global fine steps (the
    // explicit scheme's).
    double islands_skin = 0.0, global_skin = 0.0;
    // The islands skin's choice at each expiry (choose_skin(); dem.neighbor_skin = "auto"): the
    // sub-iterations and pair evaluations at the last build (the list's life and the pair work
    // since), measured when that build began an islands list; the largest diameter.
    // nominal_skin: the starting islands skin, which the length choice prices the rows with
    // (the same on any rank count; R ranks do not choose their skin).
    bool adapt_skin = false, measured = false;
    double nominal_skin = 0.0;
    std::int64_t build_subits = 0, build_pairs = 0;
    double d_max = 0.0;
    bool built = false, incremental = true;
    // Canonical state pending (a communicator of size 1): the next sub-iteration sorts the store
    // by id and builds.
    bool canonical = false;
    bool with_comm = false; // constructed with a communicator (of size 1)
    ContactHistory pending; // friction: records the next build attaches (a restore, a save)
    // A bound on every particle's displacement since the build: the sum over the sub-iterations
    // since of the largest speed bound x dt_sp + margin (infinite when unknown: after a restore,
    // a dense sub-iteration or a bound violation); list_expires() skips its exact pass while
    // twice this plus the largest reach of the sub-iteration stays below the skin.
    double moved = std::numeric_limits<double>::infinity();
    double bound_max = 0.0; // the largest speed bound of the current sub-iteration
    // The global steps without friction (global_contacts): the list's pairs once each, laid out
    // after a build (half_stale: not yet), their contacts and the particles near a wall.
    PairStream head_pairs, tail_pairs;
    std::vector<PairContacts> head, tail;
    std::vector<std::uint32_t> near_wall;
    // Friction: per pair of head_pairs, tail_pairs the list entry of its lower end's row.
    std::vector<std::uint32_t> head_mirror, tail_mirror;
    std::size_t nh = 0, nt = 0; // blocks of head, tail written by the last step
    bool half_stale = true;
    bool clear_all = true; // the next step clears every listed particle's force
  };
  // dem.nsubit = "auto": the control interval and the choice for the next one.
  struct AutoLength {
    bool on = false;
    double interval = 0.0;                // D [s]
    std::int64_t next = 1, intervals = 0; // next interval's nsubit; intervals begun
    std::int64_t subits_base = 0, q = 0;  // subits at this interval's start; taken in it
    double t0 = 0.0;                      // this interval's start time
    // An adaptive fluid.dt: intervals differ. `interval` is then the reference the choices are
    // made for (the first fluid step), `actual` the interval in force and `previous` the one
    // before (over which the gas force changed).
    bool variable = false;
    double actual = 0.0, previous = 0.0;
    double fine_sum = 0.0;                // fine fractions of the sub-iterations since the
    std::int64_t fine_count = 0;          // last choice, and their number
    double members_sum = 0.0;             // their fractions of particles in an island
    double gas_dA = 0.0, gas_aref = 0.0;  // the last fluid step's force change, reference
    double gas_ratio_max = 0.0;
    // Running means (length::kSmoothing) of the first-contact histogram, of the fine particles
    // per sub-iteration (nominal work: every member on every step after its lead), of the
    // members per sub-iteration and of the first-contact count at the length they were measured
    // at (fine_avg < 0: none yet).
    std::vector<double> hist_avg;
    double fine_avg = -1.0, busy_avg = 0.0, members_avg = 0.0;
    std::vector<double> log; // kChoiceColumns rows
    // The global mode (length::Choice::global) in this interval, and chosen for the next one.
    bool global_now = false, next_global = false;
  };
  void choose_length();
  void open_interval(std::int64_t m);
  void note_gas_change(std::span<const double> fx, std::span<const double> fy,
                       std::span<const double> fz);
  struct RankPart; // R ranks: ownership, ghosts, rows, reductions (islands_ranks.cpp)
  // The recorded state (synchronised_previous).
  struct Recorded {
    std::vector<double> x, y, z, vx, vy, vz, mass, radius, dt;
    std::vector<std::int64_t> id, island;
  };
  // Counters (over all ranks unless local_) and the interval statistics.
  struct Stats {
    std::int64_t subits = 0, particle_steps = 0, pair_evaluations = 0, builds = 0,
                 overlap_violations = 0, bound_violations = 0, global_subits = 0;
    std::int64_t regrids = 0, retries = 0, expired_builds = 0, span_subits = 0, span_particles = 0,
                 span_parts = 0;
    std::int64_t local_particle_steps = 0, local_pair_evaluations = 0;
    double max_overlap_ratio = 0.0, last_fine_fraction = 0.0;
    // The last sub-iteration's fine member steps / (K x particles): what the fine particles cost,
    // their leading steps folded (islands_kernels.hpp, entry_lead); "auto" measures with it.
    double last_fine_work = 0.0;
    std::int64_t iv_fine = 0, iv_particles = 0, iv_steps = 0;
    std::int64_t iv_min = std::numeric_limits<std::int64_t>::max(), iv_max = 0;
    std::vector<std::int64_t> size_hist = std::vector<std::int64_t>(34, 0);
    // The interval statistics of one sub-iteration: `fine` of `n` particles on K steps.
    void add_interval(std::int64_t fine, std::int64_t n, std::int64_t K);
    std::vector<std::int64_t> counters() const;
    void set_counters(const std::vector<std::int64_t>& k);
  };
  static constexpr std::uint32_t kAlone = 0xffffffffu;

  islands::Columns cols() { return islands::columns(p_, hprev_, ext_); }
  // The sub-iteration (islands_subiteration.cpp), on any rank count.
  islands::SubiterationCounts island_steps(bool record);
  islands::SubiterationCounts dense_steps(bool record);
  template <bool External, bool Record, bool Walls> void free_flight();
  void run_islands(bool record, const unsigned char* spans);
  template <bool External, bool Ranks, bool Friction>
  void run_island(std::uint32_t c, bool record, const islands::ContactView& view);
  std::optional<islands::Fault> find_fault();
  void count_subiteration(const islands::SubiterationCounts& t, bool record);
  void count_island_sizes();
  void age_list(bool violated);
  // Shared by the link rounds of both rank counts and the steps.
  void island_sums(std::size_t owned);
  template <bool External, bool Friction> void island_sums_of(std::size_t owned);
  void record_state();
  // A recorded sub-iteration: the velocities of particles [0, n) synchronised at its start,
  // v + (F/m + g) h_prev (F: the forces of its first step), into rec_.
  template <bool External> void record_start_velocities(std::size_t n);
  void speed_bounds();
  // The rows of the contact forces: the Verlet list's (one rank) or the rank's rows.
  islands::ContactView contact_view();
  // Speed bounds, links and islands: the one-rank list's or the R-rank rows' (find_islands_ranks).
  void find_islands() { rank_ ? find_islands_ranks() : find_islands_one(); }
  // One rank.
  void find_islands_one();
  void rebuild();
  void choose_skin();
  void canonical_order();
  void make_links(bool incremental);
  void link();
  bool list_expires();
  void global_steps(bool record);
  template <bool External, bool Friction> void run_global_steps(bool record);
  template <bool Friction> void global_contacts(double hk);
  void mirror_history();
  static void mirror_entries(const VerletList& list, const PairStream& stream,
                             std::vector<std::uint32_t>& mirror);
  // R ranks (islands_ranks.cpp).
  void init_ranks();
  void set_external_force_ranks(std::span<const double> fx, std::span<const double> fy,
                                std::span<const double> fz);
  void find_islands_ranks();
  void regrid();
  // Returns the history records `held` that arrive with their owner particles (friction).
  ContactHistory migrate(ContactHistory held);
  void own_bounds();
  void refresh_ghosts();
  void rebuild_ranks();
  void build_ghosts_and_rows();
  double link_rounds();
  void make_links_ranks(bool incremental);
  void ghost_entries();
  islands::IslandResult fine_together(bool record, bool all);
  template <bool External, bool Friction>
  islands::IslandResult step_together(bool record, bool all);
  template <bool External, class Between>
  islands::IslandResult dense_kicks(bool record, Between&& between);
  void span_leads(const islands::ContactView& view, islands::Members& mb);
  void canonicalize();
  // The verbs of the sub-iteration that differ on R ranks (islands_ranks.cpp): on one rank each
  // is a no-op or the identity.
  void keep_start(); // the dense mode's start, for a rollback
  void roll_back();  // back to it, to redo the sub-iteration after a wider build
  void step_spanning(bool record, islands::SubiterationCounts& t);     // islands spanning ranks
  void reduce_counts(islands::SubiterationCounts& t);                  // sum over the ranks
  void check_conservation(const islands::SubiterationCounts& t) const; // no particle lost
  void note_overlap_ratio(double ratio, bool record);
  [[noreturn]] void raise_fault(const std::optional<islands::Fault>& fault) const;

  const Scene& scene_;
  ParticleStore& p_;
  PhaseTimer& timer_;
  DomainGeometry geom_;
  StepModel model_;
  ExternalForce ext_; // per owned particle
  double dt_sp_ = 0.0, skin_ = 0.0, margin_ = 0.0;
  // The largest skin whose cutoff 2 r_max + skin stays under half of every periodic axis
  // (periodic_skin_cap; r_max over all ranks on R ranks), on any rank count.
  double skin_cap_ = 0.0;
  std::int64_t nsubit_ = 1, n_global_ = 0;
  std::size_t owned_ = 0;
  bool global_ = false; // this sub-iteration: everyone on the fine steps
  FineSteps steps_;
  // Per owned particle (carried through migrations): half of its last step, and sub-iterations
  // in a fine island (a count, below 2^53).
  std::vector<double> hprev_, fine_;
  // Friction: the tangential history per entry of one_.list (R ranks: of rank_->rows).
  std::vector<double> hx_, hy_, hz_;
  std::vector<double> x0_, y0_, z0_;           // island members' start positions (members order)
  std::vector<islands::IslandResult> results_; // per island, reduced in island order
  std::uint64_t fault_flag_ = 0;               // sign bit: some particle may be NaN or outside
  std::vector<double> imbalances_;
  Links ln_;
  OneRank one_;
  std::unique_ptr<RankPart> rank_;
  Recorded rec_;
  Stats st_;
  AutoLength auto_;
  IntervalClock clock_; // an integer dem.nsubit's time base (adaptive fluid.dt)
};

} // namespace cfddem::dem
