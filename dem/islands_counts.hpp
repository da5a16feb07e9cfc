// What one sub-iteration of the islands scheme (dem/islands_scheme.hpp) counts. A rank fills its
// own share; on R ranks one sum over the ranks closes the sub-iteration (one reduction for all of
// them: the summed fields travel as one array of doubles, exact for counts below 2^53), on one
// rank the share is the total. Private to the scheme's sources.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>

#include "dem/islands_kernels.hpp"

namespace cfddem::dem::islands {

struct SubiterationCounts {
  // Summed over the ranks (summed(), set_summed() list them in this order).
  double owned = 0.0;            // R ranks: particles after migration (none may be lost)
  double particle_steps = 0.0;   // free particles' one step each, members' fine steps
  double pairs = 0.0;            // pair evaluations
  double overlaps = 0.0;         // overlaps beyond dem.max_overlap
  double bound_violations = 0.0; // members that moved farther than their speed bound
  double faults = 0.0;           // ranks that found NaN or a particle outside a wall
  double fine_members = 0.0;     // particles in an island (everyone in the dense mode)
  double span_members = 0.0;     // R ranks: members of islands spanning ranks
  double span_parts = 0.0;       // R ranks: spanning islands as each rank sees its part
  double outran = 0.0;           // R ranks, dense mode: particles past half the skin (roll back)
  double mass = 0.0;             // R ranks: owned mass (none may be lost)
  double lead_steps = 0.0;       // members' steps less their leads alone ("auto" prices them)
  // Not summed: this rank's largest overlap ratio, and its own share of the steps and pairs
  // (run.json's rank_counts).
  double max_ratio = 0.0;
  std::int64_t local_steps = 0, local_pairs = 0;

  static constexpr std::size_t kSummed = 12;
  std::array<double, kSummed> summed() const {
    return {owned,        particle_steps, pairs,  overlaps, bound_violations, faults, fine_members,
            span_members, span_parts,     outran, mass,     lead_steps};
  }
  void set_summed(const std::array<double, kSummed>& v) {
    owned = v[0], particle_steps = v[1], pairs = v[2], overlaps = v[3], bound_violations = v[4];
    faults = v[5], fine_members = v[6], span_members = v[7], span_parts = v[8], outran = v[9];
    mass = v[10], lead_steps = v[11];
  }

  // One island's (or the spanning members') fine steps.
  void add(const IslandResult& r) {
    particle_steps += static_cast<double>(r.steps);
    lead_steps += static_cast<double>(r.lead_steps);
    pairs += static_cast<double>(r.pairs);
    overlaps += static_cast<double>(r.violations);
    bound_violations += static_cast<double>(r.bound_violations);
    max_ratio = std::max(max_ratio, r.max_ratio);
  }
};

} // namespace cfddem::dem::islands
