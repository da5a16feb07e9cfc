// The leapfrog kick-drift over a contiguous range of particles, written with restrict pointers
// so that it vectorizes: the explicit scheme's arithmetic (contact_kernels.hpp kick_drift) for
// the orb scheme's batches and the islands scheme's global steps.
#pragma once

#include <array>

#include <bit>
#include <cstddef>
#include <cstdint>

#include "dem/contact_kernels.hpp"

namespace cfddem::dem {

// The constant-step kick-drift of particles [0, n) (every local step of a leaf but its first):
// the arithmetic of kick_drift (contact_kernels.hpp), in a function of restrict pointers so that
// it vectorizes; `still` keeps its sign bit while no particle is farther than skin/2 from its
// reference position (sign-bit AND: see integrate_range in explicit_scheme.cpp).
// With First, the kick of particle i spans its own h_prev + h/2 (hp[i] + half, the first step of
// a sub-iteration; hp[i] is set to half afterwards) instead of the common s.
template <bool External, bool First = false>
inline void kick_drift_range(double* __restrict x, double* __restrict y, double* __restrict z,
                             double* __restrict vx, double* __restrict vy, double* __restrict vz,
                             const double* __restrict fx, const double* __restrict fy,
                             const double* __restrict fz, const double* __restrict ex,
                             const double* __restrict ey, const double* __restrict ez,
                             const double* __restrict im, const double* __restrict xr,
                             const double* __restrict yr, const double* __restrict zr,
                             std::size_t n, double s, double gsx, double gsy, double gsz,
                             double h, double half_skin2, std::uint64_t& still_out,
                             double* __restrict hp = nullptr, double half = 0.0,
                             const double* g = nullptr) {
  std::uint64_t still = still_out;
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
    const double dx = px - xr[i], dy = py - yr[i], dz = pz - zr[i];
    still &= std::bit_cast<std::uint64_t>(dx * dx + dy * dy + dz * dz > half_skin2 ? 1.0 : -1.0);
  }
  still_out = still;
}

} // namespace cfddem::dem
