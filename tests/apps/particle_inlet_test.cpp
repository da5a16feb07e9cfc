// apps/particle_inlet.hpp: where and how many particles enter. Every particle placed lies in the
// region, a radius off the walls, and overlaps no particle already there nor one placed with it;
// the count follows the mass due (one particle as soon as the rate covers it, the rest carried);
// the same fluid step places the same particles (the stream is the seed and the step), and the
// recycle queue enters in id order with each particle's own radius and mass.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <vector>

#include "apps/particle_inlet.hpp"
#include "core/communicator.hpp"
#include "core/scene_config.hpp"

using namespace cfddem;
using namespace cfddem::apps;

namespace {

Scene inlet_scene(const std::string& extra) {
  auto cfg = SceneConfig::from_string(R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.0e-3, 2.0e-3, 1.0e-3]
periodic = [true, false, true]
[particles]
count = 0
diameter = 1.0e-4
density = 1000.0
[dem]
spring_constant = 10.0
restitution = 0.8
[fluid]
cells = [4, 8, 4]
density = 1.0
viscosity = 2.0e-5
dt = 1.0e-4
bc.y_lo = "inflow"
bc.y_hi = "outflow"
inflow_velocity = [0.0, 1.0, 0.0]
[run]
end_time = 1.0e-3
[inlet]
region_lo = [0.0, 0.0, 0.0]
region_hi = [1.0e-3, 3.0e-4, 1.0e-3]
)" + extra,
                                      "inlet test");
  return read_scene(cfg, "inlet");
}

double gap(double d, double length) { // periodic minimum image
  return d - length * std::round(d / length);
}

// Centre distance minus the two radii (>= 0: no overlap), x and z periodic with length 1 mm.
double clearance(double x0, double y0, double z0, double r0, double x1, double y1, double z1,
                 double r1) {
  const double dx = gap(x0 - x1, 1e-3), dy = y0 - y1, dz = gap(z0 - z1, 1e-3);
  return std::sqrt(dx * dx + dy * dy + dz * dz) - (r0 + r1);
}

} // namespace

TEST(ParticleInlet, PlacesWhereParticlesFitAtTheRateDue) {
  const Scene s = inlet_scene("mass_rate = 2.0e-5\n");
  const ParticleInlet inlet(s);
  const double m = ParticleStore::sphere_mass(1000.0, 5e-5); // 5.236e-10 kg
  // Particles already in the region, on a lattice: the new ones must fit between them.
  ParticleStore p;
  std::int64_t id = 0;
  for (double x = 1e-4; x < 1e-3; x += 2e-4)
    for (double z = 1e-4; z < 1e-3; z += 2e-4)
      p.add(x, 1.5e-4, z, 0, 0, 0, 5e-5, 1000.0, id++);
  const Communicator serial = Communicator::serial();
  InletState st;
  inlet.start(st, p, p.size(), serial);
  EXPECT_EQ(st.next_id, id);
  // 2e-5 kg/s x 1e-4 s = 2e-9 kg due: 3 particles of 5.236e-10 kg, 4.3e-10 kg carried.
  const EnteringParticles e = inlet.enter(st, p, p.size(), 1e-4, 0, serial);
  ASSERT_EQ(e.size(), 3u);
  EXPECT_NEAR(st.owed, 2e-9 - 3 * m, 1e-24);
  EXPECT_EQ(st.drawn, 3);
  for (std::size_t k = 0; k < e.size(); ++k) {
    EXPECT_EQ(e.id[k], id + static_cast<std::int64_t>(k));
    EXPECT_DOUBLE_EQ(e.mass[k], m);
    EXPECT_GE(e.y[k], 5e-5); // a radius off the floor
    EXPECT_LE(e.y[k], 3e-4);
    for (std::size_t i = 0; i < p.size(); ++i)
      EXPECT_GE(clearance(e.x[k], e.y[k], e.z[k], 5e-5, p.x[i], p.y[i], p.z[i], 5e-5), 0.0);
    for (std::size_t j = 0; j < k; ++j)
      EXPECT_GE(clearance(e.x[k], e.y[k], e.z[k], 5e-5, e.x[j], e.y[j], e.z[j], 5e-5), 0.0);
  }
  // The same step from the same state places the same particles; the next step others.
  InletState again;
  inlet.start(again, p, p.size(), serial);
  const EnteringParticles same = inlet.enter(again, p, p.size(), 1e-4, 0, serial);
  EXPECT_EQ(same.x, e.x);
  const EnteringParticles next = inlet.enter(again, p, p.size(), 1e-4, 1, serial);
  ASSERT_FALSE(next.x.empty());
  EXPECT_NE(next.x[0], e.x[0]);
}

TEST(ParticleInlet, RecycledParticlesEnterInIdOrderWithTheirOwnSize) {
  const Scene s = inlet_scene("recycle = true\n");
  const ParticleInlet inlet(s);
  ParticleStore p;
  p.add(5e-4, 1.9e-3, 5e-4, 0, 1, 0, 4e-5, 1000.0, 7); // leaving, larger id first in the store
  p.add(2e-4, 1.9e-3, 2e-4, 0, 1, 0, 5e-5, 2000.0, 3);
  const Communicator serial = Communicator::serial();
  InletState st;
  inlet.start(st, p, p.size(), serial);
  const std::vector<std::uint32_t> leaving = {0, 1};
  inlet.queue(st, p, leaving, serial);
  ASSERT_EQ(st.queue_mass.size(), 2u);
  const EnteringParticles e = inlet.enter(st, p, p.size(), 1e-4, 0, serial);
  ASSERT_EQ(e.size(), 2u);
  EXPECT_EQ(e.radius[0], 5e-5); // id 3 first
  EXPECT_EQ(e.mass[0], p.mass[1]);
  EXPECT_EQ(e.radius[1], 4e-5);
  EXPECT_EQ(e.mass[1], p.mass[0]);
  EXPECT_EQ(e.id[0], 8); // new ids after the largest
  EXPECT_TRUE(st.queue_mass.empty());
}
