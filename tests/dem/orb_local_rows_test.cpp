// OrbLocalRows (the distributed orb scheme's rows): every owned particle's row and proximity flag
// equal the brute-force ones over all local particles, in both the half-stencil (three or more
// cells per axis) and the full-stencil (fewer) paths, with periodic and walled axes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <vector>

#include "core/scene.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/orb_local_rows.hpp"

namespace cfddem {
namespace {

struct Local {
  std::vector<double> x, y, z, r, speed;
  std::vector<std::int64_t> id;
  std::vector<std::uint32_t> leaf; // owned only
};

// n local particles (the first `owned` owned), anywhere in the box (ghosts are unshifted copies),
// ids a random permutation so that id order is not index order.
Local make_local(const dem::DomainGeometry& g, std::size_t n, std::size_t owned, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Local p;
  for (std::size_t i = 0; i < n; ++i) {
    p.x.push_back(g.lo[0] + u(rng) * g.length[0]);
    p.y.push_back(g.lo[1] + u(rng) * g.length[1]);
    p.z.push_back(g.lo[2] + u(rng) * g.length[2]);
    p.r.push_back(40e-6 + 20e-6 * u(rng));
    p.speed.push_back(0.5 * u(rng));
  }
  p.id.resize(n);
  std::iota(p.id.begin(), p.id.end(), 0);
  std::shuffle(p.id.begin(), p.id.end(), rng);
  for (std::size_t i = 0; i < owned; ++i) p.leaf.push_back(static_cast<std::uint32_t>(rng() % 4));
  return p;
}

void expect_brute_force(const dem::DomainGeometry& g, const Local& p, std::size_t owned, bool ttc,
                        bool* half_stencil_used) {
  const double skin = 20e-6, prox = 1.5, dt_sp = 1e-4;
  const double r_max = 60e-6;
  const double cutoff = std::max(2.0 * r_max + skin, ttc ? 2.0 * r_max + 2.0 * 0.5 * dt_sp
                                                          : 2.0 * prox * r_max);
  dem::OrbLocalRows rows;
  rows.build({g, p.x, p.y, p.z, p.r, p.id, p.speed, p.leaf, owned, cutoff, skin, prox, dt_sp, ttc});
  // Cubic boxes with few particles: the cells are of the cutoff (the 8-per-particle cap is far).
  *half_stencil_used = std::floor(g.length[0] / cutoff) >= 3.0;
  std::size_t linked = 0, flagged = 0;
  for (std::size_t i = 0; i < owned; ++i) {
    std::vector<std::uint32_t> own, other;
    bool near = false;
    for (std::size_t j = 0; j < p.x.size(); ++j) {
      if (j == i) continue;
      const double dx = g.image(p.x[j] - p.x[i], 0), dy = g.image(p.y[j] - p.y[i], 1),
                   dz = g.image(p.z[j] - p.z[i], 2);
      const double r2 = dx * dx + dy * dy + dz * dz, rs = p.r[i] + p.r[j];
      if (r2 < (rs + skin) * (rs + skin))
        (j < owned && p.leaf[j] == p.leaf[i] ? own : other).push_back(static_cast<std::uint32_t>(j));
      const double d = ttc ? rs + (p.speed[i] + p.speed[j]) * dt_sp : prox * rs;
      near = near || r2 < d * d;
    }
    auto by_id = [&](std::uint32_t a, std::uint32_t b) { return p.id[a] < p.id[b]; };
    std::sort(own.begin(), own.end(), by_id);
    std::sort(other.begin(), other.end(), by_id);
    const auto nb = rows.nb();
    const std::vector<std::uint32_t> got_own(nb.begin() + rows.off()[i], nb.begin() + rows.mid()[i]);
    const std::vector<std::uint32_t> got_other(nb.begin() + rows.mid()[i],
                                               nb.begin() + rows.off()[i + 1]);
    EXPECT_EQ(got_own, own) << "particle " << i;
    EXPECT_EQ(got_other, other) << "particle " << i;
    EXPECT_EQ(rows.near()[i] != 0, near) << "particle " << i;
    linked += own.size() + other.size();
    flagged += near;
  }
  // The scene is not trivial: rows and flags of both kinds occur.
  EXPECT_GT(linked, owned / 4);
  EXPECT_GT(flagged, 0U);
  EXPECT_LT(flagged, owned);
  // Active rows: exactly the non-empty ones.
  std::vector<std::uint32_t> active;
  for (std::size_t i = 0; i < owned; ++i)
    if (rows.off()[i + 1] > rows.off()[i]) active.push_back(static_cast<std::uint32_t>(i));
  EXPECT_EQ(std::vector<std::uint32_t>(rows.active().begin(), rows.active().end()), active);
}

dem::DomainGeometry box(double side) {
  DomainSpec d;
  d.lo = {0.0, 0.0, 0.0};
  d.hi = {side, side, side};
  d.periodic = {true, true, false};
  return dem::DomainGeometry(d);
}

TEST(OrbLocalRows, HalfStencilRowsAndFlagsEqualBruteForce) {
  const dem::DomainGeometry g = box(1.2e-3);
  const Local p = make_local(g, 400, 250, 1);
  bool half = false;
  expect_brute_force(g, p, 250, false, &half);
  EXPECT_TRUE(half);
  expect_brute_force(g, p, 250, true, &half);
}

TEST(OrbLocalRows, FullStencilRowsAndFlagsEqualBruteForceInABoxOfTwoCells) {
  const dem::DomainGeometry g = box(0.45e-3);
  const Local p = make_local(g, 40, 25, 2);
  bool half = true;
  expect_brute_force(g, p, 25, false, &half);
  EXPECT_FALSE(half);
}

} // namespace
} // namespace cfddem
