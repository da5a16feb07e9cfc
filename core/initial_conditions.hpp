// Initial particle states: a CSV list, or a seeded generator (random non-overlapping or lattice
// placement, Gaussian velocities at a granular temperature with zero net momentum).
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include "core/particle_store.hpp"
#include "core/scene.hpp"

namespace cfddem {

// Build the initial particles of a scene; throws ConfigError on bad files or impossible packing,
// and on overlapping particles unless particles.allow_overlap.
ParticleStore make_initial_particles(const Scene& scene);

// One rank's share of make_initial_particles(scene): the particles whose id k has
// k % ranks == rank, in increasing id, bit for bit the values the whole set gets. Lattice
// placement and particle files with particles.allow_overlap build only the share (memory
// O(n / ranks); the thermal velocities' normal stream is drawn twice over all n without being
// stored); random placement and the overlap test of a file need every particle's position, so
// they build the whole set and keep the share. Throws as make_initial_particles does, on every
// rank alike.
ParticleStore make_initial_share(const Scene& scene, int rank, int ranks);

// Random sequential addition, what random placement (and an inlet) does, jams near 0.384
// (Torquato, Uche & Stillinger, PRE 74, 061308 (2006)) and slows to a crawl well before that:
// the most solids such a placement reaches.
constexpr double kRandomSequentialLimit = 0.38;

// Throw ConfigError (naming particles.count) when the generator's particles cannot fit: their
// solid fraction in the region above random close packing (0.64), more memory than the machine
// has, or, for random placement, above the jamming limit of random sequential addition (0.38,
// lattice placement suggested). Checked before any placement starts; no-op for a particle file.
void check_packing_feasible(const Scene& scene);

// Where long set-ups report progress (a line every output.progress_seconds while the random
// placement runs); none by default. apps/main.cpp sets it unless --quiet.
void set_setup_progress(std::function<void(const std::string&)> sink);

// Read `x,y,z,vx,vy,vz,diameter,density` (SI, header row required, columns in any order).
ParticleStore read_particle_csv(const std::string& path);
// The same, keeping only the data rows r (0-based, ids r) for which keep(r) holds; every row is
// still parsed and checked.
ParticleStore read_particle_csv_rows(const std::string& path,
                                     const std::function<bool(std::int64_t)>& keep);

// Throw ConfigError naming the first overlapping pair (ids, positions, overlap).
void check_no_overlap(const ParticleStore& p, const DomainSpec& domain);

// Set velocities to Gaussian with the given granular temperature T0 = (1/3)<|v-<v>|^2> exactly,
// zero net momentum, plus a mean velocity.
void assign_thermal_velocities(ParticleStore& p, double temperature,
                               const std::array<double, 3>& mean, std::uint64_t seed);

} // namespace cfddem
