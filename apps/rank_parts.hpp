// What every particle-scheme adapter of the time loop shares (apps/scheme_runs.hpp): the
// particles of a recorded step, what a restart keeps of its checkpoint, and the parts that
// differ by rank count (RankParts), so that each adapter says only what its scheme differs in.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include "apps/checkpoint.hpp"
#include "apps/coupled_checkpoint.hpp"
#include "apps/derived_numbers.hpp"
#include "apps/rank_setup.hpp"
#include "core/communicator.hpp"
#include "core/initial_conditions.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/contact_history.hpp"
#include "dem/step_model.hpp"

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
  // store on one rank, which holds them all, else from the range derived() reduced (or, with an
  // inlet, the sizes it may add).
  dem::StepModel step_model(const Scene& scene, const ParticleStore& p,
                            const dem::ParticleRange& range) const {
    // One rank: range is set only for an inlet's sizes (widen_for_inlet).
    return ranks || range.count > 0 ? dem::make_step_model(scene, range)
                                    : dem::make_step_model(scene, p);
  }
  // The scheme on this rank's particles. One rank: the one-rank constructor, no communicator at
  // all (the islands scheme keeps its one-rank list and order only without one).
  // `step_clock`: the particle step and control interval the time loop fixed (run_loop.hpp).
  template <class S>
  S make(const Scene& scene, ParticleStore& p, const dem::ParticleRange& range,
         const Communicator& comm, PhaseTimer& timer, const dem::StepClock& step_clock) const {
    if (ranks)
      return S(scene, p, dem::make_step_model(scene, range, step_clock), &comm, timer);
    // One rank: the store's sizes, or an inlet's (widen_for_inlet), which the store may not hold
    // yet.
    return S(scene, p,
             range.count > 0 ? dem::make_step_model(scene, range, step_clock)
                             : dem::make_step_model(scene, p, step_clock),
             nullptr, timer);
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

} // namespace cfddem::apps
