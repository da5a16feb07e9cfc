// What one pass of a particle step found: particles farther than skin/2 from where the neighbor
// list was built, and the first (lowest index) particle that failed a check. Both combine
// order-independently (sum, min), so a report does not depend on how TBB split the range.
#pragma once

#include <cstdint>
#include <limits>

namespace cfddem::dem {

inline constexpr std::uint32_t kNoParticle = std::numeric_limits<std::uint32_t>::max();
enum class StepFault { none = 0, nan, overlap, speed, left_domain };

struct StepReport {
  std::int64_t moved = 0; // particles farther than skin/2 from where the list was built
  std::uint32_t bad = kNoParticle;
  std::uint32_t partner = kNoParticle;
  StepFault fault = StepFault::none;
  double value = 0.0;
  // Tallied only where a pass is asked to (pair_pass<.., Tally = true>): the largest overlap
  // ratio delta / r_min of the contacts seen, and how many exceeded dem.max_overlap.
  double max_ratio = 0.0;
  std::int64_t overlaps = 0;
  void flag(std::uint32_t i, StepFault f, double v, std::uint32_t j = kNoParticle) {
    if (i < bad)
      bad = i, fault = f, value = v, partner = j;
  }
  void join(const StepReport& o) {
    moved += o.moved;
    max_ratio = o.max_ratio > max_ratio ? o.max_ratio : max_ratio;
    overlaps += o.overlaps;
    if (o.bad < bad)
      bad = o.bad, fault = o.fault, value = o.value, partner = o.partner;
  }
};

} // namespace cfddem::dem
