// The kick-drift loop runs as one of up to three copies, compiled for baseline x86-64,
// x86-64-v3 and x86-64-v4 (dem/kick_drift_range.cpp), picked by the CPU. Every copy must give
// bitwise what the scalar kernel (kick_drift, dem/contact_kernels.hpp) gives particle by
// particle, for every variant of the loop and for lengths that leave a remainder at every
// vector width: a copy with a fused multiply-add or a reordered sum would differ in the last
// bits, and a wrong remainder loop would leave particles out.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <random>
#include <string>
#include <type_traits>
#include <vector>

#include "core/simd_level.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/kick_drift_range.hpp"
#include "dem/particle_views.hpp"

namespace cfddem::dem {
namespace {

struct Columns {
  std::vector<double> x, y, z, vx, vy, vz, fx, fy, fz, ex, ey, ez, im, xr, yr, zr, hp;
  explicit Columns(std::size_t n, std::uint32_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(-1.0, 1.0), pos(0.5, 2.0);
    for (auto* c : {&x, &y, &z, &vx, &vy, &vz, &fx, &fy, &fz, &ex, &ey, &ez})
      for (std::size_t i = 0; i < n; ++i)
        c->push_back(u(rng) * 3.1);
    for (std::size_t i = 0; i < n; ++i) {
      im.push_back(pos(rng));
      hp.push_back(0.5e-3 * pos(rng));
      // References near the positions: about half of the particles end up beyond skin/2.
      xr.push_back(x[i] + 0.02 * u(rng)), yr.push_back(y[i] + 0.02 * u(rng));
      zr.push_back(z[i] + 0.02 * u(rng));
    }
  }
  KickDriftColumns view(bool external, bool first) {
    KickDriftColumns c{x, y, z, vx, vy, vz, fx, fy, fz, {}, {}, {}, im, xr, yr, zr, {}};
    if (external)
      c.ex = ex, c.ey = ey, c.ez = ez;
    if (first)
      c.h_prev = hp;
    return c;
  }
};

struct Flags {
  bool moved = false, too_fast = false, over_cap = false, left_box = false;
};

// The scalar kernel, particle by particle, as kick_drift_range documents it.
template <bool External, bool First, bool CheckSpeed, bool CheckMoved, bool CheckBox>
Flags reference(Columns& c, const KickDriftStep& k) {
  Flags f;
  double* pos[3] = {c.x.data(), c.y.data(), c.z.data()};
  double* vel[3] = {c.vx.data(), c.vy.data(), c.vz.data()};
  const double* force[3] = {c.fx.data(), c.fy.data(), c.fz.data()};
  const double* ext[3] = {c.ex.data(), c.ey.data(), c.ez.data()};
  const double* ref[3] = {c.xr.data(), c.yr.data(), c.zr.data()};
  for (std::size_t i = 0; i < c.x.size(); ++i) {
    double s = k.s;
    if (First) {
      s = c.hp[i] + 0.5 * k.h;
      c.hp[i] = 0.5 * k.h;
    }
    for (int a = 0; a < 3; ++a) {
      const double fa = External ? force[a][i] + ext[a][i] : force[a][i];
      kick_drift(pos[a][i], vel[a][i], fa, c.im[i] * s, k.g[a] * s, k.h);
    }
    const double u2 = vel[0][i] * vel[0][i] + vel[1][i] * vel[1][i] + vel[2][i] * vel[2][i];
    const double dx = pos[0][i] - ref[0][i], dy = pos[1][i] - ref[1][i], dz = pos[2][i] - ref[2][i];
    const double d2 = dx * dx + dy * dy + dz * dz;
    if (CheckMoved)
      f.moved = f.moved || d2 > k.half_skin2;
    else
      f.over_cap = f.over_cap || !(u2 <= k.cap2);
    if (CheckSpeed)
      f.too_fast = f.too_fast || !(u2 <= k.vmax2);
    if (CheckBox)
      for (int a = 0; a < 3; ++a)
        f.left_box = f.left_box || !(pos[a][i] >= k.lo[a] && pos[a][i] <= k.hi[a]);
  }
  return f;
}

template <bool External, bool First, bool CheckSpeed, bool CheckMoved, bool CheckBox = false>
void expect_copy_matches(SimdLevel level, std::size_t n, std::uint32_t seed, double vmax2,
                         bool nan) {
  SCOPED_TRACE(::testing::Message()
               << simd_level_name(level) << " n=" << n << " vmax2=" << vmax2 << " NaN=" << nan
               << " External=" << External << " First=" << First << " CheckSpeed=" << CheckSpeed
               << " CheckMoved=" << CheckMoved << " CheckBox=" << CheckBox);
  KickDriftStep k;
  k.s = 1.3e-3, k.h = 1.1e-3, k.g = {0.3, -9.81, 0.1};
  k.half_skin2 = 0.25 * 0.02 * 0.02, k.vmax2 = vmax2, k.cap2 = 9.0;
  // Walls on x and z that some particles (at +-3.1) lie beyond; y periodic.
  k.lo[0] = k.lo[2] = -3.0, k.hi[0] = k.hi[2] = 3.0;
  Columns want(n, seed), got(n, seed);
  if (nan)
    got.vy[n - 2] = want.vy[n - 2] = std::numeric_limits<double>::quiet_NaN();
  const Flags f = reference<External, First, CheckSpeed, CheckMoved, CheckBox>(want, k);
  KickDriftFlags flags;
  detail::kick_drift_at<External, First, CheckSpeed, CheckMoved, CheckBox>(
      level, got.view(External, First), k, flags);
  auto same = [](const std::vector<double>& a, const std::vector<double>& b) {
    for (std::size_t i = 0; i < a.size(); ++i)
      if (std::bit_cast<std::uint64_t>(a[i]) != std::bit_cast<std::uint64_t>(b[i]))
        return ::testing::AssertionFailure() << "element " << i << ": " << a[i] << " vs " << b[i];
    return ::testing::AssertionSuccess();
  };
  EXPECT_TRUE(same(want.x, got.x));
  EXPECT_TRUE(same(want.y, got.y));
  EXPECT_TRUE(same(want.z, got.z));
  EXPECT_TRUE(same(want.vx, got.vx));
  EXPECT_TRUE(same(want.vy, got.vy));
  EXPECT_TRUE(same(want.vz, got.vz));
  EXPECT_TRUE(same(want.hp, got.hp));
  if (CheckMoved) {
    EXPECT_EQ(flags.moved(), f.moved);
  } else {
    EXPECT_EQ(flags.over_cap(), f.over_cap);
  }
  if (CheckSpeed) {
    EXPECT_EQ(flags.too_fast(), f.too_fast);
  }
  if (CheckBox) {
    EXPECT_EQ(flags.left_box(), f.left_box);
  }
}

template <bool External, bool First>
void expect_variants_match(SimdLevel level, std::size_t n, std::uint32_t seed, double vmax2,
                           bool nan) {
  expect_copy_matches<External, First, false, false>(level, n, seed, vmax2, nan);
  expect_copy_matches<External, First, false, true>(level, n, seed, vmax2, nan);
  expect_copy_matches<External, First, true, false>(level, n, seed, vmax2, nan);
  expect_copy_matches<External, First, true, true>(level, n, seed, vmax2, nan);
  if constexpr (!First) { // the explicit update's walls
    expect_copy_matches<External, First, true, false, true>(level, n, seed, vmax2, nan);
    expect_copy_matches<External, First, true, true, true>(level, n, seed, vmax2, nan);
  }
}

TEST(KickDriftRange, EveryInstructionSetCopyMatchesTheScalarKernelBitwise) {
  const SimdLevel cpu = cpu_simd_level();
  std::printf("this CPU runs the copies up to %s\n", std::string(simd_level_name(cpu)).c_str());
  for (int l = 0; l <= static_cast<int>(cpu); ++l) {
    const auto level = static_cast<SimdLevel>(l);
    // Lengths with a remainder at 2, 4 and 8 lanes. Speeds reach about 5.4 m/s: the bound 9
    // (m/s)^2 flags some, the infinite one none; a NaN velocity (with the infinite bound)
    // must fail the speed test and the box.
    for (const std::size_t n : {1, 3, 7, 13, 37, 1003}) {
      for (const double vmax2 : {std::numeric_limits<double>::infinity(), 9.0}) {
        const bool nan = n > 3 && vmax2 > 10.0;
        const auto seed = static_cast<std::uint32_t>(n) + (nan ? 100u : 0u);
        expect_variants_match<false, false>(level, n, seed + 11u, vmax2, nan);
        expect_variants_match<false, true>(level, n, seed + 12u, vmax2, nan);
        expect_variants_match<true, false>(level, n, seed + 13u, vmax2, nan);
        expect_variants_match<true, true>(level, n, seed + 14u, vmax2, nan);
      }
    }
  }
}

// One particle anywhere in the range (every lane and the remainder) that leaves the box on one
// axis, moves too fast, passes the cap or moves beyond skin/2 must set its flag on every copy;
// without it, none is set. A lane whose flag the reduction drops, or a remainder loop that
// skips the test, fails here.
TEST(KickDriftRange, EveryCopyFlagsASingleOffenderAnywhere) {
  const SimdLevel cpu = cpu_simd_level();
  for (int l = 0; l <= static_cast<int>(cpu); ++l) {
    const auto level = static_cast<SimdLevel>(l);
    for (const std::size_t n : {7, 13, 37}) {
      for (std::size_t at = 0; at < n; ++at) {
        for (int a = 0; a < 3; ++a) {
          SCOPED_TRACE(::testing::Message() << simd_level_name(level) << " n=" << n << " particle "
                                            << at << " axis " << a);
          KickDriftStep k;
          k.s = k.h = 1e-3;
          k.half_skin2 = 1.0, k.vmax2 = 100.0, k.cap2 = 100.0;
          k.lo = {-10.0, -10.0, -10.0}, k.hi = {10.0, 10.0, 10.0};
          auto run = [&](auto checks, auto edit) {
            Columns c(n, static_cast<std::uint32_t>(7 * n + at));
            c.xr = c.x, c.yr = c.y, c.zr = c.z; // nobody has moved yet
            edit(c);
            KickDriftFlags f;
            constexpr bool moved = decltype(checks)::value;
            detail::kick_drift_at<false, false, true, moved, true>(level, c.view(false, false), k,
                                                                   f);
            return f;
          };
          const std::true_type exact;
          const std::false_type capped;
          auto none = [](Columns&) {};
          const KickDriftFlags clean = run(exact, none);
          EXPECT_FALSE(clean.left_box() || clean.too_fast() || clean.moved());
          EXPECT_FALSE(run(capped, none).over_cap());
          auto coord = [a](Columns& c) -> std::vector<double>& {
            return a == 0 ? c.x : a == 1 ? c.y : c.z;
          };
          auto vel = [a](Columns& c) -> std::vector<double>& {
            return a == 0 ? c.vx : a == 1 ? c.vy : c.vz;
          };
          auto ref = [a](Columns& c) -> std::vector<double>& {
            return a == 0 ? c.xr : a == 1 ? c.yr : c.zr;
          };
          const double side = at % 2 ? -1.0 : 1.0;
          EXPECT_TRUE(run(exact, [&](Columns& c) { coord(c)[at] = 10.5 * side; }).left_box());
          EXPECT_TRUE(run(exact, [&](Columns& c) { vel(c)[at] = 30.0 * side; }).too_fast());
          EXPECT_TRUE(run(capped, [&](Columns& c) { vel(c)[at] = 30.0 * side; }).over_cap());
          EXPECT_TRUE(run(exact, [&](Columns& c) { ref(c)[at] += 2.0 * side; }).moved());
        }
      }
    }
  }
}

} // namespace
} // namespace cfddem::dem
