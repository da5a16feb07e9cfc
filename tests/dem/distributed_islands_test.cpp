// One rank equals R ranks: IslandsScheme with the world communicator (run under mpirun -np 1, 2
// and 3) against IslandsScheme without one: the same particles within round-off on R > 1 ranks
// (a spanning island sums its forces in another order, and a particle that spans may take K
// fine steps where one rank flies it free, equal under a constant force only to round-off) and
// bitwise on one rank (the same path), no particle or mass lost at any sub-iteration, no bound
// violated, bitwise the same result for 1 and 2 threads per rank, and a restart from save_state()
// bitwise the run that wrote it.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <functional>
#include <map>
#include <random>
#include <string>
#include <utility>

#include <fmt/format.h>
#include <tbb/global_control.h>

#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"
#include "core/phase_timer.hpp"
#include "dem/granular_diagnostics.hpp"
#include "dem/islands_scheme.hpp"
#include "distributed_test_support.hpp"

namespace cfddem {
namespace {

using demtest::apply_force;
using demtest::force_of;
using demtest::scene_from;
using demtest::share;

// A dense granular gas (phi ~ 0.25): islands everywhere, often the dense (global) mode.
const char* kGas = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.86e-3, 0.86e-3, 0.86e-3]
periodic = [true, true, true]
[particles]
count = 300
diameter = 100.0e-6
density = 1000.0
temperature = 0.05
seed = 11
[dem]
scheme = "islands"
spring_constant = 10.0
restitution = 0.8
max_overlap = 0.9
regrid_interval = 5.0e-5
nsubit = 5
[run]
end_time = 1.0e-3
)";

// Walls on every side and gravity along -y (100 g): wall ties and a settling bed.
const char* kWalls = R"(
gravity = [0.0, -1.0e3, 0.0]
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.2e-3, 0.8e-3, 0.6e-3]
periodic = [false, false, false]
[particles]
count = 250
diameter = 100.0e-6
density = 1000.0
temperature = 0.05
seed = 5
[dem]
scheme = "islands"
spring_constant = 10.0
restitution = 0.7
wall_restitution = 0.9
max_overlap = 0.9
regrid_interval = 5.0e-5
nsubit = 5
[run]
end_time = 1.0e-3
)";

constexpr int kSubits = 40;

using State = std::map<std::int64_t, std::array<double, 6>>;

using Spins = std::map<std::int64_t, std::array<double, 3>>;

struct Outcome {
  State state;                        // one rank: all; R ranks: this rank's owned
  Spins spin;                         // with friction: the angular velocities (the same)
  std::vector<double> kinetic_energy; // per sub-iteration, over all particles
  std::int64_t bound_violations = 0, spanning_subits = 0, global_subits = 0;
  std::int64_t incremental_link_rounds = 0;
  double max_overlap_ratio = 0.0;
};

State state_of(const ParticleStore& p, std::size_t n) {
  State s;
  for (std::size_t i = 0; i < n; ++i)
    s[p.id[i]] = {p.x[i], p.y[i], p.z[i], p.vx[i], p.vy[i], p.vz[i]};
  return s;
}

Spins spins_of(const ParticleStore& p, std::size_t n) {
  Spins s;
  if (p.rotation)
    for (std::size_t i = 0; i < n; ++i)
      s[p.id[i]] = {p.wx[i], p.wy[i], p.wz[i]};
  return s;
}

Outcome one_rank(const Scene& scene, int subits, bool external = false) {
  ParticleStore p = make_initial_particles(scene);
  PhaseTimer timer;
  dem::IslandsScheme s(scene, p, timer);
  s.start();
  if (external)
    apply_force(p, p.size(), s);
  Outcome r;
  for (int k = 0; k < subits; ++k) {
    s.subiterate();
    r.kinetic_energy.push_back(0.5 * [&] {
      double e = 0.0;
      for (std::size_t i = 0; i < p.size(); ++i)
        e += p.mass[i] * (p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i]);
      return e;
    }());
  }
  r.state = state_of(p, p.size());
  r.spin = spins_of(p, p.size());
  r.bound_violations = s.bound_violations();
  return r;
}

// The scheme with the world communicator on `threads` threads; every sub-iteration the particles
// over all ranks are counted and identified (count, sum of ids and of squared ids) and their mass
// compared.
Outcome on_ranks(const Scene& scene, int subits, int threads, bool external = false,
                 bool incremental_links = true) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(threads));
  const Communicator c = Communicator::world();
  const ParticleStore all = make_initial_particles(scene);
  ParticleStore p = share(all, c.rank(), c.size());
  PhaseTimer timer;
  dem::IslandsScheme s(scene, p, dem::make_step_model(scene, all), &c, timer);
  s.use_incremental_links(incremental_links);
  s.start();
  if (external)
    apply_force(p, s.owned(), s);
  std::array<std::int64_t, 3> expect{};
  for (const std::int64_t id : all.id)
    expect[0] += 1, expect[1] += id, expect[2] += id * id;
  const double mass0 = all.total_mass();
  Outcome r;
  for (int k = 0; k < subits; ++k) {
    s.subiterate(k + 1 == subits);
    std::array<std::int64_t, 3> got{};
    std::array<double, 2> sums{};
    for (std::size_t i = 0; i < s.owned(); ++i) {
      got[0] += 1, got[1] += p.id[i], got[2] += p.id[i] * p.id[i], sums[0] += p.mass[i];
      sums[1] += 0.5 * p.mass[i] * (p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i]);
    }
    c.sum(got);
    c.sum(sums);
    EXPECT_EQ(got, expect) << "sub-iteration " << k;
    EXPECT_NEAR(sums[0], mass0, 1e-13 * mass0) << "sub-iteration " << k;
    r.kinetic_energy.push_back(sums[1]);
  }
  r.state = state_of(p, s.owned());
  r.spin = spins_of(p, s.owned());
  r.bound_violations = s.bound_violations();
  r.spanning_subits = s.spanning_subiterations();
  r.global_subits = s.global_subiterations();
  r.incremental_link_rounds = c.sum(s.incremental_link_rounds());
  r.max_overlap_ratio = s.max_overlap_ratio();
  return r;
}

// Every owned particle of every rank against the one-rank run: |position| differences below
// `pos` (m), velocity differences below `vel` (m/s); the kinetic energy at every sub-iteration
// within a relative `energy`.
void expect_close(const Scene& scene, const Outcome& one, const Outcome& mine, double pos,
                  double vel, double energy, const std::string& what) {
  const Communicator c = Communicator::world();
  std::int64_t count = 0;
  const std::array<double, 2> worst =
      demtest::worst_differences(scene, one.state, mine.state, count, what);
  EXPECT_EQ(count, static_cast<std::int64_t>(one.state.size())) << what;
  EXPECT_LE(worst[0], pos) << what << ": positions";
  EXPECT_LE(worst[1], vel) << what << ": velocities";
  ASSERT_EQ(one.kinetic_energy.size(), mine.kinetic_energy.size());
  double e_worst = 0.0;
  for (std::size_t k = 0; k < mine.kinetic_energy.size(); ++k)
    e_worst = std::max(e_worst, std::abs(mine.kinetic_energy[k] - one.kinetic_energy[k]) /
                                    one.kinetic_energy[k]);
  EXPECT_LE(e_worst, energy) << what << ": kinetic energy";
  if (c.rank() == 0)
    std::printf("[ %s ] worst |dx| %.3g m, |dv| %.3g m/s, dE/E %.3g\n", what.c_str(), worst[0],
                worst[1], e_worst);
}

// Round-off bounds: positions ~1e-3 m and speeds ~0.1 m/s carry 1e-19 m and 1e-17 m/s of
// rounding per operation; collisions amplify a difference by a factor of a few each (granular
// gases are chaotic). Measured after 40 sub-iterations on 1-3 ranks: 1.5e-16 m, 2.4e-12 m/s and
// 1e-13 relative energy (dense gas); the bounds leave a factor ~50-100 and stay far below any
// physical difference (a missed collision changes a velocity by ~0.1 m/s, the energy by percent).
constexpr double kPos = 1e-14, kVel = 1e-10, kEnergy = 1e-11;

TEST(DistributedIslands, DenseGasMatchesOneRankToRoundOff) {
  const Scene scene = scene_from(kGas);
  const Outcome d = on_ranks(scene, kSubits, 1);
  const Outcome s = one_rank(scene, kSubits);
  expect_close(scene, s, d, kPos, kVel, kEnergy, "dense gas");
  EXPECT_EQ(d.bound_violations, 0);
  EXPECT_GT(d.max_overlap_ratio, 0.0);
  EXPECT_GT(d.global_subits, 0); // the dense mode: every particle on the fine steps
}

TEST(DistributedIslands, HcsSmallMatchesOneRankToRoundOff) {
  const Scene scene = scene_from(kGas, {"domain.hi=[1.737e-3, 1.737e-3, 1.737e-3]",
                                        "particles.count=100", "particles.temperature=0.01",
                                        "particles.seed=3", "dem.regrid_interval=1.0e-4"});
  // 4 ms: collisions, and on several ranks islands across them.
  const int subits = 200;
  const Outcome d = on_ranks(scene, subits, 1);
  expect_close(scene, one_rank(scene, subits), d, kPos, kVel, kEnergy, "HCS small");
  EXPECT_EQ(d.bound_violations, 0);
  EXPECT_GT(d.max_overlap_ratio, 0.0);
  if (Communicator::world().size() > 1) {
    EXPECT_GT(d.spanning_subits, 0);
  }
}

TEST(DistributedIslands, WalledBoxWithGravityMatchesOneRankToRoundOff) {
  const Scene scene = scene_from(kWalls);
  const Outcome d = on_ranks(scene, kSubits, 1);
  expect_close(scene, one_rank(scene, kSubits), d, kPos, kVel, kEnergy, "walls and gravity");
  EXPECT_EQ(d.bound_violations, 0);
}

// Friction (tangential springs with history, spins, wall friction): R ranks route each record
// with its owner particle and refresh the ghosts' spins, so they agree with one rank to the same
// round-off; a spin w ~ v / r carries the velocities' rounding over a radius (50 um), hence the
// bound kVel / r on |dw|. The histories enter the islands' energies on every rank count alike
// (no bound is violated), and a rerun on two threads is bitwise the one-thread run.
TEST(DistributedIslands, FrictionMatchesOneRankToRoundOff) {
  const Communicator c = Communicator::world();
  // The dense gas and the bed run in the dense mode; the dilute gas (HcsSmallMatchesOneRank's)
  // in islands, some of them spanning ranks on R > 1.
  auto dilute = [](bool friction) {
    return friction ? scene_from(kGas, {"domain.hi=[1.737e-3, 1.737e-3, 1.737e-3]",
                                        "particles.count=100", "particles.temperature=0.01",
                                        "particles.seed=3", "dem.regrid_interval=1.0e-4",
                                        "dem.friction=0.3", "dem.wall_friction=0.2"})
                    : scene_from(kGas, {"domain.hi=[1.737e-3, 1.737e-3, 1.737e-3]",
                                        "particles.count=100", "particles.temperature=0.01",
                                        "particles.seed=3", "dem.regrid_interval=1.0e-4"});
  };
  struct Case {
    Scene with, without;
    const char* what;
  };
  const Case cases[] = {{scene_from(kGas, {"dem.friction=0.3", "dem.wall_friction=0.2"}),
                         scene_from(kGas), "frictional dense gas"},
                        {scene_from(kWalls, {"dem.friction=0.3", "dem.wall_friction=0.2"}),
                         scene_from(kWalls), "frictional walls and gravity"},
                        {dilute(true), dilute(false), "frictional dilute gas"}};
  for (const Case& cs : cases) {
    const Scene& scene = cs.with;
    const char* what = cs.what;
    const Outcome d = on_ranks(scene, kSubits, 1);
    const Outcome s = one_rank(scene, kSubits);
    expect_close(scene, s, d, kPos, kVel, kEnergy, what);
    EXPECT_EQ(d.bound_violations, 0) << what;
    EXPECT_NE(s.state, one_rank(cs.without, kSubits).state) << what << ": friction acts";
    std::array<double, 2> w{}; // worst |dw|, largest |w|
    for (const auto& [id, q] : d.spin) {
      const auto it = s.spin.find(id);
      ASSERT_NE(it, s.spin.end()) << what << ": unknown id " << id;
      for (int a = 0; a < 3; ++a)
        w[0] = std::max(w[0], std::abs(q[a] - it->second[a])),
        w[1] = std::max(w[1], std::abs(q[a]));
    }
    c.max(w);
    EXPECT_EQ(static_cast<std::int64_t>(s.spin.size()),
              c.sum(static_cast<std::int64_t>(d.spin.size())));
    EXPECT_LE(w[0], kVel / 50e-6) << what << ": spins";
    EXPECT_GT(w[1], 1.0) << what << ": friction spun the particles up";
    if (c.rank() == 0)
      std::printf("[ %s ] worst |dw| %.3g rad/s of max |w| %.3g rad/s; spanning sub-iterations "
                  "%lld, dense %lld\n",
                  what, w[0], w[1], static_cast<long long>(d.spanning_subits),
                  static_cast<long long>(d.global_subits));
    if (&cs == &cases[2]) { // islands, not the dense mode; some span ranks
      EXPECT_LT(d.global_subits, kSubits);
      if (c.size() > 1) {
        EXPECT_GT(d.spanning_subits, 0);
      }
    }
    const Outcome t = on_ranks(scene, kSubits, 2);
    EXPECT_EQ(d.state, t.state) << what << ": two threads";
    EXPECT_EQ(d.spin, t.spin) << what << ": two threads";
  }
}

TEST(DistributedIslands, ExternalForceFollowsItsParticleAndMatchesOneRank) {
  // The force set once at the start travels with each particle through the migrations and
  // enters the speed bounds.
  const Scene scene = scene_from(kWalls);
  const Outcome d = on_ranks(scene, kSubits, 1, true);
  expect_close(scene, one_rank(scene, kSubits, true), d, kPos, kVel, kEnergy, "external force");
  EXPECT_EQ(d.bound_violations, 0);
  // And it matters: without it the particles end elsewhere.
  EXPECT_NE(one_rank(scene, kSubits, true).state, one_rank(scene, kSubits).state);
}

// The link rounds after the first test only the pairs of the particles whose bound was raised
// (IslandsScheme::make_links_ranks): the same links in the same order as a scan of every row, so
// the runs are bit for bit the same, in a dilute gas whose islands grow over several rounds and
// span the ranks, with and without friction.
TEST(DistributedIslands, IncrementalLinkRoundsGiveTheFullScansRun) {
  for (const bool friction : {false, true}) {
    Scene scene = scene_from(kGas, {"domain.hi=[1.737e-3, 1.737e-3, 1.737e-3]",
                                    "particles.count=100", "particles.temperature=0.01",
                                    "particles.seed=3", "dem.regrid_interval=1.0e-4"});
    if (friction)
      scene.dem.friction = 0.3;
    const int subits = 200; // 4 ms: new links across the ranks from raised ghost bounds too
    const Outcome full = on_ranks(scene, subits, 1, false, false);
    const Outcome fast = on_ranks(scene, subits, 1, false, true);
    EXPECT_EQ(full.state, fast.state) << "friction " << friction;
    EXPECT_EQ(full.kinetic_energy, fast.kinetic_energy) << "friction " << friction;
    EXPECT_EQ(full.incremental_link_rounds, 0);
    if (Communicator::world().size() > 1) {
      EXPECT_GT(fast.incremental_link_rounds, 0) << "friction " << friction;
      EXPECT_GT(fast.spanning_subits, 0) << "friction " << friction;
    }
  }
}

// In the dense mode every particle steps finely and reads its partners live, so the islands'
// raised bounds (an island's whole energy on its lightest member: about sqrt(N) x the members'
// speeds for an island of N) bound nothing, and the rows' skin follows the particles' own reach.
// A cubic lattice with gaps of 10% of a diameter, at rest but for its first plane (1/8 of the
// particles, at 0.15 m/s): over dt_sp = 50 us the plane's pairs link and no other, the plane's
// raised bound (8 x 0.15 m/s) links the planes beside it, and the second link round finds the
// dense mode (3/8 of the particles linked). Every later build's skin
// is at most the islands skin or four sub-iterations of the fastest particle (no gravity: its
// own bound is its speed) plus the link margin (1e-3 r_min). With the raised bounds the first
// sub-iteration built rows with four sub-iterations of the raised bound, 3.2 x the islands skin.
// Long sub-iterations in a box eight diameters wide: four sub-iterations of the fastest
// particle's travel (the rows' first skin) reach past what the periodic box allows a halo. One
// rank caps its skin there (periodic_skin_cap); R ranks stopped at their first rows ("not more
// than twice the distributed islands scheme's halo"), and the elutriation scene on 2 ranks after
// 4 ms. Capped too, they run as one rank does, and keep the skin under the cap.
TEST(DistributedIslands, LongSubiterationsInASmallPeriodicBoxMatchOneRank) {
  const Scene scene =
      scene_from(kGas, {"particles.count=150", "dem.regrid_interval=1.0e-4", "dem.nsubit=1"});
  const Communicator c = Communicator::world();
  const double cap = 0.499 * 0.86e-3 - 100.0e-6;
  {
    const ParticleStore all = make_initial_particles(scene);
    double v = 0.0;
    for (std::size_t i = 0; i < all.size(); ++i)
      v = std::max(
          v, std::sqrt(all.vx[i] * all.vx[i] + all.vy[i] * all.vy[i] + all.vz[i] * all.vz[i]));
    ASSERT_GT(4.0 * v * scene.dem.regrid_interval, cap); // the case this test is about
  }
  // 0.4 ms, as the dense gas above runs: the round-off bounds are for that horizon.
  const int subits = 4;
  const Outcome d = on_ranks(scene, subits, 1);
  expect_close(scene, one_rank(scene, subits), d, kPos, kVel, kEnergy, "small periodic box");
  EXPECT_EQ(d.bound_violations, 0);
  // A hundred times the temperature: a sub-iteration's travel (up to the box's width) no longer
  // fits under the cap. R ranks' dense mode steps a whole sub-iteration on rows built at its
  // start, so every rank stops alike and says what to change; one rank's dense mode rebuilds its
  // list inside the sub-iteration and runs on.
  if (c.size() > 1) {
    const Scene hot = scene_from(kGas, {"particles.count=150", "dem.regrid_interval=1.0e-4",
                                        "dem.nsubit=1", "particles.temperature=5.0"});
    std::string what = "no stop";
    try {
      on_ranks(hot, subits, 1);
    } catch (const RunError& e) {
      what = e.what();
    }
    EXPECT_NE(what.find("the periodic box allows"), std::string::npos) << what;
    EXPECT_NE(what.find("raise dem.nsubit or run on one rank"), std::string::npos) << what;
  }
}

TEST(DistributedIslands, DenseModeRowsFollowTheParticlesOwnReach) {
  constexpr int kSide = 8;
  constexpr double kD = 100.0e-6, kGap = 0.1 * kD, kA = kD + kGap, kL = kSide * kA;
  Scene scene = scene_from(kGas, {fmt::format("domain.hi=[{0}, {0}, {0}]", kL),
                                  fmt::format("particles.count={}", kSide * kSide * kSide),
                                  "particles.temperature=0.0", "particles.placement=\"lattice\"",
                                  "dem.regrid_interval=1.0e-4", "dem.nsubit=2"});
  ParticleStore all = make_initial_particles(scene);
  ASSERT_EQ(all.size(), static_cast<std::size_t>(kSide * kSide * kSide));
  std::mt19937_64 rng(7);
  std::normal_distribution<double> gauss;
  for (std::size_t n = 0; n < all.size(); ++n) {
    const auto i = static_cast<int>(n) % kSide, j = static_cast<int>(n) / kSide % kSide,
               k = static_cast<int>(n) / (kSide * kSide);
    all.x[n] = (i + 0.5) * kA, all.y[n] = (j + 0.5) * kA, all.z[n] = (k + 0.5) * kA;
    all.vx[n] = all.vy[n] = all.vz[n] = 0.0;
    if (i == 0) {
      const double ux = gauss(rng), uy = gauss(rng), uz = gauss(rng);
      const double u = 0.15 / std::sqrt(ux * ux + uy * uy + uz * uz);
      all.vx[n] = u * ux, all.vy[n] = u * uy, all.vz[n] = u * uz;
    }
  }
  const Communicator c = Communicator::world();
  ParticleStore p = share(all, c.rank(), c.size());
  PhaseTimer timer;
  dem::IslandsScheme s(scene, p, dem::make_step_model(scene, all), &c, timer);
  s.start();
  const double dt_sp = scene.dem.regrid_interval / static_cast<double>(scene.dem.nsubit);
  const double margin = 1e-3 * 0.5 * kD;
  auto fastest = [&] {
    double v = 0.0;
    for (std::size_t i = 0; i < s.owned(); ++i)
      v = std::max(v, std::sqrt(p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i]));
    return c.max(v);
  };
  const double skin0 = s.skin(); // the islands skin
  double v_max = fastest();
  int checked = 0;
  for (int k = 0; k < 20; ++k) {
    const std::int64_t dense0 = s.global_subiterations();
    s.subiterate();
    if (s.global_subiterations() > dense0) {
      EXPECT_LE(s.skin(), std::max(skin0, 4.0 * v_max * dt_sp + 2.0 * margin) * (1.0 + 1e-12))
          << "sub-iteration " << k;
      ++checked;
    }
    v_max = std::max(v_max, fastest());
  }
  EXPECT_GE(checked, 10); // the dense mode, mostly
  EXPECT_EQ(s.retries(), 0);
}

TEST(DistributedIslands, RerunAndThreadCountsAreBitwiseIdentical) {
  const Scene scene = scene_from(kGas);
  const Outcome a = on_ranks(scene, kSubits, 1);
  const Outcome b = on_ranks(scene, kSubits, 1);
  const Outcome c = on_ranks(scene, kSubits, 2);
  EXPECT_EQ(a.state, b.state);
  EXPECT_EQ(a.state, c.state);
  EXPECT_EQ(a.kinetic_energy, c.kinetic_energy);
}

// A checkpoint between sub-iterations: save_state() (the canonical state) restored on a fresh
// scheme over the same owned particles goes on bitwise as the run that wrote it, on one rank with
// a communicator (the store in id order, the list rebuilt) and on R ranks (ownership and rows
// rebuilt).
TEST(DistributedIslands, RestartFromSavedStateIsBitwiseTheRunThatWroteIt) {
  for (const Scene& scene :
       {scene_from(kGas), scene_from(kWalls),
        scene_from(kGas, {"dem.friction=0.3", "dem.wall_friction=0.2"}),
        scene_from(kWalls, {"dem.friction=0.3", "dem.wall_friction=0.2"}),
        // islands (spanning ranks on R > 1) with friction
        scene_from(kGas, {"domain.hi=[1.737e-3, 1.737e-3, 1.737e-3]", "particles.count=100",
                          "particles.temperature=0.01", "particles.seed=3",
                          "dem.regrid_interval=1.0e-4", "dem.friction=0.3"})}) {
    const Communicator c = Communicator::world();
    const ParticleStore all = make_initial_particles(scene);
    const dem::StepModel model = dem::make_step_model(scene, all);
    ParticleStore p = share(all, c.rank(), c.size());
    PhaseTimer timer;
    dem::IslandsScheme a(scene, p, model, &c, timer);
    a.start();
    for (int k = 0; k < kSubits / 2; ++k)
      a.subiterate();
    dem::IslandsScheme::State saved = a.save_state();
    EXPECT_TRUE(saved.offsets.empty()); // no list: the next sub-iteration builds one
    ParticleStore q = p;
    q.resize(a.owned());
    dem::IslandsScheme b(scene, q, model, &c, timer);
    b.restore_state(std::move(saved));
    for (int k = 0; k < kSubits / 2; ++k) {
      a.subiterate(k + 1 == kSubits / 2);
      b.subiterate(k + 1 == kSubits / 2);
    }
    EXPECT_EQ(state_of(p, a.owned()), state_of(q, b.owned()));
    EXPECT_EQ(spins_of(p, a.owned()), spins_of(q, b.owned()));
    EXPECT_EQ(a.particle_steps(), b.particle_steps());
    EXPECT_EQ(a.pair_evaluations(), b.pair_evaluations());
    EXPECT_EQ(a.max_overlap_ratio(), b.max_overlap_ratio());
    EXPECT_GT(a.pair_evaluations(), 0);
    EXPECT_EQ(a.bound_violations(), 0);
  }
}

TEST(DistributedIslands, ParticleThroughAWallStopsEveryRankWithTheSameError) {
  demtest::expect_shot_through_a_wall_stops_every_rank<dem::IslandsScheme>(scene_from(kWalls),
                                                                          kSubits, 7, "islands");
}

} // namespace
} // namespace cfddem
