// The `explicit` scheme: one global time step for every particle (tau_p * dem.dt_factor), velocity
// Verlet in the paper's form (v at half steps, x at whole steps). Each step is two passes: contact
// forces over the particles that have a neighbor-list row (few, in a dilute gas), then a branch-free
// update of every particle that the compiler vectorizes. It is the baseline every adaptive scheme is
// measured against, so it is written to be as fast as we can make it.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/external_force.hpp"
#include "dem/linear_spring_dashpot.hpp"
#include "dem/step_report.hpp"
#include "dem/verlet_list.hpp"

namespace cfddem::dem {

// Physics and numerics of one step, resolved from the scene.
struct StepModel {
  double dt = 0.0;
  std::array<double, 3> gravity{};
  NormalLaw pair{}, wall{};
  TangentialLaw pair_t{}, wall_t{};
  bool friction = false;
  double max_overlap = 0.3; // fraction of the smaller radius
  double r_min = 0.0;       // smallest radius (the per-step displacement bound)
  double skin = 0.0;
  bool uniform_mass = false;  // every particle has the same mass: m_eff and eta_n are constants
  double uniform_meff = 0.0, uniform_eta = 0.0;
};

// Global dt = min over particles of tau_p * dt_factor, tau_p = sqrt(m / k) (docs/theory.md §1),
// with k the stiffest of the pair and wall springs. Throws RunError when dt is unstable
// (omega dt >= 2 for the stiffest contact, docs/theory.md §2).
StepModel make_step_model(const Scene& scene, const ParticleStore& p);

// What the step model reads of the particles: their count and the extremes of mass and radius
// (of this store, or reduced over ranks: the model is then the same on every rank).
struct ParticleRange {
  std::int64_t count = 0;
  double m_min = 0.0, m_max = 0.0, r_min = 0.0, r_max = 0.0;
};
ParticleRange particle_range(const ParticleStore& p);
StepModel make_step_model(const Scene& scene, const ParticleRange& range);

class ExplicitScheme {
public:
  ExplicitScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer);

  // Evaluate forces at t = 0 and set the half-step velocity v(-dt/2) = v(0) - a(0) dt/2, so the
  // first step reproduces velocity Verlet started from v(0). Builds the neighbor list.
  void start();
  // One step: x(n) -> x(n+1), v(n-1/2) -> v(n+1/2). Throws RunError naming particle, time, cause.
  // With record = true the state at time n (x(n) and the synchronised velocity v(n)) is kept for
  // synchronised_previous().
  void step(bool record = false);

  double dt() const { return model_.dt; }
  std::int64_t steps_taken() const { return steps_; }
  double time() const { return static_cast<double>(steps_) * model_.dt; }
  std::int64_t particle_steps() const { return particle_steps_; }
  std::int64_t pair_evaluations() const { return pair_evaluations_; }
  std::int64_t neighbor_builds() const { return builds_; }
  const StepModel& model() const { return model_; }

  // Per-particle external force [N] (the gas's drag and pressure force), added in the update pass
  // and held fixed until set again (MFIX-Exa holds them over the particle sub-cycle, docs/theory.md
  // §2). Spans of size() entries, in the store's order; an empty span removes it. Without one the
  // update pass is the same instantiation as before (no extra loads).
  void set_external_force(std::span<const double> fx, std::span<const double> fy,
                          std::span<const double> fz);
  bool has_external_force() const { return ext_.active(); }

  // State at the start of the last step recorded (time() - dt): positions x(n) and velocity
  // Verlet's synchronised velocity v(n) = v(n-1/2) + a(n) dt/2.
  struct Synchronised {
    std::span<const double> x, y, z, vx, vy, vz;
  };
  Synchronised synchronised_previous() const { return {sx_, sy_, sz_, svx_, svy_, svz_}; }

  // Checkpoint/restart: everything beyond the particle store that the next step reads (the
  // neighbor list with its reference positions, tangential history, counters). A scheme built on
  // a restored store and given restore_state() instead of start() continues bit for bit.
  struct State {
    std::vector<std::uint32_t> offsets, neighbors;
    std::vector<double> x_ref, y_ref, z_ref;
    std::vector<double> hx, hy, hz;
    double skin = 0.0;
    bool need_rebuild = true;
    std::int64_t steps = 0, particle_steps = 0, pair_evaluations = 0, builds = 0;
  };
  State save_state() const;
  // Throws RunError if the state does not fit the particle store.
  void restore_state(State s);

private:
  using Report = StepReport;
  template <bool Friction> void contact_pass(double dt, Report& report);
  template <bool Walls, bool Friction, bool External> void update_pass(double dt, Report& report);
  template <bool Walls> void update(double dt, Report& report);
  void evaluate_and_update(double dt, Report& report);
  void record_synchronised();
  void rebuild();
  void raise(const Report& report, double t) const;

  const Scene& scene_;
  ParticleStore& p_;
  PhaseTimer& timer_;
  DomainGeometry geom_;
  StepModel model_;
  VerletList list_;
  // Angular velocities at n-1/2 while torques are evaluated (friction: w_j enters v_rel).
  // Recorded state at the last output step.
  std::vector<double> sx_, sy_, sz_, svx_, svy_, svz_;
  // Tangential history per full-list entry (friction only).
  std::vector<double> hx_, hy_, hz_;
  // External force per particle (set_external_force).
  ExternalForce ext_;
  bool need_rebuild_ = true;
  std::int64_t steps_ = 0, particle_steps_ = 0, pair_evaluations_ = 0, builds_ = 0;
};

} // namespace cfddem::dem
