// Small views of the particle columns and step constants that the step kernels read, so that a
// kernel takes two or three structs instead of twenty pointers and knows nothing of the store it
// came from, of threads or of ranks. Spans of one range of particles, all of the same length.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>

#include "core/particle_store.hpp"
#include "dem/external_force.hpp"

namespace cfddem::dem {

// The columns one kick-drift reads and writes. The external force is empty without one, h_prev
// empty unless the kernel's first step reads it (the variable-step schemes).
struct KickDriftColumns {
  std::span<double> x, y, z, vx, vy, vz;
  std::span<const double> fx, fy, fz; // contact (and wall) force [N]
  std::span<const double> ex, ey, ez; // external force [N], or empty
  std::span<const double> inv_mass;
  std::span<const double> xr, yr, zr; // positions of the last list build: the skin test's origin
  std::span<double> h_prev;           // half of each particle's last step [s], or empty

  std::size_t size() const { return x.size(); }
  // Particles [b, e) of these columns (empty columns stay empty).
  KickDriftColumns range(std::size_t b, std::size_t e) const {
    const auto cut = [b, e](auto s) { return s.empty() ? s : s.subspan(b, e - b); };
    return {cut(x),        cut(y),  cut(z),  cut(vx), cut(vy),    cut(vz),
            cut(fx),       cut(fy), cut(fz), cut(ex), cut(ey),    cut(ez),
            cut(inv_mass), cut(xr), cut(yr), cut(zr), cut(h_prev)};
  }
};

// The columns of a whole store, with the reference positions of its list, its external force
// (none when null or inactive) and, for the variable-step schemes, h_prev. A kernel takes
// range(b, e) of it.
inline KickDriftColumns kick_drift_columns(ParticleStore& p, std::span<const double> xr,
                                           std::span<const double> yr, std::span<const double> zr,
                                           const ExternalForce* ext = nullptr,
                                           std::span<double> h_prev = {}) {
  const bool e = ext != nullptr && ext->active();
  KickDriftColumns c{p.x, p.y, p.z, p.vx,       p.vy, p.vz, p.fx, p.fy,  p.fz,
                     {},  {},  {},  p.inv_mass, xr,   yr,   zr,   h_prev};
  if (e)
    c.ex = ext->x, c.ey = ext->y, c.ez = ext->z;
  return c;
}

// The constants of one kick-drift: v += (F/m + g) s, x += v h.
struct KickDriftStep {
  double s = 0.0; // kick [s] (the whole step h for a constant step)
  double h = 0.0; // drift [s]
  std::array<double, 3> g{};
  double half_skin2 = 0.0; // (skin/2)^2: a particle farther from its reference asks for a list
  double vmax2 = std::numeric_limits<double>::infinity(); // (r_min/h)^2: faster could tunnel
  double cap2 = 0.0; // without the displacement test: the speed^2 no particle may pass
  // With CheckBox: the box every new position must lie in (walls; -inf/inf on periodic axes).
  std::array<double, 3> lo{-std::numeric_limits<double>::infinity(),
                           -std::numeric_limits<double>::infinity(),
                           -std::numeric_limits<double>::infinity()};
  std::array<double, 3> hi{std::numeric_limits<double>::infinity(),
                           std::numeric_limits<double>::infinity(),
                           std::numeric_limits<double>::infinity()};
};

// What a kick-drift found, as sign-bit ANDs (the sign bit stays set while all is well): integer
// reductions that vectorize with no floating-point reassociation (a max, a floating-point count
// or int64 counts of double compares all vectorize badly or not at all on baseline x86-64).
struct KickDriftFlags {
  std::uint64_t still = ~std::uint64_t{0}; // every particle within skin/2 of its reference
  std::uint64_t slow = ~std::uint64_t{0};  // every speed^2 <= vmax2, none NaN (when checked)
  std::uint64_t capped = ~std::uint64_t{0}; // every new speed^2 <= cap2 (without CheckMoved)
  std::uint64_t inside = ~std::uint64_t{0}; // every new position in [lo, hi] (with CheckBox)
  bool over_cap() const { return !(capped >> 63); }
  bool left_box() const { return !(inside >> 63); }
  bool moved() const { return !(still >> 63); }
  bool too_fast() const { return !(slow >> 63); }
};

// The tangential spring history per list entry (friction only; empty otherwise).
struct HistoryColumns {
  std::span<double> x, y, z;
};

} // namespace cfddem::dem
