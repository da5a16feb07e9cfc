// A bound on how far the particles can have moved since their neighbor list was built, which
// lets the explicit scheme's update pass leave out its displacement test (dem/verlet_passes.hpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "dem/domain_geometry.hpp"
#include "dem/particle_views.hpp"

namespace cfddem::dem {

// How far any particle can have moved since the list's build. A drift x += v dt moves no
// particle farther than dt x the largest new |v|, so while every new |v| stays within a cap the
// bound grows by dt x cap per update pass; while it stays below skin/2, less an allowance for
// the rounding of the drifts, no particle can be farther than skin/2 from its reference
// position, and the update pass need not read the reference positions (24 of its ~180 bytes per
// particle). A pass where some |v| passed the cap (and the first after a build) measures the
// displacements and speeds exactly instead (a separate pass, once), which restarts the bound at
// the largest displacement with the cap at twice the largest speed; from the pass that could
// cross the limit on, the exact test runs in the pass as before. Every step's `moved` count is
// the exact test's: the run is bitwise the same.
struct TravelBound {
  double travelled = std::numeric_limits<double>::infinity(); // infinite: unknown, exact tests
  double cap = 0.0;                                           // m/s; 0: not measured yet
  std::int64_t passes = 0;                                    // drifts since the measurement
  void reset() { travelled = 0.0, cap = 0.0, passes = 0; }
  void forget() { travelled = std::numeric_limits<double>::infinity(); }
  // skin/2 less the drifts' rounding: each x += v dt rounds by at most 2^-53 |x|, |x| no more
  // than the farthest wall (or periodic face) plus the skin; a relative 1e-9 covers the
  // rounding of the sums and of the squared test.
  static double limit(const DomainGeometry& g, double skin, std::int64_t passes) {
    double far = 0.0;
    for (int a = 0; a < 3; ++a)
      far = std::max({far, std::abs(g.lo[a]), std::abs(g.hi[a])});
    return 0.5 * skin * (1.0 - 1e-9) - static_cast<double>(passes + 1) * 0x1p-52 * (far + skin);
  }
  // Whether the next pass of length dt can leave out the displacement test.
  bool may_skip(const DomainGeometry& g, double skin, double dt) const {
    return travelled + dt * cap < limit(g, skin, passes);
  }
  // After a pass of length dt that left the test out, every new |v| within the cap.
  void advance(double dt) {
    travelled += dt * cap;
    ++passes;
  }
  // The bound after a pass of length dt, by the rule above: a pass that ran the exact test
  // (`exact`) leaves it unknown until the next build; one that left it out grows it while every
  // new |v| stayed within the cap (`within_cap`), and otherwise calls `measure` (the exact test
  // over the particles, restarting the bound: measure() below). Returns what `measure` counted
  // (the particles farther than skin/2), 0 where it was not called.
  template <class Measure>
  std::int64_t close_pass(bool exact, bool within_cap, double dt, Measure&& measure) {
    if (exact) {
      forget();
      return 0;
    }
    if (within_cap) {
      advance(dt);
      return 0;
    }
    return measure();
  }
  // After a pass that left the test out where some new |v| passed the cap: the exact test over
  // particles [0, n) of `c` (returns how many are farther than sqrt(half_skin2) from their
  // reference), the bound restarted at the largest displacement and the cap at twice the largest
  // speed (unknown again when either is not finite).
  std::int64_t measure(const KickDriftColumns& c, std::size_t n, double half_skin2) {
    std::int64_t moved = 0;
    double d2 = 0.0, v2 = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
      const double dx = c.x[i] - c.xr[i], dy = c.y[i] - c.yr[i], dz = c.z[i] - c.zr[i];
      const double di = dx * dx + dy * dy + dz * dz;
      moved += di > half_skin2 ? 1 : 0;
      d2 = std::max(d2, di);
      v2 = std::max(v2, c.vx[i] * c.vx[i] + c.vy[i] * c.vy[i] + c.vz[i] * c.vz[i]);
    }
    travelled = std::sqrt(d2) * (1.0 + 1e-15), cap = 2.0 * std::sqrt(v2), passes = 0;
    if (!std::isfinite(travelled + cap))
      forget();
    return moved;
  }
};

} // namespace cfddem::dem
