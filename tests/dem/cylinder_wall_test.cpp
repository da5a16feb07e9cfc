// The curved wall of a cylindrical column (domain.shape = "cylinder", docs/theory.md §11): the
// planar walls' contact law with a radial normal, in every scheme. A radial throw rebounds with
// the wall's restitution; a particle sliding round the wall stays inside it, and with friction
// ends rolling at 5/7 of its speed; a granular gas in the column loses nobody and only cools;
// the results do not depend on the thread count.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>
#include <type_traits>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "dem/cylinder_wall.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"
#include "dem_test_support.hpp"

using namespace cfddem;

namespace {

// One particle of the paper (d = 100 um, 1000 kg/m^3) in a 2 mm column along y (R = 1 mm, the
// default: half the box's width), periodic along the axis; no gravity, no gas; e_w = 0.7.
Scene column(std::initializer_list<std::string> overrides) {
  auto cfg = SceneConfig::from_string(demtest::kPairScene, "column");
  for (const char* o : {"domain.hi=[2.0e-3, 1.0e-3, 2.0e-3]", "domain.periodic=[false, true, false]",
                        "domain.shape=\"cylinder\"", "dem.wall_restitution=0.7", "run.end_time=1.0"})
    cfg.apply_override(o);
  for (const auto& o : overrides)
    cfg.apply_override(o);
  return read_scene(cfg, "column");
}

constexpr double kR = 1e-3, kCentre = 1e-3, kRadius = 50e-6, kRho = 1000.0;

// The speed after one wall contact over the speed before: a particle starting 1 um from the
// wall along the unit direction (ux, 0, uz) across the axis, moving outward at 0.1 m/s.
double rebound(const Scene& s, double ux, double uz) {
  ParticleStore p;
  const double start = kR - kRadius - 1e-6, v0 = 0.1;
  p.add(kCentre + start * ux, 0.5e-3, kCentre + start * uz, v0 * ux, 0.0, v0 * uz, kRadius, kRho,
        0);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  // Until it has left the wall: moving inward with no force on it.
  while (scheme.time() < 1e-3) {
    scheme.step();
    if (p.vx[0] * ux + p.vz[0] * uz < 0.0 && p.fx[0] == 0.0 && p.fz[0] == 0.0)
      break;
  }
  return std::hypot(p.vx[0], p.vy[0], p.vz[0]) / v0;
}

} // namespace

// docs/theory.md §2.2: a wall contact separates with e_w of its approach speed. The leapfrog's
// dashpot on the half-step velocity errs by O(omega dt) on e: 0.32% at omega dt = 0.028
// (the pair's 0.797431 for 0.8, §2.2), so at dt = tau_p/500 (omega dt = 0.002 against a wall,
// m_eff = m) about 2.3e-4; the bound is 1e-3. The radial normal is the planar wall's along x:
// the same law gives the same e (to round-off), and any direction across the axis does too.
TEST(CylinderWall, RadialReboundHasTheWallsRestitution) {
  const Scene cyl = column({"dem.dt_factor=0.002"});
  const Scene box = column({"dem.dt_factor=0.002", "domain.shape=\"box\""});
  const double e_w = 0.7;
  const double e_cyl = rebound(cyl, 1.0, 0.0);
  const double e_box = rebound(box, 1.0, 0.0); // the planar wall at x = 2 mm
  const double d = std::numbers::sqrt2 / 2.0;
  const double e_diag = rebound(cyl, -d, d);
  EXPECT_NEAR(e_cyl, e_w, 1e-3 * e_w);
  EXPECT_NEAR(e_cyl, e_box, 1e-9 * e_box);
  EXPECT_NEAR(e_diag, e_cyl, 1e-9 * e_cyl);
  std::printf("restitution: cylinder %.9f, planar wall %.9f, diagonal %.9f, analytic %.9f\n",
              e_cyl, e_box, e_diag, e_w);
}

namespace {

struct Slide {
  double turns = 0.0, max_overlap = 0.0, min_gap = 1.0, speed = 0.0;
};

// A particle touching the wall (rho = R - r) moving along it at v0 across the axis, for `time`
// seconds: the wall turns it round (docs/theory.md §11). Overrides: friction and restitution.
Slide slide(std::initializer_list<std::string> overrides, double v0, double time) {
  const Scene s = column(overrides);
  ParticleStore p;
  p.add(kCentre + kR - kRadius, 0.5e-3, kCentre, 0.0, 0.0, v0, kRadius, kRho, 0);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  const dem::DomainGeometry g(s.domain);
  Slide out;
  double angle = 0.0, last = 0.0;
  while (scheme.time() < time) {
    scheme.step();
    const double a = std::atan2(p.z[0] - kCentre, p.x[0] - kCentre);
    double da = a - last;
    da -= 2.0 * std::numbers::pi * std::round(da / (2.0 * std::numbers::pi));
    angle += da, last = a;
    const double gap = dem::cylinder_gap(g, p.x[0], p.y[0], p.z[0], kRadius);
    out.max_overlap = std::max(out.max_overlap, -gap);
    out.min_gap = std::min(out.min_gap, gap + kRadius); // R - rho
  }
  out.turns = std::abs(angle) / (2.0 * std::numbers::pi);
  out.speed = std::hypot(p.vx[0], p.vy[0], p.vz[0]);
  return out;
}

} // namespace

// Without friction the wall supplies the centripetal force m v^2 / (R - r) = k_w delta_c: from
// rest in the radial direction at zero overlap the overlap swings up to at most 2 delta_c (the
// dashpot only shortens the swing), so the centre stays inside (rho <= R) at every step, and the
// speed along the wall is kept (the dashpot takes only the small radial swing's energy).
TEST(CylinderWall, SlidingParticleStaysInsideOverManyTurns) {
  const double v0 = 1.0, m = kRho * std::numbers::pi / 6.0 * 1e-12;
  const double delta_c = m * v0 * v0 / (10.0 * (kR - kRadius));
  const Slide r = slide({}, v0, 0.035); // 5.9 mm per turn at 1 m/s
  EXPECT_GT(r.turns, 5.0);
  EXPECT_GE(r.min_gap, 0.0); // rho <= R at every step
  EXPECT_GT(r.max_overlap, delta_c);
  EXPECT_LT(r.max_overlap, 2.0 * delta_c * 1.01);
  EXPECT_NEAR(r.speed, v0, 1e-3 * v0);
  std::printf("sliding: %.2f turns, max overlap %.4g m (centripetal %.4g m), speed %.6f m/s\n",
              r.turns, r.max_overlap, delta_c, r.speed);
}

// With wall friction the sliding particle spins up until it rolls: m v + (I / r) w is kept by
// the tangential force (its torque r F_t), so it ends at v = v0 / (1 + I / (m r^2)) = 5/7 v0,
// as on a flat wall (docs/theory.md §2.3). Slip stops within 0.3 ms here (mu v^2 / (R - r) =
// 1100 m/s^2); the dashpot then damps the rest at eta_t / m = 1e4 /s; 1e-3 covers the step.
TEST(CylinderWall, FrictionTurnsSlidingIntoRollingAtFiveSevenths) {
  const double v0 = 1.0;
  const Slide r = slide({"dem.friction=0.5"}, v0, 0.003);
  EXPECT_GE(r.min_gap, 0.0);
  EXPECT_NEAR(r.speed, 5.0 / 7.0 * v0, 1e-3 * v0);
  std::printf("rolling: speed %.6f m/s (5/7 v0 = %.6f)\n", r.speed, 5.0 / 7.0 * v0);
}

namespace {

Scene granular(std::initializer_list<std::string> overrides) {
  auto cfg = SceneConfig::from_file(std::string(CFDDEM_SOURCE_DIR) + "/scenes/cylinder_granular.toml");
  for (const auto& o : overrides)
    cfg.apply_override(o);
  return read_scene(cfg, "cylinder_granular");
}

struct GasRun {
  double worst_overlap = 0.0; // max over the run of (rho + r - R) / r
  double e0 = 0.0, e_rise = 0.0, e_end = 0.0;
  std::size_t count = 0;
};

// Kinetic energy (of the stored velocities) plus the springs' energy k delta^2 / 2 of every
// overlap, pairs and the curved wall (docs/theory.md §2.1, §11): what the contacts can only
// dissipate.
double energy(const ParticleStore& p, const dem::DomainGeometry& g, double k, double k_wall) {
  double e = 0.0;
  const std::size_t n = p.size();
  for (std::size_t i = 0; i < n; ++i) {
    e += 0.5 * p.mass[i] * (p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i]);
    const double pos[3] = {p.x[i], p.y[i], p.z[i]};
    for (int a = 0; a < 3; ++a) // the planar walls that act: not those across a column
      if (!g.periodic[a] && !(g.cylinder && a != g.axis)) {
        const double d = p.radius[i] - std::min(pos[a] - g.lo[a], g.hi[a] - pos[a]);
        if (d > 0.0)
          e += 0.5 * k_wall * d * d;
      }
    const double dw = g.cylinder ? -dem::cylinder_gap(g, pos, p.radius[i]) : 0.0;
    if (dw > 0.0)
      e += 0.5 * k_wall * dw * dw;
    for (std::size_t j = i + 1; j < n; ++j) {
      const double dx = g.image(p.x[j] - p.x[i], 0), dy = g.image(p.y[j] - p.y[i], 1),
                   dz = g.image(p.z[j] - p.z[i], 2);
      const double d = p.radius[i] + p.radius[j] - std::sqrt(dx * dx + dy * dy + dz * dz);
      if (d > 0.0)
        e += 0.5 * k * d * d;
    }
  }
  return e;
}

// scenes/cylinder_granular.toml for 2 ms with `Scheme`, checked after every step
// (sub-iteration): the worst overlap with the curved wall and the largest rise of the kinetic
// energy between samples.
template <class Scheme> GasRun run_gas(const Scene& s, int samples) {
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  Scheme scheme(s, p, timer);
  scheme.start();
  const dem::DomainGeometry g(s.domain);
  GasRun out;
  const double k = s.dem.spring_constant, kw = s.dem.wall_spring_constant;
  out.e0 = energy(p, g, k, kw);
  double last = out.e0;
  const double end = 2e-3;
  int steps = 0;
  while (scheme.time() < end * (1.0 - 1e-12)) {
    if constexpr (std::is_same_v<Scheme, dem::ExplicitScheme>)
      scheme.step();
    else
      scheme.subiterate();
    for (std::size_t i = 0; g.cylinder && i < p.size(); ++i)
      out.worst_overlap = std::max(
          out.worst_overlap, -dem::cylinder_gap(g, p.x[i], p.y[i], p.z[i], p.radius[i]) /
                                 p.radius[i]);
    if (++steps % samples == 0) {
      const double e = energy(p, g, k, kw);
      out.e_rise = std::max(out.e_rise, e / last - 1.0);
      last = e;
    }
  }
  out.e_end = energy(p, g, k, kw);
  out.count = p.size();
  return out;
}

// Every particle stays in the column (its overlap with the curved wall within dem.max_overlap,
// 0.3 r) and the gas cools: collisions with each other and the wall only take energy. The
// energy (kinetic of the stored velocities plus the springs') is sampled every 100 steps
// (explicit) or every sub-iteration (orb, islands). Between samples it may rise only by the
// integrator's error: the half-step velocity of a particle in contact is off by a h / 2, a
// relative O(omega h / 2) = 0.014 of its energy, and about 1% of the particles are in contact
// (nu t_c, docs/theory.md §3.1), so about 1.4e-4 of the total; `rise` is the bound.
void expect_contained_and_cooling(const GasRun& r, std::size_t n, const char* scheme,
                                  double rise) {
  EXPECT_EQ(r.count, n) << scheme;
  EXPECT_LT(r.worst_overlap, 0.3) << scheme;
  EXPECT_LT(r.e_rise, rise) << scheme;
  EXPECT_LT(r.e_end, r.e0) << scheme;
  std::printf("%s: worst wall overlap %.3g r, energy %.4g -> %.4g J (largest rise %.2g)\n",
              scheme, r.worst_overlap, r.e0, r.e_end, r.e_rise);
}

} // namespace

TEST(CylinderGranularGas, ExplicitKeepsEveryParticleInsideAndCools) {
  expect_contained_and_cooling(run_gas<dem::ExplicitScheme>(granular({}), 100), 500, "explicit",
                               1e-3);
}

// Orb's leaves read partners in other leaves frozen at the sub-iteration's start
// (docs/schemes.md), which is not energy-conserving: the same gas in a walled box (planar walls
// at the column's place) rises by up to 0.68% between sub-iterations, as it does here; the
// bound is 1e-2.
TEST(CylinderGranularGas, OrbKeepsEveryParticleInsideAndCools) {
  const Scene s = granular({"dem.scheme=\"orb\"", "dem.regrid_interval=1e-4", "dem.nsubit=10"});
  expect_contained_and_cooling(run_gas<dem::OrbScheme>(s, 1), 500, "orb", 1e-2);
}

TEST(CylinderGranularGas, IslandsKeepsEveryParticleInsideAndCools) {
  const Scene s = granular({"dem.scheme=\"islands\"", "dem.regrid_interval=1e-4", "dem.nsubit=10"});
  expect_contained_and_cooling(run_gas<dem::IslandsScheme>(s, 1), 500, "islands", 1e-3);
}

// Orb and islands fine-step a particle whose gap to the curved wall could close within the
// sub-iteration (orb's near-wall rule, islands' wall ties). A dilute gas (40 particles: most orb
// leaves and most islands particles are alone) in long sub-iterations (dt_sp = 50 us, twice a
// wall contact's duration; omega_w dt_sp = 6.9, far beyond the leapfrog's limit of 2) shows it:
// a particle the rule missed would meet the wall in one coarse step and leave (or blow up); with
// the rule its deepest wall overlap is the fine contact's, v / omega_w, 0.15 r at 1 m/s.
TEST(CylinderGranularGas, DiluteGasMeetsTheWallOnTheFineStep) {
  for (const char* scheme : {"orb", "islands"}) {
    const Scene s = granular({fmt::format("dem.scheme=\"{}\"", scheme), "particles.count=40",
                              "particles.temperature=0.1", "dem.regrid_interval=1e-4",
                              "dem.nsubit=2"});
    const GasRun r = std::string(scheme) == "orb" ? run_gas<dem::OrbScheme>(s, 1)
                                                  : run_gas<dem::IslandsScheme>(s, 1);
    EXPECT_LT(r.worst_overlap, 0.3) << scheme;
    EXPECT_GT(r.worst_overlap, 0.0) << scheme; // the wall was met
    EXPECT_EQ(r.count, 40u) << scheme;
    std::printf("dilute gas, %s: worst wall overlap %.3g r\n", scheme, r.worst_overlap);
  }
}

namespace {

// 12000 particles of 50 um in a 4 mm column (so the passes run as TBB loops), with friction
// (the wall's tangential force and torque): the state after `steps` steps (sub-iterations).
template <class Scheme> ParticleStore column_with_threads(int threads, const char* scheme, int steps) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(threads));
  const Scene s = granular({fmt::format("dem.scheme=\"{}\"", scheme), "particles.count=12000",
                            "particles.diameter=50e-6", "particles.temperature=0.05",
                            "domain.hi=[4e-3, 2e-3, 4e-3]", "domain.cylinder_radius=2e-3",
                            "dem.friction=0.3", "dem.regrid_interval=2e-5", "dem.nsubit=4"});
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  Scheme sch(s, p, timer);
  sch.start();
  demtest::advance(sch, steps);
  return p;
}

template <class Scheme> void expect_thread_independent(const char* scheme, int steps) {
  const ParticleStore a = column_with_threads<Scheme>(1, scheme, steps);
  const ParticleStore b = column_with_threads<Scheme>(2, scheme, steps);
  demtest::expect_same_state(a, b, scheme);
}

} // namespace

TEST(CylinderThreadCount, ExplicitBitwiseIdentical) {
  expect_thread_independent<dem::ExplicitScheme>("explicit", 300);
}

TEST(CylinderThreadCount, IslandsBitwiseIdentical) {
  expect_thread_independent<dem::IslandsScheme>("islands", 6);
}

TEST(CylinderThreadCount, OrbBitwiseIdentical) {
  expect_thread_independent<dem::OrbScheme>("orb", 6);
}

