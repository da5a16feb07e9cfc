// What the one time loop (apps/run_loop.hpp) needs from each particle scheme, in one small
// adapter per algorithm: ExplicitRun (the explicit scheme, one step per particle step) and
// SubiteratedRun (orb and islands, one sub-iteration of dt_sp per particle step). The rank count
// is a runtime property (the communicator's size, RankParts::ranks), not a template parameter:
// every scheme class serves one rank and R alike, so one instantiation per scheme is enough, and
// the branches on it sit outside the schemes' kernels (set-up, checkpoints, run.json), where a
// runtime test costs nothing. One rank takes the one-rank path alone: the serial communicator,
// the scheme built without one (no ghosts, no reductions), the scene's particles as they are.
// What differs with the rank count (the share of a checkpoint's particles, gathering a
// checkpoint, reductions) sits here too, so that the loop itself reads the same for every scheme
// and rank count.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/coupled_checkpoint.hpp"
#include "apps/derived_numbers.hpp"
#include "apps/gas_side.hpp"
#include "apps/rank_checkpoint.hpp"
#include "apps/rank_setup.hpp"
#include "apps/run_output.hpp"
#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/granular_diagnostics.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"
#include "dem/subiteration_length.hpp"

namespace cfddem::apps {

// The particles of a recorded step, for a row and a snapshot (this rank's owned ones).
struct SyncedParticles {
  std::span<const double> x, y, z, vx, vy, vz, mass, radius;
  std::span<const std::int64_t> id, leaf;
  std::span<const double> local_dt;
};

// What a restart keeps of the checkpoint before its particles are handed out to the ranks.
template <class State> struct RestartShare {
  std::vector<std::uint32_t> taken; // the checkpoint's particles this rank got, in its order
  dem::ContactHistory history;      // explicit with friction: the contact history by id
  std::optional<State> state;       // sub-iterated: this rank's share of the scheme state
};

// The parts every adapter does alike, by rank count: `ranks` is true on R > 1 ranks (the
// communicator's size), false on one rank, where the one-rank path is taken unchanged.
struct RankParts {
  explicit RankParts(const Communicator& comm) : ranks(comm.size() > 1) {}
  bool ranks;

  // This rank's particles: all of them (the checkpoint's or the scene's) on one rank, every
  // R-th on R ranks (the scheme's start() or restore sends each to its owner).
  ParticleStore particles(const Scene& scene, std::optional<Checkpoint>& ck,
                          const Communicator& comm, std::vector<std::uint32_t>& taken) const {
    if (ranks)
      return rank_share(scene, ck, comm, &taken);
    return ck ? std::move(ck->particles) : make_initial_particles(scene);
  }
  DerivedNumbers derived(const Scene& scene, const ParticleStore& p, const Communicator& comm,
                         dem::ParticleRange& range) const {
    return ranks ? derive(scene, p, comm, &range) : derive(scene, p);
  }
  // The step model over all particles (the contact time), the same on every rank: from the
  // store on one rank, which holds them all, else from the range derived() reduced.
  dem::StepModel step_model(const Scene& scene, const ParticleStore& p,
                            const dem::ParticleRange& range) const {
    return ranks ? dem::make_step_model(scene, range) : dem::make_step_model(scene, p);
  }
  // The scheme on this rank's particles. One rank: the one-rank constructor, no communicator at
  // all (the islands scheme keeps its one-rank list and order only without one).
  template <class S>
  S make(const Scene& scene, ParticleStore& p, const dem::ParticleRange& range,
         const Communicator& comm, PhaseTimer& timer) const {
    if (ranks)
      return S(scene, p, dem::make_step_model(scene, range), &comm, timer);
    return S(scene, p, timer);
  }
  // The particles this rank owns: the first owned() of the store (R ranks), else all.
  template <class S> std::size_t owned(const S& s, const ParticleStore& p) const {
    return ranks ? s.owned() : p.size();
  }
  // This rank's particle steps and pair evaluations (run.json's rank_counts).
  template <class S> std::array<std::int64_t, 2> local_work(const S& s) const {
    if (ranks)
      return {s.local_particle_steps(), s.local_pair_evaluations()};
    return {s.particle_steps(), s.pair_evaluations()};
  }
  // The gas force held at a checkpoint, for this rank's particles.
  std::array<std::vector<double>, 3> held(const Checkpoint& ck,
                                          const std::vector<std::uint32_t>& taken) const {
    return ranks ? held_share(ck, taken) : ck.loop.held_force;
  }
};

template <class S> class ExplicitRun {
public:
  static constexpr bool kSub = false;
  static constexpr const char* kName = "explicit";
  using Restart = RestartShare<int>;

  static ParticleStore particles(const Scene& scene, std::optional<Checkpoint>& ck,
                                 const Communicator& comm, const std::string&, Restart& r) {
    // The history rows of a checkpoint with friction become records by id before the
    // particles are handed out (restore() gives each to the particle's owner).
    const RankParts parts(comm);
    if (parts.ranks && ck)
      r.history = saved_contact_history(*ck);
    return parts.particles(scene, ck, comm, r.taken);
  }

  ExplicitRun(const Scene& scene, ParticleStore& p, const dem::ParticleRange& range,
              const Communicator& comm, PhaseTimer& timer)
      : scheme(RankParts(comm).make<S>(scene, p, range, comm, timer)), parts_(comm), p_(p) {}

  S scheme;
  double dt() const { return scheme.dt(); }
  double fine_dt() const { return scheme.dt(); }
  long long steps() const { return scheme.steps_taken(); }
  std::size_t owned() const { return parts_.owned(scheme, p_); }
  long long checkpoint_every(long long every) const { return every; }
  bool auto_length() const { return false; }
  long long begin_interval() { return 1; }
  void begin_completion() {}
  void start() { scheme.start(); }
  // In place of start(). held: the gas force held at the checkpoint (null without a gas).
  void restore(Checkpoint& ck, Restart& r, const std::array<std::vector<double>, 3>* held) {
    if (parts_.ranks) {
      // The force travels with its particle to the owner restore() sends it to.
      if (held)
        scheme.set_external_force((*held)[0], (*held)[1], (*held)[2]);
      const auto& st = ck.state;
      scheme.restore({held ? st.steps : ck.step, st.particle_steps, st.pair_evaluations, st.builds},
                     r.history);
    } else {
      if (ck.state.x_ref.empty() && !ck.state.offsets.empty()) {
        // An R-rank checkpoint with friction: its rows hold only the contact history, over the
        // saved particles (the store's order here). Reinstated as a list due for a rebuild, they
        // are carried over by ids as any rebuild carries the history.
        ck.state.x_ref = p_.x, ck.state.y_ref = p_.y, ck.state.z_ref = p_.z;
        ck.state.need_rebuild = true;
      }
      scheme.restore_state(std::move(ck.state));
      if (held)
        scheme.set_external_force((*held)[0], (*held)[1], (*held)[2]);
    }
  }
  // One step; `k`: its index; the row's step statistics (every step a full one).
  dem::LeafStepStats advance(bool /*record*/, bool sync, long long k_last_row, long long& k) {
    scheme.step(sync);
    k = scheme.steps_taken() - 1;
    const auto steps = static_cast<double>(k - k_last_row);
    return {steps, steps, steps, 1.0};
  }
  void hold_gas_force(const GasSide::Force& f) { scheme.set_external_force(f[0], f[1], f[2]); }
  // R ranks with a gas: the particles owned by the gas boxes (`now`: moved at once, else at
  // start()).
  void own_by(partition::RankDecomposition d, bool now) {
    if (parts_.ranks) {
      scheme.set_decomposition(std::move(d));
      if (now)
        scheme.redistribute_now();
    }
  }
  // The velocities at t = 0 from the half-step ones start() left (v(-dt/2) + a dt/2).
  bool initial_velocities(std::vector<double> (&v)[3]) const {
    const std::size_t n = owned();
    const double h = 0.5 * scheme.dt();
    const auto& g = scheme.model().gravity;
    const std::vector<double>* f[3] = {&p_.fx, &p_.fy, &p_.fz};
    const std::vector<double>* u[3] = {&p_.vx, &p_.vy, &p_.vz};
    for (int a = 0; a < 3; ++a) {
      v[a].resize(n);
      for (std::size_t i = 0; i < n; ++i)
        v[a][i] = (*u[a])[i] + ((*f[a])[i] * p_.inv_mass[i] + g[static_cast<std::size_t>(a)]) * h;
    }
    return true;
  }
  SyncedParticles synced() const {
    const auto s = scheme.synchronised_previous();
    const std::size_t n = s.x.size();
    return {s.x,
            s.y,
            s.z,
            s.vx,
            s.vy,
            s.vz,
            {p_.mass.data(), n},
            {p_.radius.data(), n},
            {p_.id.data(), n},
            {},
            {}};
  }
  // The ORB box of each (wrapped) position: the decomposition in a snapshot (R ranks).
  std::vector<std::int64_t> boxes(std::span<const double> x, std::span<const double> y,
                                  std::span<const double> z) const {
    std::vector<std::int64_t> box;
    if (parts_.ranks)
      for (std::size_t i = 0; i < x.size(); ++i)
        box.push_back(scheme.decomposition().tree.locate(x[i], y[i], z[i]));
    return box;
  }
  // The particles and the scheme state into rank 0's checkpoint. Collective.
  void save(Checkpoint& c, const Communicator& comm) {
    if (parts_.ranks) {
      scheme.canonicalize();
      gather_rank_particles(scheme, p_, comm, c);
    } else {
      c.particles = p_;
      c.state = scheme.save_state();
    }
  }

  std::string banner(long long n_end) const {
    return fmt::format("dt = {:.4e} s, {} steps", scheme.dt(), n_end);
  }
  std::string banner_tail() const {
    if (parts_.ranks)
      return fmt::format(", {} boxes", 1 << scheme.levels());
    else
      return {};
  }
  static constexpr const char* kStepWord = "step";
  static constexpr const char* kStepsWord = "steps";
  std::string progress(long long k, double frac, double wall, const std::string& eta) const {
    return fmt::format("step {:>10} t = {:.6e} s ({:5.1f}%)  {:.3e} particle-steps/s  ETA {}", k,
                       scheme.time(), 100 * frac,
                       static_cast<double>(scheme.particle_steps()) / wall, eta);
  }
  void describe(nlohmann::ordered_json& j, const std::vector<std::vector<double>>&) const {
    j["dt"] = scheme.dt();
    j["steps"] = scheme.steps_taken();
  }
  const char* phase_note() const {
    return parts_.ranks
               ? "rank 0's phases; neighbor: regrid, migration, ghost exchange and the local "
                 "list; force: includes waiting for the ghost forward (after the interior "
                 "rows); other: mostly posting the forward and the per-step flag reduction"
               : nullptr;
  }
  const char* force_definition() const {
    return parts_.ranks ? "neighbor-list pairs evaluated (each pair once per step), over all ranks"
                        : "neighbor-list pairs evaluated (each pair once per step)";
  }
  void describe_balance(nlohmann::ordered_json& j) const {
    if (parts_.ranks) {
      j["boxes"] = 1 << scheme.levels();
      j["regrid_policy"] = "ORB + Hilbert knapsack at the first neighbor rebuild after "
                           "dem.regrid_interval; migration and ghosts at every rebuild";
      nlohmann::ordered_json regrids = nlohmann::ordered_json::array();
      double worst = 1.0;
      for (const auto& r : scheme.regrids()) {
        regrids.push_back({{"step", r.step}, {"imbalance", r.imbalance}});
        worst = std::max(worst, r.imbalance);
      }
      j["load_imbalance"] = regrids;
      j["load_imbalance_definition"] = "per regrid: max over ranks / mean of particles owned";
      j["load_imbalance_max"] = worst;
    }
  }
  std::string performance(const PhaseTimer& t, double pss, double wait_max) const {
    if (parts_.ranks)
      return fmt::format("Performance: {:.4g} particle-steps/s; rank 0: neighbor+exchange {:.3g} "
                         "s ({} builds, {} regrids), force {:.3g} s, integrate {:.3g} s; MPI "
                         "wait max {:.3g} s",
                         pss, t.seconds(Phase::neighbor), scheme.neighbor_builds(),
                         scheme.regrids().size(), t.seconds(Phase::force),
                         t.seconds(Phase::integrate), wait_max);
    else
      return fmt::format("Performance: {:.4g} particle-steps/s; neighbor {:.3g} s ({} builds), "
                         "force {:.3g} s, integrate {:.3g} s, io {:.3g} s",
                         pss, t.seconds(Phase::neighbor), scheme.neighbor_builds(),
                         t.seconds(Phase::force), t.seconds(Phase::integrate),
                         t.seconds(Phase::io));
  }

private:
  RankParts parts_;
  ParticleStore& p_;
};

template <class S> class SubiteratedRun {
public:
  static constexpr bool kSub = true;
  static constexpr bool kOrb = std::is_same_v<S, dem::OrbScheme>;
  static constexpr const char* kName = kOrb ? "orb" : "islands";
  using State = std::conditional_t<kOrb, dem::OrbScheme::State, dem::IslandsScheme::State>;
  using Restart = RestartShare<State>;

  static ParticleStore particles(const Scene& scene, std::optional<Checkpoint>& ck,
                                 const Communicator& comm, const std::string& path, Restart& r) {
    const std::size_t n_saved = ck ? ck->particles.size() : 0;
    const RankParts parts(comm);
    if constexpr (!kOrb)
      if (parts.ranks && ck && ck->islands.history.size() == 0 && !ck->islands.hx.empty()) {
        // A one-rank checkpoint's history per entry of its list: the records by ids the R-rank
        // scheme routes (the list itself is not restored there).
        const auto& o = ck->islands;
        ck->islands.history =
            dem::history_from_rows(ck->particles.id, o.offsets, o.neighbors, o.hx, o.hy, o.hz);
      }
    ParticleStore p = parts.particles(scene, ck, comm, r.taken);
    if (parts.ranks && ck)
      r.state = subiterated_share<S>(*ck, r.taken, n_saved, path);
    return p;
  }

  SubiteratedRun(const Scene& scene, ParticleStore& p, const dem::ParticleRange& range,
                 const Communicator& comm, PhaseTimer& timer)
      : scheme(RankParts(comm).make<S>(scene, p, range, comm, timer)), parts_(comm), p_(p),
        levels_(scene.partition.orb_levels) {}

  S scheme;
  // The loop's step: a sub-iteration, or with dem.nsubit = "auto" a control interval.
  double dt() const {
    if constexpr (!kOrb)
      if (scheme.auto_length())
        return scheme.interval();
    return scheme.dt_sub();
  }
  double fine_dt() const { return scheme.dt_fine(); }
  bool auto_length() const {
    if constexpr (kOrb)
      return false;
    else
      return scheme.auto_length();
  }
  // The sub-iterations of the next control interval ("auto" only).
  long long begin_interval() {
    if constexpr (kOrb)
      return 1;
    else
      return scheme.begin_interval();
  }
  // The step past the end that completes the last row ("auto" only: the shortest it allows).
  void begin_completion() {
    if constexpr (!kOrb)
      scheme.begin_completion();
  }
  long long steps() const { return scheme.subiterations(); }
  std::size_t owned() const { return parts_.owned(scheme, p_); }
  // orb: checkpoints only at regrid points (multiples of dem.nsubit), where the ORB is rebuilt
  // from the store: the interval rounded up to whole regrid intervals. islands: any.
  long long checkpoint_every(long long every) const {
    if (kOrb && every > 0)
      return (every + scheme.nsubit() - 1) / scheme.nsubit() * scheme.nsubit();
    return every;
  }
  void start() { scheme.start(); }
  void restore(Checkpoint& ck, Restart& r, const std::array<std::vector<double>, 3>* held) {
    if (parts_.ranks) {
      scheme.restore_state(std::move(*r.state));
    } else {
      if constexpr (kOrb)
        scheme.restore_state(std::move(ck.orb));
      else
        scheme.restore_state(std::move(ck.islands));
    }
    if (held)
      scheme.set_external_force((*held)[0], (*held)[1], (*held)[2]);
  }
  // One sub-iteration; `k`: its index; the row's statistics of the interval it closes.
  dem::LeafStepStats advance(bool record, bool sync, long long /*k_last_row*/, long long& k) {
    const dem::LeafStepStats ls = record ? scheme.take_interval_stats() : dem::LeafStepStats{};
    scheme.subiterate(sync);
    k = scheme.subiterations() - 1;
    return ls;
  }
  // The owed half kick is settled with the old force (replace_external_force).
  void hold_gas_force(const GasSide::Force& f) { scheme.replace_external_force(f[0], f[1], f[2]); }
  void own_by(const partition::RankDecomposition&, bool) {} // by the leaves, routed to the gas
  bool initial_velocities(std::vector<double> (&)[3]) const { return false; }
  SyncedParticles synced() const {
    const auto s = scheme.synchronised_previous();
    return {s.x, s.y, s.z, s.vx, s.vy, s.vz, s.mass, s.radius, s.id, s.leaf, s.local_dt};
  }
  std::vector<std::int64_t> boxes(std::span<const double>, std::span<const double>,
                                  std::span<const double>) const {
    return {};
  }
  void save(Checkpoint& c, const Communicator& comm) {
    if (parts_.ranks) {
      gather_subiterated(scheme, p_, comm, c);
    } else {
      c.particles = p_;
      if constexpr (kOrb)
        c.orb = scheme.save_state();
      else
        c.islands = scheme.save_state();
    }
  }

  std::string banner(long long n_end) const {
    const int leaves = parts_.ranks ? leaf_count() : 1 << levels_;
    if (auto_length())
      return fmt::format("islands scheme, dem.nsubit = \"auto\": dt_sp chosen per control "
                         "interval of {:.4e} s (first {:.4e} s; fine dt = {:.4e} s), {} intervals",
                         dt(), scheme.dt_sub(), scheme.dt_fine(), n_end);
    return fmt::format("{} scheme{}, dt_sp = {:.4e} s (fine dt = {:.4e} s), {} sub-iterations",
                       kName, kOrb ? fmt::format(": {} leaves", leaves) : "", scheme.dt_sub(),
                       scheme.dt_fine(), n_end);
  }
  std::string banner_tail() const { return {}; }
  static constexpr const char* kStepWord = "sub-iteration";
  static constexpr const char* kStepsWord = "sub-iterations";
  std::string progress(long long k, double frac, double, const std::string& eta) const {
    // "auto": k counts control intervals; the sub-iterations and the current count are shown.
    const std::string at = auto_length() ? fmt::format("sub-iteration {:>8} (nsubit {:>4})",
                                                       scheme.subiterations(), scheme.nsubit())
                                         : fmt::format("sub-iteration {:>8}", k);
    return fmt::format("{} t = {:.6e} s ({:5.1f}%)  fine {} {:.2f}  ETA {}", at, scheme.time(),
                       100 * frac, kOrb ? "leaves" : "particles", scheme.last_fine_fraction(), eta);
  }
  void describe(nlohmann::ordered_json& j, const std::vector<std::vector<double>>& rows) const {
    j["dt"] = scheme.dt_fine();
    j["dt_sp"] = scheme.dt_sub();
    if constexpr (!kOrb)
      if (scheme.auto_length()) // the last choice (the step past the end is a short one)
        j["dt_sp"] = scheme.interval() / static_cast<double>(scheme.next_nsubit());
    if constexpr (kOrb)
      j["leaves"] = leaf_count();
    j["steps"] = scheme.subiterations();
    j["steps_definition"] = "sub-iterations of dt_sp (one past the end, as the explicit loop)";
    if (kOrb || parts_.ranks) {
      j["regrids"] = scheme.regrids();
      j["subiteration_retries"] = scheme.retries();
    }
    j["final_skin"] = scheme.skin();
    j["max_overlap_ratio"] = scheme.max_overlap_ratio();
    j["overlap_violations"] = scheme.overlap_violations();
    if constexpr (kOrb) {
      if (parts_.ranks) {
        // The mean over the rows after the first (each closes an interval).
        const auto col = static_cast<std::size_t>(
            std::find(kBaseColumns.begin(), kBaseColumns.end(), "fine_leaf_fraction") -
            kBaseColumns.begin());
        double fine = 0.0;
        for (std::size_t r = 1; r < rows.size(); ++r)
          fine += rows[r][col];
        j["fine_leaf_fraction_mean"] =
            rows.size() > 1 ? fine / static_cast<double>(rows.size() - 1) : 0.0;
        j["fine_leaf_fraction_definition"] =
            "mean over the diagnostics rows of the fraction of (non-empty leaf, sub-iteration) "
            "pairs on the fine step, over all ranks";
      }
    } else {
      describe_islands(j);
    }
  }
  const char* phase_note() const {
    if (parts_.ranks)
      return kOrb ? "rank 0's phases; neighbor: regrid, migration, ghost exchange and the rows; "
                    "force: its leaves' local steps and the reductions that close a sub-iteration"
                  : "rank 0's phases; neighbor: regrid, migration, ghosts, rows, speed bounds, "
                    "links and islands (with their reductions); force: free flight, the local "
                    "islands' tasks and the spanning islands' fine steps with their ghost "
                    "refreshes";
    return kOrb ? "neighbor: ORB regrid and re-sort; force: the leaves' tasks (ghosts, local "
                  "lists, force and update)"
                : "neighbor: speed bounds, links, islands and Verlet list builds; force: free "
                  "flight and the islands' tasks (force and update)";
  }
  const char* force_definition() const {
    if (kOrb)
      return parts_.ranks
                 ? "candidate pairs evaluated per local step, over all ranks: pairs within a "
                   "leaf once, pairs across a leaf boundary once per side (rows rebuilt at "
                   "every sub-iteration)"
                 : "candidate pairs evaluated per local step: pairs within a leaf once, pairs "
                   "across a leaf boundary once per side (each leaf evaluates its side "
                   "against the other's frozen copy)";
    return parts_.ranks
               ? "pairs inside a fine island evaluated per local step, over all ranks (a pair "
                 "across ranks counted once)"
               : "neighbor-list pairs inside a fine island evaluated per local step (each "
                 "pair once)";
  }
  void describe_balance(nlohmann::ordered_json& j) const {
    if (parts_.ranks) {
      j["regrid_policy"] =
          kOrb ? "parallel ORB + Hilbert knapsack every dem.regrid_interval (weights: "
                 "partition.weights); migration and ghosts at every sub-iteration"
               : "parallel ORB + Hilbert knapsack at the first build after dem.nsubit "
                 "sub-iterations; migration, ghosts and rows at a build (when the rows could "
                 "miss a pair), not at every sub-iteration";
      double worst = 1.0;
      for (const double q : scheme.imbalances())
        worst = std::max(worst, q);
      j["load_imbalance"] = scheme.imbalances();
      j["load_imbalance_definition"] = "per regrid in this run: max over ranks / mean of the "
                                       "knapsack weight (orb: particles, or particles x local "
                                       "steps; islands: particles)";
      j["load_imbalance_max"] = worst;
    }
  }
  std::string performance(const PhaseTimer& t, double pss, double wait_max) const {
    if (parts_.ranks) {
      std::string islands;
      if constexpr (!kOrb)
        islands = fmt::format("; spanning sub-iterations {} of {}; bound violations {}",
                              scheme.spanning_subiterations(), scheme.subiterations(),
                              scheme.bound_violations());
      return fmt::format("Performance: {:.4g} particle-steps/s; {} force evaluations; rank 0: "
                         "neighbor+exchange {:.3g} s, stepping {:.3g} s; MPI wait max {:.3g} s; "
                         "max overlap {:.3g} r ({} beyond dem.max_overlap){}",
                         pss, scheme.pair_evaluations(), t.seconds(Phase::neighbor),
                         t.seconds(Phase::force), wait_max, scheme.max_overlap_ratio(),
                         scheme.overlap_violations(), islands);
    } else {
      return fmt::format("Performance: {:.4g} particle-steps/s; {} force evaluations; {} {:.3g} "
                         "s, {} {:.3g} s, io {:.3g} s; max overlap {:.3g} r ({} beyond "
                         "dem.max_overlap)",
                         pss, scheme.pair_evaluations(), kOrb ? "regrid+resort" : "islands",
                         t.seconds(Phase::neighbor), kOrb ? "leaves" : "steps",
                         t.seconds(Phase::force), t.seconds(Phase::io), scheme.max_overlap_ratio(),
                         scheme.overlap_violations());
    }
  }

private:
  int leaf_count() const {
    if constexpr (kOrb)
      return scheme.leaf_count();
    else
      return 0;
  }
  // The islands' run.json entries: collisions its bound could have missed (none expected), the
  // dense sub-iterations, and the island sizes (one rank) or the islands across ranks (R ranks).
  void describe_islands(nlohmann::ordered_json& j) const {
    if (scheme.auto_length())
      describe_length(j);
    j["bound_violations"] = scheme.bound_violations();
    j["global_subiterations"] = scheme.global_subiterations();
    j["global_subiterations_definition"] =
        "sub-iterations where every particle took the fine steps together (the explicit "
        "scheme's work): more than a quarter of the particles were linked (a dense bed), or "
        "dem.nsubit = \"auto\" chose the global mode for the interval";
    if (parts_.ranks) {
      const auto subits = static_cast<double>(std::max<std::int64_t>(1, scheme.subiterations()));
      j["spanning_subiterations"] = scheme.spanning_subiterations();
      j["spanning_subiteration_fraction"] =
          static_cast<double>(scheme.spanning_subiterations()) / subits;
      j["spanning_particles_mean"] = static_cast<double>(scheme.spanning_particles()) / subits;
      j["spanning_island_parts"] = scheme.spanning_island_parts();
      j["spanning_definition"] =
          "islands with members on more than one rank: sub-iterations with at least one "
          "(outside the dense mode), their member particles per sub-iteration (mean), and their "
          "parts summed over ranks and sub-iterations; they take the fine steps together with a "
          "ghost refresh per fine step";
      j["expired_builds"] = scheme.expired_builds();
      j["expired_builds_definition"] =
          "builds (of neighbor_builds) made inside a sub-iteration because two particles' "
          "reaches (displacement since the last build + speed bound x dt_sp) could add up to "
          "the skin";
    } else {
      nlohmann::ordered_json hist;
      const auto h = scheme.island_size_histogram();
      for (std::size_t b = 0; b < h.size(); ++b)
        if (h[b] > 0)
          hist[b == 0   ? std::string("1")
               : b == 1 ? std::string("2")
                        : fmt::format("{}-{}", (1LL << (b - 1)) + 1, 1LL << b)] = h[b];
      j["island_sizes"] = hist;
      const auto d = scheme.fine_fraction_distribution();
      j["fine_fraction_per_particle"] = {{"mean", d[0]}, {"min", d[1]}, {"p10", d[2]},
                                         {"p50", d[3]},  {"p90", d[4]}, {"p99", d[5]},
                                         {"max", d[6]}};
      j["fine_fraction_per_particle_definition"] =
          "distribution over particles of the fraction of sub-iterations each spent in a fine "
          "island";
      j["island_sizes_definition"] = "islands of each size, one count per island per "
                                     "sub-iteration (size 1: lone particles in free flight, or "
                                     "tied to a wall)";
    }
  }
  // dem.nsubit = "auto": every choice of the sub-iteration length with its reason.
  void describe_length(nlohmann::ordered_json& j) const {
    j["nsubit"] = "auto";
    j["control_interval"] = scheme.interval();
    nlohmann::ordered_json rows = nlohmann::ordered_json::array();
    const auto& log = scheme.choices();
    const auto& cols = dem::IslandsScheme::kChoiceColumns;
    for (std::size_t r = 0; r + cols.size() <= log.size(); r += cols.size()) {
      nlohmann::ordered_json row;
      for (std::size_t c = 0; c < cols.size(); ++c) {
        const double v = log[r + c];
        if (c == 1 || c == 3 || c == 4 || c == 5)
          row[cols[c]] = static_cast<long long>(v);
        else if (c + 1 == cols.size())
          row[cols[c]] = dem::length::reason_text(static_cast<int>(v));
        else
          row[cols[c]] = v;
      }
      rows.push_back(row);
    }
    j["nsubit_choices"] = rows;
    j["nsubit_choices_definition"] =
        "dem.nsubit = \"auto\": a row per change of the sub-iterations per control interval "
        "(dem.regrid_interval, with a gas fluid.dt), chosen at the end of an interval for the "
        "next from operation counts (docs/schemes.md): t when chosen, nsubit, dt_sp, the "
        "intervals it was kept for, the bounds it was chosen within (nsubit_min: the skin or "
        "the gas force's change; nsubit_max: dt_sp at least the fine step), the fine particles "
        "the model expected per sub-iteration, rho (fine particles measured / first-contact "
        "count), the modelled cost ratio to the previous nsubit, and the reason";
    if (scheme.gas_change_ratio_max() > 0.0) {
      j["gas_force_change_ratio_max"] = scheme.gas_change_ratio_max();
      j["gas_force_change_bound"] = dem::length::kGasChangeBound;
      j["gas_force_change_definition"] =
          "largest change of a held gas acceleration over one sub-iteration (at the rate it "
          "changed over its fluid step) / the largest held acceleration (or |g|); \"auto\" keeps "
          "it within the bound unless dt_sp would fall below the fine step";
    }
  }
  RankParts parts_;
  ParticleStore& p_;
  int levels_;
};

} // namespace cfddem::apps
