// Box geometry the kernels need: lengths, periodic axes and the minimum-image convention.
// Minimum image is valid because the run checks that every periodic length exceeds twice the
// neighbor cutoff (DomainGeometry::check_fits).
#pragma once

#include <array>

#include "core/scene.hpp"

namespace cfddem::dem {

struct DomainGeometry {
  std::array<double, 3> lo{}, hi{}, length{}, half{};
  std::array<bool, 3> periodic{};

  explicit DomainGeometry(const DomainSpec& d) : lo(d.lo), hi(d.hi), periodic(d.periodic) {
    for (int a = 0; a < 3; ++a) length[a] = hi[a] - lo[a], half[a] = 0.5 * length[a];
  }
  DomainGeometry() = default;

  // Nearest periodic image of a separation along axis a (|dx| < 1.5 L assumed: positions are
  // wrapped at every neighbor build and move less than the skin between builds).
  // Branch-free in the separation (the hot pair loop runs it three times per pair); the result
  // equals the branchy form bit for bit (dx - 0.0 == dx).
  double image(double dx, int a) const {
    if (!periodic[a]) return dx;
    const double shift = static_cast<double>(dx > half[a]) - static_cast<double>(dx < -half[a]);
    return dx - shift * length[a];
  }
  // Put a coordinate back into [lo, hi) on a periodic axis.
  double wrap(double x, int a) const {
    if (periodic[a]) {
      while (x >= hi[a]) x -= length[a];
      while (x < lo[a]) x += length[a];
    }
    return x;
  }
};

} // namespace cfddem::dem
