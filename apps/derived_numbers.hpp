// Numbers a user checks before a run (`cfddem check`) and finds again in run.json: particle mass,
// tau_p, dt, solid fraction, the Enskog collision frequency and Haff's cooling time
// (docs/theory.md §1, §3).
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "core/communicator.hpp"
#include "core/diameter_distribution.hpp"
#include "core/particle_store.hpp"
#include "core/scene.hpp"
#include "dem/explicit_scheme.hpp"

namespace cfddem::apps {

// A run counts at most this many steps of any kind: its step counters are 64-bit integers, and a
// count past 2^63 came out as INT64_MIN, so the run took 0 steps and said "done". 2^62 leaves
// room for the counters' sums.
inline constexpr double kMaxCountableSteps = static_cast<double>(std::int64_t{1} << 62);

struct DerivedNumbers {
  std::size_t particles = 0;
  double mean_diameter = 0, min_mass = 0, tau_p = 0, dt = 0, solid_fraction = 0;
  double solid_density = 0; // the particles' mass over their volume [kg/m^3]
  std::string shape;        // domain.shape = "cylinder": its axis, radius and cross-section
  double g0 = 0;            // Carnahan-Starling contact value
  double granular_temperature = 0;
  double collision_frequency = 0; // per particle, Enskog [1/s]
  double haff_time = 0;           // t_H [s] (no gas)
  double contact_duration = 0;    // pi/omega_d for two of the lightest particles [s]
  // With a gas: the shortest drag time m_i / beta_i of a particle alone in still gas (the drag
  // law at eps_g = 1 and no slip: Stokes's 3 pi mu d), infinite without a gas or a drag. Denser
  // suspensions and faster slips only shorten it: a fixed fluid.dt of twice it or more is
  // refused (the held drag is unstable there; apps/coupled_step.cpp, refuse_unstable_drag).
  double still_gas_drag_time = 0;
  // The closing speed of a head-on impact that the spring stops within dem.max_overlap, for two
  // of the largest particles (at the start or from an inlet) and for one on a wall:
  // max_overlap r sqrt(k / m_eff) (1/2 m_eff v^2 = 1/2 k delta^2; the dashpot only lowers the
  // overlap). A faster impact stops the run (exit 3); infinite without particles.
  double impact_speed_held = std::numeric_limits<double>::infinity();
  double impact_speed_held_wall = std::numeric_limits<double>::infinity();
  double dt_per_contact = 0;      // contact duration / dt
  long long steps = 0;            // steps to run.end_time
  // The Verlet list's neighbour cutoff plus skin (the largest diameter and the skin) and the
  // neighbours it would list per particle at the domain's mean number density (at most every
  // other particle): what a huge dem.neighbor_skin costs in every pair pass.
  double list_cutoff = 0, listed_neighbors = 0;
  // d10/d50/d90 by volume and the Sauter mean (core/diameter_distribution.hpp), listed when the
  // sizes differ; from the whole set only (the one-rank derive(), as `cfddem check` calls it).
  SizeStatistics sizes;
  std::vector<std::pair<std::string, std::string>> table() const;
};

DerivedNumbers derive(const Scene& scene, const ParticleStore& particles);
// The same over the particles of every rank (collective; the same numbers on every rank, sums
// in another order than one rank's). Also returns the reduced range for make_step_model.
DerivedNumbers derive(const Scene& scene, const ParticleStore& particles, const Communicator& comm,
                      dem::ParticleRange* range = nullptr);

} // namespace cfddem::apps
