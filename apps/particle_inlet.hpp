// Particles entering a run through an inlet region (scene table [inlet], docs/theory.md §12): at
// each fluid-step boundary the inlet places the particles due, at random positions in its region
// where they fit (no overlap with any particle or wall), with the inlet velocity.
// - inlet.mass_rate: new particles of inlet.diameter (one size or a distribution) and
//   inlet.density (by default the scene's size distribution and density); the mass due
//   grows by mass_rate x dt_f per fluid step, and a particle enters once the mass due covers it.
// - inlet.recycle: the particles that left through an outflow face (apps/particle_outflow.hpp)
//   enter again, in the order of their ids, each with its own radius and mass and a new id.
// A particle that finds no place in 50 tries waits for the next fluid step, and so do those
// behind it. The random numbers come from the seed and a counter (the fluid step for positions,
// the particle's serial number for its diameter), so a run is bitwise reproducible for a given
// seed and rank count, and across restarts, with no generator state to keep. Rank 0 decides; on
// R ranks it is handed the positions of every rank's particles near the region first, and the
// particles enter its store (the scheme's restore hands them to their owners).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "core/scene.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/step_model.hpp"

namespace cfddem::apps {

// What the inlet carries from one fluid step to the next (rank 0's counts; a checkpoint holds it).
struct InletState {
  double owed = 0.0;         // mass_rate: the mass due and not yet placed [kg]
  std::int64_t drawn = 0;    // mass_rate: the new particles that have entered
  std::int64_t next_id = -1; // the id of the next particle to enter (-1: not yet known)
  // recycle: the particles that left and wait to enter, in id order.
  std::vector<double> queue_radius, queue_mass;
};

// The particles entering in one fluid step (on rank 0; empty elsewhere).
struct EnteringParticles {
  std::vector<double> x, y, z, radius, mass;
  std::vector<std::int64_t> id;
  std::size_t size() const { return x.size(); }
};

class ParticleInlet {
public:
  explicit ParticleInlet(const Scene& scene);
  bool on() const { return spec_.enabled(); }
  bool recycles() const { return spec_.recycle; }
  // The first call: the next id from the largest id over the ranks (collective).
  void start(InletState& st, const ParticleStore& p, std::size_t owned,
             const Communicator& comm) const;
  // recycle: this rank's particles `leaving` (indices into p) join rank 0's queue in id order
  // (collective).
  void queue(InletState& st, const ParticleStore& p, std::span<const std::uint32_t> leaving,
             const Communicator& comm) const;
  // The particles that enter in the fluid step `step` of length dt_f, placed among this rank's
  // `owned` particles of p and those of every other rank (collective; filled on rank 0). The
  // state moves on by what entered.
  EnteringParticles enter(InletState& st, const ParticleStore& p, std::size_t owned, double dt_f,
                          std::int64_t step, const Communicator& comm) const;
  // The largest radius that may enter (the step and cut-offs must allow it).
  double largest_radius() const;
  // Empty if a particle of radius r has a place for its centre in the region, inside the walls
  // and a cylinder's; else why not (a particle that never fits would hold back every particle
  // behind it for the rest of the run).
  std::string no_room(double r) const;
  double smallest_radius() const;
  // The new particles' mean diameter (inlet.diameter or its distribution's, else the
  // particles').
  double mean_diameter() const;

private:
  // Where the new particles' sizes come from: the inlet's own (inlet.diameter, one size or a
  // distribution) or the particles'; `fixed` is the one size when `dist` is fixed.
  struct Sizes {
    const DiameterDistribution& dist;
    double fixed;
  };
  Sizes sizes() const;
  // The region's box of centres for radius r, cut to the planar walls: -1, or the first axis
  // on which it is empty.
  int centres(double r, std::array<double, 3>& lo, std::array<double, 3>& hi) const;

  InletSpec spec_;
  ParticleSpec particles_;
  DomainSpec domain_;        // as the scene gives it (no_room's cylinder test)
  dem::DomainGeometry geom_; // the same, as the particle kernels read it (placement)
  // The k-th new particle's diameter (mass_rate).
  double diameter(std::int64_t k) const;
};

// New particles from an inlet (inlet.mass_rate) may be smaller or larger than those at t = 0, or
// there may be none yet: `range` (the sizes the particle step is chosen for) becomes the scene's
// size bounds, which hold both.
void widen_for_inlet(const Scene& scene, dem::ParticleRange& range);

} // namespace cfddem::apps
