// The kick-drift loop compiled three times: for the build's target (baseline x86-64 in the
// portable build) and, with CFDDEM_SIMD_COPIES (GCC on x86-64), for x86-64-v3 (AVX2: four
// doubles per instruction) and x86-64-v4 (AVX-512: eight). With SSE2 one core spends its time
// issuing the loop's instructions (callgrind: about 34 per particle step in the explicit update)
// rather than waiting for its 13 columns read and 6 written; the wider copies take the explicit
// update pass of the 1e5 riser 1.4-1.6x faster on one thread, and of the walled 1e5 bed, whose
// wall test is in the loop (CheckBox), 1.9-2.0x (docs/performance.md). The copies differ only in
// vector width: every lane does the same operations in the same order, nothing is contracted
// into a fused multiply-add (-ffp-contract=off) and the flags are AND reductions, so all three
// give bitwise the same positions, velocities and flags.
#include "dem/kick_drift_range.hpp"

namespace cfddem::dem::detail {

namespace {

// The loop over the columns `c`, inlined into each copy below (so compiled for its target).
template <bool E, bool F, bool S, bool M, bool B>
[[gnu::always_inline]] inline void loop_over(const KickDriftColumns& c, const KickDriftStep& k,
                                             KickDriftFlags& flags) {
  kick_drift_loop<E, F, S, M, B>(c.size(), c.x.data(), c.y.data(), c.z.data(), c.vx.data(),
                                 c.vy.data(), c.vz.data(), c.fx.data(), c.fy.data(), c.fz.data(),
                                 c.ex.data(), c.ey.data(), c.ez.data(), c.inv_mass.data(),
                                 c.xr.data(), c.yr.data(), c.zr.data(), c.h_prev.data(), k, flags);
}

template <bool E, bool F, bool S, bool M, bool B>
void loop_baseline(const KickDriftColumns& c, const KickDriftStep& k, KickDriftFlags& flags) {
  loop_over<E, F, S, M, B>(c, k, flags);
}

#if defined(CFDDEM_SIMD_COPIES)
template <bool E, bool F, bool S, bool M, bool B>
[[gnu::target("arch=x86-64-v3")]] void loop_v3(const KickDriftColumns& c, const KickDriftStep& k,
                                               KickDriftFlags& flags) {
  loop_over<E, F, S, M, B>(c, k, flags);
}

template <bool E, bool F, bool S, bool M, bool B>
[[gnu::target("arch=x86-64-v4")]] void loop_v4(const KickDriftColumns& c, const KickDriftStep& k,
                                               KickDriftFlags& flags) {
  loop_over<E, F, S, M, B>(c, k, flags);
}
#endif

} // namespace

template <bool E, bool F, bool S, bool M, bool B>
void kick_drift_at([[maybe_unused]] SimdLevel level, const KickDriftColumns& c,
                   const KickDriftStep& k, KickDriftFlags& flags) {
#if defined(CFDDEM_SIMD_COPIES)
  if (level == SimdLevel::x86_64_v4)
    return loop_v4<E, F, S, M, B>(c, k, flags);
  if (level == SimdLevel::x86_64_v3)
    return loop_v3<E, F, S, M, B>(c, k, flags);
#endif
  loop_baseline<E, F, S, M, B>(c, k, flags);
}

// Every combination of External, First, CheckSpeed and CheckMoved without CheckBox; with it,
// the explicit update's (CheckSpeed, not First).
#define CFDDEM_KICK_DRIFT_AT(E, F, S, M, B)                                                        \
  template void kick_drift_at<E, F, S, M, B>(SimdLevel, const KickDriftColumns&,                   \
                                             const KickDriftStep&, KickDriftFlags&);
#define CFDDEM_KICK_DRIFT_AT_M(E, F, S)                                                            \
  CFDDEM_KICK_DRIFT_AT(E, F, S, false, false) CFDDEM_KICK_DRIFT_AT(E, F, S, true, false)
#define CFDDEM_KICK_DRIFT_AT_S(E, F)                                                               \
  CFDDEM_KICK_DRIFT_AT_M(E, F, false) CFDDEM_KICK_DRIFT_AT_M(E, F, true)
CFDDEM_KICK_DRIFT_AT_S(false, false)
CFDDEM_KICK_DRIFT_AT_S(false, true)
CFDDEM_KICK_DRIFT_AT_S(true, false)
CFDDEM_KICK_DRIFT_AT_S(true, true)
CFDDEM_KICK_DRIFT_AT(false, false, true, false, true)
CFDDEM_KICK_DRIFT_AT(false, false, true, true, true)
CFDDEM_KICK_DRIFT_AT(true, false, true, false, true)
CFDDEM_KICK_DRIFT_AT(true, false, true, true, true)
#undef CFDDEM_KICK_DRIFT_AT_S
#undef CFDDEM_KICK_DRIFT_AT_M
#undef CFDDEM_KICK_DRIFT_AT

} // namespace cfddem::dem::detail
