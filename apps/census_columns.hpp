// The contact census (dem/contact_census.hpp) as diagnostics columns: taken at every row from
// the synchronised particles, the same way for every scheme and rank count. On R ranks the
// particles are gathered to rank 0 (positions, radius, mass and id: output only, O(N) there),
// which takes the census in id order, so the columns equal the one-rank run's bit for bit for
// the same state; the values are then shared with every rank (each keeps the rows).
#pragma once

#include <span>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "core/scene.hpp"
#include "dem/contact_census.hpp"
#include "dem/domain_geometry.hpp"

namespace cfddem::apps {

// contacts, wall_contacts, overlap_mean, overlap_max, wall_overlap_mean, wall_overlap_max,
// collision_frequency, wall_collision_frequency, coordination_0 .. coordination_12 (the last:
// 12 or more). Overlaps relative to the diameter; frequencies per particle [1/s] (estimates for
// binary collisions, docs/schemes.md "The contact census").
const std::vector<std::string>& census_columns();

dem::CensusLaws census_laws(const Scene& scene);

// The columns' values for this rank's particles and every other rank's (collective).
std::vector<double> census_row(const Communicator& comm, const dem::CensusParticles& mine,
                               const dem::DomainGeometry& g, const dem::CensusLaws& laws);

} // namespace cfddem::apps
