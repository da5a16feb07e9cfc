// The contact census (dem/contact_census.hpp) as diagnostics columns: taken at every row from
// the synchronised particles, the same way for every scheme and rank count. On R ranks the
// particles are gathered to rank 0 (positions, radius and mass: output only, O(N) there), whose
// census is that of the same state on one rank bit for bit (it does not depend on the
// particles' order); the values are then shared with every rank (each keeps the rows).
// With output.contact_census = false (the default) the columns are not written and nothing is
// computed or sent.
#pragma once

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

class CensusColumns {
public:
  explicit CensusColumns(const Scene& scene);
  // The columns' values for this rank's particles and every other rank's (collective when the
  // census is on).
  std::vector<double> row(const Communicator& comm, const dem::CensusParticles& mine);
  // Wall time spent in row() so far (run.json census_seconds).
  double seconds() const { return seconds_; }
  bool enabled() const { return enabled_; }

private:
  bool enabled_;
  dem::DomainGeometry geometry_;
  dem::CensusLaws laws_;
  dem::CensusWorkspace work_;
  double seconds_ = 0.0;
};

} // namespace cfddem::apps
