// The explicit scheme at the extremes of its inputs: perfectly plastic and perfectly elastic
// contacts, a spring so stiff that dt is picoseconds, an impact faster than a radius per step,
// periodic faces crossed by nearly a box length, every particle in one cell, no particle, one.
#include <cmath>
#include <numbers>
#include <string>

#include <gtest/gtest.h>

#include "core/error.hpp"
#include "dem/contact_damping.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/verlet_passes.hpp"
#include "dem_test_support.hpp"

using namespace cfddem;
using cfddem::demtest::kPairScene;
using cfddem::demtest::scene_from;

namespace {

constexpr double kMass = 1000.0 * std::numbers::pi * 1e-12 / 6.0; // d = 100 um, rho = 1000

struct Pair {
  double v_rel_after;   // relative normal velocity after contact (x: 1 - 0), m/s
  double energy_ratio;  // kinetic energy after / before
  double contact_time;  // steps with a non-zero force x dt
  double max_overlap;   // largest overlap seen, m
  bool finite = true;
};

// Head-on pair closing at 0.2 m/s; particle 0 at x0 (left), 1 at x0 + sep.
Pair head_on(std::initializer_list<std::string> overrides, double x0, double sep, double t_end) {
  const Scene s = scene_from(kPairScene, overrides);
  ParticleStore p;
  p.add(x0, 5e-4, 5e-4, 0.1, 0, 0, 50e-6, 1000.0, 0);
  p.add(x0 + sep, 5e-4, 5e-4, -0.1, 0, 0, 50e-6, 1000.0, 1);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  Pair r{};
  long contact = 0;
  const dem::DomainGeometry g(s.domain);
  while (scheme.time() < t_end) {
    scheme.step(false);
    if (p.fx[0] != 0.0) ++contact;
    const double d = std::abs(g.image(p.x[1] - p.x[0], 0));
    r.max_overlap = std::max(r.max_overlap, 100e-6 - d);
    r.finite = r.finite && std::isfinite(p.x[0]) && std::isfinite(p.vx[0]);
  }
  scheme.step(true);
  const auto st = scheme.synchronised_previous();
  const std::size_t a = p.id[0] == 0 ? 0 : 1, b = 1 - a;
  r.v_rel_after = st.vx[b] - st.vx[a];
  const double ke = 0.5 * kMass * (st.vx[a] * st.vx[a] + st.vx[b] * st.vx[b]);
  r.energy_ratio = ke / (0.5 * kMass * 0.02);
  r.contact_time = static_cast<double>(contact) * scheme.dt();
  return r;
}

} // namespace

// e = 0 is critical damping: the overlap decays without rebound, the pair ends at rest relative to
// each other (relative normal velocity ~0, here below 0.1% of the approach speed) with half the
// kinetic energy of two equal spheres (the centre-of-mass part is zero here: all of it is lost).
TEST(Extremes, PerfectlyPlasticContactDoesNotRebound) {
  const Pair r = head_on({"dem.restitution=0"}, 4.4e-4, 1.2e-4, 3e-4);
  EXPECT_LT(std::abs(r.v_rel_after), 1e-3 * 0.2) << r.v_rel_after;
  EXPECT_LT(r.energy_ratio, 1e-5);
  EXPECT_LT(r.max_overlap, 0.3 * 50e-6);
}

// e = 1: the kinetic energy after the contact equals that before to the integrator's O(dt^2)
// error (measured at tau_p/500: 1.09e-6).
TEST(Extremes, ElasticContactConservesEnergy) {
  const Pair coarse = head_on({"dem.restitution=1"}, 4.4e-4, 1.2e-4, 2e-4);
  EXPECT_NEAR(coarse.energy_ratio, 1.0, 1e-4);
  const Pair fine = head_on({"dem.restitution=1", "dem.dt_factor=0.002"}, 4.4e-4, 1.2e-4, 2e-4);
  EXPECT_NEAR(fine.energy_ratio, 1.0, 2e-6);
  EXPECT_NEAR(fine.v_rel_after, 0.2, 1e-6);
}

// k nine decades stiffer (1e10 N/m): dt = tau_p/50 = 4.6e-12 s. The pair starts 1 nm apart so the
// run is a few thousand steps; the contact lasts pi/omega_d (5.1e-10 s), the overlap stays below
// v/omega (3.2e-11 m, 1e-7 of the position), nothing overflows and e is the input's.
TEST(Extremes, VeryStiffSpringGivesTinyDtAndCorrectContactTime) {
  const Pair r = head_on({"dem.spring_constant=1e10", "dem.restitution=0.9"}, 4.4e-4,
                         100e-6 + 1e-9, 2e-8);
  ASSERT_TRUE(r.finite);
  const double expected = dem::contact_duration(1e10, 0.9, kMass / 2);
  EXPECT_NEAR(r.contact_time, expected, 0.02 * expected);
  EXPECT_NEAR(r.v_rel_after / 0.2, 0.9, 0.01);
  const double omega = std::sqrt(1e10 / (kMass / 2));
  EXPECT_LT(r.max_overlap, 0.2 / omega);
}

// A particle faster than its radius per step would tunnel through a partner: the run stops and
// says so (RunError: exit code 3 from the program) instead of carrying on.
TEST(Extremes, ImpactFasterThanARadiusPerStepStopsTheRun) {
  const Scene s = scene_from(kPairScene);
  ParticleStore p;
  p.add(2e-4, 5e-4, 5e-4, 400.0, 0, 0, 50e-6, 1000.0, 0); // 400 m/s x 1.45e-7 s = 58 um > r
  p.add(8e-4, 5e-4, 5e-4, 0, 0, 0, 50e-6, 1000.0, 1);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  try {
    for (int k = 0; k < 100; ++k) scheme.step(false);
    FAIL() << "no error for a particle moving more than a radius per step";
  } catch (const RunError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("particle 0"), std::string::npos) << m;
    EXPECT_NE(m.find("tunnelling"), std::string::npos) << m;
    EXPECT_NE(m.find("step 0"), std::string::npos) << m;
  }
}

// The same collision straddling the periodic face x = L: particle 1 given at hi + 0.05 L, or
// 0.95 L below lo (it crosses the face by nearly a box length), is wrapped to lo + 0.05 L by the
// first build and collides with particle 0 at hi - 0.07 L across the face: the same e and contact
// time as in the middle of the box.
TEST(Extremes, CollisionAcrossPeriodicFaceMatchesInterior) {
  const Pair inside = head_on({}, 4.4e-4, 1.2e-4, 2e-4);
  const Pair across = head_on({}, 9.3e-4, 1.2e-4, 2e-4);
  const Pair far = head_on({}, 9.3e-4, -9.5e-4 - 9.3e-4, 2e-4);
  EXPECT_NEAR(across.v_rel_after, inside.v_rel_after, 1e-9);
  EXPECT_DOUBLE_EQ(across.contact_time, inside.contact_time);
  EXPECT_NEAR(far.v_rel_after, inside.v_rel_after, 1e-9);
  EXPECT_DOUBLE_EQ(far.contact_time, inside.contact_time);
}

// A particle that drifts across a periodic face many times keeps its velocity exactly and stays
// in the box.
TEST(Extremes, SingleParticleDriftsThroughPeriodicFaces) {
  const Scene s = scene_from(kPairScene);
  ParticleStore p;
  p.add(9.99e-4, 1e-6, 5e-4, 0.3, -0.2, 0.05, 50e-6, 1000.0, 42);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  while (scheme.time() < 1e-2) scheme.step(false); // 3 box lengths in x
  EXPECT_EQ(p.vx[0], 0.3);
  EXPECT_EQ(p.vy[0], -0.2);
  EXPECT_EQ(p.vz[0], 0.05);
  scheme.step(true);
  const dem::DomainGeometry g(s.domain);
  const double t = scheme.time() - scheme.dt();
  const double expect_x = g.wrap(std::fmod(9.99e-4 + 0.3 * t, 1e-3), 0);
  EXPECT_NEAR(g.wrap(p.x[0], 0), g.wrap(expect_x + 0.3 * scheme.dt(), 0), 1e-12);
  EXPECT_GT(scheme.neighbor_builds(), 1);
}

// No particle at all: the scheme starts and steps (nothing to do, no error).
// A coordinate many periods out takes its image in one step (the loops alone turned once per
// period, and forever at inf); one within a period gives the loops' bits.
TEST(Extremes, WrapFarAndNonFiniteCoordinates) {
  cfddem::DomainSpec d;
  d.lo = {0.0, 0.0, 0.0};
  d.hi = {1e-3, 1e-3, 1e-3};
  d.periodic = {true, true, false};
  const cfddem::dem::DomainGeometry g(d);
  EXPECT_EQ(g.wrap(1.25e-3, 0), 1.25e-3 - 1e-3);
  EXPECT_EQ(g.wrap(-0.25e-3, 0), -0.25e-3 + 1e-3);
  for (const double x : {1e3, -1e3, 1e12}) {
    const double w = g.wrap(x, 1);
    EXPECT_GE(w, 0.0) << x;
    EXPECT_LT(w, 1e-3) << x;
    EXPECT_NEAR(w, x - std::floor(x / 1e-3) * 1e-3, 1e-9 * std::abs(x)) << x;
  }
  EXPECT_EQ(g.wrap(INFINITY, 0), INFINITY);
  EXPECT_TRUE(std::isnan(g.wrap(NAN, 0)));
  EXPECT_EQ(g.wrap(5.0, 2), 5.0); // not periodic: as it is
}

TEST(Extremes, ZeroParticles) {
  const Scene s = scene_from(kPairScene);
  ParticleStore p;
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  for (int k = 0; k < 10; ++k) scheme.step(k == 5);
  EXPECT_EQ(scheme.steps_taken(), 10);
  EXPECT_EQ(scheme.particle_steps(), 0);
}

// One particle in a walled box under gravity: free fall, then bounces on the floor with the wall's
// e (at tau_p/500, where the dashpot's O(dt) error is small).
TEST(Extremes, SingleParticleFallsAndBounces) {
  const Scene s = scene_from(kPairScene, {"domain.periodic=[true, false, true]",
                                          "gravity=[0, -9.81, 0]", "dem.restitution=0.5",
                                          "dem.dt_factor=0.002"});
  ParticleStore p;
  p.add(5e-4, 2e-4, 5e-4, 0, 0, 0, 50e-6, 1000.0, 0);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  // Falls 150 um in sqrt(2 h / g) = 5.53 ms; before that it is in free fall, which velocity
  // Verlet integrates exactly (to round-off).
  while (scheme.time() < 5e-3) scheme.step(false);
  const double t = scheme.time();
  EXPECT_NEAR(p.y[0], 2e-4 - 0.5 * 9.81 * t * t, 1e-15);
  // Velocity when the contact ends (the first step with no wall force after some): e v_impact.
  // (Not the largest upward velocity: without a tensile clamp the dashpot pulls at the end.)
  bool touched = false;
  double v_release = 0;
  while (scheme.time() < 8e-3) {
    scheme.step(false);
    if (p.fy[0] != 0.0) touched = true;
    if (touched && p.fy[0] == 0.0) {
      v_release = p.vy[0];
      break;
    }
  }
  const double v_impact = std::sqrt(2 * 9.81 * 1.5e-4);
  EXPECT_NEAR(v_release / v_impact, 0.5, 0.005);
  EXPECT_GE(p.y[0], 0.0);
}

// Every particle in one cell of the list (a walled box only slightly wider than the cutoff):
// the neighbor list holds exactly the pairs a brute-force search finds, and 20000 steps of
// collisions among them and with the walls keep every particle finite and inside.
TEST(Extremes, AllParticlesInOneCell) {
  const Scene s = scene_from(kPairScene, {"domain.hi=[2.4e-4, 2.4e-4, 2.4e-4]",
                                          "domain.periodic=[false, false, false]"});
  ParticleStore p;
  std::int64_t id = 0;
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j)
      for (int k = 0; k < 2; ++k)
        p.add(6e-5 + 1.1e-4 * i + 1e-6 * j, 6e-5 + 1.05e-4 * j, 6e-5 + 1.05e-4 * k,
              0.01 * (i - 0.5), 0.02 * (j - 0.5), -0.01 * (k - 0.5), 50e-6, 1000.0, id++);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  const double skin = scheme.model().skin;
  std::size_t brute = 0;
  for (std::size_t a = 0; a < p.size(); ++a)
    for (std::size_t b = a + 1; b < p.size(); ++b) {
      const double dx = p.x[a] - p.x[b], dy = p.y[a] - p.y[b], dz = p.z[a] - p.z[b];
      const double rc = p.radius[a] + p.radius[b] + skin;
      brute += dx * dx + dy * dy + dz * dz < rc * rc;
    }
  scheme.step(false);
  EXPECT_EQ(scheme.pair_evaluations(), static_cast<std::int64_t>(brute));
  EXPECT_GT(brute, 8u);
  for (int k = 0; k < 20000; ++k) scheme.step(false);
  for (std::size_t a = 0; a < p.size(); ++a) {
    EXPECT_TRUE(std::isfinite(p.x[a]) && std::isfinite(p.vx[a]));
    EXPECT_TRUE(p.x[a] > 0 && p.x[a] < 2.4e-4 && p.y[a] > 0 && p.y[a] < 2.4e-4);
  }
}

// An overlap past dem.max_overlap names what the spring can hold: a head-on impact stops within
// the bound only below v = max_overlap r sqrt(k / m_eff) (1/2 m_eff v^2 = 1/2 k delta^2), a
// steady load only below k max_overlap r. Faster than that speed the impact is named, slower the
// load (a column pressed by a strong body force onto the wall at 0.7 m/s read "too fast").
TEST(Extremes, OverlapFaultSaysWhatTheSpringHolds) {
  ParticleStore p;
  p.add(1e-3, 1e-3, 1e-3, 3.0, 0.0, 0.0, 50e-6, 1000.0, 7);  // m = kMass
  p.add(1e-3, 1e-3, 1e-3, -3.0, 4.0, 0.0, 25e-6, 1000.0, 9); // m = kMass / 8
  dem::StepModel m;
  m.max_overlap = 0.3;
  m.pair.k = 10.0, m.wall.k = 40.0;
  // The pair: m_eff = kMass / 9, the smaller radius 25 um, relative speed |(6, -4, 0)|.
  const double pair_holds = 0.3 * 25e-6 * std::sqrt(10.0 / (kMass / 9.0));
  ASSERT_LT(pair_holds, std::sqrt(52.0)); // 3.11 m/s: the impact
  // Each report's words hold `needle`.
  const auto says = [&](dem::StepFault fault, double value, std::uint32_t partner,
                        const std::string& needle) {
    dem::StepReport report;
    report.flag(0, fault, value, partner);
    const std::string text = dem::describe_fault(p, report, m);
    EXPECT_NE(text.find(needle), std::string::npos) << text;
  };
  says(dem::StepFault::overlap, 0.31, 1,
       "overlap with particle 9 is 0.31 of the smaller radius (dem.max_overlap = 0.3), at a "
       "relative speed of 7.21 m/s: the impact is too fast for the spring, which stops a "
       "head-on impact of the two within that overlap only below about 3.11 m/s "
       "(dem.spring_constant = 10 N/m");
  // The wall: the particle's own mass and radius, the wall's spring; 3 m/s is below the
  // 0.3 x 50 um x sqrt(40 / kMass) = 4.15 m/s it holds: the load.
  says(dem::StepFault::overlap, 0.32, dem::kNoParticle,
       "overlap with a wall is 0.32 of its radius (dem.max_overlap = 0.3), at a relative speed "
       "of 3 m/s: the spring is too soft for the load pressing it and the wall together: it "
       "holds at most k x the bound = 0.0006 N within that overlap (dem.wall_spring_constant = "
       "40 N/m)");
  // orb and islands count overlaps: a particle through a wall says what the wall's spring holds.
  says(dem::StepFault::left_domain, -1e-6, dem::kNoParticle,
       "left the domain through a wall (coordinate -1e-06 m), at a speed of 3 m/s: the wall's "
       "spring (dem.wall_spring_constant = 40 N/m) stops an impact of this particle within "
       "dem.max_overlap = 0.3 only below about 4.15 m/s, and holds a load there only up to "
       "0.0006 N");
}
