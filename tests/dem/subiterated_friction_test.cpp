// Friction in the sub-iterated schemes (dem/orb_scheme.hpp, dem/islands_scheme.hpp): at the
// explicit step they take the explicit scheme's path (to round-off), the oblique collision
// follows Coulomb's law and spins the spheres by r J_t / I, and a restart from save_state()
// continues bit for bit, with the tangential history carried by particle ids.
#include <cmath>
#include <string>
#include <unordered_map>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"
#include "dem_test_support.hpp"

using namespace cfddem;

namespace {

// dt = 2^-22 s (tau_p / 68 for these particles): dt_sp = regrid_interval / nsubit equals it
// exactly when regrid_interval is dt times a power of two.
constexpr double kDt = 2.384185791015625e-07;

// A frictional box (box_gravity's contact model, mu = 0.3 on particles and walls): 200
// particles thrown around at T = 0.01 m^2/s^2 above a floor, so that contacts slide, stick and
// hit the walls within the first milliseconds.
const char* kBox = R"(
gravity = [0.0, -9.80665, 0.0]
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.0e-3, 1.5e-3, 1.0e-3]
periodic = [false, false, true]
[particles]
count = 200
diameter = 100.0e-6
density = 1000.0
temperature = 1.0e-2
placement = "lattice"
region_lo = [0.0, 0.0, 0.0]
region_hi = [1.0e-3, 0.7e-3, 1.0e-3]
seed = 3
[dem]
spring_constant = 10.0
restitution = 0.5
friction = 0.3
wall_friction = 0.3
[run]
end_time = 1.0
)";

struct State {
  std::unordered_map<std::int64_t, std::array<double, 9>> by_id; // x, v, w
};

State state_of(const ParticleStore& p) {
  State s;
  for (std::size_t i = 0; i < p.size(); ++i)
    s.by_id[p.id[i]] = {p.x[i],  p.y[i],  p.z[i],  p.vx[i], p.vy[i],
                        p.vz[i], p.wx[i], p.wy[i], p.wz[i]};
  return s;
}

// Largest differences in position (the minimum image on kBox's periodic z axis, 1 mm long: the
// schemes wrap at different times), velocity and spin between two states of the same particles.
std::array<double, 3> largest_difference(const State& a, const State& b) {
  std::array<double, 3> d{};
  for (const auto& [id, u] : a.by_id) {
    const auto& v = b.by_id.at(id);
    for (std::size_t c = 0; c < 9; ++c) {
      const double e = c == 2 ? std::remainder(u[c] - v[c], 1.0e-3) : u[c] - v[c];
      d[c / 3] = std::max(d[c / 3], std::abs(e));
    }
  }
  return d;
}

State explicit_after(const Scene& s, long long steps) {
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  dem::ExplicitScheme e(s, p, timer);
  e.start();
  for (long long k = 0; k < steps; ++k)
    e.step();
  return state_of(p);
}

template <class Scheme> State subiterated_after(const Scene& s, long long subits) {
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  Scheme o(s, p, timer);
  o.start();
  for (long long k = 0; k < subits; ++k)
    o.subiterate();
  return state_of(p);
}

using demtest::same_bits;

bool same_store(const ParticleStore& a, const ParticleStore& b) {
  return a.id == b.id && same_bits(a.x, b.x) && same_bits(a.y, b.y) && same_bits(a.z, b.z) &&
         same_bits(a.vx, b.vx) && same_bits(a.vy, b.vy) && same_bits(a.vz, b.vz) &&
         same_bits(a.wx, b.wx) && same_bits(a.wy, b.wy) && same_bits(a.wz, b.wz);
}

} // namespace

// With dt_sp equal to the explicit dt every leaf takes one step per sub-iteration and reads its
// partners in other leaves at the start of that step, which is what the explicit scheme reads:
// the schemes differ only by the order of the force sums (rows by id against the Verlet list's
// order) and the first step's dashpot (v(0) against v(-dt/2)). Four leaves, so that contacts
// across leaves, frozen spins, re-sorts (every sub-iteration) and regrids (every 4) all carry the
// history. 4000 steps (0.95 ms) of collisions in a frictional box. The rounding differences grow
// through the collisions (chaos: measured dv 1e-14 m/s at 1000 steps, 5e-13 at 4000, 5e-11 at
// 8000; dw 2e-10, 2e-8, 7e-7 rad/s), while a wrong term would differ at O(dt) from the first
// contact on. The bounds are the frictionless OneLeafMatchesExplicit's (1e-12 m, 1e-9 m/s), the
// spin's 1e-9 m/s over r.
TEST(OrbFriction, AtTheExplicitStepMatchesExplicit) {
  const std::string dt = fmt::format("dem.dt={:.17g}", kDt);
  const std::string regrid = fmt::format("dem.regrid_interval={:.17g}", 4 * kDt);
  const Scene s = demtest::scene_from(
      kBox, {dt, regrid, "dem.scheme=\"orb\"", "dem.nsubit=4", "partition.orb_levels=2"});
  const long long n = 4000;
  const State e = explicit_after(s, n);
  const State o = subiterated_after<dem::OrbScheme>(s, n);
  ASSERT_EQ(e.by_id.size(), o.by_id.size());
  const auto d = largest_difference(e, o);
  double spin = 0.0;
  for (const auto& [id, u] : e.by_id)
    spin = std::max({spin, std::abs(u[6]), std::abs(u[7]), std::abs(u[8])});
  fmt::print(
      "orb vs explicit at dt: dx {:.3e} m, dv {:.3e} m/s, dw {:.3e} rad/s (|w| max {:.3e})\n", d[0],
      d[1], d[2], spin);
  EXPECT_GT(spin, 10.0) << "the scene must spin particles for the comparison to mean anything";
  EXPECT_LT(d[0], 1e-12) << "max position difference [m]";
  EXPECT_LT(d[1], 1e-9) << "max velocity difference [m/s]";
  EXPECT_LT(d[2], 1e-9 / 50e-6) << "max spin difference [rad/s]";
}

namespace {

struct Oblique {
  double vt_after;             // contact-point slip velocity along y after impact
  double impulse_n, impulse_t; // sum over steps of |F.n| dt and |F - (F.n) n| dt
  double spin;                 // w_z of particle 0 after impact
  double inertia, radius;
};

// collision_test.cpp's oblique impact (particle 0 at 0.2 m/s along x with slip vt along y onto
// particle 1 at rest) with a sub-iterated scheme at dt_sp = dt (one local step per sub-iteration,
// so the contact force of each step is the one p.fx holds after it).
template <class Scheme> Oblique oblique(double vt, double mu, double e, int levels) {
  // A vector, not a braced list of temporaries: GCC 12 at -O3 warned (-Warray-bounds, falsely)
  // about the list's backing array once the test suite's precompiled header came first.
  std::vector<std::string> overrides;
  overrides.push_back("dem.friction=" + std::to_string(mu));
  overrides.push_back("dem.restitution=" + std::to_string(e));
  overrides.push_back(fmt::format("dem.dt={:.17g}", kDt));
  overrides.push_back(fmt::format("dem.regrid_interval={:.17g}", 4 * kDt));
  overrides.push_back("dem.nsubit=4");
  overrides.push_back("partition.orb_levels=" + std::to_string(levels));
  const Scene s = demtest::scene_from(demtest::kPairScene, overrides);
  ParticleStore p;
  p.add(4.45e-4, 5e-4, 5e-4, 0.2, vt, 0, 50e-6, 1000.0, 0);
  p.add(5.5e-4, 5e-4, 5e-4, 0.0, 0, 0, 50e-6, 1000.0, 1);
  PhaseTimer timer;
  Scheme scheme(s, p, timer);
  scheme.start();
  Oblique o{0, 0, 0, 0, 0, 50e-6};
  for (int k = 0; k < 2000; ++k) {
    scheme.subiterate(true);
    const auto st = scheme.synchronised_previous();
    const std::size_t a = st.id[0] == 0 ? 0 : 1, b = 1 - a;
    double n[3] = {st.x[b] - st.x[a], st.y[b] - st.y[a], st.z[b] - st.z[a]};
    const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (double& c : n)
      c /= len;
    // The store may have been re-sorted after the step: the force by id.
    const std::size_t pa = p.id[0] == 0 ? 0 : 1;
    const double f[3] = {p.fx[pa], p.fy[pa], p.fz[pa]};
    const double fn = f[0] * n[0] + f[1] * n[1] + f[2] * n[2];
    const double ft[3] = {f[0] - fn * n[0], f[1] - fn * n[1], f[2] - fn * n[2]};
    o.impulse_n += std::abs(fn) * scheme.dt_sub();
    o.impulse_t += std::sqrt(ft[0] * ft[0] + ft[1] * ft[1] + ft[2] * ft[2]) * scheme.dt_sub();
  }
  const std::size_t a = p.id[0] == 0 ? 0 : 1, b = 1 - a;
  o.vt_after = (p.vy[a] - p.vy[b]) + o.radius * (p.wz[a] + p.wz[b]);
  o.spin = p.wz[a];
  o.inertia = 0.4 * p.mass[a] * o.radius * o.radius;
  return o;
}

} // namespace

// Gross sliding (collision_test.cpp's SlidingRegimeFollowsCoulomb): J_t = mu J_n at every step
// and the spin r J_t / I, with both particles in one leaf and across a leaf boundary (L = 1 cuts
// between them: each reads the other frozen at the start of the step, which at dt_sp = dt is
// the explicit scheme's reading).
TEST(OrbFriction, ObliqueSlidingFollowsCoulomb) {
  for (const int levels : {0, 1}) {
    const double mu = 0.1;
    const Oblique o = oblique<dem::OrbScheme>(0.5, mu, 1.0, levels);
    ASSERT_GT(o.impulse_n, 0.0);
    EXPECT_NEAR(o.impulse_t, mu * o.impulse_n, 1e-9 * mu * o.impulse_n) << "L = " << levels;
    EXPECT_NEAR(-o.spin, o.radius * o.impulse_t / o.inertia,
                1e-6 * o.radius * o.impulse_t / o.inertia)
        << "L = " << levels;
  }
}

// Sticking (collision_test.cpp's StickingRegimeReversesSlipWithinCoulombBound): below the
// Coulomb bound, and the tangential spring reverses the slip.
TEST(OrbFriction, ObliqueStickingReversesSlip) {
  for (const int levels : {0, 1}) {
    const double mu = 0.5;
    const Oblique o = oblique<dem::OrbScheme>(0.05, mu, 0.8, levels);
    EXPECT_LT(o.impulse_t, mu * o.impulse_n) << "L = " << levels;
    EXPECT_LT(o.vt_after, 0.0) << "L = " << levels;
    EXPECT_GT(o.vt_after, -0.05) << "L = " << levels;
  }
}

namespace {

// The frictional box with the orb scheme sub-iterating (dt_sp = 10 dt, fine leaves near
// contacts and walls), 16 leaves.
Scene orb_box() {
  return demtest::scene_from(kBox, {"dem.scheme=\"orb\"", "dem.nsubit=5",
                                    "dem.regrid_interval=1.0e-5", "partition.orb_levels=4"});
}

} // namespace

// A restart from save_state() at a regrid point, with contacts alive, continues bit for bit:
// the history travels as records by particle id. Without them the continuation differs (the
// comparison can fail).
TEST(OrbFriction, RestartFromSaveStateIsBitwise) {
  const Scene s = orb_box();
  ParticleStore a = make_initial_particles(s);
  PhaseTimer t1;
  dem::OrbScheme full(s, a, t1);
  full.start();
  for (int k = 0; k < 100; ++k)
    full.subiterate(k % 10 == 0);
  const dem::OrbScheme::State saved = full.save_state();
  const ParticleStore at_save = a;
  for (int k = 0; k < 100; ++k)
    full.subiterate(k % 10 == 0);
  ASSERT_GT(saved.history.size(), 10u) << "contacts must be alive at the checkpoint";

  auto resume = [&](bool keep_history) {
    ParticleStore b = at_save;
    PhaseTimer t2;
    dem::OrbScheme part(s, b, t2);
    dem::OrbScheme::State st = saved;
    if (!keep_history)
      st.history = dem::ContactHistory{};
    part.restore_state(std::move(st));
    for (int k = 0; k < 100; ++k)
      part.subiterate(k % 10 == 0);
    EXPECT_EQ(part.subiterations(), full.subiterations());
    return b;
  };
  EXPECT_TRUE(same_store(a, resume(true)));
  EXPECT_FALSE(same_store(a, resume(false)));
}

// The tangential forces of a pair are equal and opposite (each side's history is the other's
// negated, bit for bit): in a fully periodic frictional gas (no walls, no gravity) on one
// fine-stepped leaf, the total linear momentum is conserved to round-off over 300
// sub-iterations of 7 local steps, while the particles spin up.
TEST(OrbFriction, OneLeafConservesMomentum) {
  const Scene s =
      demtest::scene_from(kBox, {"domain.periodic=[true, true, true]", "gravity=[0.0, 0.0, 0.0]",
                                 "dem.scheme=\"orb\"", "dem.nsubit=5", "dem.regrid_interval=1.0e-5",
                                 "partition.orb_levels=0", "dem.proximity_radii=1000.0"});
  ParticleStore p = make_initial_particles(s);
  auto momentum = [&] {
    std::array<double, 3> m{};
    for (std::size_t i = 0; i < p.size(); ++i)
      m[0] += p.mass[i] * p.vx[i], m[1] += p.mass[i] * p.vy[i], m[2] += p.mass[i] * p.vz[i];
    return m;
  };
  double scale = 0.0;
  for (std::size_t i = 0; i < p.size(); ++i)
    scale += p.mass[i] * std::sqrt(p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i]);
  PhaseTimer t;
  dem::OrbScheme o(s, p, t);
  o.start();
  const auto m0 = momentum();
  double spin = 0.0;
  for (int k = 0; k < 300; ++k)
    o.subiterate();
  for (std::size_t i = 0; i < p.size(); ++i)
    spin = std::max(spin, std::abs(p.wx[i]) + std::abs(p.wy[i]) + std::abs(p.wz[i]));
  const auto m1 = momentum();
  EXPECT_GT(spin, 0.0);
  for (int c = 0; c < 3; ++c)
    EXPECT_NEAR(m1[static_cast<std::size_t>(c)], m0[static_cast<std::size_t>(c)], 1e-12 * scale);
}

// Islands at dt_sp = dt: one step per sub-iteration, every island member read live, free
// particles (no partner within reach) without contact: the explicit scheme's step to round-off,
// as for orb (measured below the bounds by the same margin).
TEST(IslandsFriction, AtTheExplicitStepMatchesExplicit) {
  const std::string dt = fmt::format("dem.dt={:.17g}", kDt);
  const std::string regrid = fmt::format("dem.regrid_interval={:.17g}", 4 * kDt);
  const Scene s = demtest::scene_from(kBox, {dt, regrid, "dem.scheme=\"islands\"", "dem.nsubit=4"});
  const long long n = 4000;
  const State e = explicit_after(s, n);
  const State o = subiterated_after<dem::IslandsScheme>(s, n);
  ASSERT_EQ(e.by_id.size(), o.by_id.size());
  const auto d = largest_difference(e, o);
  fmt::print("islands vs explicit at dt: dx {:.3e} m, dv {:.3e} m/s, dw {:.3e} rad/s\n", d[0], d[1],
             d[2]);
  EXPECT_LT(d[0], 1e-12) << "max position difference [m]";
  EXPECT_LT(d[1], 1e-9) << "max velocity difference [m/s]";
  EXPECT_LT(d[2], 1e-9 / 50e-6) << "max spin difference [rad/s]";
}

TEST(IslandsFriction, ObliqueSlidingFollowsCoulomb) {
  const double mu = 0.1;
  const Oblique o = oblique<dem::IslandsScheme>(0.5, mu, 1.0, 0);
  ASSERT_GT(o.impulse_n, 0.0);
  EXPECT_NEAR(o.impulse_t, mu * o.impulse_n, 1e-9 * mu * o.impulse_n);
  EXPECT_NEAR(-o.spin, o.radius * o.impulse_t / o.inertia,
              1e-6 * o.radius * o.impulse_t / o.inertia);
}

TEST(IslandsFriction, ObliqueStickingReversesSlip) {
  const double mu = 0.5;
  const Oblique o = oblique<dem::IslandsScheme>(0.05, mu, 0.8, 0);
  EXPECT_LT(o.impulse_t, mu * o.impulse_n);
  EXPECT_LT(o.vt_after, 0.0);
  EXPECT_GT(o.vt_after, -0.05);
}

namespace {

// The frictional box sub-iterated by islands: dt_sp = 2 us (about 8 explicit steps).
Scene islands_box(std::initializer_list<std::string> more = {}) {
  std::vector<std::string> o = {"dem.scheme=\"islands\"", "dem.nsubit=5",
                                "dem.regrid_interval=1.0e-5"};
  o.insert(o.end(), more.begin(), more.end());
  auto cfg = SceneConfig::from_string(kBox, "test scene");
  for (const auto& x : o)
    cfg.apply_override(x);
  return read_scene(cfg, "test");
}

} // namespace

// A restart from save_state() between sub-iterations continues bit for bit (the list as built
// with its history per entry); without the history the continuation differs.
TEST(IslandsFriction, RestartFromSaveStateIsBitwise) {
  const Scene s = islands_box();
  ParticleStore a = make_initial_particles(s);
  PhaseTimer t1;
  dem::IslandsScheme full(s, a, t1);
  full.start();
  for (int k = 0; k < 103; ++k)
    full.subiterate(k % 10 == 0);
  const dem::IslandsScheme::State saved = full.save_state();
  const ParticleStore at_save = a;
  for (int k = 0; k < 100; ++k)
    full.subiterate(k % 10 == 0);
  std::size_t live = 0;
  for (const double h : saved.hx)
    live += h != 0.0;
  ASSERT_GT(live, 10u) << "contacts must be alive at the checkpoint";

  auto resume = [&](bool keep_history) {
    ParticleStore b = at_save;
    PhaseTimer t2;
    dem::IslandsScheme part(s, b, t2);
    dem::IslandsScheme::State st = saved;
    if (!keep_history)
      std::fill(st.hx.begin(), st.hx.end(), 0.0);
    part.restore_state(std::move(st));
    for (int k = 0; k < 100; ++k)
      part.subiterate(k % 10 == 0);
    return b;
  };
  EXPECT_TRUE(same_store(a, resume(true)));
  EXPECT_FALSE(same_store(a, resume(false)));
}

// The speed bound stays a bound with friction: no particle moves farther than its bound allows.
// (a) A frictional bed settling under gravity (at rest on its floor after 20 ms, contacts
// sticking and sliding, particles spinning) at dt_sp = 2 us and 10 us: mostly the global mode,
// islands while it is loose. (b) A dilute frictional gas (periodic 2 mm box, T = 0.01 m^2/s^2,
// 1.7% solids) at dt_sp = 10 us: islands throughout, every collision an oblique frictional one
// between spinning particles.
TEST(IslandsFriction, NoBoundViolationWithFriction) {
  struct Case {
    std::vector<std::string> keys;
    double end;
  };
  const std::vector<Case> cases = {
      {{"dem.nsubit=5", "particles.temperature=1.0e-3"}, 0.02},
      {{"dem.nsubit=1", "particles.temperature=1.0e-3"}, 0.02},
      {{"dem.nsubit=1", "domain.hi=[2.0e-3, 2.0e-3, 2.0e-3]", "domain.periodic=[true, true, true]",
        "gravity=[0.0, 0.0, 0.0]", "particles.region_hi=[2.0e-3, 2.0e-3, 2.0e-3]"},
       0.02}};
  for (const Case& c : cases) {
    auto cfg = SceneConfig::from_string(kBox, "test scene");
    for (const auto& x : {"dem.scheme=\"islands\"", "dem.regrid_interval=1.0e-5"})
      cfg.apply_override(x);
    for (const auto& x : c.keys)
      cfg.apply_override(x);
    const Scene s = read_scene(cfg, "test");
    ParticleStore p = make_initial_particles(s);
    PhaseTimer t;
    dem::IslandsScheme o(s, p, t);
    o.start();
    double spin = 0.0;
    while (o.time() < c.end) {
      o.subiterate();
      for (std::size_t i = 0; i < p.size(); ++i)
        spin = std::max(spin, std::abs(p.wx[i]) + std::abs(p.wy[i]) + std::abs(p.wz[i]));
    }
    fmt::print("{}: {} sub-iterations, {} global, max |w| {:.3g} rad/s, bound violations {}\n",
               c.keys[0], o.subiterations(), o.global_subiterations(), spin, o.bound_violations());
    EXPECT_GT(spin, 10.0);
    EXPECT_GT(o.subiterations() - o.global_subiterations(), 200) << "islands must be exercised";
    EXPECT_EQ(o.bound_violations(), 0) << c.keys[0];
    EXPECT_EQ(p.size(), 200u);
  }
}
