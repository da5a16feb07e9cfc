// Results must not depend on the thread count: bitwise identical states for 1 and 2 threads.
#include <cstring>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

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

bool same_bits(const std::vector<double>& a, const std::vector<double>& b) {
  // Empty vectors (no rotation fields) have null data(): memcmp must not see them (UBSan).
  return a.size() == b.size() &&
         (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0);
}

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
