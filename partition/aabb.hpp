// Axis-aligned box [lo, hi) in 3-D: the geometric unit ORB cuts, SFC keys quantize and
// halo searches grow. Half-open so that a point on a shared face belongs to exactly one box.
#pragma once

#include <array>
#include <cstddef>

namespace cfddem::partition {

struct Aabb {
  std::array<double, 3> lo{0.0, 0.0, 0.0};
  std::array<double, 3> hi{0.0, 0.0, 0.0};

  [[nodiscard]] constexpr double extent(int axis) const { return hi[axis] - lo[axis]; }
  [[nodiscard]] constexpr std::array<double, 3> extents() const {
    return {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
  }
  // Midpoint as lo + extent/2 rather than (lo+hi)/2, which can overflow for huge coordinates.
  [[nodiscard]] constexpr std::array<double, 3> centre() const {
    return {lo[0] + 0.5 * (hi[0] - lo[0]), lo[1] + 0.5 * (hi[1] - lo[1]),
            lo[2] + 0.5 * (hi[2] - lo[2])};
  }
  [[nodiscard]] constexpr double volume() const {
    return (hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2]);
  }
  // Half-open [lo, hi) on every axis: boxes that tile a domain never both claim a point.
  [[nodiscard]] constexpr bool contains(const std::array<double, 3>& p) const {
    return lo[0] <= p[0] && p[0] < hi[0] && lo[1] <= p[1] && p[1] < hi[1] && lo[2] <= p[2] &&
           p[2] < hi[2];
  }
  // Closed [lo, hi]: the domain itself, whose hi face is clamped into the last box.
  [[nodiscard]] constexpr bool contains_closed(const std::array<double, 3>& p) const {
    return lo[0] <= p[0] && p[0] <= hi[0] && lo[1] <= p[1] && p[1] <= hi[1] && lo[2] <= p[2] &&
           p[2] <= hi[2];
  }
  // Closed overlap: boxes that only touch count, so halo searches stay conservative.
  [[nodiscard]] constexpr bool touches(const Aabb& o) const {
    return lo[0] <= o.hi[0] && o.lo[0] <= hi[0] && lo[1] <= o.hi[1] && o.lo[1] <= hi[1] &&
           lo[2] <= o.hi[2] && o.lo[2] <= hi[2];
  }
  // Ties go to the lowest axis so the choice is the same on every machine.
  [[nodiscard]] constexpr int longest_axis() const {
    int best = 0;
    for (int a = 1; a < 3; ++a) {
      if (extent(a) > extent(best)) {
        best = a;
      }
    }
    return best;
  }
  // Grown by `margin` on every side (the halo width of a ghost search).
  [[nodiscard]] constexpr Aabb grown(double margin) const {
    return {{lo[0] - margin, lo[1] - margin, lo[2] - margin},
            {hi[0] + margin, hi[1] + margin, hi[2] + margin}};
  }

  friend constexpr bool operator==(const Aabb&, const Aabb&) = default;
};

// A point of the closed domain belongs to `box` (a leaf of a tiling of `domain`): half-open
// inside the domain, closed on the faces the box shares with the domain's hi faces.
[[nodiscard]] constexpr bool owns_point(const Aabb& box, const Aabb& domain,
                                        const std::array<double, 3>& p) {
  for (int a = 0; a < 3; ++a) {
    const bool below_hi = p[a] < box.hi[a] || (p[a] == domain.hi[a] && box.hi[a] == domain.hi[a]);
    if (!(box.lo[a] <= p[a] && below_hi)) {
      return false;
    }
  }
  return true;
}

} // namespace cfddem::partition
