// The explicit scheme over MPI ranks (run under mpirun -np 2 and 3): particles reach their
// owners, ghosts are exactly the brute-force halo set, and a gas and a walled, gravity-driven
// box advance as the serial ExplicitScheme does, to round-off, with no particle lost.
#include <gtest/gtest.h>
#include <mpi.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <tuple>

#include <tbb/global_control.h>

#include "core/cell_box.hpp"
#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"
#include "core/particle_exchange.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/granular_diagnostics.hpp"
#include "dem/verlet_list.hpp"
#include "distributed_test_support.hpp"
#include "partition/cell_box_decomposition.hpp"

namespace cfddem {
namespace {

using demtest::run_explicit_with_threads;
using demtest::scene_from;
using demtest::share;

// A dense granular gas (phi ~ 0.25, so particles collide within a few hundred steps) in a
// periodic box. max_overlap is raised: the fastest pairs of the tail overlap more than 0.3 r.
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
spring_constant = 10.0
restitution = 0.8
max_overlap = 0.9
regrid_interval = 2.0e-6
[run]
end_time = 1.0e-3
)";

// Walls on every side, gravity along -y (100 g, so it shows within the run).
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
spring_constant = 10.0
restitution = 0.7
wall_restitution = 0.9
max_overlap = 0.9
regrid_interval = 2.0e-6
[run]
end_time = 1.0e-3
)";

Communicator comm() {
  return Communicator::world();
}

std::map<std::int64_t, std::size_t> index_by_id(const ParticleStore& p, std::size_t n) {
  std::map<std::int64_t, std::size_t> m;
  for (std::size_t i = 0; i < n; ++i)
    m[p.id[i]] = i;
  return m;
}

TEST(ParticleExchange, MigrationMovesEveryParticleWithAllItsFields) {
  const Communicator c = comm();
  const Scene scene = scene_from(kGas);
  const ParticleStore all = make_initial_particles(scene);
  ParticleStore p = share(all, c.rank(), c.size());
  // A random owner per particle, the same on every rank (drawn by global index).
  std::mt19937_64 rng(42);
  std::vector<int> owner_of_id(all.size());
  for (auto& o : owner_of_id)
    o = static_cast<int>(rng() % static_cast<std::uint64_t>(c.size()));
  std::vector<int> dest(p.size());
  for (std::size_t i = 0; i < p.size(); ++i)
    dest[i] = owner_of_id[static_cast<std::size_t>(p.id[i])];
  ParticleExchange ex(c);
  ex.migrate(p, dest);
  std::size_t expected = 0;
  for (const int o : owner_of_id)
    expected += o == c.rank() ? 1 : 0;
  EXPECT_EQ(p.size(), expected);
  const auto by_id = index_by_id(all, all.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    ASSERT_EQ(owner_of_id[static_cast<std::size_t>(p.id[i])], c.rank()) << "id " << p.id[i];
    const std::size_t j = by_id.at(p.id[i]);
    EXPECT_EQ(std::tie(p.x[i], p.y[i], p.z[i], p.vx[i], p.vy[i], p.vz[i]),
              std::tie(all.x[j], all.y[j], all.z[j], all.vx[j], all.vy[j], all.vz[j]));
    EXPECT_EQ(std::tie(p.radius[i], p.mass[i], p.inv_mass[i]),
              std::tie(all.radius[j], all.mass[j], all.inv_mass[j]));
  }
  EXPECT_EQ(c.sum(static_cast<std::int64_t>(p.size())), static_cast<std::int64_t>(all.size()));
}

// After start() (positions unchanged, wrapped): each rank owns the particles its boxes hold, and
// its ghosts are exactly every image p + s L (s in {-1, 0, 1}^3 on periodic axes) within the
// halo of one of its boxes, other than its own particles' identity images.
void expect_owners_and_ghosts(const char* toml) {
  const Communicator c = comm();
  if (c.size() == 1)
    GTEST_SKIP() << "one rank owns every particle and keeps no ghost (minimum image)";
  const Scene scene = scene_from(toml);
  ParticleStore all = make_initial_particles(scene);
  const dem::StepModel model = dem::make_step_model(scene, all);
  ParticleStore p = share(all, c.rank(), c.size());
  PhaseTimer timer;
  dem::ExplicitScheme s(scene, p, model, &c, timer);
  s.start();
  const auto& d = s.decomposition();
  for (std::size_t i = 0; i < s.owned(); ++i)
    ASSERT_EQ(d.owner_of(p.x[i], p.y[i], p.z[i]), c.rank()) << "particle " << p.id[i];
  EXPECT_EQ(c.sum(static_cast<std::int64_t>(s.owned())), static_cast<std::int64_t>(all.size()));

  const dem::DomainGeometry g(scene.domain);
  double r_max = 0.0;
  for (const double r : all.radius)
    r_max = std::max(r_max, r);
  const double h = 2.0 * r_max + model.skin;
  using Ghost = std::tuple<std::int64_t, double, double, double>;
  std::vector<Ghost> expected, actual;
  const auto leaves = d.tree.leaves();
  for (std::size_t j = 0; j < all.size(); ++j) {
    const double q[3] = {g.wrap(all.x[j], 0), g.wrap(all.y[j], 1), g.wrap(all.z[j], 2)};
    const int home = d.owner_of(q[0], q[1], q[2]);
    for (int sz = -1; sz <= 1; ++sz)
      for (int sy = -1; sy <= 1; ++sy)
        for (int sx = -1; sx <= 1; ++sx) {
          const int sh[3] = {sx, sy, sz};
          bool ok = true;
          std::array<double, 3> im{};
          for (int a = 0; a < 3; ++a) {
            ok = ok && (g.periodic[a] || sh[a] == 0);
            im[a] = q[a] + sh[a] * g.length[a];
          }
          if (!ok || (home == c.rank() && sx == 0 && sy == 0 && sz == 0))
            continue;
          bool near = false;
          for (std::size_t l = 0; l < leaves.size() && !near; ++l)
            near = d.owner[l] == c.rank() && leaves[l].box.grown(h).contains_closed(im);
          if (near)
            expected.emplace_back(all.id[j], im[0], im[1], im[2]);
        }
  }
  for (std::size_t i = s.owned(); i < p.size(); ++i)
    actual.emplace_back(p.id[i], p.x[i], p.y[i], p.z[i]);
  std::sort(expected.begin(), expected.end());
  std::sort(actual.begin(), actual.end());
  EXPECT_EQ(actual.size(), expected.size());
  EXPECT_TRUE(actual == expected) << "rank " << c.rank();
}

TEST(DistributedGhosts, PeriodicGasGhostsEqualBruteForceHalo) {
  expect_owners_and_ghosts(kGas);
}
TEST(DistributedGhosts, WalledBoxGhostsEqualBruteForceHalo) {
  expect_owners_and_ghosts(kWalls);
}

struct Compared {
  double dx = 0.0, dv = 0.0;     // largest |x - x_serial|, |v - v_serial| over particles
  double ke = 0.0, ke_rel = 0.0; // kinetic energy (serial) and its relative difference
  double dp = 0.0;               // largest momentum component difference [kg m/s]
  double ke_loss = 0.0;          // 1 - KE/KE(0) of the serial run: the collisions' dissipation
  std::int64_t builds = 0, regrids = 0, pairs = 0;
  std::size_t max_owned = 0, local_cells = 0, serial_cells = 0;
};

// Run `steps` steps serially (every rank, whole system) and distributed; compare by id.
// Every step: the particle count and total mass over the ranks equal the initial ones.
Compared run_and_compare(const char* toml, int steps, ParticleStore* final_state = nullptr,
                         std::initializer_list<std::string> overrides = {}) {
  const Communicator c = comm();
  const Scene scene = scene_from(toml, overrides);
  ParticleStore all = make_initial_particles(scene);
  const double mass0 = all.total_mass();
  const dem::StepModel model = dem::make_step_model(scene, all);
  ParticleStore serial = all;
  PhaseTimer t1, t2;
  dem::ExplicitScheme ref(scene, serial, t1);
  ParticleStore p = share(all, c.rank(), c.size());
  dem::ExplicitScheme s(scene, p, model, &c, t2);
  ref.start();
  s.start();
  for (int k = 0; k < steps; ++k) {
    ref.step();
    s.step();
    std::array<double, 2> tot{static_cast<double>(s.owned()), 0.0};
    for (std::size_t i = 0; i < s.owned(); ++i)
      tot[1] += p.mass[i];
    c.sum(tot);
    EXPECT_EQ(tot[0], static_cast<double>(all.size())) << "step " << k;
    EXPECT_NEAR(tot[1], mass0, 1e-13 * mass0) << "step " << k;
  }
  Compared r;
  const dem::DomainGeometry g(scene.domain);
  const auto ref_index = index_by_id(serial, serial.size());
  double local[2] = {0.0, 0.0};
  for (std::size_t i = 0; i < s.owned(); ++i) {
    const std::size_t j = ref_index.at(p.id[i]);
    const double d[6] = {g.image(p.x[i] - serial.x[j], 0), g.image(p.y[i] - serial.y[j], 1),
                         g.image(p.z[i] - serial.z[j], 2), p.vx[i] - serial.vx[j],
                         p.vy[i] - serial.vy[j],           p.vz[i] - serial.vz[j]};
    for (int a = 0; a < 3; ++a)
      local[0] = std::max(local[0], std::abs(d[a]));
    for (int a = 3; a < 6; ++a)
      local[1] = std::max(local[1], std::abs(d[a]));
  }
  r.dx = c.max(local[0]);
  r.dv = c.max(local[1]);
  // Kinetic energy and momentum of the half-step velocities, summed over ranks.
  std::array<double, 4> q{0.0, 0.0, 0.0, 0.0};
  for (std::size_t i = 0; i < s.owned(); ++i) {
    q[0] += 0.5 * p.mass[i] * (p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i]);
    q[1] += p.mass[i] * p.vx[i], q[2] += p.mass[i] * p.vy[i], q[3] += p.mass[i] * p.vz[i];
  }
  c.sum(q);
  const auto sref = demtest::measure_now(serial);
  r.ke = sref.kinetic_energy;
  r.ke_loss = 1.0 - sref.kinetic_energy / demtest::measure_now(all).kinetic_energy;
  r.ke_rel = std::abs(q[0] - sref.kinetic_energy) / sref.kinetic_energy;
  for (int a = 0; a < 3; ++a)
    r.dp = std::max(r.dp, std::abs(q[1 + a] - sref.momentum[a]));
  r.builds = s.neighbor_builds();
  r.regrids = static_cast<std::int64_t>(s.regrids().size());
  r.pairs = s.pair_evaluations();
  EXPECT_EQ(s.pair_evaluations(), ref.pair_evaluations());
  EXPECT_EQ(s.particle_steps(), ref.particle_steps());
  EXPECT_EQ(s.neighbor_builds(), ref.neighbor_builds());
  std::int64_t mo = static_cast<std::int64_t>(s.owned()),
               lc = static_cast<std::int64_t>(s.local_cells());
  c.max(std::span<std::int64_t>(&mo, 1));
  c.max(std::span<std::int64_t>(&lc, 1));
  r.max_owned = static_cast<std::size_t>(mo);
  r.local_cells = static_cast<std::size_t>(lc);
  dem::VerletList global;
  ParticleStore copy = serial;
  global.build(copy, g, model.skin);
  r.serial_cells = global.cell_count();
  if (final_state)
    *final_state = p;
  return r;
}

// Round-off bound: each step's forces differ from the serial ones only in summation order
// (~1e-16 relative); collisions amplify it, over these runs by far less than 1e6. So positions
// agree to 1e-9 of a diameter and velocities to 1e-9 of the thermal speed (0.2 m/s).
constexpr double kPositionBound = 1e-9 * 100e-6;
constexpr double kVelocityBound = 1e-9 * 0.2;
constexpr int kSteps = 4000;

TEST(DistributedExplicit, GranularGasMatchesSerialScheme) {
  const Compared r = run_and_compare(kGas, kSteps);
  EXPECT_LT(r.dx, kPositionBound);
  EXPECT_LT(r.dv, kVelocityBound);
  EXPECT_LT(r.ke_rel, 1e-12);
  EXPECT_LT(r.dp, 1e-12 * std::sqrt(2.0 * r.ke * 300 * 5.2e-10));
  EXPECT_GT(r.pairs, 0);
  EXPECT_GT(r.builds, 2); // migration and ghosts rebuilt during the run
  if (comm().size() > 1) {
    EXPECT_GT(r.regrids, 1); // and the decomposition too (one rank has none)
    EXPECT_LT(r.max_owned, 300U);
  }
  if (comm().rank() == 0)
    std::printf("gas: |dx| %.3g m, |dv| %.3g m/s, KE rel %.3g, KE lost %.3g, builds %lld, "
                "regrids %lld, owned max %zu/300\n",
                r.dx, r.dv, r.ke_rel, r.ke_loss, static_cast<long long>(r.builds),
                static_cast<long long>(r.regrids), r.max_owned);
}

TEST(DistributedExplicit, WalledBoxWithGravityMatchesSerialScheme) {
  const Compared r = run_and_compare(kWalls, kSteps);
  EXPECT_LT(r.dx, kPositionBound);
  EXPECT_LT(r.dv, kVelocityBound);
  EXPECT_LT(r.ke_rel, 1e-12);
  EXPECT_GT(r.builds, 2);
  if (comm().size() > 1) {
    EXPECT_LT(r.max_owned, 250U);
    // Walls: no periodic images widen a rank's frame, so its cell grid is smaller.
    EXPECT_LT(r.local_cells, r.serial_cells);
  }
  if (comm().rank() == 0)
    std::printf("walls: |dx| %.3g m, |dv| %.3g m/s, KE rel %.3g, KE lost %.3g, builds %lld, "
                "cells %zu local / %zu global\n",
                r.dx, r.dv, r.ke_rel, r.ke_loss, static_cast<long long>(r.builds), r.local_cells,
                r.serial_cells);
}

// kWalls's particles in a cylindrical column along y (docs/theory.md §11), periodic along its
// axis, gravity across it: the curved wall's contacts on R ranks.
TEST(DistributedExplicit, CylinderMatchesSerialScheme) {
  const Compared r = run_and_compare(
      kWalls, kSteps, nullptr,
      {"domain.shape=\"cylinder\"", "domain.hi=[1.2e-3, 0.8e-3, 1.2e-3]",
       "domain.periodic=[false, true, false]", "gravity=[0.0, 0.0, -1.0e3]"});
  EXPECT_LT(r.dx, kPositionBound);
  EXPECT_LT(r.dv, kVelocityBound);
  EXPECT_LT(r.ke_rel, 1e-12);
  EXPECT_GT(r.builds, 2);
  if (comm().rank() == 0)
    std::printf("cylinder: |dx| %.3g m, |dv| %.3g m/s, KE rel %.3g, KE lost %.3g, builds %lld\n",
                r.dx, r.dv, r.ke_rel, r.ke_loss, static_cast<long long>(r.builds));
}

TEST(DistributedExplicit, SameRanksSameResultBitwise) {
  ParticleStore a, b;
  run_and_compare(kGas, 150, &a);
  run_and_compare(kGas, 150, &b);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_TRUE(a.x == b.x && a.y == b.y && a.z == b.z && a.vx == b.vx && a.vy == b.vy &&
              a.vz == b.vz && a.id == b.id);
}

// Particles in one half of the box: the ORB follows them, so every rank still gets its share,
// and the imbalance reported at the regrid is the max/mean of the particles the ranks then own.
TEST(DistributedExplicit, ClusteredParticlesStayBalanced) {
  const Communicator c = comm();
  if (c.size() == 1)
    GTEST_SKIP() << "one rank has no decomposition to balance";
  const Scene scene =
      scene_from(kGas, {"particles.region_hi=[0.43e-3, 0.86e-3, 0.86e-3]", "particles.count=150"});
  ParticleStore all = make_initial_particles(scene);
  const dem::StepModel model = dem::make_step_model(scene, all);
  ParticleStore p = share(all, c.rank(), c.size());
  PhaseTimer timer;
  dem::ExplicitScheme s(scene, p, model, &c, timer);
  s.start();
  std::array<double, 2> owned{static_cast<double>(s.owned()), static_cast<double>(s.owned())};
  c.max(std::span<double>(owned.data(), 1));
  c.sum(std::span<double>(owned.data() + 1, 1));
  const double imbalance = owned[0] / (owned[1] / c.size());
  ASSERT_EQ(s.regrids().size(), 1U);
  EXPECT_DOUBLE_EQ(s.regrids().back().imbalance, imbalance);
  EXPECT_LT(imbalance, 1.2); // 16 boxes of ~equal counts: 6/5/5 at worst over 3 ranks
}

TEST(DistributedExplicit, BitwiseIndependentOfThreadCount) {
  const ParticleStore a = run_explicit_with_threads(kGas, 1, 150),
                      b = run_explicit_with_threads(kGas, 2, 150);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_TRUE(a.x == b.x && a.y == b.y && a.z == b.z && a.vx == b.vx && a.vy == b.vy &&
              a.vz == b.vz && a.id == b.id);
}

// A coupled run's set-up: the particles are owned by the ranks' fluid boxes (12 x 8 x 6 cells
// of the walled box, cut as the gas is) and feel a per-particle external force (here a function
// of the id, of the order of gravity), which must follow them through every migration. Against
// the serial scheme with the same force, to the same round-off bound as above.
TEST(DistributedExplicit, FluidBoxOwnershipWithExternalForceMatchesSerialScheme) {
  const Communicator c = comm();
  const Scene scene = scene_from(kWalls);
  ParticleStore all = make_initial_particles(scene);
  const dem::StepModel model = dem::make_step_model(scene, all);
  const auto force = [](const ParticleStore& p, std::size_t n) {
    std::array<std::vector<double>, 3> f;
    for (std::size_t i = 0; i < n; ++i) {
      const double id = static_cast<double>(p.id[i]);
      f[0].push_back(p.mass[i] * 400.0 * std::sin(id));
      f[1].push_back(p.mass[i] * 600.0 * std::cos(0.7 * id));
      f[2].push_back(p.mass[i] * 300.0 * std::sin(1.3 * id + 0.2));
    }
    return f;
  };
  ParticleStore serial = all;
  PhaseTimer t1, t2;
  dem::ExplicitScheme ref(scene, serial, t1);
  const auto fs = force(serial, serial.size());
  ref.set_external_force(fs[0], fs[1], fs[2]);
  ParticleStore p = share(all, c.rank(), c.size());
  dem::ExplicitScheme s(scene, p, model, &c, t2);
  const std::vector<CellBox> boxes = orb_cell_boxes({12, 8, 6}, c.size(), 3);
  s.set_decomposition(partition::decomposition_of_cell_boxes(
      boxes, scene.domain.lo, {1e-4, 1e-4, 1e-4}, {scene.domain.lo, scene.domain.hi}));
  const auto fd = force(p, p.size());
  s.set_external_force(fd[0], fd[1], fd[2]);
  ASSERT_TRUE(s.has_external_force());
  ref.start();
  s.start();
  for (int k = 0; k < 2000; ++k) {
    ref.step();
    s.step();
  }
  // Every owned particle lies in its rank's fluid box, and none is lost.
  const CellBox& mine = boxes[static_cast<std::size_t>(c.rank())];
  std::int64_t outside = 0;
  for (std::size_t i = 0; i < s.owned(); ++i) {
    const double q[3] = {p.x[i], p.y[i], p.z[i]};
    for (int a = 0; a < 3; ++a) {
      const double lo = scene.domain.lo[a] + mine.lo[a] * 1e-4;
      const double hi = scene.domain.lo[a] + mine.hi[a] * 1e-4;
      // Owners are settled at the last rebuild: a particle may since have moved skin/2.
      outside += (q[a] < lo - model.skin || q[a] > hi + model.skin) ? 1 : 0;
    }
  }
  EXPECT_EQ(c.sum(outside), 0);
  EXPECT_EQ(c.sum(static_cast<std::int64_t>(s.owned())), static_cast<std::int64_t>(all.size()));
  double mass = 0.0;
  for (std::size_t i = 0; i < s.owned(); ++i)
    mass += p.mass[i];
  c.sum(std::span<double>(&mass, 1));
  EXPECT_NEAR(mass, all.total_mass(), 1e-13 * all.total_mass());
  const auto ref_index = index_by_id(serial, serial.size());
  const dem::DomainGeometry g(scene.domain);
  double dx = 0.0, dv = 0.0;
  for (std::size_t i = 0; i < s.owned(); ++i) {
    const std::size_t j = ref_index.at(p.id[i]);
    dx = std::max({dx, std::abs(p.x[i] - serial.x[j]), std::abs(p.y[i] - serial.y[j]),
                   std::abs(p.z[i] - serial.z[j])});
    dv = std::max({dv, std::abs(p.vx[i] - serial.vx[j]), std::abs(p.vy[i] - serial.vy[j]),
                   std::abs(p.vz[i] - serial.vz[j])});
  }
  dx = c.max(dx);
  dv = c.max(dv);
  EXPECT_LT(dx, kPositionBound);
  EXPECT_LT(dv, kVelocityBound);
  // The force did act: the serial run without it ends elsewhere.
  ParticleStore plain = all;
  PhaseTimer t3;
  dem::ExplicitScheme no_force(scene, plain, t3);
  no_force.start();
  for (int k = 0; k < 2000; ++k)
    no_force.step();
  const auto plain_index = index_by_id(plain, plain.size());
  double moved = 0.0;
  for (std::size_t j = 0; j < serial.size(); ++j)
    moved = std::max(moved, std::abs(serial.y[j] - plain.y[plain_index.at(serial.id[j])]));
  EXPECT_GT(moved, 1e3 * kPositionBound);
  EXPECT_GT(s.neighbor_builds(), 2); // migrations happened, carrying the force
  if (c.rank() == 0)
    std::printf("fluid boxes + external force: |dx| %.3g m, |dv| %.3g m/s, builds %lld, force "
                "moved particles by %.3g m\n",
                dx, dv, static_cast<long long>(s.neighbor_builds()), moved);
}

} // namespace
} // namespace cfddem
