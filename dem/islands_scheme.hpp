// The `islands` scheme (dem.scheme = "islands"): adaptive steps that miss no collision. The
// seed paper's conclusions ask for a time step from the relative distance of particles and for a
// clustering that "respects probable collision partners"; this is that scheme.
//
// Time advances in sub-iterations of dt_sp = dem.regrid_interval / dem.nsubit, as in `orb`. At
// the start of each one every particle gets a speed bound s_i over the sub-iteration:
//   s_i = |v_i| + |F_ext,i / m_i + g| (h_prev,i + dt_sp)
// (v_i is the half-step velocity, h_prev its half step). A pair (i, j) of the Verlet list is
// linked when it could touch within dt_sp:
//   |x_j - x_i| - (r_i + r_j) < (s_i + s_j) dt_sp + margin,
// and a particle is tied to a wall when its gap to the wall is below s_i dt_sp + margin. The
// connected components of the links are the contact islands (partition/contact_islands).
// Contacts inside an island can speed a member up beyond its own s_i; no member can exceed the
// speed that takes the island's whole energy (kinetic, from the s_i, plus the springs'
// potential energy of current overlaps) on its lightest member, plus what the external forces
// add over the sub-iteration:
//   s_max = sqrt(2 E / m_min) + a_max (h_prev,max + dt_sp),
// so every member's bound is raised to its island's s_max and the links are made again, until
// no island grows. Then no particle of one island can touch a particle of another (or a wall,
// unless tied to it) within dt_sp: nothing is frozen at an island's boundary, and no collision
// is missed by construction. The bound is checked: a particle that moves farther than its bound
// is counted (bound_violations(); the tests require none).
//
// Steps: a particle alone in its island and not tied to a wall takes one step of dt_sp (free
// flight under gravity and its frozen external force); an island with a link or a wall takes
// K = ceil(dt_sp / dt) steps of the explicit scheme's dt (the last one shortened to land on the
// sub-iteration's end) with the explicit scheme's contact law, its members read live. The step
// arithmetic is the orb scheme's variable-step leapfrog (h_prev per particle), so a constant
// step is the explicit update exactly. Islands are TBB tasks (a giant island runs its passes
// as nested parallel_for); every island's arithmetic is independent of the others and of the
// thread count. The Verlet list (dem/verlet_list) is rebuilt when some particle's displacement
// since the build plus its bound over the next sub-iteration would exceed skin/2.
//
// Limits: frictionless contacts (the constructor refuses friction); an overlap beyond
// dem.max_overlap is counted, NaN or a particle leaving through a wall stops the run.
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/external_force.hpp"
#include "dem/orb_scheme.hpp"
#include "dem/verlet_list.hpp"
#include "partition/contact_islands.hpp"

namespace cfddem::dem {

class IslandsScheme {
public:
  // Above this fraction of particles linked or tied, a sub-iteration steps everyone finely (the
  // distributed scheme applies it over all ranks).
  static constexpr double kGlobalFraction = 0.25;

  IslandsScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer);

  // h_prev = 0 (velocities are the synchronised v(0)); builds the Verlet list.
  void start();
  // One sub-iteration t -> t + dt_sp. With record = true the state at t is kept
  // (synchronised_previous()).
  void subiterate(bool record = false);

  double dt_fine() const { return model_.dt; }
  double dt_sub() const { return dt_sp_; }
  std::int64_t nsubit() const { return nsubit_; }
  std::int64_t subiterations() const { return subits_; }
  double time() const { return static_cast<double>(subits_) * dt_sp_; }
  std::int64_t particle_steps() const { return particle_steps_; }
  // Pairs of an island evaluated per local step (each pair once), summed over steps.
  std::int64_t pair_evaluations() const { return pair_evaluations_; }
  std::int64_t neighbor_builds() const { return builds_; }
  double skin() const { return skin_; }
  double max_overlap_ratio() const { return max_overlap_ratio_; }
  std::int64_t overlap_violations() const { return overlap_violations_; }
  // Particles that moved farther than their speed bound allowed (a collision could then have
  // been missed): zero unless the bound is wrong.
  std::int64_t bound_violations() const { return bound_violations_; }
  // Sub-iterations taken with every particle on the fine step (a dense bed: see kGlobalFraction).
  std::int64_t global_subiterations() const { return global_subits_; }
  const StepModel& model() const { return model_; }
  // The fraction of particles in an island (on the fine step) in the last sub-iteration.
  double last_fine_fraction() const { return last_fine_fraction_; }
  // Island sizes over the run: bin b counts islands (fine or not) with 2^(b-1) < size <= 2^b
  // members (bin 0: single particles), one count per island per sub-iteration.
  std::span<const std::int64_t> island_size_histogram() const { return size_hist_; }
  // Per particle, the fraction of sub-iterations it spent in a fine island: its distribution over
  // the particles as {mean, min, p10, p50, p90, p99, max} (nearest-rank percentiles).
  std::array<double, 7> fine_fraction_distribution() const;

  void set_external_force(std::span<const double> fx, std::span<const double> fy,
                          std::span<const double> fz);
  // With false, every link round rescans all rows instead of the raised particles' rows only
  // (the reference the tests hold the incremental rounds to: the same links in the same order,
  // hence bitwise the same run).
  void set_incremental_links(bool on) { incremental_links_ = on; }
  // At a fluid-step boundary (the coupled loops' gas step): the owed half kick settled with the
  // force held so far (settle_owed_half_kick, dem/external_force.hpp), then set_external_force.
  // set_external_force alone is for a restart (the held force as it was).
  void replace_external_force(std::span<const double> fx, std::span<const double> fy,
                              std::span<const double> fz);

  // Per output interval: local steps per particle per sub-iteration (min/mean/max over particles
  // and sub-iterations) and the fraction of particle sub-iterations on the fine step.
  LeafStepStats take_interval_stats();

  // The recorded state, with each particle's island (-1: alone, free flight) and local step.
  OrbScheme::Synchronised synchronised_previous() const {
    return {sx_, sy_, sz_, svx_, svy_, svz_, smass_, sid_, sisland_, sradius_, sdt_};
  }

  // Checkpoint/restart between sub-iterations: what a sub-iteration reads that it did not compute
  // itself -- the Verlet list exactly as built (rows in order, reference positions, skin; the
  // store's order is the list's, which the checkpoint keeps), the per-particle half step and
  // fine-sub-iteration count, the counters, the island-size histogram and the interval
  // statistics. Speed bounds, links and islands are remade at the start of every sub-iteration.
  // A gas force held over the sub-cycle is the caller's (set_external_force after restore).
  // restore_state() replaces start().
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
    // Written by the R-rank scheme only (DistributedIslandsScheme::save_state; empty from one
    // rank, ignored by it): regrids, retries, expired builds, spanning sub-iterations, spanning
    // particles, spanning island parts; and the overlap ratio not yet recorded.
    std::vector<std::int64_t> rank_counters;
    std::vector<double> rank_values;
  };
  State save_state() const;
  // Throws RunError if the state does not fit the store.
  void restore_state(State s);

private:
  void rebuild();
  void speed_bounds();
  void make_links(bool incremental);
  void link();
  bool list_expires() const;
  template <bool External> void free_flight(bool record);
  template <bool External, bool Record, bool Walls>
  std::uint64_t free_flight_run(std::size_t b, std::size_t e);
  template <bool External> void run_island(std::uint32_t c, bool record);
  template <bool External> void global_steps(bool record);
  template <bool Label, bool Indexed>
  std::int64_t particle_forces(const std::uint32_t* idx, std::uint32_t u0, std::uint32_t u1,
                               std::uint32_t c, double& max_ratio, std::int64_t& violations);
  void raise_faults(double t) const;

  const Scene& scene_;
  ParticleStore& p_;
  PhaseTimer& timer_;
  DomainGeometry geom_;
  StepModel model_;
  VerletList list_;
  ExternalForce ext_;
  double dt_sp_ = 0.0, skin_ = 0.0, skin_cap_ = 0.0, margin_ = 0.0;
  // Skins of the two modes: islands (a longer list: fewer builds) and global fine steps (the
  // explicit scheme's), and the mode of the current sub-iteration.
  double islands_skin_ = 0.0, global_skin_ = 0.0;
  bool global_ = false;
  std::int64_t global_subits_ = 0;
  std::int64_t nsubit_ = 1;
  bool built_ = false;
  std::vector<double> hprev_;                 // per particle: half of its last step
  std::vector<std::int64_t> fine_subits_;     // per particle: sub-iterations in a fine island
  std::vector<double> bound_;                 // per particle: speed bound s_i [m/s]
  std::vector<double> own_bound_;             // ... from its own velocity (busy particles only)
  std::vector<std::uint32_t> own_stamp_;      // own_bound_[i] is this link() call's when == stamp_
  std::uint32_t stamp_ = 0;
  // link(): per island energy, lightest mass, largest external acceleration and half step.
  std::vector<double> energy_, m_min_, a_max_, hp_max_;
  std::vector<std::uint32_t> busy_before_, label_before_;
  std::vector<double> x0_, y0_, z0_;          // members' start positions (members_ order)
  std::vector<std::uint32_t> ea_, eb_;        // links (ea_ < eb_), in row-scan order
  std::vector<std::uint32_t> ek_;             // ... each one's position in ea_'s row, increasing
  std::vector<std::uint32_t> changed_, new_k_; // link(): particles raised by the last round
  bool incremental_links_ = true;
  std::vector<std::uint32_t> tied_;           // particles tied to a wall
  // Busy particles (linked or tied), increasing; the islands over them (local indices), each
  // island's members as particle indices, and per particle its island or kAlone.
  static constexpr std::uint32_t kAlone = 0xffffffffu;
  std::vector<std::uint32_t> busy_v_, la_, lb_, members_, island_of_;
  std::vector<unsigned char> mark_; // make_links: all zero between calls
  std::uint64_t fault_flag_ = 0;    // sign bit: some particle may be NaN or outside a wall
  partition::Islands islands_;
  std::vector<std::uint32_t> uf_scratch_;
  std::int64_t K_ = 1;
  double h_ = 0.0, h_last_ = 0.0;
  // Per island, results of its task (reduced in island order; faults are flagged apart).
  struct IslandResult {
    std::int64_t pairs = 0, violations = 0, bound_violations = 0;
    double max_ratio = 0.0;
  };
  std::vector<IslandResult> results_;
  std::vector<double> sx_, sy_, sz_, svx_, svy_, svz_, smass_, sradius_, sdt_;
  std::vector<std::int64_t> sid_, sisland_;
  std::vector<std::int64_t> size_hist_;
  std::int64_t subits_ = 0, particle_steps_ = 0, pair_evaluations_ = 0, builds_ = 0,
               overlap_violations_ = 0, bound_violations_ = 0;
  double max_overlap_ratio_ = 0.0, last_fine_fraction_ = 0.0;
  // Interval statistics.
  std::int64_t iv_fine_ = 0, iv_particles_ = 0, iv_steps_ = 0;
  std::int64_t iv_min_ = std::numeric_limits<std::int64_t>::max(), iv_max_ = 0;
};

} // namespace cfddem::dem
