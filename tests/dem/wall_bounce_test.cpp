// A ball bouncing on a floor under gravity: the MFIX DEM verification problem (Garg et al. 2012):
// apex heights h_k = r + e^(2k) (h_0 - r).
#include <cmath>

#include <gtest/gtest.h>

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
    if (prev_vy > 0 && p.vy[0] <= 0) apex.push_back(p.y[0]);
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
