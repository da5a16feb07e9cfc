// The orb scheme (dem/orb_scheme.hpp): agreement with the explicit scheme where it must agree,
// thread-count independence, the missed collision of a coarse step, and momentum drift.
#include <cmath>
#include <cstring>
#include <unordered_map>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "dem/orb_scheme.hpp"
#include "dem_test_support.hpp"

using namespace cfddem;

namespace {

// A small HCS gas: d = 100 um, rho = 1000, e = 0.8, k = 10 in a periodic 1 mm box.
const char* kGas = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.0e-3, 1.0e-3, 1.0e-3]
[particles]
count = 100
diameter = 100.0e-6
density = 1000.0
temperature = 0.01
seed = 5
[dem]
spring_constant = 10.0
restitution = 0.8
[run]
end_time = 1.0
)";

struct Snapshot {
  std::unordered_map<std::int64_t, std::array<double, 6>> by_id;
  double T = 0.0;
};

Snapshot snap(std::span<const std::int64_t> id, std::span<const double> x, std::span<const double> y,
              std::span<const double> z, std::span<const double> vx,
              std::span<const double> vy, std::span<const double> vz,
              std::span<const double> mass) {
  Snapshot s;
  for (std::size_t i = 0; i < id.size(); ++i)
    s.by_id[id[i]] = {x[i], y[i], z[i], vx[i], vy[i], vz[i]};
  s.T = dem::measure({x, y, z, vx, vy, vz, mass}).granular_temperature;
  return s;
}

// Explicit: state at step n (recorded by step n+1).
Snapshot explicit_at(const Scene& s, long long n) {
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  dem::ExplicitScheme e(s, p, timer);
  e.start();
  for (long long k = 0; k < n; ++k) e.step();
  const std::vector<std::int64_t> ids = p.id; // the recorded state is in the order before step
  e.step(true);
  const auto r = e.synchronised_previous();
  (void)ids;
  return snap(p.id, r.x, r.y, r.z, r.vx, r.vy, r.vz, p.mass);
}

Snapshot orb_at(const Scene& s, long long n) {
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  dem::OrbScheme o(s, p, timer);
  o.start();
  for (long long k = 0; k < n; ++k) o.subiterate();
  const std::vector<std::int64_t> ids = p.id; // order at the start of the recording sub-iteration
  o.subiterate(true);
  const auto r = o.synchronised_previous();
  return snap(ids, r.x, r.y, r.z, r.vx, r.vy, r.vz, r.mass);
}

} // namespace

// (a) L = 0: one leaf, no ghosts; proximity_radii huge so the leaf always takes the fine step;
// dem.dt = 1e-7 s divides dt_sp = 1e-6 s (10 steps, the last one dt_sp - 9 dt, equal to dt up
// to one rounding). The schemes then differ only by rounding (force summation order; the first
// step's damping uses v(0) instead of v(-dt/2), a change of a(0) dt/2 in v = O(1e-7) relative
// when no pair is in contact at t = 0), amplified by the few collisions in 0.2 ms: 1e-9 relative
// is a generous bound on that.
TEST(OrbScheme, OneLeafMatchesExplicit) {
  const Scene s = demtest::scene_from(kGas, {"dem.dt=1.0e-7", "dem.scheme=\"orb\"",
                                             "partition.orb_levels=0", "dem.nsubit=10",
                                             "dem.regrid_interval=1.0e-5",
                                             "dem.proximity_radii=1000.0"});
  const Snapshot e = explicit_at(s, 2000);
  const Snapshot o = orb_at(s, 200);
  ASSERT_EQ(e.by_id.size(), o.by_id.size());
  double dx = 0.0, dv = 0.0;
  for (const auto& [id, a] : e.by_id) {
    const auto& b = o.by_id.at(id);
    for (int c = 0; c < 3; ++c) dx = std::max(dx, std::abs(a[c] - b[c]));
    for (int c = 3; c < 6; ++c) dv = std::max(dv, std::abs(a[c] - b[c]));
  }
  EXPECT_LT(dx, 1e-12) << "max position difference [m]";
  EXPECT_LT(dv, 1e-9) << "max velocity difference [m/s]";
  EXPECT_NEAR(o.T, e.T, 1e-9 * e.T);
}

// (b) Every leaf fine-stepped (proximity_radii huge): count and mass conserved, T(t) within 2%
// of explicit over 2 ms. What remains is the frozen ghosts: a contact across a leaf boundary sees
// its partner fixed for a whole sub-iteration. In this 10%-solids gas that error is large at
// dt_sp = 10 us (measured 25% at L = 2: a contact lasts ~16 us, so the partner's motion over
// dt_sp is the size of the overlap itself), 0.8% at dt_sp = 1 us (used here), 0.4% with the ghosts
// refreshed every step (dt_sp < dt), the level of L = 0 (0.7%, the shortened last step and
// the chaotic amplification of rounding). The bound is 2.5x the measured 0.8%.
TEST(OrbScheme, AllFineFollowsExplicit) {
  const Scene s = demtest::scene_from(kGas, {"particles.count=200", "dem.scheme=\"orb\"",
                                             "partition.orb_levels=2", "dem.nsubit=100",
                                             "dem.proximity_radii=40.0"});
  ParticleStore p = make_initial_particles(s);
  const double mass0 = p.total_mass();
  ParticleStore q = p;
  PhaseTimer t1, t2;
  dem::OrbScheme o(s, p, t1);
  dem::ExplicitScheme e(s, q, t2);
  o.start();
  e.start();
  const double dt_sp = o.dt_sub();
  double worst = 0.0;
  for (int row = 1; row <= 10; ++row) {
    // Both schemes to t = 20 row dt_sp (explicit to the nearest step), then record.
    while (o.subiterations() < 200.0 * row) {
      o.subiterate();
      EXPECT_EQ(o.last_fine_fraction(), 1.0);
    }
    o.subiterate(true);
    const auto r = o.synchronised_previous();
    const double To = dem::measure({r.x, r.y, r.z, r.vx, r.vy, r.vz, r.mass}).granular_temperature;
    const auto target = std::llround(200.0 * row * dt_sp / e.dt());
    while (e.steps_taken() < target) e.step();
    e.step(true);
    const auto x = e.synchronised_previous();
    const double Te = dem::measure({x.x, x.y, x.z, x.vx, x.vy, x.vz, q.mass}).granular_temperature;
    worst = std::max(worst, std::abs(To - Te) / Te);
  }
  EXPECT_EQ(p.size(), 200u);
  EXPECT_DOUBLE_EQ(p.total_mass(), mass0);
  EXPECT_LT(worst, 0.02) << "max |T_orb - T_explicit| / T_explicit";
  fmt::print("all-fine: max relative T difference {:.3e}\n", worst);
}

// (c) Bitwise identical results for 1 and 2 threads: 5000 particles, 16 leaves, 3 regrids.
namespace {
ParticleStore orb_with_threads(int threads) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
  const Scene s = demtest::scene_from(kGas, {"particles.count=5000", "particles.diameter=50.0e-6",
                                             "domain.hi=[2.0e-3, 2.0e-3, 2.0e-3]",
                                             "particles.temperature=0.05", "dem.scheme=\"orb\"",
                                             "partition.orb_levels=4", "dem.nsubit=10"});
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  dem::OrbScheme o(s, p, timer);
  o.start();
  for (int k = 0; k < 25; ++k) o.subiterate(k % 10 == 0);
  return p;
}
bool same_bits(const std::vector<double>& a, const std::vector<double>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0;
}
} // namespace

TEST(OrbScheme, BitwiseIdenticalForOneAndTwoThreads) {
  const ParticleStore a = orb_with_threads(1);
  const ParticleStore b = orb_with_threads(2);
  EXPECT_EQ(a.id, b.id);
  EXPECT_TRUE(same_bits(a.x, b.x) && same_bits(a.y, b.y) && same_bits(a.z, b.z));
  EXPECT_TRUE(same_bits(a.vx, b.vx) && same_bits(a.vy, b.vy) && same_bits(a.vz, b.vz));
}

// (d) The trade is real: two particles approaching at 1 m/s each across the leaf boundary of an
// L = 1 tree, centres 310 um apart (more than the 150 um proximity distance, so both leaves take
// the coarse step). With one sub-iteration of 300 us each moves 300 um in one step: they pass
// through each other untouched. With dt_sp = 0.1 us the approach is seen and the collision is
// resolved: the restitution measured matches the explicit scheme's within 2%.
namespace {
struct PairResult {
  double xa, xb, va, vb;
};
template <class Run> PairResult pair_run(const Scene& s, Run&& run) {
  ParticleStore p;
  p.add(1.845e-3, 2.0e-3, 2.0e-3, 1.0, 0.0, 0.0, 50e-6, 1000.0, 0);
  p.add(2.155e-3, 2.0e-3, 2.0e-3, -1.0, 0.0, 0.0, 50e-6, 1000.0, 1);
  run(s, p);
  const std::size_t a = p.id[0] == 0 ? 0 : 1, b = 1 - a;
  return {p.x[a], p.x[b], p.vx[a], p.vx[b]};
}
const char* kPair = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [4.0e-3, 4.0e-3, 4.0e-3]
[particles]
count = 0
diameter = 100.0e-6
density = 1000.0
[dem]
spring_constant = 10.0
restitution = 0.8
scheme = "orb"
[partition]
orb_levels = 1
[run]
end_time = 1.0
)";
} // namespace

TEST(OrbScheme, MissedCollisionAtCoarseStepCaughtAtFine) {
  auto orb = [](long long subits) {
    return [subits](const Scene& s, ParticleStore& p) {
      PhaseTimer t;
      dem::OrbScheme o(s, p, t);
      o.start();
      for (long long k = 0; k < subits; ++k) o.subiterate();
    };
  };
  const Scene coarse = demtest::scene_from(kPair, {"dem.regrid_interval=3.0e-4", "dem.nsubit=1"});
  const auto c = pair_run(coarse, orb(1));
  EXPECT_EQ(c.va, 1.0) << "coarse: no force ever acted";
  EXPECT_EQ(c.vb, -1.0);
  EXPECT_GT(c.xa, c.xb) << "coarse: the particles passed through each other";

  const Scene fine = demtest::scene_from(kPair, {"dem.regrid_interval=3.0e-4", "dem.nsubit=3000"});
  const auto f = pair_run(fine, orb(3000));
  const auto e = pair_run(fine, [](const Scene& s, ParticleStore& p) {
    PhaseTimer t;
    dem::ExplicitScheme x(s, p, t);
    x.start();
    const auto n = std::llround(3.0e-4 / x.dt());
    for (long long k = 0; k < n; ++k) x.step();
  });
  const double e_orb = (f.va - f.vb) / -2.0, e_exp = (e.va - e.vb) / -2.0;
  EXPECT_LT(f.xa, f.xb) << "fine: they bounced";
  EXPECT_NEAR(e_orb, e_exp, 0.02 * e_exp);
  EXPECT_NEAR(e_exp, 0.8, 0.05);
  fmt::print("missed collision: coarse v_a = {}, fine e = {:.4f}, explicit e = {:.4f}\n",
             c.va, e_orb, e_exp);
}

// dem.local_dt = "time_to_contact": the same coarse sub-iteration that let the pair pass through
// each other now sees that their gap closes within dt_sp, so both leaves step finely and the
// particles bounce (each against the other's frozen copy across the leaf boundary).
TEST(OrbScheme, TimeToContactCatchesTheFastPairAtTheCoarseStep) {
  const Scene coarse = demtest::scene_from(
      kPair, {"dem.regrid_interval=3.0e-4", "dem.nsubit=1", "dem.local_dt=time_to_contact"});
  const auto c = pair_run(coarse, [](const Scene& s, ParticleStore& p) {
    PhaseTimer t;
    dem::OrbScheme o(s, p, t);
    o.start();
    o.subiterate();
  });
  EXPECT_LT(c.xa, c.xb) << "no tunnelling";
  EXPECT_LT(c.va, 0.0);
  EXPECT_GT(c.vb, 0.0);
}

// (e) Momentum drift per sub-iteration. Within a leaf every own-own pair is exactly reciprocal;
// only contacts across a leaf boundary (each side against the other's frozen copy) are not, so
// the drift of one sub-iteration is bounded by the impulse of those contacts: at most
// (1 + e) m_eff v_n <= m v_rel per contact, with v_rel ~ 2 sqrt(3 T). The test asserts the
// worst sub-iteration drifts less than two such impulses (a few cross-boundary contacts at
// most are active at once in this gas, and each is only partly non-reciprocal).
TEST(OrbScheme, MomentumDriftAcrossLeavesIsBounded) {
  const Scene s = demtest::scene_from(kGas, {"particles.count=200", "dem.scheme=\"orb\"",
                                             "partition.orb_levels=2", "dem.nsubit=10"});
  ParticleStore p = make_initial_particles(s);
  PhaseTimer t;
  dem::OrbScheme o(s, p, t);
  o.start();
  auto momentum = [&] {
    std::array<double, 3> m{0, 0, 0};
    for (std::size_t i = 0; i < p.size(); ++i)
      m[0] += p.mass[i] * p.vx[i], m[1] += p.mass[i] * p.vy[i], m[2] += p.mass[i] * p.vz[i];
    return m;
  };
  const double impulse = p.mass[0] * 2.0 * std::sqrt(3.0 * 0.01);
  double worst = 0.0;
  auto prev = momentum();
  for (int k = 0; k < 200; ++k) {
    o.subiterate();
    const auto now = momentum();
    worst = std::max(worst, std::hypot(now[0] - prev[0], now[1] - prev[1], now[2] - prev[2]));
    prev = now;
  }
  fmt::print("momentum drift: worst per sub-iteration {:.3e} = {:.3f} contact impulses\n", worst,
             worst / impulse);
  EXPECT_LT(worst, 2.0 * impulse);
}

// (f) Measured-cost weights (partition.weights = "cost"): the run is still bitwise independent of
// the thread count, and the cuts move: with cost weights the fine leaves (particles x ~70 local
// steps) get fewer particles than with counts, so the store order after a regrid differs.
namespace {
ParticleStore orb_cost_run(int threads, const char* weights) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
  const Scene s = demtest::scene_from(
      kGas, {"particles.count=400", "domain.hi=[1.6e-3, 1.6e-3, 1.6e-3]", "dem.scheme=\"orb\"",
             "partition.orb_levels=3", "dem.nsubit=5", "dem.proximity_radii=2.0",
             fmt::format("partition.weights=\"{}\"", weights)});
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  dem::OrbScheme o(s, p, timer);
  o.start();
  for (int k = 0; k < 11; ++k) o.subiterate();
  return p;
}
} // namespace

TEST(OrbScheme, CostWeightsDeterministicAndMoveTheCuts) {
  const ParticleStore a = orb_cost_run(1, "cost");
  const ParticleStore b = orb_cost_run(2, "cost");
  EXPECT_EQ(a.id, b.id);
  EXPECT_TRUE(same_bits(a.x, b.x) && same_bits(a.vx, b.vx));
  const ParticleStore c = orb_cost_run(1, "count");
  EXPECT_NE(a.id, c.id) << "cost weights should move at least one cut";
}

// (g) A wall counts as a partner: a lone particle whose centre is within proximity_radii radii of
// a wall takes the fine step (a coarse step of dt_sp would drive it into the wall unresolved);
// far from the walls it takes the coarse one.
TEST(OrbScheme, WallIsAPartnerForTheStepRule) {
  const Scene s = demtest::scene_from(kPair, {"domain.periodic=[false, false, false]",
                                              "partition.orb_levels=0", "dem.nsubit=10"});
  for (const double y : {2.0e-3, 0.12e-3}) {
    ParticleStore p;
    p.add(2.0e-3, y, 2.0e-3, 0.0, -0.1, 0.0, 50e-6, 1000.0, 0);
    PhaseTimer t;
    dem::OrbScheme o(s, p, t);
    o.start();
    o.subiterate();
    EXPECT_EQ(o.last_fine_fraction(), y < 0.15e-3 ? 1.0 : 0.0) << "y = " << y;
  }
}

// (h) With a gas, every ORB cut lies on a fluid cell face (leaves are whole numbers of cells), so
// the box can own both its particles and its cells.
TEST(OrbScheme, CutsSnapToFluidCellFacesWithAGas) {
  const Scene s = demtest::scene_from(std::string(kGas) + R"(
[partition]
orb_levels = 4
[fluid]
cells = [8, 10, 6]
density = 1.0
viscosity = 2.0e-5
dt = 1.0e-4
)", {"dem.scheme=orb"});
  ParticleStore p = make_initial_particles(s);
  PhaseTimer t;
  dem::OrbScheme o(s, p, t);
  o.start();
  o.subiterate();
  const std::array<double, 3> dx{1e-3 / 8, 1e-3 / 10, 1e-3 / 6};
  ASSERT_EQ(o.tree().cuts().size(), 15u);
  for (const auto& cut : o.tree().cuts()) {
    const double k = cut.position / dx[static_cast<std::size_t>(cut.axis)];
    EXPECT_NEAR(k, std::round(k), 1e-9) << "axis " << cut.axis << " at " << cut.position;
  }
}
