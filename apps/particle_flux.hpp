// Particles leaving through the outflow faces and entering through the inlet, at the start of a
// fluid step (the rules: apps/particle_outflow.hpp, apps/particle_inlet.hpp; docs/theory.md §12),
// for the one time loop (apps/run_loop.hpp), every scheme and rank count.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "apps/checkpoint.hpp"
#include "apps/particle_inlet.hpp"
#include "apps/particle_outflow.hpp"
#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/state_edit.hpp"
#include "dem/step_model.hpp"
#include "dem/verlet_passes.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::apps {

// The scene's open faces and inlet.
struct ParticleFlux {
  explicit ParticleFlux(const Scene& scene) : outflow(outflow_faces(scene)), inlet(scene) {}
  bool on() const { return outflow.any() || inlet.on(); }
  OutflowFaces outflow;
  ParticleInlet inlet;
};

// A particle on a velocity the particle step cannot follow (dem::flag_unfollowable: not finite,
// or more than the smallest radius per step), in the words of the particle step's own stop, with
// its id; an empty message when none. Two places ask it:
// - the particles about to leave through an outflow face: such a one is a failed step, not an
//   outflow; removed, it would end the run as if nothing were wrong;
// - all of a rank's particles before each gas step, which deposits their drag: a speed no
//   particle step can follow (thermal speeds of 5e4 m/s, a velocity of 1e300) is named as the
//   step names it, rather than as a drag the fluid step cannot hold or a gas solve that fails.
struct ParticleFault {
  std::int64_t id = 0;
  std::string message;
};
// The fault with the smallest id among the particles `indices` of p (every rank then agrees on
// the smallest over the ranks).
template <class Indices>
ParticleFault unfollowable_fault(const ParticleStore& p, const Indices& indices,
                                 const dem::StepModel& m) {
  const double vmax = m.r_min / m.dt;
  bool found = false;
  std::size_t at = 0;
  dem::StepReport first;
  for (const std::size_t i : indices) {
    dem::StepReport report;
    if (dem::flag_unfollowable(p, i, vmax * vmax, report) && (!found || p.id[i] < p.id[at]))
      found = true, at = i, first = report;
  }
  if (!found)
    return {};
  return {static_cast<std::int64_t>(p.id[at]), dem::describe_fault(p, first, m)};
}

// Particles leaving through an outflow face and entering through the inlet at the start of a
// fluid step of dt_f (the rules: apps/particle_outflow.hpp, apps/particle_inlet.hpp). The
// scheme's state is saved as for a checkpoint (R ranks: each rank's canonical share); the
// leaving particles go from the store, the state and the held gas force, the entering ones are
// appended (rank 0's store) with no force held yet; the scheme is rebuilt on them and restored,
// as at a restart, so that a run with removals and insertions restarts bit for bit. Nothing is
// done in a fluid step where none leaves or enters.
// Collective. `run` is rebuilt on `particles` (with `range` and `step_clock`, as the loop built
// it); `loop` counts the mass and particles through the faces and holds the inlet's state.
// Returns the change of the particle count over all ranks.
template <class Run>
std::int64_t change_particles(const ParticleFlux& flux, std::optional<Run>& run, const Scene& scene,
                              ParticleStore& particles, const dem::ParticleRange& range,
                              const Communicator& comm, PhaseTimer& timer,
                              const dem::StepClock& step_clock, CoupledLoopState& loop,
                              double dt_f) {
  if (!flux.on())
    return 0;
  std::size_t n_leaving = 0;
  if (flux.outflow.any()) {
    const std::vector<std::uint32_t> leaving =
        leaving_particles(particles, run->owned(), flux.outflow, dt_f);
    // Every rank stops on the same fault (the smallest id's), before any particle is taken out.
    const ParticleFault fault = unfollowable_fault(particles, leaving, run->scheme.model());
    const std::string agreed = comm.agree_on_error(fault.id, fault.message);
    if (!agreed.empty())
      throw RunError(
          fmt::format("t = {:.9g} s, leaving through an outflow face: {}", loop.time, agreed));
    n_leaving = leaving.size();
    if (comm.size() > 1)
      n_leaving = static_cast<std::size_t>(comm.sum(static_cast<std::int64_t>(n_leaving)));
    if (n_leaving > 0)
      flux.inlet.queue(loop.inlet, particles, leaving, comm); // recycle: they enter again
  }
  EnteringParticles entering;
  std::size_t n_entering = 0;
  if (flux.inlet.on()) {
    flux.inlet.start(loop.inlet, particles, run->owned(), comm);
    entering = flux.inlet.enter(loop.inlet, particles, run->owned(), dt_f, loop.fluid_steps, comm);
    n_entering = entering.size();
    if (comm.size() > 1)
      n_entering = static_cast<std::size_t>(comm.sum(static_cast<std::int64_t>(n_entering)));
  }
  if (n_leaving == 0 && n_entering == 0)
    return 0;
  const PhaseTimer::Scope changing(timer, Phase::regrid);
  Checkpoint c;
  typename Run::Restart share;
  std::optional<partition::RankDecomposition> owners;
  run->save_for_change(c, share, owners); // R ranks: may reorder the store
  const std::size_t owned = run->owned();
  const std::vector<std::uint32_t> leaving =
      leaving_particles(particles, owned, flux.outflow, dt_f);
  double mass[2] = {0.0, 0.0}; // out, in
  for (const std::uint32_t i : leaving)
    mass[0] += particles.mass[i];
  for (const double m : entering.mass)
    mass[1] += m;
  // The force the scheme holds, in the store's order (at a restart the gas's own force is that
  // of its attach, not the one held).
  const dem::ExternalForce& f = run->scheme.external_force();
  std::array<std::vector<double>, 3> held = {f.x, f.y, f.z};
  const std::vector<std::uint32_t> kept = staying_particles(owned, leaving);
  const dem::Compaction compaction(owned, kept);
  Run::erase_removed(c, share, compaction, std::span(particles.id.data(), owned));
  for (auto& h : held)
    compaction.apply(h);
  run.reset();
  particles.permute(kept); // R ranks: the ghosts go too
  if (entering.size() > 0) {
    Run::admit(c, share, particles.id, entering.x, entering.y, entering.z);
    const auto& v = scene.inlet.velocity;
    for (std::size_t k = 0; k < entering.size(); ++k) {
      const std::size_t i =
          particles.add(entering.x[k], entering.y[k], entering.z[k], v[0], v[1], v[2],
                        entering.radius[k], scene.particles.density, entering.id[k]);
      // The mass as it left (recycled) or as drawn, exactly: the balance closes to round-off.
      particles.set_mass(i, entering.mass[k]);
    }
    for (auto& h : held)
      if (!h.empty())
        h.resize(particles.size(), 0.0); // the gas force comes with the next gas step
  }
  run.emplace(scene, particles, range, comm, timer, step_clock);
  if (owners)
    run->own_by(std::move(*owners), false);
  run->restore(c, share, &held);
  if (comm.size() > 1)
    comm.sum(std::span<double>(mass));
  loop.mass_out += mass[0], loop.mass_in += mass[1];
  loop.particles_out += static_cast<std::int64_t>(n_leaving);
  loop.particles_in += static_cast<std::int64_t>(n_entering);
  return static_cast<std::int64_t>(n_entering) - static_cast<std::int64_t>(n_leaving);
}

} // namespace cfddem::apps
