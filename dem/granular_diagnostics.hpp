// Bulk observables of a particle set: granular temperature T = (1/3)<|v - <v>|^2>
// (docs/theory.md §3), kinetic energy, momentum, mean speed and mean position. Serial sums in
// index order, so the values are a deterministic function of the state.
#pragma once

#include <array>
#include <span>

#include "core/communicator.hpp"

namespace cfddem::dem {

struct GranularState {
  double granular_temperature = 0.0; // [m^2/s^2]
  double kinetic_energy = 0.0;       // translational [J]
  double mean_speed = 0.0;           // [m/s]
  std::array<double, 3> mean_position{};
  std::array<double, 3> momentum{};  // [kg m/s]
  std::array<double, 3> mean_velocity{};
  double mass = 0.0;                 // total [kg]
};

struct ParticleSpans {
  std::span<const double> x, y, z, vx, vy, vz, mass;
};

GranularState measure(const ParticleSpans& p);
// The same over the particles of every rank (collective; each rank passes its own): the sums are
// reduced, so the values are the serial ones up to the order of summation.
GranularState measure(const ParticleSpans& p, const Communicator& comm);

} // namespace cfddem::dem
