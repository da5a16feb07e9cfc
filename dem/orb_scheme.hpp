// The `orb` scheme (dem.scheme = "orb"): the explicit adaptive time stepping of Sitaraman & Grout
// (Algorithm 2). Every dem.regrid_interval (dt_f) of simulated time the particles are split by
// an ORB into 2^partition.orb_levels leaves and the store is permuted so that each leaf is a
// contiguous range (partition.weights = "cost": each particle weighs the local steps its leaf
// took since the last regrid, so a leaf weighs particles x local steps). Time advances in sub-iterations of dt_sp = dt_f / dem.nsubit; in each one
// every leaf picks its own step (leaves with the same step run together as TBB tasks, below):
//   dt_local = the explicit step (tau_p * dt_factor) if some own particle has a partner (own or
//              ghost) closer than dem.proximity_radii * (r_i + r_j) / 2 centre to centre,
//              or its centre is closer than dem.proximity_radii * r_i to a wall (with
//              dem.local_dt = "time_to_contact": if some gap to a partner or a wall could close
//              within dt_sp at the particles' speeds plus gravity and external forces),
//            = dt_sp otherwise,
// and takes K = ceil(dt_sp / dt_local) velocity-Verlet steps with the explicit scheme's contact
// law, the last one shortened so that the leaf lands exactly on the end of the sub-iteration.
// Particles of other leaves are read frozen at their state at the start of the sub-iteration
// (ghosts). Afterwards particles that left their leaf are re-sorted into the leaf that now holds
// them (OrbTree::locate), keeping every leaf contiguous.
//
// Implementation (what makes it cheap when most leaves are fine-stepped):
// - One cell list over the whole store gives candidate pairs: contact candidates (centres within
//   r_i + r_j + skin) and proximity candidates (within proximity_radii (r_i + r_j)/2 + skin).
//   They are rebuilt only when some particle's displacement since the build plus its free flight
//   over one sub-iteration exceeds skin/2 (Verlet criterion, checked between sub-iterations), and
//   are remapped, not rebuilt, when the store is re-sorted.
// - Each particle's row is split into partners of its own leaf (read live) and of other leaves
//   (read from the frozen copies): the ghost refresh is one copy of x and v per sub-iteration, and
//   only particles that are actual partners are ever read as ghosts. Rows are summed in particle-id
//   order, so results do not depend on the store's order, the batching or the thread count.
// - Consecutive leaves with the same local step are advanced in lockstep as one TBB task (a
//   batch, cut at ~max(256, n / 4 threads) particles): the contact pass over the rows, then the
//   branch-free kick-drift over the batch's contiguous range (dem/contact_kernels.hpp, the
//   explicit scheme's arithmetic). Leaves never read each other's live state, so the batching
//   changes no result bit; it amortises the loop overhead of ~20-particle leaves.
// - A fine leaf whose particle moves more than skin/2 during the sub-iteration (a collision sped
//   it up) makes the whole sub-iteration roll back to the frozen copies and run again with rows
//   rebuilt; if they were already fresh, with the skin doubled until the next regrid
//   (retries() counts them).
// Force evaluations (pair_evaluations) = per local step, own-leaf pairs once plus other-leaf
// pairs once per side: a pair across a leaf boundary is evaluated by both leaves, against the
// other's frozen copy, and counted twice. With one leaf it is the explicit scheme's count.
//
// Velocities are kept at half steps as in the explicit scheme, with the length of the half step
// stored per particle (h_prev = dt_last / 2; 0 at the start, where v is the synchronised v(0)).
// A step of length h evaluates F(n) with x(n), v(n-1/2), then
//   v(n+1/2) = v(n-1/2) + a(n) (h_prev + h/2),  x(n+1) = x(n) + v(n+1/2) h,  h_prev = h/2,
// which is v(n) = v(n-1/2) + a(n) h_prev (re-synchronise with the old step) followed by
// v(n+1/2) = v(n) + a(n) h/2 (start the new one): variable-step leapfrog. With a constant h it is
// the explicit scheme's update exactly (h/2 + h/2 == h in floating point).
//
// Limits (documented, not hidden): frictionless contacts only (the constructor throws with
// friction); an overlap beyond dem.max_overlap is counted (max_overlap_ratio) rather than fatal,
// since a coarse step missing a collision is the trade this scheme makes; NaN or a particle
// leaving through a wall stops the run.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/external_force.hpp"
#include "partition/orb_tree.hpp"

namespace cfddem::dem {

// Local steps per leaf over an output interval (non-empty leaves only), and the fraction of
// (leaf, sub-iteration) pairs that took the fine step.
struct LeafStepStats {
  double steps_min = 0.0, steps_mean = 0.0, steps_max = 0.0, fine_fraction = 0.0;
};

class OrbScheme {
public:
  OrbScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer);
  ~OrbScheme();
  OrbScheme(const OrbScheme&) = delete;
  OrbScheme& operator=(const OrbScheme&) = delete;

  // Regrid and set h_prev = 0 (velocities are the synchronised v(0)); evaluates nothing.
  void start();
  // One sub-iteration t -> t + dt_sp. With record = true the state at t (x and the synchronised
  // v(t) = v(t-h_prev) + a(t) h_prev, with a(t) from the first local step) is kept.
  void subiterate(bool record = false);

  double dt_fine() const { return model_.dt; }
  double dt_sub() const { return dt_sp_; }
  std::int64_t subiterations() const { return subits_; }
  double time() const { return static_cast<double>(subits_) * dt_sp_; }
  std::int64_t particle_steps() const { return particle_steps_; }
  std::int64_t pair_evaluations() const { return pair_evaluations_; }
  std::int64_t neighbor_builds() const { return builds_; }
  std::int64_t regrids() const { return regrids_; }
  // Sub-iterations redone with a larger skin because a fine leaf outran the neighbor list.
  std::int64_t retries() const { return retries_; }
  double skin() const { return skin_; }
  double max_overlap_ratio() const { return max_overlap_ratio_; }
  std::int64_t overlap_violations() const { return overlap_violations_; }
  const StepModel& model() const { return model_; }
  int leaf_count() const { return static_cast<int>(ranges_.size()) - 1; }
  // The decomposition of the last regrid.
  const partition::OrbTree& tree() const { return tree_; }
  // Fraction of non-empty leaves on the fine step in the last sub-iteration.
  double last_fine_fraction() const { return last_fine_fraction_; }

  // Benchmark hooks (perf/dem): after at least one subiterate(), run leaf `leaf`'s fine-step
  // sub-iteration alone (the batch of that one leaf, from the current state), and refresh the
  // ghosts (frozen copies and the rows' own/other-leaf split, as after a re-sort).
  void benchmark_leaf_subiteration(int leaf);
  void benchmark_ghost_refresh();

  // Per-particle external force [N] (the gas's drag and pressure), as ExplicitScheme's: held
  // fixed until set again, follows its particle through regrids and re-sorts; in the store's
  // current order; an empty span removes it.
  void set_external_force(std::span<const double> fx, std::span<const double> fy,
                          std::span<const double> fz);
  // At a fluid-step boundary (the coupled loops' gas step): the owed half kick settled with the
  // force held so far (settle_owed_half_kick, dem/external_force.hpp), then set_external_force.
  // set_external_force alone is for a restart (the held force as it was).
  void replace_external_force(std::span<const double> fx, std::span<const double> fy,
                              std::span<const double> fz);

  // Statistics since the last call (then reset).
  LeafStepStats take_interval_stats();

  // With the identity, radius, ORB leaf and local step (dt_sp / the leaf's step count) of each
  // recorded particle, in the same order (snapshots).
  struct Synchronised {
    std::span<const double> x, y, z, vx, vy, vz, mass;
    std::span<const std::int64_t> id, leaf;
    std::span<const double> radius, local_dt;
  };
  Synchronised synchronised_previous() const {
    return {sx_, sy_, sz_, svx_, svy_, svz_, smass_, sid_, sleaf_, sradius_, sdt_};
  }

  // Checkpoint/restart at a regrid point (subiterations() a multiple of dem.nsubit): the ORB,
  // the leaf ranges, the rows and the batches are rebuilt from the particle store by the next
  // sub-iteration exactly as they would have been. What survives a regrid is saved: the
  // per-particle half step and cost weights, the candidate pairs with their reference positions
  // (global indices in the store's order, which the checkpoint keeps), the counters and the
  // interval statistics. restore_state() replaces start().
  struct State {
    std::vector<double> hprev, cost;
    std::vector<std::int64_t> leaf_steps;
    std::int64_t fine_count = 0, leaf_subits = 0, subits = 0, particle_steps = 0,
                 pair_evaluations = 0, builds = 0, regrids = 0, overlap_violations = 0,
                 retries = 0;
    double last_fine_fraction = 0.0, max_overlap_ratio = 0.0, skin = 0.0;
    // Candidate pairs: contact (ca, cb) and proximity (pa, pb); references x_ref..z_ref.
    bool pairs_valid = false, prox_from_pairs = true;
    std::vector<std::uint32_t> ca, cb, pa, pb;
    std::vector<double> x_ref, y_ref, z_ref;
  };
  std::int64_t nsubit() const { return nsubit_; }
  State save_state() const;
  void restore_state(State s); // throws RunError if it does not fit the store

private:
  struct Batch;
  void regrid();
  void resort();
  void apply_permutation(std::span<const std::uint32_t> order);
  void rebuild_pairs();
  void derive_rows();
  void bind_rows();
  bool rows_expire() const;
  void run_batch(Batch& b, bool record);
  template <bool External> void run_batch_impl(Batch& b, bool record);
  bool attempt(bool record);

  const Scene& scene_;
  ParticleStore& p_;
  PhaseTimer& timer_;
  DomainGeometry geom_;
  StepModel model_;
  partition::Aabb domain_;
  partition::OrbTree tree_;
  double dt_sp_ = 0.0, r_max_ = 0.0, skin_ = 0.0, skin_cap_ = 0.0;
  std::int64_t nsubit_ = 1;
  bool cost_weights_ = false;
  bool time_to_contact_ = false;   // dem.local_dt = "time_to_contact"
  std::vector<double> speed_;      // its per-particle speed bound
  std::vector<double> hprev_;         // per particle: half of its last step
  ExternalForce ext_; // set_external_force
  std::vector<double> cost_;          // per particle: local steps of its leaf since the regrid
  std::vector<std::uint32_t> ranges_; // leaf l owns [ranges_[l], ranges_[l+1])
  std::vector<std::uint32_t> leaf_of_;
  // Candidate pairs (a, b), global indices, valid while every particle stays within skin_/2 of
  // its reference position: contact candidates (centres within r_a + r_b + skin) and proximity
  // candidates (within proximity_radii (r_a + r_b) / 2 + skin).
  std::vector<std::uint32_t> ca_, cb_, pa_, pb_;
  std::vector<double> xr_, yr_, zr_;
  bool pairs_valid_ = false;
  // Rows derived from the contact candidates: particle i's partners of its own leaf in
  // [off_[i], mid_[i]) (read live) and of other leaves in [mid_[i], off_[i+1]) (read frozen).
  std::vector<std::uint32_t> off_, mid_, nb_, active_, cell_start_, cell_of_, scratch_, fill_;
  std::vector<std::uint32_t> own_before_; // own-leaf row entries of particles [0, i)
  // rebuild_pairs: the binned particles' x, y, z, radius in cell order; kNoCell marks a forward
  // neighbour beyond a wall.
  static constexpr std::uint32_t kNoCell = 0xffffffffu;
  std::array<std::vector<double>, 4> sorted_;
  // State at the start of the sub-iteration: the ghosts' frozen copies and the rollback point.
  std::vector<double> gx_, gy_, gz_, gvx_, gvy_, gvz_, ghp_, dscratch_;
  bool prox_from_pairs_ = true;
  std::vector<unsigned char> near_, leaf_fine_;
  std::vector<Batch> batches_;
  std::vector<double> sx_, sy_, sz_, svx_, svy_, svz_, smass_, sradius_, sdt_;
  std::vector<std::int64_t> sid_, sleaf_;
  std::vector<std::int64_t> leaf_steps_; // per leaf, this interval
  std::int64_t fine_count_ = 0, leaf_subits_ = 0;
  double last_fine_fraction_ = 0.0, max_overlap_ratio_ = 0.0;
  std::int64_t subits_ = 0, particle_steps_ = 0, pair_evaluations_ = 0, builds_ = 0,
               regrids_ = 0, overlap_violations_ = 0, retries_ = 0;
};

} // namespace cfddem::dem
