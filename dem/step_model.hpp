// The physics and numerics of one particle step (time step, contact laws, list skin), resolved
// once from the scene and the particles' extremes: what every particle scheme steps with.
#pragma once

#include <array>
#include <cstdint>

#include "core/particle_store.hpp"
#include "core/scene.hpp"
#include "dem/linear_spring_dashpot.hpp"

namespace cfddem::dem {

// What the time loop fixes of the particles' clock before a scheme is built, passed as a value
// (the scene stays as read): the particle step (> 0: a fixed fluid.dt divided into whole steps,
// which overrides dem.dt and dem.dt_factor; 0: the scene's own) and the control interval of orb
// and islands (> 0: the fluid step with a gas; 0: dem.regrid_interval).
struct StepClock {
  double dt = 0.0;
  double interval = 0.0;
};

// Physics and numerics of one step, resolved from the scene.
struct StepModel {
  double dt = 0.0;
  // orb and islands: the control interval D they sub-iterate (dem.regrid_interval, or the
  // StepClock's); explicit on R ranks: the time between regrids.
  double interval = 0.0;
  std::array<double, 3> gravity{};
  NormalLaw pair{}, wall{};
  TangentialLaw pair_t{}, wall_t{};
  bool friction = false;
  double max_overlap = 0.3; // fraction of the smaller radius
  double r_min = 0.0;       // smallest radius (the per-step displacement bound)
  double skin = 0.0;
  bool uniform_mass = false; // every particle has the same mass: m_eff and eta_n are constants
  double uniform_meff = 0.0, uniform_eta = 0.0;
  // Every particle has the same radius (r_min): a pair's contact distance is 2 r_min, with no
  // load of the partner's radius in the pair loop.
  bool uniform_radius = false;
};

// Global dt = min over particles of tau_p * dt_factor, tau_p = sqrt(m / k) (docs/theory.md §1),
// with k the stiffest of the pair and wall springs. Throws RunError when dt is unstable
// (omega dt >= 2 for the stiffest contact, docs/theory.md §2).
StepModel make_step_model(const Scene& scene, const ParticleStore& p, const StepClock& clock = {});

// What the step model reads of the particles: their count and the extremes of mass and radius
// (of this store, or reduced over ranks: the model is then the same on every rank).
struct ParticleRange {
  std::int64_t count = 0;
  double m_min = 0.0, m_max = 0.0, r_min = 0.0, r_max = 0.0;
};
ParticleRange particle_range(const ParticleStore& p);
StepModel make_step_model(const Scene& scene, const ParticleRange& range,
                          const StepClock& clock = {});

} // namespace cfddem::dem
