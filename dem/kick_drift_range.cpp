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

#include <bit>
#include <cstddef>
#include <cstdint>

#include "dem/contact_kernels.hpp"

namespace cfddem::dem::detail {

namespace {

// The loop of kick_drift_range over n particles. Its pointers are restrict parameters because
// GCC takes no-alias from parameters only (not from restrict locals), and without it the loop
// does not vectorize. Always inlined: each copy below takes it into a function compiled for its
// instruction set.
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

// The loop over the columns `c`, inlined into each copy at_simd_level compiles
// (core/simd_level.hpp).
template <bool E, bool F, bool S, bool M, bool B>
[[gnu::always_inline]] inline void loop_over(const KickDriftColumns& c, const KickDriftStep& k,
                                             KickDriftFlags& flags) {
  kick_drift_loop<E, F, S, M, B>(c.size(), c.x.data(), c.y.data(), c.z.data(), c.vx.data(),
                                 c.vy.data(), c.vz.data(), c.fx.data(), c.fy.data(), c.fz.data(),
                                 c.ex.data(), c.ey.data(), c.ez.data(), c.inv_mass.data(),
                                 c.xr.data(), c.yr.data(), c.zr.data(), c.h_prev.data(), k, flags);
}

} // namespace

template <bool E, bool F, bool S, bool M, bool B>
void kick_drift_at(SimdLevel level, const KickDriftColumns& c, const KickDriftStep& k,
                   KickDriftFlags& flags) {
  at_simd_level(level, [&]() CFDDEM_SIMD_BODY { loop_over<E, F, S, M, B>(c, k, flags); });
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
