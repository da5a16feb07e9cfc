// The leapfrog kick-drift over a contiguous range of particles, written so that it vectorizes:
// the arithmetic of kick_drift (contact_kernels.hpp) for every particle scheme: the explicit
// scheme's update pass, the orb scheme's batches and the islands scheme's global steps. Its
// loop is compiled for baseline x86-64 and, where the compiler can, for x86-64-v3 and -v4
// (kick_drift_range.cpp); simd_level() picks one at run time, with the same results from each.
#pragma once

#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>

#include "core/simd_level.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/particle_views.hpp"

namespace cfddem::dem {

namespace detail {
// The loop of kick_drift_range over n particles. Its pointers are restrict parameters because
// GCC takes no-alias from parameters only (not from restrict locals), and without it the loop
// does not vectorize; callers use kick_drift_range. Always inlined: kick_drift_range.cpp's
// copies for wider vectors take it into functions compiled for their instruction set.
template <bool External, bool First, bool CheckSpeed, bool CheckMoved, bool CheckBox>
[[gnu::always_inline]] inline void
kick_drift_loop(std::size_t n, double* __restrict x, double* __restrict y, double* __restrict z,
                double* __restrict vx, double* __restrict vy, double* __restrict vz,
                const double* __restrict fx, const double* __restrict fy,
                const double* __restrict fz, const double* __restrict ex,
                const double* __restrict ey, const double* __restrict ez,
                const double* __restrict im, const double* __restrict xr,
                const double* __restrict yr, const double* __restrict zr, double* __restrict hp,
                const KickDriftStep& k, KickDriftFlags& flags) {
  const double h = k.h, half = 0.5 * k.h, half_skin2 = k.half_skin2;
  [[maybe_unused]] const double vmax2 = k.vmax2;
  const std::array<double, 3> g = k.g;
  double s = k.s, gsx = g[0] * s, gsy = g[1] * s, gsz = g[2] * s;
  std::uint64_t still = flags.still, slow = flags.slow;
  std::uint64_t capped = flags.capped, inside = flags.inside;
  [[maybe_unused]] const double cap2 = k.cap2;
  [[maybe_unused]] const double lox = k.lo[0], loy = k.lo[1], loz = k.lo[2];
  [[maybe_unused]] const double hix = k.hi[0], hiy = k.hi[1], hiz = k.hi[2];
  for (std::size_t i = 0; i < n; ++i) {
    if constexpr (First) {
      s = hp[i] + half;
      gsx = g[0] * s, gsy = g[1] * s, gsz = g[2] * s;
      hp[i] = half;
    }
    const double ims = im[i] * s;
    double px = x[i], py = y[i], pz = z[i], ux = vx[i], uy = vy[i], uz = vz[i];
    if constexpr (External) {
      kick_drift(px, ux, fx[i] + ex[i], ims, gsx, h);
      kick_drift(py, uy, fy[i] + ey[i], ims, gsy, h);
      kick_drift(pz, uz, fz[i] + ez[i], ims, gsz, h);
    } else {
      kick_drift(px, ux, fx[i], ims, gsx, h);
      kick_drift(py, uy, fy[i], ims, gsy, h);
      kick_drift(pz, uz, fz[i], ims, gsz, h);
    }
    x[i] = px, y[i] = py, z[i] = pz, vx[i] = ux, vy[i] = uy, vz[i] = uz;
    const double u2 = ux * ux + uy * uy + uz * uz;
    if constexpr (CheckMoved) {
      const double dx = px - xr[i], dy = py - yr[i], dz = pz - zr[i];
      still &= std::bit_cast<std::uint64_t>(dx * dx + dy * dy + dz * dz > half_skin2 ? 1.0 : -1.0);
    } else {
      capped &= std::bit_cast<std::uint64_t>(u2 <= cap2 ? -1.0 : 1.0);
    }
    if constexpr (CheckSpeed)
      slow &= std::bit_cast<std::uint64_t>(u2 <= vmax2 ? -1.0 : 1.0);
    if constexpr (CheckBox) {
      // The six compares as sign-bit selects ANDed together (a NaN fails them): no branch, and
      // it vectorizes at every width (a chain of bool ANDs does not with SSE2).
      auto ok = [](bool c) { return std::bit_cast<std::uint64_t>(c ? -1.0 : 1.0); };
      inside &= ok(px >= lox) & ok(px <= hix) & ok(py >= loy) & ok(py <= hiy) & ok(pz >= loz) &
                ok(pz <= hiz);
    }
  }
  flags.still = still, flags.slow = slow, flags.capped = capped, flags.inside = inside;
}

// kick_drift_loop over the columns `c`, compiled for `level` (kick_drift_range.cpp; a level
// without a copy runs the baseline one).
template <bool External, bool First, bool CheckSpeed, bool CheckMoved, bool CheckBox = false>
void kick_drift_at(SimdLevel level, const KickDriftColumns& c, const KickDriftStep& k,
                   KickDriftFlags& flags);
} // namespace detail

// v += (F/m + g) s, x += v h over the columns `c` (KickDriftStep: s, h, g): the arithmetic of
// kick_drift, in a loop that vectorizes. flags.still keeps its sign bit while no particle is
// farther than skin/2 from its reference; with CheckSpeed, flags.slow while every |v|^2 <= vmax2
// (a NaN compares false: it fails too). Without CheckMoved the reference positions are not read
// (flags.still is left as it is); flags.capped keeps its sign bit while every new |v|^2 <= cap2.
// With First, the kick of particle i spans its own h_prev + h/2 (c.h_prev[i] + h/2, the first
// step of a sub-iteration; h_prev[i] is set to h/2 afterwards) instead of the common s.
// With CheckBox, flags.inside keeps its sign bit while every new position lies in
// [k.lo, k.hi] on every axis (a NaN fails; the explicit scheme's update with walls, whose
// particles may not leave the domain): compiled for CheckSpeed without First only.
template <bool External, bool First = false, bool CheckSpeed = false, bool CheckMoved = true,
          bool CheckBox = false>
inline void kick_drift_range(const KickDriftColumns& c, const KickDriftStep& k,
                             KickDriftFlags& flags) {
  detail::kick_drift_at<External, First, CheckSpeed, CheckMoved, CheckBox>(simd_level(), c, k,
                                                                           flags);
}

// Local step k of K of an orb leaf batch `c` (variable-step leapfrog): the first step kicks
// each particle over its own h_prev + h/2, later ones over (h_before + h)/2 (= h exactly for a
// constant step: the explicit scheme's update); the last one leaves h_prev = h/2. `still`
// keeps its sign bit while every particle stays within skin/2 of its reference (c.xr, yr, zr).
template <bool External>
inline void leaf_kick_drift(std::int64_t k, std::int64_t K, const KickDriftColumns& c,
                            double h_before, double hk, const std::array<double, 3>& gravity,
                            double half_skin2, std::uint64_t& still) {
  const double half = 0.5 * hk;
  KickDriftFlags flags;
  flags.still = still;
  KickDriftStep step;
  step.h = hk, step.g = gravity, step.half_skin2 = half_skin2;
  if (k == 0) {
    kick_drift_range<External, true>(c, step, flags);
  } else {
    step.s = 0.5 * h_before + half;
    kick_drift_range<External>(c, step, flags);
    if (k + 1 == K)
      for (double& hp : c.h_prev)
        hp = half;
  }
  still = flags.still;
}

} // namespace cfddem::dem
