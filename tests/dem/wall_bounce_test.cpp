// A ball bouncing on a floor under gravity: the MFIX DEM verification problem (Garg et al. 2012):
// apex heights h_k = r + e^(2k) (h_0 - r).
#include <algorithm>
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "dem/verlet_list.hpp"
#include "dem/verlet_passes.hpp"
#include "dem_test_support.hpp"

using namespace cfddem;

TEST(WallBounce, ApexHeightsFollowRestitution) {
  const double e = 0.9, r = 50e-6, h0 = 2.0e-3;
  const Scene s = demtest::scene_from(R"(
gravity = [0.0, -9.81, 0.0]
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.0e-3, 3.0e-3, 1.0e-3]
periodic = [true, false, true]
[particles]
count = 0
diameter = 100.0e-6
density = 1000.0
[dem]
spring_constant = 10.0
restitution = 0.9
dt_factor = 0.005
[run]
end_time = 1.0
)");
  ParticleStore p;
  p.add(5e-4, h0, 5e-4, 0, 0, 0, r, 1000.0, 0);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  // Apex = the top of each flight; record y whenever vy changes sign from + to -.
  std::vector<double> apex;
  double prev_vy = 0;
  while (apex.size() < 3 && scheme.time() < 0.2) {
    scheme.step(false);
    if (prev_vy > 0 && p.vy[0] <= 0)
      apex.push_back(p.y[0]);
    prev_vy = p.vy[0];
  }
  ASSERT_EQ(apex.size(), 3u);
  for (int k = 1; k <= 3; ++k) {
    const double expected = r + std::pow(e, 2 * k) * (h0 - r);
    // O(dt) dashpot error on e (0.03% at tau_p/200) compounds over 2k powers; the apex sampling
    // error is g dt^2, negligible.
    EXPECT_NEAR(apex[k - 1] - r, expected - r, 0.004 * k * (expected - r)) << "bounce " << k;
  }
}

// The update pass tests walls only for the particles near_walls() lists: exactly those whose
// build position lies within radius + skin of a face of a non-periodic axis.
TEST(WallBounce, NearWallsListsExactlyThoseWithinRadiusPlusSkin) {
  const Scene s = demtest::scene_from(demtest::kPairScene, {"domain.periodic=[true,false,false]"});
  const double r = 50e-6, skin = 20e-6;
  ParticleStore p;
  // y (or z) distance to the nearest wall, in units of r + skin: in, in, out, out (x is periodic:
  // its "faces" do not count).
  const double ys[] = {0.5e-3, 1.0e-3 - 0.99 * (r + skin), 0.5e-3, 0.5e-3, 1.01 * (r + skin)};
  const double zs[] = {0.99 * (r + skin), 0.5e-3, 0.5e-3, 0.5e-3, 0.5e-3};
  const double xs[] = {0.5e-3, 0.3e-3, 0.0, 0.2e-3, 0.7e-3};
  for (int k = 0; k < 5; ++k)
    p.add(xs[k], ys[k], zs[k], 0, 0, 0, r, 1000.0, k);
  const dem::DomainGeometry g(s.domain);
  dem::VerletList list;
  list.build(p, g, skin, dem::RowKind::half);
  std::vector<std::uint32_t> near;
  dem::near_walls(p, p.size(), list, g, skin, near);
  std::vector<std::int64_t> ids;
  for (const std::uint32_t i : near)
    ids.push_back(p.id[i]);
  std::sort(ids.begin(), ids.end());
  EXPECT_EQ(ids, (std::vector<std::int64_t>{0, 1}));
  EXPECT_TRUE(std::is_sorted(near.begin(), near.end()));
}

// A checkpoint written on R ranks holds no list (its canonical state): restored on one rank in
// a box with walls, the next step builds the list and finds the walls as a fresh start does
// (once it crashed: the near-wall list was laid out from the missing list's build positions).
TEST(WallBounce, AStateWithoutAListRestartsInABoxWithWalls) {
  const Scene s = demtest::scene_from(demtest::kPairScene,
                                      {"domain.periodic=[false,false,false]", "gravity=[0,-9.81,0]",
                                       "particles.count=200", "particles.temperature=1e-3"});
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  dem::ExplicitScheme a(s, p, timer);
  a.start();
  for (int k = 0; k < 100; ++k)
    a.step();
  dem::ExplicitScheme::State st = a.save_state();
  st.offsets.clear(), st.neighbors.clear(), st.x_ref.clear(), st.y_ref.clear(), st.z_ref.clear();
  ParticleStore q = p;
  dem::ExplicitScheme b(s, q, timer);
  b.restore_state(st);
  // Without the list the next step rebuilds; the pair sums may then run in another order, so
  // the two agree to round-off, not bit for bit.
  std::int64_t bounced = 0;
  for (int k = 0; k < 2000; ++k) {
    a.step(), b.step();
    for (std::size_t i = 0; i < q.size(); ++i)
      bounced += q.y[i] < 2.0 * q.radius[i] && q.vy[i] > 0.0;
  }
  ASSERT_GT(bounced, 0) << "no particle met the floor: the case tests nothing";
  std::vector<double> ya(p.size()), yb(q.size());
  for (std::size_t i = 0; i < p.size(); ++i)
    ya[static_cast<std::size_t>(p.id[i])] = p.y[i], yb[static_cast<std::size_t>(q.id[i])] = q.y[i];
  for (std::size_t i = 0; i < ya.size(); ++i)
    EXPECT_NEAR(ya[i], yb[i], 1e-12) << "particle " << i;
}
