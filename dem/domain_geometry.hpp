// Box geometry the kernels need: lengths, periodic axes and the minimum-image convention.
// Minimum image is valid because the run checks that every periodic length exceeds twice the
// neighbor cutoff (DomainGeometry::check_fits).
#pragma once

#include <array>
#include <cmath>

#include "core/scene.hpp"

namespace cfddem::dem {

struct DomainGeometry {
  std::array<double, 3> lo{}, hi{}, length{}, half{};
  std::array<bool, 3> periodic{};
  // domain.shape = "cylinder": a curved wall of radius `radius` around the line through
  // (centre_u, centre_w) on the cross axes u, w (dem/cylinder_wall.hpp; docs/theory.md §11).
  // A bool known for the whole run: the kernels test it outside their particle loops.
  bool cylinder = false;
  int axis = 1, u = 0, w = 2;
  double centre_u = 0.0, centre_w = 0.0, radius = 0.0;

  explicit DomainGeometry(const DomainSpec& d) : lo(d.lo), hi(d.hi), periodic(d.periodic) {
    for (int a = 0; a < 3; ++a) length[a] = hi[a] - lo[a], half[a] = 0.5 * length[a];
    if (d.cylinder()) {
      cylinder = true;
      axis = d.cylinder_axis;
      u = d.cross_axes()[0], w = d.cross_axes()[1];
      centre_u = d.centre(u), centre_w = d.centre(w), radius = d.cylinder_radius;
    }
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
  // A coordinate not finite is left as it is (the caller's checks name it), and one many periods
  // out takes floor's image first: the loops alone would turn once per period (or forever at
  // inf, where x - length is x).
  double wrap(double x, int a) const {
    if (periodic[a] && std::isfinite(x)) {
      if (!(std::abs(x - lo[a]) < 4.0 * length[a]))
        x -= std::floor((x - lo[a]) / length[a]) * length[a];
      while (x >= hi[a]) x -= length[a];
      while (x < lo[a]) x += length[a];
    }
    return x;
  }
};

} // namespace cfddem::dem
