// Results must not depend on the thread count: bitwise identical states for 1 and 2 threads.
#include <cstdint>
#include <string>
#include <type_traits>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"
#include "dem_test_support.hpp"

using namespace cfddem;

namespace {

// A gas large enough that both passes run in parallel (above the serial cut-offs).
ParticleStore run_with_threads(int threads, const std::vector<std::string>& extra) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
  auto cfg = SceneConfig::from_string(R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [2.0e-3, 2.0e-3, 2.0e-3]
[particles]
count = 12000
diameter = 50.0e-6
density = 1000.0
temperature = 0.05
seed = 3
[dem]
spring_constant = 10.0
restitution = 0.7
[run]
end_time = 1.0
)", "determinism");
  for (const auto& o : extra) cfg.apply_override(o);
  const Scene s = read_scene(cfg, "det");
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  for (int k = 0; k < 400; ++k) scheme.step(k % 50 == 0);
  return p;
}

using demtest::same_bits;

void expect_identical(const std::vector<std::string>& extra) {
  const ParticleStore a = run_with_threads(1, extra);
  const ParticleStore b = run_with_threads(2, extra);
  EXPECT_EQ(a.id, b.id);
  EXPECT_TRUE(same_bits(a.x, b.x) && same_bits(a.y, b.y) && same_bits(a.z, b.z));
  EXPECT_TRUE(same_bits(a.vx, b.vx) && same_bits(a.vy, b.vy) && same_bits(a.vz, b.vz));
  EXPECT_TRUE(same_bits(a.wx, b.wx) && same_bits(a.wz, b.wz));
}

} // namespace

TEST(ThreadCount, FrictionlessPeriodicBitwiseIdentical) { expect_identical({}); }

TEST(ThreadCount, FrictionAndWallsBitwiseIdentical) {
  expect_identical({"dem.friction=0.3", "domain.periodic=[false, false, true]",
                    "gravity=[0.0, -9.81, 0.0]"});
}

namespace {

// 40,000 particles (solid fraction 0.24) in a slab six diameters thick between two walls on x
// (and walls on y, gravity along -y), so that the per-particle passes split into ranges on two
// threads: the contact scatter and its clear (dem/contact_scatter.hpp, from 2 x 16384 particles),
// the walls of orb's and islands' global steps over the same ranges, and the kick-drifts' static
// blocks. The gas is hot (T = 1 m^2/s^2, k = 100 N/m for overlaps below 0.3 r) so that particles
// meet the walls within the few steps run: applying a range's walls twice then changes the state
// (checked). The state after `steps` steps (explicit) or sub-iterations (orb, islands), and how
// many of those sub-iterations ran as global steps (every particle on the fine steps).
struct DenseRun {
  ParticleStore p;
  std::int64_t global = 0;
  // orb and islands: the state their last (recorded) sub-iteration synchronised at its start
  // (positions wrapped, velocities v(n) and local steps), as a row or snapshot reads it.
  std::vector<double> rec;
};

template <class Scheme>
DenseRun dense_box_with_threads(int threads, const char* scheme, int steps) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
  auto cfg = SceneConfig::from_string(R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.3e-3, 6.0e-3, 6.0e-3]
periodic = [false, false, true]
[particles]
count = 40000
diameter = 50.0e-6
density = 1000.0
temperature = 1.0
seed = 5
[dem]
spring_constant = 100.0
restitution = 0.7
nsubit = 4
regrid_interval = 2e-5
[run]
end_time = 1.0
)",
                                      "dense_threads");
  cfg.apply_override(std::string("dem.scheme=\"") + scheme + "\"");
  cfg.apply_override("gravity=[0.0, -9.81, 0.0]");
  const Scene s = read_scene(cfg, "dense");
  DenseRun r{make_initial_particles(s), 0, {}};
  PhaseTimer timer;
  Scheme sch(s, r.p, timer);
  sch.start();
  if constexpr (std::is_same_v<Scheme, dem::ExplicitScheme>) {
    demtest::advance(sch, steps);
  } else {
    demtest::advance(sch, steps - 1);
    sch.subiterate(true);
    r.global = sch.global_subiterations();
    const auto synced = sch.synchronised_previous();
    for (const auto& column :
         {synced.x, synced.y, synced.z, synced.vx, synced.vy, synced.vz, synced.local_dt})
      r.rec.insert(r.rec.end(), column.begin(), column.end());
  }
  return r;
}

template <class Scheme> void expect_dense_identical(const char* scheme, int steps) {
  const DenseRun a = dense_box_with_threads<Scheme>(1, scheme, steps);
  const DenseRun b = dense_box_with_threads<Scheme>(2, scheme, steps);
  demtest::expect_same_state(a.p, b.p, scheme); // frictionless: no spins to compare
  EXPECT_EQ(a.global, b.global) << scheme;
  EXPECT_TRUE(demtest::same_bits(a.rec, b.rec)) << scheme << ": the recorded state";
  if constexpr (!std::is_same_v<Scheme, dem::ExplicitScheme>) {
    EXPECT_GT(a.global, 0) << scheme << ": no global sub-iteration, the ranged walls went untested";
    EXPECT_EQ(a.rec.size(), 7 * a.p.size()) << scheme;
  }
}

} // namespace

TEST(ThreadCount, DenseWalledBoxExplicitBitwiseIdentical) {
  expect_dense_identical<dem::ExplicitScheme>("explicit", 200);
}

TEST(ThreadCount, DenseWalledBoxOrbBitwiseIdentical) {
  expect_dense_identical<dem::OrbScheme>("orb", 4);
}

TEST(ThreadCount, DenseWalledBoxIslandsBitwiseIdentical) {
  expect_dense_identical<dem::IslandsScheme>("islands", 4);
}
