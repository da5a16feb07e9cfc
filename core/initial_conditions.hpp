// Initial particle states: a CSV list, or a seeded generator (random non-overlapping or lattice
// placement, Gaussian velocities at a granular temperature with zero net momentum).
#pragma once

#include <string>

#include "core/particle_store.hpp"
#include "core/scene.hpp"

namespace cfddem {

// Build the initial particles of a scene; throws ConfigError on bad files or impossible packing,
// and on overlapping particles unless particles.allow_overlap.
ParticleStore make_initial_particles(const Scene& scene);

// Read `x,y,z,vx,vy,vz,diameter,density` (SI, header row required, columns in any order).
ParticleStore read_particle_csv(const std::string& path);

// Throw ConfigError naming the first overlapping pair (ids, positions, overlap).
void check_no_overlap(const ParticleStore& p, const DomainSpec& domain);

// Set velocities to Gaussian with the given granular temperature T0 = (1/3)<|v-<v>|^2> exactly,
// zero net momentum, plus a mean velocity.
void assign_thermal_velocities(ParticleStore& p, double temperature,
                               const std::array<double, 3>& mean, std::uint64_t seed);

} // namespace cfddem
