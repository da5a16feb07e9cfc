// The explicit update pass leaves out its displacement test while TravelBound proves that no
// particle can be farther than skin/2 from its reference position (dem/travel_bound.hpp). The
// `moved` count of every pass must equal the exact test's, including the passes where the bound
// runs out, where a particle passes the speed cap and where the particles cross skin/2.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <random>

#include "core/initial_conditions.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/external_force.hpp"
#include "dem/step_model.hpp"
#include "dem/step_report.hpp"
#include "dem/travel_bound.hpp"
#include "dem/verlet_list.hpp"
#include "dem/verlet_passes.hpp"
#include "dem_test_support.hpp"

namespace cfddem {
namespace {

std::int64_t exact_moved(const ParticleStore& p, const dem::VerletList& list, double skin) {
  std::int64_t moved = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    const double dx = p.x[i] - list.x_ref()[i], dy = p.y[i] - list.y_ref()[i],
                 dz = p.z[i] - list.z_ref()[i];
    moved += dx * dx + dy * dy + dz * dz > 0.25 * skin * skin ? 1 : 0;
  }
  return moved;
}

// A dilute gas (no contacts: 20 diameters apart) drifting at up to 0.05 m/s, one particle
// pushed by a steady force so that it passes every speed cap in turn, in a box with walls (the
// wall branch of the pass) and without. Passes of dt = 1e-6 s: skin/2 = 12.5 um is crossed after
// a few hundred passes. Every pass's moved count is the exact one, the test is left out in most
// passes before the crossing, and the first pass with a moved particle is the exact test's.
TEST(TravelBound, UpdatePassCountsExactlyWhatTheFullTestCounts) {
  for (const bool walls : {false, true}) {
    const std::string periodic = walls ? "false" : "true";
    const Scene scene = demtest::scene_from(
        demtest::kPairScene, {"particles.count=64", "particles.placement=\"lattice\"",
                              "domain.hi=[8e-3, 8e-3, 8e-3]",
                              "domain.periodic=[" + periodic + ", " + periodic + ", " + periodic +
                                  "]"});
    ParticleStore p = make_initial_particles(scene);
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> u(-0.05, 0.05);
    for (std::size_t i = 0; i < p.size(); ++i)
      p.vx[i] = u(rng), p.vy[i] = u(rng), p.vz[i] = u(rng);
    const dem::StepModel model = dem::make_step_model(scene, p);
    const dem::DomainGeometry geom(scene.domain);
    dem::VerletList list;
    list.build(p, geom, model.skin, dem::RowKind::half);
    std::vector<std::uint32_t> near_wall;
    dem::near_walls(p, p.size(), list, geom, model.skin, near_wall);
    dem::ExternalForce none;
    dem::TravelBound travel;
    travel.reset();
    const double dt = 1e-6;
    int skipped = 0, first_moved = -1, first_exact = -1;
    for (int k = 0; k < 2000 && first_moved < 0; ++k) {
      std::fill(p.fx.begin(), p.fx.end(), 0.0);
      std::fill(p.fy.begin(), p.fy.end(), 0.0);
      std::fill(p.fz.begin(), p.fz.end(), 0.0);
      p.fx[5] = 2.0 * p.mass[5] * 50.0; // 100 m/s^2 along x: passes the cap again and again
      skipped += travel.may_skip(geom, model.skin, dt) ? 1 : 0;
      dem::StepReport rep;
      if (walls)
        dem::update_pass<true, false, false>(p, p.size(), list, near_wall, none, geom, model, dt,
                                             rep, travel);
      else
        dem::update_pass<false, false, false>(p, p.size(), list, near_wall, none, geom, model,
                                              dt, rep, travel);
      const std::int64_t exact = exact_moved(p, list, model.skin);
      ASSERT_EQ(rep.moved > 0, exact > 0) << "pass " << k << " walls " << walls;
      if (exact > 0 && first_exact < 0)
        first_exact = k;
      if (rep.moved > 0 && first_moved < 0)
        first_moved = k;
    }
    EXPECT_GT(first_moved, 100) << "walls " << walls;
    EXPECT_EQ(first_moved, first_exact) << "walls " << walls;
    // The bound (twice the fastest speed) runs out near half the crossing time.
    EXPECT_GT(skipped, first_moved / 4) << "walls " << walls;
    std::printf("walls %d: first moved at pass %d, test left out in %d passes\n", walls ? 1 : 0,
                first_moved, skipped);
  }
}

// After a restore the bound is unknown: every pass tests exactly until the next build.
TEST(TravelBound, ForgottenBoundNeverSkips) {
  dem::TravelBound travel;
  const dem::DomainGeometry geom(demtest::scene_from(demtest::kPairScene).domain);
  EXPECT_FALSE(travel.may_skip(geom, 1e-5, 0.0));
  travel.reset();
  EXPECT_TRUE(travel.may_skip(geom, 1e-5, 1e-6));
  travel.forget();
  EXPECT_FALSE(travel.may_skip(geom, 1e-5, 0.0));
}

} // namespace
} // namespace cfddem
