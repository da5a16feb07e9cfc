// The `islands` scheme over MPI ranks: IslandsScheme's speed bounds, links and contact islands
// (dem/islands_scheme.hpp) with the particles owned by ranks as in the distributed orb scheme
// (parallel ORB + Hilbert knapsack, partition/rank_decomposition.hpp).
//
// Update sequence of one sub-iteration t -> t + dt_sp:
//   1. at a build (the first sub-iteration, or when step 3 finds the rows too short): a new
//      decomposition when dem.nsubit sub-iterations have passed since the last (the first build
//      after it, as the distributed explicit scheme regrids at its first rebuild); every
//      particle migrates to the rank owning its position (with its half step, fine-sub-iteration
//      count and external force), the owned ones in id order; ghosts: every owned particle
//      within 2 r_max + skin of another rank's box is copied there unshifted (separations take
//      the minimum image, as IslandsScheme's); rows of the owned particles over owned + ghosts
//      with every pair within r_i + r_j + skin (OrbLocalRows). The skin is IslandsScheme's
//      islands skin, at least 4 dt_sp times the largest bound (one reduction). Between builds
//      ownership, ghosts and rows stay (a particle may wander out of its owner's boxes);
//   2. own speed bounds s_i (IslandsScheme's formula) of the owned particles; the ghosts' x, v
//      and own bounds from their owners in one message round (forward_columns);
//   3. link rounds: links and wall ties as IslandsScheme's, over pairs with an owned end; the
//      islands over their ends. An island with a ghost member SPANS ranks; one without is LOCAL
//      (entirely on this rank, and by the link test no particle of another rank can reach it).
//      A local island's members are raised to its s_max as IslandsScheme raises them; every
//      spanning island's members, on every rank, to one s_span from reductions over all spanning
//      particles of all ranks (energy summed, lightest mass, largest acceleration and half
//      step): at least any one spanning island's own s_max, so conservative. The raised bounds
//      go to the ghosts (forward_columns) and the links are made again, until no rank's islands
//      changed (one reduction per round). Every rank then sees every particle
//      it holds with the same bound, so a link exists on one rank iff on every rank holding its
//      two ends, and "spanning" on the owner is the same as "some member on another rank" over
//      the whole system. The rows and ghosts hold every pair that can link while no two
//      particles' reaches (displacement since the build + final bound x dt_sp) add up to the
//      skin (IslandsScheme::list_expires's rule, the largest reach reduced with the rounds);
//      otherwise the sub-iteration builds again (step 1, expired_builds()) and redoes the rounds,
//      with a doubled skin when even a fresh build was too short. When more than a quarter of
//      all particles are linked (IslandsScheme::kGlobalFraction, over all ranks) every particle
//      takes the fine steps, as the distributed explicit scheme (the dense mode);
//   4. steps: lone particles fly free one step of dt_sp, local islands take the K fine steps
//      (one TBB task each), exactly as IslandsScheme; then, when some rank has a spanning island
//      (or in the dense mode), all spanning members (all particles) take the K fine steps
//      together, each rank its owned ones with forces from their island's partners, and the
//      ghosts' x and v are refreshed after EVERY fine step (the ghost plan of the last build,
//      fixed over the sub-iteration);
//   5. one reduction of the counters, the particle count and mass (none may be lost), faults
//      (every rank throws the same RunError) and the dense mode's displacement test: a particle
//      that moved more than half the skin since the build (its rows may miss a pair) makes
//      every rank roll back and redo the sub-iteration after a build with twice the skin
//      (retries()).
// So a sub-iteration without a build costs one ghost refresh, one reduction per link round
// (usually two rounds) and one closing reduction, plus K - 1 ghost refreshes when an island
// spans ranks.
// Results are bitwise independent of the thread count; different rank counts agree with the
// one-rank IslandsScheme to round-off (island sums in another order; a particle that spans
// takes fine steps where IslandsScheme may fly it free). Frictionless.
// Checkpoints: save_state() puts the scheme in a canonical state (the next sub-iteration builds
// afresh: a new decomposition, every particle to its owner in id order, the skin from the bounds
// alone), which restore_state() recreates from the particles and their saved values on any
// number of ranks; the run that wrote the checkpoint goes on from that state too.
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_exchange.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/external_force.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/orb_local_rows.hpp"
#include "dem/orb_scheme.hpp"
#include "partition/contact_islands.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::dem {

class DistributedIslandsScheme {
public:
  // `particles`: this rank's share (any split). `model`: make_step_model over all particles, the
  // same on every rank. Throws ConfigError with friction (as IslandsScheme).
  DistributedIslandsScheme(const Scene& scene, ParticleStore& particles, const StepModel& model,
                           const Communicator& comm, PhaseTimer& timer);
  DistributedIslandsScheme(const DistributedIslandsScheme&) = delete;
  DistributedIslandsScheme& operator=(const DistributedIslandsScheme&) = delete;

  // h_prev = 0: velocities are the synchronised v(0).
  void start();
  // Collective. As IslandsScheme::subiterate; every rank throws the same RunError on a fault.
  void subiterate(bool record = false);

  double dt_fine() const { return model_.dt; }
  double dt_sub() const { return dt_sp_; }
  std::int64_t nsubit() const { return nsubit_; }
  std::int64_t subiterations() const { return subits_; }
  double time() const { return static_cast<double>(subits_) * dt_sp_; }
  // Counters over all ranks (the same value on every rank).
  std::int64_t particle_steps() const { return particle_steps_; }
  std::int64_t pair_evaluations() const { return pair_evaluations_; }
  // This rank's share of the work since this process started (run.json's rank_counts; not in
  // checkpoints): owned particle steps and the pair evaluations of its rows.
  std::int64_t local_particle_steps() const { return local_particle_steps_; }
  std::int64_t local_pair_evaluations() const { return local_pair_evaluations_; }
  std::int64_t neighbor_builds() const { return builds_; }
  std::int64_t regrids() const { return regrids_; }
  std::int64_t retries() const { return retries_; }
  // Builds made inside a sub-iteration because the rows ran short (step 3 of the header).
  std::int64_t expired_builds() const { return expired_builds_; }
  double skin() const { return skin_; }
  double max_overlap_ratio() const { return max_overlap_ratio_; }
  std::int64_t overlap_violations() const { return overlap_violations_; }
  std::int64_t bound_violations() const { return bound_violations_; }
  std::int64_t global_subiterations() const { return global_subits_; }
  // Sub-iterations in which some island spanned ranks; spanning particles summed over
  // sub-iterations; spanning islands summed over ranks and sub-iterations (an island over two
  // ranks counts twice: each rank sees its part).
  std::int64_t spanning_subiterations() const { return span_subits_; }
  std::int64_t spanning_particles() const { return span_particles_; }
  std::int64_t spanning_island_parts() const { return span_parts_; }
  double last_fine_fraction() const { return last_fine_fraction_; }
  std::int64_t global_count() const { return n_global_; }
  const StepModel& model() const { return model_; }

  // Per regrid: max over ranks / mean of the particles per rank.
  const std::vector<double>& imbalances() const { return imbalances_; }

  std::size_t owned() const { return owned_; }
  std::size_t ghosts() const { return p_.size() - owned_; }

  // Collective. External force [N] per owned particle in the store's current order, held until
  // set again and carried with its particle; empty spans on every rank remove it.
  void set_external_force(std::span<const double> fx, std::span<const double> fy,
                          std::span<const double> fz);
  // At a fluid-step boundary (the coupled loops' gas step): the owed half kick settled with the
  // force held so far (settle_owed_half_kick, dem/external_force.hpp), then set_external_force.
  // set_external_force alone is for a restart (the held force as it was).
  void replace_external_force(std::span<const double> fx, std::span<const double> fy,
                              std::span<const double> fz);

  // IslandsScheme's interval statistics over all ranks (reduced every sub-iteration; then reset).
  LeafStepStats take_interval_stats();

  // Checkpoint/restart, both collective. save_state(): the canonical state above, and per owned
  // particle (store order) the half step and fine-sub-iteration count, the counters (the same on
  // every rank; IslandsScheme::State's layout, no list, no histogram) and the R-rank ones.
  // restore_state() replaces start(): each rank passes its share's values (any split of the
  // particles); a state that does not fit throws RunError on every rank.
  IslandsScheme::State save_state();
  void restore_state(IslandsScheme::State s);

  // The owned particles' recorded state; `leaf` holds the island (-1: alone, free flight).
  OrbScheme::Synchronised synchronised_previous() const {
    return {sx_, sy_, sz_, svx_, svy_, svz_, smass_, sid_, sisland_, sradius_, sdt_};
  }

private:
  void canonicalize();
  void regrid();
  void migrate();
  void own_bounds();
  void rebuild();
  void build_ghosts_and_rows();
  // Link rounds (step 3); returns the largest final bound over all ranks.
  double link_rounds();
  void make_links();
  template <bool External> void free_flight(bool record);
  template <bool External> void run_local_island(std::uint32_t c, bool record);
  template <bool External> void fine_together(bool record, bool all);
  std::int64_t forces(std::uint32_t i, bool label, double& max_ratio, std::int64_t& violations);
  void record_state();

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
  double dt_sp_ = 0.0, r_max_ = 0.0, margin_ = 0.0, skin_ = 0.0, last_max_bound_ = 0.0;
  double mass_global_ = 0.0, base_skin_ = 0.0, grown_skin_ = 0.0;
  std::int64_t last_regrid_ = -1, spanning_global_ = 0;
  bool need_rebuild_ = true;
  std::int64_t nsubit_ = 1, n_global_ = 0;
  std::size_t owned_ = 0;
  bool ext_on_ = false, global_ = false;
  // Per owned particle, carried through migrations: half step, fine sub-iterations, force.
  std::vector<double> hprev_, fine_, ex_, ey_, ez_;
  // Per local particle (owned, then ghosts): speed bound and own bound.
  std::vector<double> bound_, own_bound_;
  std::vector<double> x_ref_, y_ref_, z_ref_; // owned positions at the last build
  std::vector<double> imbalances_;
  std::vector<std::uint32_t> leaf0_; // all zero: the rows' one "leaf" of owned particles
  OrbLocalRows rows_;
  static constexpr std::uint32_t kAlone = 0xffffffffu;
  std::vector<std::uint32_t> ea_, eb_, tied_, busy_v_, la_, lb_, island_of_, members_;
  std::vector<std::uint32_t> busy_before_, label_before_, span_members_;
  std::vector<unsigned char> mark_, spans_; // spans_: per island, has a ghost member
  partition::Islands islands_;
  std::vector<std::uint32_t> uf_scratch_;
  std::vector<double> energy_, m_min_, a_max_, hp_max_;
  std::int64_t K_ = 1;
  double h_ = 0.0, h_last_ = 0.0;
  // Start of the sub-iteration (bound test and rollback).
  std::vector<double> x0_, y0_, z0_, vx0_, vy0_, vz0_, hp0_;
  struct Result {
    std::int64_t pairs = 0, violations = 0, bound_violations = 0, outran = 0;
    double max_ratio = 0.0;
  };
  std::vector<Result> results_;
  Result span_result_;
  std::vector<double> sx_, sy_, sz_, svx_, svy_, svz_, smass_, sradius_, sdt_;
  std::vector<std::int64_t> sid_, sisland_;
  std::int64_t local_particle_steps_ = 0, local_pair_evaluations_ = 0;
  std::int64_t local_c_[2] = {0, 0}; // this rank's counts of the last attempt, before its reduction
  std::int64_t subits_ = 0, particle_steps_ = 0, pair_evaluations_ = 0, builds_ = 0, regrids_ = 0,
               retries_ = 0, expired_builds_ = 0, overlap_violations_ = 0, bound_violations_ = 0,
               global_subits_ = 0, span_subits_ = 0, span_particles_ = 0, span_parts_ = 0;
  double max_overlap_ratio_ = 0.0, last_fine_fraction_ = 0.0, max_ratio_local_ = 0.0;
  std::int64_t iv_fine_ = 0, iv_particles_ = 0, iv_steps_ = 0;
  std::int64_t iv_min_ = std::numeric_limits<std::int64_t>::max(), iv_max_ = 0;
};

} // namespace cfddem::dem
