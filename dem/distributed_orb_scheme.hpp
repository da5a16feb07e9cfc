// The `orb` scheme over MPI ranks: OrbScheme's sub-iterations (dem/orb_scheme.hpp, Sitaraman &
// Grout Algorithm 2) with the leaves of the parallel ORB dealt to ranks by the knapsack
// (partition/rank_decomposition.hpp); each rank advances the leaves it owns.
//
// Update sequence of one sub-iteration t -> t + dt_sp (the paper: ghosts refreshed and particles
// redistributed between sub-iterations):
//   1. at a regrid point (every dem.nsubit sub-iterations): wrap, parallel ORB with
//      2^partition.orb_levels leaves (weights as OrbScheme's: counts, or the measured local steps
//      with partition.weights = "cost"), knapsack over the same weights; otherwise the leaves
//      stay and only particles that left them are located again (OrbScheme::resort's rule);
//   2. one round of messages (ParticleExchange::redistribute): every particle to the rank owning
//      its leaf (with its half step and cost), and ghosts: every particle within the cutoff of
//      one of a rank's leaves (periodic images included) is copied there UNSHIFTED, so that pair
//      separations take OrbScheme's minimum-image arithmetic bit for bit; ghosts are read frozen
//      for the whole sub-iteration, as OrbScheme reads particles of other leaves, and so are
//      this rank's other leaves; the owned particles are ordered by (leaf, id);
//   3. rows of the owned particles from a cell list over owned + ghosts (fresh at every
//      sub-iteration, each local pair tested once, cut at the contact distance + skin), the
//      proximity (or time-to-contact) test of each leaf, exact, then K velocity-Verlet steps
//      per leaf with OrbScheme's per-pair and kick-drift arithmetic (contact_kernels.hpp,
//      kick_drift_range.hpp). Rows sum own-leaf partners by id, then other partners by id:
//      OrbScheme's order, so with the same leaves the result is OrbScheme's bit for bit,
//      whatever the rank and thread counts (consecutive leaves with the same step run as one
//      TBB task, OrbScheme's batches);
//   4. one reduction of the counters and flags, the particle count among them (none may be
//      lost): a fine leaf that moved a particle more than skin/2 (its rows may miss a pair)
//      makes every rank roll back and redo the sub-iteration with twice the skin (retries()); a
//      NaN or a particle through a wall stops every rank with the same RunError.
// So a sub-iteration costs one all-to-all of counts, one exchange of particles between
// neighbouring ranks and one allreduce (with time_to_contact, one more for the largest reach),
// plus the parallel ORB's reductions at a regrid.
// Frictionless. An external force per particle (the gas's) travels with its particle; with a
// gas the ORB cuts lie on its cell faces, as OrbScheme's (orb_snap_grid), and the gas force is
// computed on the gas boxes' ranks and routed back (apps/gas_routing.hpp). With more ranks than
// leaves some ranks own none (they still take part in every collective).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_exchange.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/external_force.hpp"
#include "dem/orb_local_rows.hpp"
#include "dem/orb_scheme.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::dem {

class DistributedOrbScheme {
public:
  // `particles`: this rank's share of the particles (any split: the first sub-iteration moves
  // each to its owner). `model`: make_step_model over all particles, the same on every rank.
  // Throws ConfigError with friction (as OrbScheme).
  DistributedOrbScheme(const Scene& scene, ParticleStore& particles, const StepModel& model,
                       const Communicator& comm, PhaseTimer& timer);
  DistributedOrbScheme(const DistributedOrbScheme&) = delete;
  DistributedOrbScheme& operator=(const DistributedOrbScheme&) = delete;

  // h_prev = 0: velocities are the synchronised v(0). Evaluates nothing.
  void start();
  // Collective. As OrbScheme::subiterate; every rank throws the same RunError on a fault.
  void subiterate(bool record = false);

  double dt_fine() const { return model_.dt; }
  double dt_sub() const { return dt_sp_; }
  std::int64_t nsubit() const { return nsubit_; }
  std::int64_t subiterations() const { return subits_; }
  double time() const { return static_cast<double>(subits_) * dt_sp_; }
  // Over all ranks (the same value on every rank).
  std::int64_t particle_steps() const { return particle_steps_; }
  // OrbScheme's definition, over the rows of this scheme's lists (built at every sub-iteration,
  // so the count differs from OrbScheme's, whose lists live longer).
  std::int64_t pair_evaluations() const { return pair_evaluations_; }
  // This rank's share of the work since this process started (run.json's rank_counts; not in
  // checkpoints): owned particle steps and the pair evaluations of its rows.
  std::int64_t local_particle_steps() const { return local_particle_steps_; }
  std::int64_t local_pair_evaluations() const { return local_pair_evaluations_; }
  std::int64_t neighbor_builds() const { return builds_; }
  std::int64_t regrids() const { return regrids_; }
  std::int64_t retries() const { return retries_; }
  double skin() const { return skin_; }
  // Over all ranks as of the last recorded sub-iteration (subiterate(true)).
  double max_overlap_ratio() const { return max_overlap_ratio_; }
  std::int64_t overlap_violations() const { return overlap_violations_; }
  double last_fine_fraction() const { return last_fine_fraction_; }
  std::int64_t global_count() const { return n_global_; }
  int leaf_count() const { return 1 << levels_; }
  const StepModel& model() const { return model_; }
  const partition::RankDecomposition& decomposition() const { return decomposition_; }
  // Per regrid: max over ranks / mean of the knapsack load.
  const std::vector<double>& imbalances() const { return imbalances_; }

  // This rank: owned particles are [0, owned()) of the store, ghosts after them.
  std::size_t owned() const { return owned_; }
  std::size_t ghosts() const { return p_.size() - owned_; }

  // Collective. A per-particle external force [N] (the gas's), as OrbScheme's: one value per
  // owned particle in the store's current order ([0, owned())), held fixed until set again,
  // following its particle through migrations and re-sorts; empty spans on every rank remove it
  // (a rank without particles passes empty spans either way).
  void set_external_force(std::span<const double> fx, std::span<const double> fy,
                          std::span<const double> fz);
  // At a fluid-step boundary (the coupled loops' gas step): the owed half kick settled with the
  // force held so far (settle_owed_half_kick, dem/external_force.hpp), then set_external_force.
  // set_external_force alone is for a restart (the held force as it was).
  void replace_external_force(std::span<const double> fx, std::span<const double> fy,
                              std::span<const double> fz);

  // Collective: statistics over all ranks since the last call (then reset).
  LeafStepStats take_interval_stats();

  // The owned particles' recorded state (OrbScheme::Synchronised's meaning).
  OrbScheme::Synchronised synchronised_previous() const {
    return {sx_, sy_, sz_, svx_, svy_, svz_, smass_, sid_, sleaf_, sradius_, sdt_};
  }

  // Checkpoint/restart at a regrid point (subiterations() a multiple of dem.nsubit), where the
  // next sub-iteration rebuilds everything from the particles. save_state() (collective): the
  // owned particles' h_prev and cost in store order (the caller gathers them with the
  // particles), the counters over all ranks. restore_state() replaces start(): each rank passes
  // the h_prev and cost of its share of the checkpoint's particles; the run continues bit for
  // bit (the owned order is (leaf, id), the decomposition depends on the particles only).
  OrbScheme::State save_state() const;
  void restore_state(OrbScheme::State s);

private:
  void regrid();
  std::int64_t locate(bool regridding, std::string& message, std::int64_t& key);
  void exchange_and_rows();
  void run_batch(std::size_t which, bool record);
  template <bool External> void run_batch_impl(std::size_t which, bool record);
  bool attempt(bool record);

  // Per owned leaf: its step count and length, whether fine, force evaluations per step.
  struct LeafRun {
    std::int64_t K = 1, evals = 0;
    double h = 0.0, h_last = 0.0;
    bool fine = false;
  };
  // A run of consecutive owned leaves with the same step, advanced as one TBB task: [b, e) in the
  // store, rows rows_.active()[a0, a1) (OrbScheme's batches), and the results of its last attempt.
  struct Batch {
    std::uint32_t b = 0, e = 0, a0 = 0, a1 = 0;
    std::int64_t K = 1, violations = 0;
    double h = 0.0, h_last = 0.0, max_ratio = 0.0;
    bool outran = false;
    int fault = 0; // 1: NaN, 2: left the domain through a wall
    std::uint32_t fault_index = 0;
    double fault_value = 0.0;
  };

  const Scene& scene_;
  ParticleStore& p_;
  const Communicator& comm_;
  PhaseTimer& timer_;
  DomainGeometry geom_;
  StepModel model_;
  ParticleExchange exchange_;
  partition::RankDecomposition decomposition_;
  partition::Aabb domain_;
  int levels_ = 0;
  double dt_sp_ = 0.0, r_max_ = 0.0, skin_ = 0.0, skin_cap_ = 0.0, reach_ = 0.0;
  std::int64_t nsubit_ = 1, n_global_ = 0;
  bool cost_weights_ = false, time_to_contact_ = false;
  std::size_t owned_ = 0;
  // Per owned particle: half of its last step, local steps since the regrid, its leaf.
  std::vector<double> hprev_, cost_;
  std::vector<std::uint32_t> leaf_of_;
  std::vector<int> dest_; // per owned particle: the rank it goes to
  // Per leaf: leaves of other ranks than its owner (with the periodic image) within the cutoff
  // of its box, found when first needed in a sub-iteration.
  std::vector<std::vector<partition::LeafImage>> near_leaves_;
  std::vector<unsigned char> near_known_;
  std::vector<double> speed_; // time_to_contact: speed bound, owned and ghosts
  bool ext_on_ = false;       // set_external_force: on for every rank alike
  std::vector<double> ex_, ey_, ez_; // per owned particle
  // This rank's non-empty leaves: leaf ids_[k] owns [ranges_[k], ranges_[k+1]).
  std::vector<int> ids_;
  std::vector<std::uint32_t> ranges_;
  std::vector<LeafRun> runs_;
  std::vector<Batch> batches_;
  OrbLocalRows rows_; // of the owned particles, rebuilt at every sub-iteration
  // State at the start of the sub-iteration: what other leaves read, and the rollback point.
  std::vector<double> gx_, gy_, gz_, gvx_, gvy_, gvz_, ghp_;
  std::vector<double> sx_, sy_, sz_, svx_, svy_, svz_, smass_, sradius_, sdt_;
  std::vector<std::int64_t> sid_, sleaf_;
  std::vector<std::int64_t> leaf_steps_; // per leaf, this rank's part, this interval
  std::vector<double> imbalances_;
  double last_fine_fraction_ = 0.0, max_overlap_ratio_ = 0.0;
  double ratio_ = 0.0; // this rank's largest overlap ratio (max_overlap_ratio_: over the ranks)
  std::int64_t fine_count_ = 0, leaf_subits_ = 0;
  std::int64_t local_particle_steps_ = 0, local_pair_evaluations_ = 0;
  std::int64_t local_c_[2] = {0, 0}; // this rank's counts of the last attempt, before its reduction
  std::int64_t subits_ = 0, particle_steps_ = 0, pair_evaluations_ = 0, builds_ = 0,
               regrids_ = 0, overlap_violations_ = 0, retries_ = 0;
};

} // namespace cfddem::dem
