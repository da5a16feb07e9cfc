// OrbLocalRows (the distributed orb scheme's rows): every owned particle's row and proximity flag
// equal the brute-force ones over all local particles, in both the half-stencil (three or more
// cells per axis) and the full-stencil (fewer) paths, with periodic and walled axes; and the
// proximity candidates the global mode keeps.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <utility>
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

// With Input::proximity_pairs the rows and flags stay the same, and the proximity candidates are
// every pair of local particles but two ghosts within prox (r_i + r_j) + skin, each once, none
// beyond (what OrbScheme::rank_keep_rows tests the proximity on while it keeps the rows).
void expect_proximity_candidates(const dem::DomainGeometry& g, const Local& p, std::size_t owned) {
  const double skin = 20e-6, prox = 1.5, dt_sp = 1e-4, r_max = 60e-6;
  const double cutoff = 2.0 * prox * r_max + skin;
  dem::OrbLocalRows plain, with;
  plain.build({g, p.x, p.y, p.z, p.r, p.id, p.speed, p.leaf, owned, cutoff, skin, prox, dt_sp,
               false});
  with.build({g, p.x, p.y, p.z, p.r, p.id, p.speed, p.leaf, owned, cutoff, skin, prox, dt_sp, false,
              true});
  EXPECT_TRUE(plain.proximity_candidates().empty());
  EXPECT_TRUE(std::ranges::equal(plain.nb(), with.nb()));
  EXPECT_TRUE(std::ranges::equal(plain.off(), with.off()));
  EXPECT_TRUE(std::ranges::equal(plain.near(), with.near()));
  std::vector<std::pair<std::uint32_t, std::uint32_t>> want, got;
  for (std::uint32_t i = 0; i < p.x.size(); ++i)
    for (std::uint32_t j = i + 1; j < p.x.size(); ++j) {
      if (i >= owned && j >= owned)
        continue;
      const double dx = g.image(p.x[j] - p.x[i], 0), dy = g.image(p.y[j] - p.y[i], 1),
                   dz = g.image(p.z[j] - p.z[i], 2);
      const double d = prox * (p.r[i] + p.r[j]) + skin;
      if (dx * dx + dy * dy + dz * dz < d * d)
        want.emplace_back(i, j);
    }
  const auto cand = with.proximity_candidates();
  ASSERT_EQ(cand.size() % 2, 0U);
  for (std::size_t q = 0; q < cand.size(); q += 2)
    got.emplace_back(std::min(cand[q], cand[q + 1]), std::max(cand[q], cand[q + 1]));
  std::sort(got.begin(), got.end());
  EXPECT_EQ(got, want);
  EXPECT_GT(want.size(), owned / 2); // not a trivial scene
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
  expect_proximity_candidates(g, p, 250);
}

TEST(OrbLocalRows, FullStencilRowsAndFlagsEqualBruteForceInABoxOfTwoCells) {
  const dem::DomainGeometry g = box(0.45e-3);
  const Local p = make_local(g, 40, 25, 2);
  bool half = true;
  expect_brute_force(g, p, 25, false, &half);
  EXPECT_FALSE(half);
  expect_proximity_candidates(g, p, 25);
}

} // namespace
} // namespace cfddem
