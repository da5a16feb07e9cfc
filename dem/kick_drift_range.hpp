// The leapfrog kick-drift over a contiguous range of particles, written so that it vectorizes:
// the arithmetic of kick_drift (contact_kernels.hpp) for every particle scheme: the explicit
// scheme's update pass, the orb scheme's batches and the islands scheme's global steps. Its
// loop is compiled for baseline x86-64 and, where the compiler can, for x86-64-v3 and -v4
// (kick_drift_range.cpp); simd_level() picks one at run time, with the same results from each.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

#include "core/simd_level.hpp"
#include "dem/particle_views.hpp"

namespace cfddem::dem {

namespace detail {
// The kick-drift over the columns `c` with the loop compiled for `level` (kick_drift_range.cpp;
// a level without a copy runs the baseline one).
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
// Without Moved the skin test is left out (a TravelBound covers it): `still` then keeps its sign
// bit while every new |v|^2 <= cap2 (the flags' `capped`; a NaN fails it).
template <bool External, bool Moved = true>
inline void leaf_kick_drift(std::int64_t k, std::int64_t K, const KickDriftColumns& c,
                            double h_before, double hk, const std::array<double, 3>& gravity,
                            double half_skin2, std::uint64_t& still, double cap2 = 0.0) {
  const double half = 0.5 * hk;
  KickDriftFlags flags;
  (Moved ? flags.still : flags.capped) = still;
  KickDriftStep step;
  step.h = hk, step.g = gravity, step.half_skin2 = half_skin2, step.cap2 = cap2;
  if (k == 0) {
    kick_drift_range<External, true, false, Moved>(c, step, flags);
  } else {
    step.s = 0.5 * h_before + half;
    kick_drift_range<External, false, false, Moved>(c, step, flags);
    if (k + 1 == K)
      for (double& hp : c.h_prev)
        hp = half;
  }
  still = Moved ? flags.still : flags.capped;
}

} // namespace cfddem::dem
