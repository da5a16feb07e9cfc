// The dense mode's near rows (dem/near_rows.hpp): the contact forces over them are bit for bit
// those over the wide rows they are filtered from, while particles move and the near rows are
// taken again when some particle has moved about half their skin; with friction the springs end
// the same too. And the expiry test fires at 0.45 skin, not before.
#include <array>
#include <cstdint>
#include <cstring>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "dem/islands_kernels.hpp"
#include "dem/near_rows.hpp"

namespace cfddem::dem::islands {
namespace {

constexpr double kLength = 1.2e-3; // periodic cube
constexpr double kWideSkin = 2e-4;
constexpr double kNearSkin = 2.5e-5;

struct Gas {
  std::size_t n = 0;
  std::vector<double> x, y, z, vx, vy, vz, fx, fy, fz, hp, im, radius, mass, wx, wy, wz, tx, ty,
      tz, ii;
  std::vector<std::int64_t> id;
  std::vector<std::uint32_t> off, nb, label;
  DomainGeometry geom;
  StepModel model;

  Columns columns() {
    return {x,  y,  z,  vx,     vy,   vz, fx, fy, fz, hp, im, radius, mass, id, {}, {}, {},
            wx, wy, wz, tx, ty, tz, ii};
  }
};

// A jittered lattice of particles of radii 45-55 um at 100 um spacing (many touch), random
// velocities and spins; wide rows: every pair within r_i + r_j + kWideSkin (minimum image), both
// directions, in index order.
Gas make_gas(unsigned seed) {
  Gas g;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const int side = 12;
  const double a = kLength / side;
  for (int k = 0; k < side; ++k)
    for (int j = 0; j < side; ++j)
      for (int i = 0; i < side; ++i) {
        g.x.push_back((i + 0.5) * a + 0.08 * a * u(rng));
        g.y.push_back((j + 0.5) * a + 0.08 * a * u(rng));
        g.z.push_back((k + 0.5) * a + 0.08 * a * u(rng));
        g.radius.push_back(5e-5 + 5e-6 * u(rng));
      }
  g.n = g.x.size();
  for (std::size_t i = 0; i < g.n; ++i) {
    const double m = 2500.0 * 4.18879 * g.radius[i] * g.radius[i] * g.radius[i];
    g.mass.push_back(m);
    g.im.push_back(1.0 / m);
    g.ii.push_back(1.0 / (0.4 * m * g.radius[i] * g.radius[i]));
    g.id.push_back(static_cast<std::int64_t>(i));
    g.vx.push_back(0.3 * u(rng)), g.vy.push_back(0.3 * u(rng)), g.vz.push_back(0.3 * u(rng));
    g.wx.push_back(100.0 * u(rng)), g.wy.push_back(100.0 * u(rng)), g.wz.push_back(100.0 * u(rng));
  }
  for (auto* v : {&g.fx, &g.fy, &g.fz, &g.hp, &g.tx, &g.ty, &g.tz})
    v->assign(g.n, 0.0);
  g.label.assign(g.n, 0);
  g.geom.lo = {0.0, 0.0, 0.0};
  g.geom.hi = {kLength, kLength, kLength};
  for (int d = 0; d < 3; ++d) {
    g.geom.length[d] = kLength, g.geom.half[d] = 0.5 * kLength, g.geom.periodic[d] = true;
  }
  g.model.pair = {1e3, 0.05};
  g.model.pair_t = {800.0, 0.02, 0.3};
  g.model.max_overlap = 0.3;
  g.off.push_back(0);
  for (std::size_t i = 0; i < g.n; ++i) {
    for (std::size_t j = 0; j < g.n; ++j) {
      const double dx = g.geom.image(g.x[j] - g.x[i], 0), dy = g.geom.image(g.y[j] - g.y[i], 1),
                   dz = g.geom.image(g.z[j] - g.z[i], 2);
      const double reach = g.radius[i] + g.radius[j] + kWideSkin;
      if (j != i && dx * dx + dy * dy + dz * dz < reach * reach)
        g.nb.push_back(static_cast<std::uint32_t>(j));
    }
    g.off.push_back(static_cast<std::uint32_t>(g.nb.size()));
  }
  return g;
}

template <bool Friction>
std::int64_t forces(Gas& g, const Rows& rows, std::span<double> hx, std::span<double> hy,
                    std::span<double> hz) {
  const ContactView view{g.columns(), rows, g.label, &g.geom, &g.model, hx, hy, hz};
  double max_ratio = 0.0;
  std::int64_t violations = 0;
  return contact_forces<false, false, false, true, Friction>(
      view, nullptr, 0, static_cast<std::uint32_t>(g.n), 0, max_ratio, violations, 1e-7);
}

template <bool Friction> void check_same_forces() {
  Gas g = make_gas(7);
  const Rows wide{g.off, g.nb, {}};
  const std::size_t entries = g.nb.size();
  std::vector<double> hw[3], hn[3];
  for (int a = 0; a < 3; ++a)
    hw[a].assign(Friction ? entries : 0, 0.0), hn[a].assign(Friction ? entries : 0, 0.0);
  NearRows near;
  filter_near_rows(wide, g.n, g.columns(), g.geom, kNearSkin, hn[0], hn[1], hn[2], near);
  EXPECT_LT(near.nb.size() * 4, entries) << "the near rows are much shorter";
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::int64_t touching = 0;
  for (int step = 0; step < 40; ++step) {
    if (near_rows_expired(near, g.columns())) {
      if (Friction)
        return_near_springs(near, hn[0], hn[1], hn[2]);
      filter_near_rows(wide, g.n, g.columns(), g.geom, kNearSkin, hn[0], hn[1], hn[2], near);
    }
    const std::int64_t pw = forces<Friction>(g, wide, hw[0], hw[1], hw[2]);
    const std::vector<double> fw[3] = {g.fx, g.fy, g.fz};
    const std::vector<double> tw[3] = {g.tx, g.ty, g.tz};
    const std::int64_t pn = forces<Friction>(g, near.rows(), near.hx, near.hy, near.hz);
    EXPECT_LE(pn, pw);
    for (int a = 0; a < 3; ++a) {
      const std::vector<double>& f = a == 0 ? g.fx : a == 1 ? g.fy : g.fz;
      ASSERT_EQ(std::memcmp(f.data(), fw[a].data(), g.n * sizeof(double)), 0)
          << "step " << step << " axis " << a;
      if (Friction) {
        const std::vector<double>& t = a == 0 ? g.tx : a == 1 ? g.ty : g.tz;
        ASSERT_EQ(std::memcmp(t.data(), tw[a].data(), g.n * sizeof(double)), 0)
            << "torque, step " << step;
      }
    }
    for (std::size_t i = 0; i < g.n; ++i)
      touching += g.fx[i] != 0.0;
    // Move every particle by up to 0.2 near skins per step (some pass 0.45 within 3 steps).
    for (std::size_t i = 0; i < g.n; ++i) {
      g.x[i] += 0.2 * kNearSkin / 1.8 * u(rng);
      g.y[i] += 0.2 * kNearSkin / 1.8 * u(rng);
      g.z[i] += 0.2 * kNearSkin / 1.8 * u(rng);
    }
  }
  EXPECT_GT(near.filters, 5) << "the near rows were taken again as the particles moved";
  EXPECT_GT(touching, 1000) << "contacts acted";
  if (Friction) {
    return_near_springs(near, hn[0], hn[1], hn[2]);
    for (int a = 0; a < 3; ++a)
      EXPECT_EQ(std::memcmp(hn[a].data(), hw[a].data(), entries * sizeof(double)), 0)
          << "springs, axis " << a;
  }
}

TEST(NearRows, ForcesEqualTheWideRowsBitwise) { check_same_forces<false>(); }

TEST(NearRows, FrictionForcesTorquesAndSpringsEqualTheWideRowsBitwise) {
  check_same_forces<true>();
}

TEST(NearRows, ExpireWhenAParticleMovesPastFortyFivePercentOfTheSkin) {
  Gas g = make_gas(3);
  NearRows near;
  std::vector<double> none;
  filter_near_rows(Rows{g.off, g.nb, {}}, g.n, g.columns(), g.geom, kNearSkin, none, none, none,
                   near);
  EXPECT_FALSE(near_rows_expired(near, g.columns()));
  g.y[17] += 0.44 * kNearSkin;
  EXPECT_FALSE(near_rows_expired(near, g.columns()));
  g.y[17] += 0.02 * kNearSkin;
  EXPECT_TRUE(near_rows_expired(near, g.columns()));
}

} // namespace
} // namespace cfddem::dem::islands
