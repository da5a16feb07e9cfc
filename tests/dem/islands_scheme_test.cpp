// The islands scheme (dem/islands_scheme.hpp): it misses no collision (fast binary encounters
// give the explicit scheme's outgoing velocities), it equals the explicit scheme to round-off
// when dt divides dt_sp (gas, and walls with gravity), and it does not depend on the thread
// count.
#include <cmath>
#include <limits>
#include <numbers>
#include <string>
#include <tuple>
#include <unordered_map>
#include <vector>

#include <fmt/format.h>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "core/error.hpp"
#include "dem/contact_damping.hpp"
#include "dem/islands_scheme.hpp"
#include "dem_test_support.hpp"

using namespace cfddem;

namespace {

using State = std::unordered_map<std::int64_t, std::array<double, 6>>;

State state_of(const ParticleStore& p) {
  State s;
  for (std::size_t i = 0; i < p.size(); ++i)
    s[p.id[i]] = {p.x[i], p.y[i], p.z[i], p.vx[i], p.vy[i], p.vz[i]};
  return s;
}

// Both schemes from the same particles for `time` seconds; returns the synchronised states at
// `time` (positions and v(t), as the diagnostics see them).
template <class Setup>
std::pair<State, State> run_both(const Scene& s, double time, Setup setup,
                                 std::int64_t* bound_violations = nullptr) {
  ParticleStore pe = make_initial_particles(s);
  setup(pe);
  ParticleStore pi = pe;
  PhaseTimer t;
  dem::ExplicitScheme e(s, pe, t);
  e.start();
  const auto steps = std::llround(time / e.dt());
  for (long long k = 0; k < steps; ++k)
    e.step();
  e.step(true);
  State ref;
  {
    const auto r = e.synchronised_previous();
    for (std::size_t i = 0; i < pe.size(); ++i)
      ref[pe.id[i]] = {r.x[i], r.y[i], r.z[i], r.vx[i], r.vy[i], r.vz[i]};
  }
  dem::IslandsScheme isl(s, pi, t);
  isl.start();
  const auto subits = std::llround(time / isl.dt_sub());
  for (long long k = 0; k < subits; ++k)
    isl.subiterate();
  isl.subiterate(true);
  if (bound_violations)
    *bound_violations = isl.bound_violations();
  State out;
  const auto r = isl.synchronised_previous();
  for (std::size_t i = 0; i < r.id.size(); ++i)
    out[r.id[i]] = {r.x[i], r.y[i], r.z[i], r.vx[i], r.vy[i], r.vz[i]};
  return {ref, out};
}

double wrap_diff(double a, double b, double length) {
  double d = std::fabs(a - b);
  d = std::fmod(d, length);
  return std::min(d, length - d);
}

// 12 head-on pairs on separate lines along x, closing at 1 m/s from gaps of 0.05 to 1.2 mm: the
// coarse sub-iteration (1e-4 s, a whole radius of travel per particle per step) would let them
// pass through each other; the islands scheme must give every collision the explicit outcome.
const char* kEncounters = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [4.0e-3, 4.0e-3, 4.0e-3]
periodic = [true, true, true]
[particles]
count = 0
diameter = 100.0e-6
density = 1000.0
[dem]
scheme = "islands"
spring_constant = 10.0
restitution = 0.8
dt = 1.0e-7
nsubit = 1
regrid_interval = 1.0e-4
[run]
end_time = 1.0
)";

} // namespace

TEST(IslandsScheme, MissesNoCollisionOfFastBinaryEncounters) {
  const Scene s = demtest::scene_from(kEncounters);
  auto setup = [](ParticleStore& p) {
    for (int q = 0; q < 12; ++q) {
      const double y = 0.3e-3 + 0.3e-3 * (q % 4), z = 0.5e-3 + 1.0e-3 * (q / 4);
      const double gap = 0.05e-3 + 0.1e-3 * q; // surface gap: collision at t = gap / 1 m/s
      const double xa = 1.0e-3, xb = xa + 100e-6 + gap;
      p.add(xa, y, z, 0.5, 0.0, 0.0, 50e-6, 1000.0, 2 * q);
      p.add(xb, y, z, -0.5, 0.0, 0.0, 50e-6, 1000.0, 2 * q + 1);
    }
  };
  std::int64_t violations = -1;
  const auto [ref, isl] = run_both(s, 2.0e-3, setup, &violations);
  EXPECT_EQ(violations, 0);
  int collided_ref = 0, collided_isl = 0;
  for (const auto& [id, r] : ref) {
    const auto& v = isl.at(id);
    const double v0 = id % 2 == 0 ? 0.5 : -0.5;
    collided_ref += std::fabs(r[3] - v0) > 1e-3;
    collided_isl += std::fabs(v[3] - v0) > 1e-3;
    // Outgoing velocity of every collision: the explicit one to round-off (the fine steps of an
    // island fall on the explicit scheme's time grid here, since dt divides dt_sp).
    EXPECT_NEAR(v[3], r[3], 1e-9) << "particle " << id;
    EXPECT_EQ(v[4], 0.0);
    EXPECT_NEAR(wrap_diff(v[0], r[0], 4e-3), 0.0, 1e-12) << "particle " << id;
  }
  EXPECT_EQ(collided_ref, 24) << "every pair collided in the reference";
  EXPECT_EQ(collided_isl, 24);
  // The explicit outcome is a real collision: e = 0.8 for head-on equal spheres.
  EXPECT_NEAR(ref.at(0)[3], -0.4, 0.02);
}

namespace {
// One pair closing head-on at 1 m/s from a surface gap (ids 0 and 1) and 16 particles at rest
// far from it, so that the pair is a small part of the scene (not the dense mode, where everyone
// steps finely); one sub-iteration of the islands scheme (K = 1000 steps of h = 1e-7 s). Returns
// the pair evaluations; vx gets the pair's velocities after it.
std::int64_t closing_pair_evaluations(const Scene& s, double gap, std::int64_t& bound_violations,
                                      double (&vx)[2]) {
  ParticleStore p = make_initial_particles(s);
  p.add(1.0e-3, 2e-3, 2e-3, 0.5, 0.0, 0.0, 50e-6, 1000.0, 0);
  p.add(1.0e-3 + 100e-6 + gap, 2e-3, 2e-3, -0.5, 0.0, 0.0, 50e-6, 1000.0, 1);
  for (int q = 0; q < 16; ++q)
    p.add(0.25e-3 * (q % 4) + 0.5e-3, 0.5e-3 + 0.25e-3 * (q / 4), 0.5e-3, 0.0, 0.0, 0.0, 50e-6,
          1000.0, 2 + q);
  PhaseTimer t;
  dem::IslandsScheme isl(s, p, t);
  isl.start();
  isl.subiterate();
  for (std::size_t i = 0; i < p.size(); ++i)
    if (p.id[i] < 2)
      vx[p.id[i]] = p.vx[i];
  bound_violations = isl.bound_violations();
  return isl.pair_evaluations();
}
} // namespace

// An island's fine steps before its entry time are one step (islands_kernels.hpp, entry_lead):
// one pair closing at 1 m/s (own bounds 0.5 m/s each, no gravity) from a surface gap g takes,
// in its first sub-iteration of K = 1000 steps of h = 1e-7 s, one step up to L h with
// L = ceil(t_e / h) - 1, t_e = (g - margin) / 1 m/s (margin 1e-3 r), then the K - L steps of h:
// K - L + 1 force evaluations of its one pair instead of K. The gaps put the contact (16 us)
// across the sub-iteration's end, so no step after it is folded.
TEST(IslandsScheme, FoldsTheFineStepsBeforeAnIslandsEntryTimeIntoOne) {
  const Scene s = demtest::scene_from(kEncounters);
  for (const double gap : {0.085e-3, 0.09e-3, 0.0951e-3}) {
    std::int64_t violations = -1;
    double vx[2] = {0.0, 0.0};
    const std::int64_t evaluations = closing_pair_evaluations(s, gap, violations, vx);
    const double h = 1e-7, t_e = (gap - 1e-3 * 50e-6) / 1.0;
    const auto lead = static_cast<std::int64_t>(std::ceil(t_e / h)) - 1;
    EXPECT_EQ(evaluations, 1000 - lead + 1) << "gap " << gap;
    EXPECT_EQ(violations, 0);
  }
}

// ... and the steps after its last contact too (islands_kernels.hpp, free_time): the same pair
// from gaps whose contact ends well inside the sub-iteration. The pair touches from t_e = g / v
// for the damped contact's duration t_c (contact_duration); once the gap has opened past the
// margin (at the separation speed e v, within one step of h) the island flies free up to the
// sub-iteration's last step, which is one step. So the pair is evaluated at the sub-iteration's
// start, then at every node up to the first one past t_e + t_c + margin / (e v), then at the
// last step's node: within a step or two of that count (the leapfrog's contact ends within a
// step of t_c), against the hundreds of steps that follow.
TEST(IslandsScheme, FoldsTheFineStepsAfterAnIslandsLastContactIntoOne) {
  const Scene s = demtest::scene_from(kEncounters);
  const double m = 1000.0 * std::numbers::pi / 6.0 * 1e-12, h = 1e-7, margin = 1e-3 * 50e-6;
  const double t_c = dem::contact_duration(10.0, 0.8, 0.5 * m);
  for (const double gap : {0.03e-3, 0.05e-3, 0.0701e-3}) {
    std::int64_t violations = -1;
    double vx[2] = {0.0, 0.0};
    const std::int64_t evaluations = closing_pair_evaluations(s, gap, violations, vx);
    const auto lead = static_cast<std::int64_t>(std::ceil((gap - margin) / h)) - 1;
    const auto last = static_cast<std::int64_t>(std::ceil((gap / 1.0 + t_c + margin / 0.8) / h));
    const std::int64_t expect = 1 + (last - lead) + 1;
    EXPECT_NEAR(static_cast<double>(evaluations), static_cast<double>(expect), 2.0)
        << "gap " << gap;
    EXPECT_EQ(violations, 0);
    // The collision happened, with the restitution's outgoing speed.
    EXPECT_NEAR(vx[0], -0.4, 0.02) << "gap " << gap;
    EXPECT_NEAR(vx[1], 0.4, 0.02) << "gap " << gap;
  }
}

namespace {
// 100 particles of a 1% gas (periodic) and 60 in a closed box under gravity.
const char* kGas = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.737e-3, 1.737e-3, 1.737e-3]
periodic = [true, true, true]
[particles]
count = 100
diameter = 100.0e-6
density = 1000.0
temperature = 0.01
seed = 3
[dem]
scheme = "islands"
spring_constant = 10.0
restitution = 0.8
dt = 1.0e-7
nsubit = 10
regrid_interval = 1.0e-4
[run]
end_time = 1.0
)";

const char* kBox = R"(
gravity = [0.0, -9.80665, 0.0]
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.0e-3, 1.0e-3, 1.0e-3]
periodic = [false, false, false]
[particles]
count = 60
diameter = 100.0e-6
density = 1000.0
temperature = 0.001
seed = 8
[dem]
scheme = "islands"
spring_constant = 10.0
restitution = 0.8
wall_restitution = 0.9
dt = 1.0e-7
nsubit = 20
regrid_interval = 1.0e-4
[run]
end_time = 1.0
)";

void expect_round_off(const State& ref, const State& isl, double length, double tol_v) {
  ASSERT_EQ(ref.size(), isl.size());
  for (const auto& [id, r] : ref) {
    const auto& v = isl.at(id);
    for (int a = 0; a < 3; ++a) {
      EXPECT_NEAR(wrap_diff(v[a], r[a], length), 0.0, 1e-12) << "particle " << id << " axis " << a;
      EXPECT_NEAR(v[3 + a], r[3 + a], tol_v) << "particle " << id << " axis " << a;
    }
  }
}
} // namespace

// With dt dividing dt_sp the two schemes differ only by the rounding of free flight (one step of
// dt_sp instead of many of dt): round-off, amplified by a few collisions over 3 ms.
TEST(IslandsScheme, EqualsExplicitToRoundOffInAGas) {
  std::int64_t violations = -1;
  const auto [ref, isl] = run_both(
      demtest::scene_from(kGas), 3.0e-3, [](ParticleStore&) {}, &violations);
  EXPECT_EQ(violations, 0);
  expect_round_off(ref, isl, 1.737e-3, 1e-9);
}

TEST(IslandsScheme, EqualsExplicitToRoundOffWithWallsAndGravity) {
  std::int64_t violations = -1;
  const auto [ref, isl] = run_both(
      demtest::scene_from(kBox), 5.0e-3, [](ParticleStore&) {}, &violations);
  EXPECT_EQ(violations, 0);
  // Walls are not periodic: plain differences (wrap_diff with a huge length).
  expect_round_off(ref, isl, 1.0, 1e-9);
}

TEST(IslandsScheme, BitwiseIndependentOfThreadCount) {
  const Scene s =
      demtest::scene_from(kGas, {"particles.count=400", "domain.hi=[2.757e-3,2.757e-3,2.757e-3]"});
  auto run = [&](int threads) {
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism,
                           static_cast<std::size_t>(threads));
    ParticleStore p = make_initial_particles(s);
    PhaseTimer t;
    dem::IslandsScheme isl(s, p, t);
    isl.start();
    for (int k = 0; k < 30; ++k)
      isl.subiterate();
    return state_of(p);
  };
  const State one = run(1), two = run(2);
  for (const auto& [id, a] : one)
    EXPECT_EQ(a, two.at(id)) << "particle " << id;
}

// The link rounds after the first rescan only the rows of particles whose bound was raised
// (IslandsScheme::make_links): the run must be bitwise the one that rescans every row in every
// round, with walls and gravity and in a periodic gas.
TEST(IslandsScheme, IncrementalLinksBitwiseEqualFullRescans) {
  for (const Scene& s : {demtest::scene_from(kBox, {"particles.count=150"}),
                         demtest::scene_from(kGas, {"particles.count=400",
                                                    "domain.hi=[2.757e-3,2.757e-3,2.757e-3]"})}) {
    auto run = [&](bool incremental) {
      ParticleStore p = make_initial_particles(s);
      PhaseTimer t;
      dem::IslandsScheme isl(s, p, t);
      isl.set_incremental_links(incremental);
      isl.start();
      for (int k = 0; k < 40; ++k)
        isl.subiterate();
      EXPECT_EQ(isl.bound_violations(), 0);
      const auto hist = isl.island_size_histogram();
      return std::tuple(state_of(p), isl.pair_evaluations(),
                        std::vector<std::int64_t>(hist.begin(), hist.end()));
    };
    const auto [full, full_pairs, full_hist] = run(false);
    const auto [inc, inc_pairs, inc_hist] = run(true);
    // The runs must have islands of several particles (links made over several rounds).
    ASSERT_GT(full_pairs, 0);
    ASSERT_GT(full_hist[1], 0);
    EXPECT_EQ(inc_pairs, full_pairs);
    EXPECT_EQ(inc_hist, full_hist);
    for (const auto& [id, a] : full)
      EXPECT_EQ(a, inc.at(id)) << "particle " << id;
  }
}

// A dense gas (phi = 0.3): most particles are linked, every sub-iteration steps everyone finely
// (the explicit scheme's work, no bounds); with dt dividing dt_sp it is the explicit scheme to
// round-off (only the neighbor-list rebuilds, hence the summation order, differ).
TEST(IslandsScheme, DenseGasStepsEveryoneFinelyAsExplicit) {
  const Scene s =
      demtest::scene_from(kGas, {"particles.count=600", "domain.hi=[1.0e-3,1.0e-3,1.0e-3]"});
  ParticleStore p = make_initial_particles(s);
  PhaseTimer t;
  dem::IslandsScheme isl(s, p, t);
  isl.start();
  for (int k = 0; k < 3; ++k)
    isl.subiterate();
  EXPECT_EQ(isl.global_subiterations(), 3);
  EXPECT_DOUBLE_EQ(isl.last_fine_fraction(), 1.0);
  std::int64_t violations = -1;
  const auto [ref, out] = run_both(
      s, 3.0e-4, [](ParticleStore&) {}, &violations);
  EXPECT_EQ(violations, 0);
  expect_round_off(ref, out, 1.0e-3, 1e-9);
}

// Without dem.neighbor_skin the islands list starts at three explicit skins and each expiry
// prices the next one (IslandsScheme::choose_skin): builds against the entries every
// sub-iteration scans. A 1% gas has few entries per particle, so its builds dominate and the
// skin grows; at 10% the entries (and the pair work in islands) dominate and it shrinks. Either
// way no bound is violated (EqualsExplicitToRoundOffInAGas checks the outcome with the chosen
// skins).
TEST(IslandsScheme, SkinGrowsInADiluteGasAndShrinksInADenseOne) {
  auto final_skin = [](const Scene& s, double& first) {
    ParticleStore p = make_initial_particles(s);
    PhaseTimer t;
    dem::IslandsScheme isl(s, p, t);
    isl.start();
    first = isl.skin();
    for (int k = 0; k < 500; ++k)
      isl.subiterate();
    EXPECT_EQ(isl.bound_violations(), 0);
    EXPECT_EQ(isl.global_subiterations(), 0);
    return isl.skin();
  };
  double first = 0.0;
  const double dilute = final_skin(demtest::scene_from(kGas), first);
  EXPECT_GT(dilute, 1.2 * first) << "1% gas";
  const double dense =
      final_skin(demtest::scene_from(kGas, {"domain.hi=[0.806e-3,0.806e-3,0.806e-3]"}), first);
  EXPECT_LT(dense, 0.8 * first) << "10% gas";
}

// A particle whose velocity became NaN stops the run with a message naming it, not a hang.
TEST(IslandsScheme, NonFiniteVelocityStopsTheRunNamingTheParticle) {
  const Scene s = demtest::scene_from(kGas);
  ParticleStore p = make_initial_particles(s);
  PhaseTimer t;
  dem::IslandsScheme isl(s, p, t);
  isl.start();
  isl.subiterate();
  const std::int64_t victim = p.id[7];
  p.vx[7] = std::numeric_limits<double>::quiet_NaN();
  try {
    for (int k = 0; k < 5; ++k)
      isl.subiterate();
    FAIL() << "no error";
  } catch (const RunError& e) {
    EXPECT_NE(std::string(e.what()).find(fmt::format("particle {}", victim)), std::string::npos)
        << e.what();
  }
}
