// The kick-drift loop compiled three times: for the build's target (baseline x86-64 in the
// portable build) and, with CFDDEM_SIMD_COPIES (GCC on x86-64), for x86-64-v3 (AVX2: four
// doubles per instruction) and x86-64-v4 (AVX-512: eight). The loop streams 13 columns and
// writes 6, about 10 instructions per particle with SSE2, and one core runs it faster than its
// caches deliver only with the wider vectors: on the riser at 1e5 particles the explicit
// scheme's update pass takes 1.3-1.5x less time with AVX-512 (docs/performance.md). The copies
// differ only in vector width: every lane does the same operations in the same order, nothing
// is contracted into a fused multiply-add (-ffp-contract=off) and the flags are AND
// reductions, so all three give bitwise the same positions, velocities and flags.
#include "dem/kick_drift_range.hpp"

namespace cfddem::dem::detail {

namespace {

// The loop over the columns `c`, inlined into each copy below (so compiled for its target).
template <bool E, bool F, bool S, bool M>
[[gnu::always_inline]] inline void loop_over(const KickDriftColumns& c, const KickDriftStep& k,
                                             KickDriftFlags& flags) {
  kick_drift_loop<E, F, S, M>(c.size(), c.x.data(), c.y.data(), c.z.data(), c.vx.data(),
                              c.vy.data(), c.vz.data(), c.fx.data(), c.fy.data(), c.fz.data(),
                              c.ex.data(), c.ey.data(), c.ez.data(), c.inv_mass.data(), c.xr.data(),
                              c.yr.data(), c.zr.data(), c.h_prev.data(), k, flags);
}

template <bool E, bool F, bool S, bool M>
void loop_baseline(const KickDriftColumns& c, const KickDriftStep& k, KickDriftFlags& flags) {
  loop_over<E, F, S, M>(c, k, flags);
}

#if defined(CFDDEM_SIMD_COPIES)
template <bool E, bool F, bool S, bool M>
[[gnu::target("arch=x86-64-v3")]] void loop_v3(const KickDriftColumns& c, const KickDriftStep& k,
                                               KickDriftFlags& flags) {
  loop_over<E, F, S, M>(c, k, flags);
}

template <bool E, bool F, bool S, bool M>
[[gnu::target("arch=x86-64-v4")]] void loop_v4(const KickDriftColumns& c, const KickDriftStep& k,
                                               KickDriftFlags& flags) {
  loop_over<E, F, S, M>(c, k, flags);
}
#endif

} // namespace

template <bool E, bool F, bool S, bool M>
void kick_drift_at([[maybe_unused]] SimdLevel level, const KickDriftColumns& c,
                   const KickDriftStep& k, KickDriftFlags& flags) {
#if defined(CFDDEM_SIMD_COPIES)
  if (level == SimdLevel::x86_64_v4)
    return loop_v4<E, F, S, M>(c, k, flags);
  if (level == SimdLevel::x86_64_v3)
    return loop_v3<E, F, S, M>(c, k, flags);
#endif
  loop_baseline<E, F, S, M>(c, k, flags);
}

// Every combination of External, First, CheckSpeed and CheckMoved.
#define CFDDEM_KICK_DRIFT_AT(E, F, S, M)                                                           \
  template void kick_drift_at<E, F, S, M>(SimdLevel, const KickDriftColumns&,                      \
                                          const KickDriftStep&, KickDriftFlags&);
#define CFDDEM_KICK_DRIFT_AT_M(E, F, S)                                                            \
  CFDDEM_KICK_DRIFT_AT(E, F, S, false) CFDDEM_KICK_DRIFT_AT(E, F, S, true)
#define CFDDEM_KICK_DRIFT_AT_S(E, F)                                                               \
  CFDDEM_KICK_DRIFT_AT_M(E, F, false) CFDDEM_KICK_DRIFT_AT_M(E, F, true)
CFDDEM_KICK_DRIFT_AT_S(false, false)
CFDDEM_KICK_DRIFT_AT_S(false, true)
CFDDEM_KICK_DRIFT_AT_S(true, false)
CFDDEM_KICK_DRIFT_AT_S(true, true)
#undef CFDDEM_KICK_DRIFT_AT_S
#undef CFDDEM_KICK_DRIFT_AT_M
#undef CFDDEM_KICK_DRIFT_AT

} // namespace cfddem::dem::detail
