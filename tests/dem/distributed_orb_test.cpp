// The orb scheme over MPI ranks (run under mpirun -np 1, 2 and 3): one rank equals R ranks. With
// the same leaves (the parallel ORB builds the one-rank ORB's boxes) and rows summed in the
// one-rank order, every particle's position and velocity on R ranks equal the one-rank
// OrbScheme's (no communicator) bit for bit, for any rank and thread count; no particle or mass
// is lost at any sub-iteration. The global mode (every particle on the fine steps, each pair
// once) agrees with one rank's to round-off, takes the same sub-iterations global, and is bitwise
// the same on any thread count.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <random>
#include <set>
#include <string>
#include <utility>

#include <tbb/global_control.h>

#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"
#include "core/particle_exchange.hpp"
#include "core/phase_timer.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/orb_scheme.hpp"
#include "distributed_test_support.hpp"

namespace cfddem {
namespace {

using demtest::apply_force;
using demtest::force_of;
using demtest::scene_from;
using demtest::share;

// A dense granular gas (phi ~ 0.25: collisions within a few sub-iterations, every leaf fine) in a
// periodic box, 8 leaves; kHcs below is the dilute, HCS-like variant where leaves differ.
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
scheme = "orb"
spring_constant = 10.0
restitution = 0.8
max_overlap = 0.9
regrid_interval = 5.0e-5
nsubit = 5
[partition]
orb_levels = 3
[run]
end_time = 1.0e-3
)";

// HCS-like: phi ~ 1.5 %, 16 leaves of ~19 particles; some leaves take the fine step, some not.
const char* kHcs = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [2.2e-3, 2.2e-3, 2.2e-3]
periodic = [true, true, true]
[particles]
count = 300
diameter = 100.0e-6
density = 1000.0
temperature = 0.1
seed = 7
[dem]
scheme = "orb"
spring_constant = 10.0
restitution = 0.8
regrid_interval = 1.0e-4
nsubit = 5
[partition]
orb_levels = 4
[run]
end_time = 1.0e-3
)";

// Walls on every side and gravity along -y (100 g): wall contacts and the wall proximity rule.
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
scheme = "orb"
spring_constant = 10.0
restitution = 0.7
wall_restitution = 0.9
max_overlap = 0.9
regrid_interval = 5.0e-5
nsubit = 5
[partition]
orb_levels = 3
[run]
end_time = 1.0e-3
)";

constexpr int kSubits = 40; // 8 regrids, a few hundred collisions in the gas

using State = std::map<std::int64_t, std::array<double, 6>>;

// The one-rank run. By default the leaf steps, which R ranks take bit for bit alike
// (dem.orb_global = false; OrbScheme::kGlobalFraction); `global`: the global mode allowed, its
// sub-iterations counted into `global_subits`, the leaves' steps over the run into `leaf_steps`.
State one_rank_orb(const Scene& leaf_scene, int subits, bool external = false,
                   bool global = false, std::int64_t* global_subits = nullptr,
                   dem::LeafStepStats* leaf_steps = nullptr) {
  Scene scene = leaf_scene;
  scene.dem.orb_global = global;
  ParticleStore p = make_initial_particles(scene);
  PhaseTimer timer;
  dem::OrbScheme s(scene, p, timer);
  s.start();
  if (external)
    apply_force(p, p.size(), s);
  for (int k = 0; k < subits; ++k)
    s.subiterate();
  if (global_subits)
    *global_subits = s.global_subiterations();
  if (leaf_steps)
    *leaf_steps = s.take_interval_stats();
  State out;
  for (std::size_t i = 0; i < p.size(); ++i)
    out[p.id[i]] = {p.x[i], p.y[i], p.z[i], p.vx[i], p.vy[i], p.vz[i]};
  return out;
}

struct DistributedRun {
  State owned; // this rank's particles at the end
  double fine_fraction = 0.0, max_overlap_ratio = 0.0;
  std::int64_t pair_evaluations = 0, particle_steps = 0, retries = 0, global_subits = 0;
  std::int64_t builds = 0; // exchanges and rows built (the global mode keeps some)
  dem::LeafStepStats leaf_steps;
};

// The one-rank run with the global mode allowed: its particles and global sub-iterations.
std::pair<State, std::int64_t> one_rank_global(const Scene& scene, int subits) {
  std::int64_t global_subits = 0;
  State out = one_rank_orb(scene, subits, false, true, &global_subits);
  return {out, global_subits};
}

// The scheme over the world communicator on `threads` TBB threads; at every sub-iteration the
// particles over all ranks are counted and identified (count, sum of ids, sum of squared ids: none
// lost, none twice) and their total mass compared with the initial one.
// `global`: dem.orb_global (false: the leaf steps, which equal one rank's bit for bit), with
// dem.orb_global_min_per_rank = `min_per_rank` (0: the global mode on any rank count).
DistributedRun distributed_orb(const Scene& leaf_scene, int subits, int threads,
                               bool external = false, bool global = false,
                               std::int64_t min_per_rank = 0) {
  Scene scene = leaf_scene;
  scene.dem.orb_global = global;
  scene.dem.orb_global_min_per_rank = min_per_rank;
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(threads));
  const Communicator c = Communicator::world();
  const ParticleStore all = make_initial_particles(scene);
  ParticleStore p = share(all, c.rank(), c.size());
  const dem::StepModel model = dem::make_step_model(scene, all);
  PhaseTimer timer;
  dem::OrbScheme s(scene, p, model, &c, timer);
  s.start();
  if (external)
    apply_force(p, s.owned(), s);
  std::array<std::int64_t, 3> expect{};
  for (const std::int64_t id : all.id)
    expect[0] += 1, expect[1] += id, expect[2] += id * id;
  const double mass0 = all.total_mass();
  DistributedRun r;
  for (int k = 0; k < subits; ++k) {
    s.subiterate(k + 1 == subits); // the last one recorded: max_overlap_ratio over the ranks
    std::array<std::int64_t, 3> got{};
    double mass = 0.0;
    for (std::size_t i = 0; i < s.owned(); ++i)
      got[0] += 1, got[1] += p.id[i], got[2] += p.id[i] * p.id[i], mass += p.mass[i];
    c.sum(got);
    c.sum(std::span<double>(&mass, 1));
    EXPECT_EQ(got, expect) << "sub-iteration " << k;
    // Equal masses summed in another order: N eps relative at most (300 x 1.1e-16).
    EXPECT_NEAR(mass, mass0, 1e-13 * mass0) << "sub-iteration " << k;
    // On several ranks the leaves do read other ranks' particles (ghosts).
    if (c.size() > 1) {
      EXPECT_GT(c.sum(static_cast<std::int64_t>(s.ghosts())), 0);
    }
  }
  for (std::size_t i = 0; i < s.owned(); ++i)
    r.owned[p.id[i]] = {p.x[i], p.y[i], p.z[i], p.vx[i], p.vy[i], p.vz[i]};
  r.leaf_steps = s.take_interval_stats();
  r.fine_fraction = r.leaf_steps.fine_fraction;
  r.builds = s.neighbor_builds();
  r.pair_evaluations = s.pair_evaluations();
  r.max_overlap_ratio = s.max_overlap_ratio();
  r.retries = s.retries();
  r.particle_steps = s.particle_steps();
  r.global_subits = s.global_subiterations();
  return r;
}

// Every owned particle of every rank against the one-rank scheme: bitwise (the bound is 0).
void expect_bitwise(const State& one_rank, const State& mine, const std::string& what) {
  const Communicator c = Communicator::world();
  std::int64_t count = static_cast<std::int64_t>(mine.size()), differ = 0;
  double worst = 0.0;
  for (const auto& [id, q] : mine) {
    const auto it = one_rank.find(id);
    ASSERT_NE(it, one_rank.end()) << what << ": unknown id " << id;
    for (int a = 0; a < 6; ++a) {
      if (q[a] != it->second[a])
        ++differ;
      worst = std::max(worst, std::abs(q[a] - it->second[a]));
    }
  }
  count = c.sum(count);
  differ = c.sum(differ);
  worst = c.max(worst);
  EXPECT_EQ(count, static_cast<std::int64_t>(one_rank.size())) << what;
  EXPECT_EQ(differ, 0) << what << ": " << differ << " coordinates differ, worst by " << worst;
}

TEST(DistributedOrb, DenseGasMatchesOneRankBitwise) {
  const Scene scene = scene_from(kGas);
  const DistributedRun d = distributed_orb(scene, kSubits, 1);
  expect_bitwise(one_rank_orb(scene, kSubits), d.owned, "dense gas");
  EXPECT_GT(d.max_overlap_ratio, 0.0); // particles collided
}

TEST(DistributedOrb, BoxOfTwoCellsMatchesOneRankBitwise) {
  // Two cells of the cutoff per axis: the rows come from the full stencil, images collapsed.
  const Scene scene = scene_from(
      kGas, {"domain.hi=[0.4e-3, 0.4e-3, 0.4e-3]", "particles.count=20", "partition.orb_levels=2"});
  expect_bitwise(one_rank_orb(scene, kSubits), distributed_orb(scene, kSubits, 1).owned,
                 "box of two cells");
}

TEST(DistributedOrb, HcsMatchesOneRankBitwise) {
  const Scene scene = scene_from(kHcs);
  const DistributedRun d = distributed_orb(scene, kSubits, 1);
  expect_bitwise(one_rank_orb(scene, kSubits), d.owned, "HCS");
  // Collisions, and leaves on both steps: the local steps do differ between leaves.
  EXPECT_GT(d.max_overlap_ratio, 0.0);
  EXPECT_GT(d.fine_fraction, 0.0);
  EXPECT_LT(d.fine_fraction, 1.0);
  EXPECT_GT(d.pair_evaluations, 0);
}

TEST(DistributedOrb, RetriesWithLongSubiterationsMatchOneRankBitwise) {
  // dt_sp = 50 us: fine leaves outrun their rows and redo sub-iterations with a larger skin.
  const Scene scene = scene_from(
      kHcs, {"dem.regrid_interval=2.0e-4", "dem.nsubit=4", "particles.temperature=0.05"});
  const DistributedRun d = distributed_orb(scene, kSubits, 1);
  expect_bitwise(one_rank_orb(scene, kSubits), d.owned, "retries");
  EXPECT_GT(d.retries, 0);
}

TEST(DistributedOrb, CostWeightsMatchOneRankBitwise) {
  // Integer weights (local steps) sum exactly, so the parallel ORB cuts where the one-rank one
  // does.
  const Scene scene = scene_from(kHcs, {"partition.weights=\"cost\""});
  expect_bitwise(one_rank_orb(scene, kSubits), distributed_orb(scene, kSubits, 1).owned,
                 "gas, cost weights");
}

TEST(DistributedOrb, WallsAndGravityMatchOneRankBitwise) {
  const Scene scene = scene_from(kWalls);
  expect_bitwise(one_rank_orb(scene, kSubits), distributed_orb(scene, kSubits, 1).owned,
                 "walls and gravity");
}

TEST(DistributedOrb, ExternalForceFollowsItsParticleAndMatchesOneRankBitwise) {
  // The force set once at the start travels with each particle through 8 regrids and their
  // migrations; with time_to_contact it also enters the speed bounds.
  for (const char* rule : {"proximity", "time_to_contact"}) {
    const Scene scene = scene_from(kWalls, {std::string("dem.local_dt=\"") + rule + "\""});
    expect_bitwise(one_rank_orb(scene, kSubits, true),
                   distributed_orb(scene, kSubits, 1, true).owned,
                   std::string("external force, ") + rule);
  }
  // And it matters: without it the particles end elsewhere.
  const Scene scene = scene_from(kWalls);
  EXPECT_NE(one_rank_orb(scene, kSubits, true), one_rank_orb(scene, kSubits, false));
}

TEST(DistributedOrb, TimeToContactMatchesOneRankBitwise) {
  const Scene scene = scene_from(kWalls, {"dem.local_dt=\"time_to_contact\""});
  expect_bitwise(one_rank_orb(scene, kSubits), distributed_orb(scene, kSubits, 1).owned,
                 "time_to_contact");
}

// Every owned particle of every rank against the one-rank run to round-off: positions within
// `pos` (m, through a periodic face either way), velocities within `vel` (m/s).
void expect_close(const Scene& scene, const State& one_rank, const State& mine, double pos,
                  double vel, const std::string& what) {
  std::int64_t count = 0;
  const std::array<double, 2> worst = demtest::worst_differences(scene, one_rank, mine, count, what);
  EXPECT_EQ(count, static_cast<std::int64_t>(one_rank.size())) << what;
  EXPECT_LE(worst[0], pos) << what << ": positions";
  EXPECT_LE(worst[1], vel) << what << ": velocities";
  if (Communicator::world().rank() == 0)
    std::printf("[ %s ] worst |dx| %.3g m, |dv| %.3g m/s\n", what.c_str(), worst[0], worst[1]);
}

// Round-off bounds of the global mode against one rank's (the pair sums run in another order;
// the dense gas is chaotic and collisions amplify a difference a few times each): the bounds of
// the distributed islands scheme's dense mode on the same gas (tests/dem/distributed_islands_test
// .cpp, measured 1.5e-16 m and 2.4e-12 m/s there), far below a physical difference (a missed
// collision changes a velocity by ~0.1 m/s).
constexpr double kPos = 1e-14, kVel = 1e-10;

TEST(DistributedOrb, GlobalModeMatchesOneRankToRoundOff) {
  // The dense gas: every leaf fine, every sub-iteration global, on one rank and on R ranks alike.
  const Scene scene = scene_from(kGas);
  std::int64_t one_global = 0;
  dem::LeafStepStats one_steps;
  const State one = one_rank_orb(scene, kSubits, false, true, &one_global, &one_steps);
  const DistributedRun d = distributed_orb(scene, kSubits, 1, false, true);
  EXPECT_GT(one_global, 0);
  EXPECT_EQ(d.global_subits, one_global);
  EXPECT_GT(d.max_overlap_ratio, 0.0); // particles collided
  // R ranks keep the rows and ghosts over the global sub-iterations of an interval
  // (OrbScheme::rank_keep_rows), and the leaves' steps, summed over the ranks, are one rank's:
  // none counted on two ranks when its particles stay on several.
  if (Communicator::world().size() > 1) {
    EXPECT_LT(d.builds, kSubits);
  }
  EXPECT_EQ(d.leaf_steps.steps_min, one_steps.steps_min);
  EXPECT_EQ(d.leaf_steps.steps_max, one_steps.steps_max);
  EXPECT_EQ(d.leaf_steps.steps_mean, one_steps.steps_mean);
  EXPECT_EQ(d.leaf_steps.fine_fraction, one_steps.fine_fraction);
  expect_close(scene, one, d.owned, kPos, kVel, "dense gas, global mode");
  // And the global steps are not the leaf steps (no frozen partners): the test can tell them.
  const State leaf = one_rank_orb(scene, kSubits);
  double most = 0.0;
  for (const auto& [id, q] : one)
    most = std::max(most, std::abs(q[3] - leaf.at(id)[3]));
  EXPECT_GT(most, 1e3 * kVel);
}

TEST(DistributedOrb, GlobalModeRetriesWithTwiceTheSkinAndMatchesOneRank) {
  // dt_sp = 50 us: a particle outruns the rows within a global sub-iteration; every rank redoes
  // it with twice the skin, where one rank rebuilds its pairs in the middle.
  const Scene scene =
      scene_from(kGas, {"dem.regrid_interval=2.0e-4", "dem.nsubit=4", "particles.temperature=0.1"});
  const auto [one, one_global] = one_rank_global(scene, kSubits);
  const DistributedRun d = distributed_orb(scene, kSubits, 1, false, true);
  if (Communicator::world().size() > 1) { // one rank's global steps rebuild instead of redoing
    EXPECT_GT(d.retries, 0);
  }
  EXPECT_EQ(d.global_subits, one_global);
  expect_close(scene, one, d.owned, kPos, kVel, "dense gas, global mode, retries");
}

TEST(DistributedOrb, GlobalModeWithWallsGravityAndTimeToContactMatchesOneRank) {
  // Walls on every side (near_walls from the rows' start), gravity, and with time_to_contact the
  // ghosts' speed bounds forwarded after the two-round exchange (the box's small leaves all touch
  // a wall or a partner: its sub-iterations are global on one rank and on R ranks alike).
  for (const char* rule : {"proximity", "time_to_contact"}) {
    const Scene scene = scene_from(kWalls, {std::string("dem.local_dt=\"") + rule + "\""});
    const auto [one, one_global] = one_rank_global(scene, kSubits);
    const DistributedRun d = distributed_orb(scene, kSubits, 1, false, true);
    EXPECT_GT(one_global, 0) << rule;
    EXPECT_EQ(d.global_subits, one_global) << rule;
    expect_close(scene, one, d.owned, kPos, kVel, std::string("walls, global mode, ") + rule);
  }
}

TEST(DistributedOrb, FewParticlesPerRankKeepTheLeafSteps) {
  // 300 particles, below dem.orb_global_min_per_rank's 10^4 per rank: R ranks keep the leaf steps
  // (bit for bit one rank's with dem.orb_global = false); one rank takes the global mode.
  const Scene scene = scene_from(kGas);
  const DistributedRun d = distributed_orb(scene, kSubits, 1, false, true, 10000);
  if (Communicator::world().size() > 1) {
    EXPECT_EQ(d.global_subits, 0);
    expect_bitwise(one_rank_orb(scene, kSubits), d.owned, "few particles per rank");
  } else {
    EXPECT_GT(d.global_subits, 0);
  }
}

TEST(DistributedOrb, GlobalModeIsBitwiseTheSameOnAnyThreadCount) {
  const Scene scene = scene_from(kGas);
  const DistributedRun a = distributed_orb(scene, kSubits, 1, false, true);
  const DistributedRun b = distributed_orb(scene, kSubits, 2, false, true);
  EXPECT_GT(a.global_subits, 0);
  EXPECT_EQ(a.owned, b.owned);
  EXPECT_EQ(a.pair_evaluations, b.pair_evaluations);
}

TEST(DistributedOrb, RerunAndThreadCountsAreBitwiseIdentical) {
  const Scene scene = scene_from(kHcs);
  const DistributedRun a = distributed_orb(scene, kSubits, 1);
  const DistributedRun b = distributed_orb(scene, kSubits, 1);
  const DistributedRun c = distributed_orb(scene, kSubits, 2);
  EXPECT_EQ(a.owned, b.owned);
  EXPECT_EQ(a.owned, c.owned);
  EXPECT_EQ(a.pair_evaluations, c.pair_evaluations);
  EXPECT_EQ(a.particle_steps, c.particle_steps);
}

TEST(DistributedOrb, ParticleThroughAWallStopsEveryRankWithTheSameError) {
  // The leaf steps (R ranks below dem.orb_global_min_per_rank) and the global mode alike.
  for (const std::int64_t min_per_rank : {std::int64_t{10000}, std::int64_t{0}}) {
    Scene scene = scene_from(kWalls);
    scene.dem.orb_global_min_per_rank = min_per_rank;
    demtest::expect_shot_through_a_wall_stops_every_rank<dem::OrbScheme>(
        scene, kSubits, 7, "min_per_rank " + std::to_string(min_per_rank));
  }
}

// Friction over R ranks: the tangential history travels by particle ids with its owner (routed
// at every sub-iteration's exchange), ghosts carry their spins: with contacts sliding and
// sticking among the particles and on the walls, every rank's particles equal the one-rank run's
// bit for bit (x and v: the spins and histories act through them), at 1 and 2 threads.
TEST(DistributedOrb, FrictionMatchesOneRankBitwise) {
  const Scene scene = scene_from(kWalls, {"dem.friction=0.3", "dem.wall_friction=0.2"});
  const State one = one_rank_orb(scene, kSubits);
  EXPECT_NE(one, one_rank_orb(scene_from(kWalls), kSubits)) << "friction must act";
  expect_bitwise(one, distributed_orb(scene, kSubits, 1).owned, "friction");
  expect_bitwise(one, distributed_orb(scene, kSubits, 2).owned, "friction, 2 threads");
}

// ParticleExchange::redistribute: each particle reaches its new owner once, each ghost copy the
// ranks named for it (this rank included, for a leaver), with every field and extra column.
TEST(ParticleExchange, RedistributeMovesOwnersAndCopiesGhostsWithTheirColumns) {
  const Communicator c = Communicator::world();
  const ParticleStore all = make_initial_particles(scene_from(kGas));
  ParticleStore p = share(all, c.rank(), c.size());
  const auto ranks = static_cast<std::uint64_t>(c.size());
  // Owner and ghost ranks drawn by id, the same on every rank.
  std::mt19937_64 rng(3);
  std::vector<int> owner(all.size());
  std::vector<std::set<int>> ghost(all.size());
  for (std::size_t i = 0; i < all.size(); ++i) {
    owner[i] = static_cast<int>(rng() % ranks);
    for (std::uint64_t r = 0; r < ranks; ++r)
      if (static_cast<int>(r) != owner[i] && rng() % 3 == 0)
        ghost[i].insert(static_cast<int>(r));
  }
  std::vector<int> dest(p.size());
  std::vector<ParticleExchange::Copy> copies;
  std::vector<double> half(p.size()), cost(p.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    const auto id = static_cast<std::size_t>(p.id[i]);
    dest[i] = owner[id];
    for (const int r : ghost[id])
      copies.push_back({r, static_cast<std::uint32_t>(i), {}});
    half[i] = 0.5 * static_cast<double>(id), cost[i] = 3.0 * static_cast<double>(id);
  }
  ParticleExchange ex(c);
  std::vector<double>* extra[] = {&half, &cost};
  const std::size_t owned = ex.redistribute(p, dest, copies, extra);
  ASSERT_EQ(half.size(), p.size());
  ASSERT_EQ(cost.size(), p.size());
  std::set<std::int64_t> own_ids, ghost_ids;
  for (std::size_t i = 0; i < p.size(); ++i) {
    const auto id = static_cast<std::size_t>(p.id[i]);
    (i < owned ? own_ids : ghost_ids).insert(p.id[i]);
    if (i < owned) {
      EXPECT_EQ(owner[id], c.rank()) << "id " << id;
    } else {
      EXPECT_EQ(ghost[id].count(c.rank()), 1U) << "id " << id;
    }
    EXPECT_EQ(p.x[i], all.x[id]);
    EXPECT_EQ(p.vz[i], all.vz[id]);
    EXPECT_EQ(p.mass[i], all.mass[id]);
    EXPECT_EQ(half[i], 0.5 * static_cast<double>(id));
    EXPECT_EQ(cost[i], 3.0 * static_cast<double>(id));
  }
  std::size_t expect_own = 0, expect_ghost = 0;
  for (std::size_t i = 0; i < all.size(); ++i)
    expect_own += owner[i] == c.rank(), expect_ghost += ghost[i].count(c.rank());
  EXPECT_EQ(own_ids.size(), expect_own);
  EXPECT_EQ(owned, expect_own);
  EXPECT_EQ(ghost_ids.size(), expect_ghost);
  EXPECT_EQ(p.size() - owned, expect_ghost);
}

} // namespace
} // namespace cfddem
