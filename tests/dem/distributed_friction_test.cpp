// Friction on R ranks (run under mpirun -np 1, 2 and 3): the distributed explicit scheme with
// tangential springs, Coulomb sliding, spin and wall friction advances a frictional gas and a
// frictional pile under gravity as the serial ExplicitScheme does, to round-off; the history of
// contacts whose particle changes rank travels with it (a run that dropped it would be off by
// far more than round-off); a checkpoint of the canonical state plus the contact history
// restarts bit for bit; and the result does not depend on the thread count.
#include <gtest/gtest.h>
#include <mpi.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <numeric>

#include <tbb/global_control.h>

#include "core/communicator.hpp"
#include "core/initial_conditions.hpp"
#include "dem/explicit_scheme.hpp"
#include "distributed_test_support.hpp"

namespace cfddem {
namespace {

using demtest::run_explicit_with_threads;
using demtest::scene_from;
using demtest::share;

// A dense periodic gas (phi ~ 0.25) with friction: many contacts, spin exchanged.
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
friction = 0.5
max_overlap = 0.9
regrid_interval = 2.0e-6
[run]
end_time = 1.0e-3
)";

// A walled box under strong gravity (1000 g): the particles rain down into a pile whose
// contacts last the whole run, with wall friction; the ORB cuts follow them (regrid_interval),
// so particles in contact change rank with their history.
const char* kPile = R"(
gravity = [0.0, -1.0e4, 0.0]
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.6e-3, 0.8e-3, 0.6e-3]
periodic = [false, false, false]
[particles]
count = 120
diameter = 100.0e-6
density = 1000.0
temperature = 0.01
seed = 5
[dem]
spring_constant = 10.0
restitution = 0.5
wall_restitution = 0.5
friction = 0.5
wall_friction = 0.4
max_overlap = 0.9
regrid_interval = 1.0e-6
[run]
end_time = 1.0e-3
)";

Communicator comm() {
  return Communicator::world();
}

template <class T> std::vector<T> all_gather(std::span<const T> mine) {
  const int ranks = comm().size();
  int n = static_cast<int>(mine.size());
  std::vector<int> counts(static_cast<std::size_t>(ranks)), at(static_cast<std::size_t>(ranks));
  MPI_Allgather(&n, 1, MPI_INT, counts.data(), 1, MPI_INT, MPI_COMM_WORLD);
  std::exclusive_scan(counts.begin(), counts.end(), at.begin(), 0);
  std::vector<T> out(static_cast<std::size_t>(at.back() + counts.back()));
  const MPI_Datatype t = std::is_same_v<T, double> ? MPI_DOUBLE : MPI_INT64_T;
  MPI_Allgatherv(mine.data(), n, t, out.data(), counts.data(), at.data(), t, MPI_COMM_WORLD);
  return out;
}

// Every rank's owned particles in one store, in id order (rotation fields included).
ParticleStore gather_owned(const ParticleStore& p, std::size_t owned) {
  ParticleStore all;
  all.enable_rotation();
  const std::vector<double>* from[] = {&p.x,  &p.y,      &p.z,          &p.vx,       &p.vy,
                                       &p.vz, &p.radius, &p.mass,       &p.inv_mass, &p.wx,
                                       &p.wy, &p.wz,     &p.inv_inertia};
  std::vector<double>* to[] = {&all.x,  &all.y,      &all.z,          &all.vx,       &all.vy,
                               &all.vz, &all.radius, &all.mass,       &all.inv_mass, &all.wx,
                               &all.wy, &all.wz,     &all.inv_inertia};
  const std::vector<std::int64_t> ids = all_gather<std::int64_t>({p.id.data(), owned});
  all.resize(ids.size());
  all.id = ids;
  for (std::size_t f = 0; f < std::size(from); ++f)
    *to[f] = all_gather<double>({from[f]->data(), owned});
  std::vector<std::uint32_t> order(ids.size());
  std::iota(order.begin(), order.end(), 0U);
  std::sort(order.begin(), order.end(), [&](auto a, auto b) { return ids[a] < ids[b]; });
  all.permute(order);
  return all;
}

struct Compared {
  double dx = 0, dv = 0, dw = 0; // largest difference from the serial run (by id)
  double w_scale = 0;            // largest |w| of the serial run
  double dp = 0, p_scale = 0;    // total momentum change over the run, and its scale
  double dl = 0, l_scale = 0;    // total spin I w: distributed minus serial, and its scale
  std::int64_t builds = 0, regrids = 0, migrated = 0;
  std::int64_t loaded_contacts = 0; // contacts with a non-zero spring at the end
};

// `steps` steps serially (every rank, the whole system) and on the ranks; compared by id. Every
// step: particle count and mass over the ranks are the initial ones.
Compared run_and_compare(const char* toml, int steps) {
  const Communicator c = comm();
  const Scene scene = scene_from(toml);
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
  auto momentum = [&] {
    std::array<double, 3> q{};
    for (std::size_t i = 0; i < s.owned(); ++i)
      q[0] += p.mass[i] * p.vx[i], q[1] += p.mass[i] * p.vy[i], q[2] += p.mass[i] * p.vz[i];
    c.sum(q);
    return q;
  };
  const std::array<double, 3> p0 = momentum();
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
  std::map<std::int64_t, std::size_t> ref_index;
  for (std::size_t j = 0; j < serial.size(); ++j)
    ref_index[serial.id[j]] = j;
  const dem::DomainGeometry g(scene.domain);
  std::array<double, 3> l{};
  for (std::size_t i = 0; i < s.owned(); ++i) {
    const std::size_t j = ref_index.at(p.id[i]);
    r.dx = std::max({r.dx, std::abs(g.image(p.x[i] - serial.x[j], 0)),
                     std::abs(g.image(p.y[i] - serial.y[j], 1)),
                     std::abs(g.image(p.z[i] - serial.z[j], 2))});
    r.dv = std::max({r.dv, std::abs(p.vx[i] - serial.vx[j]), std::abs(p.vy[i] - serial.vy[j]),
                     std::abs(p.vz[i] - serial.vz[j])});
    r.dw = std::max({r.dw, std::abs(p.wx[i] - serial.wx[j]), std::abs(p.wy[i] - serial.wy[j]),
                     std::abs(p.wz[i] - serial.wz[j])});
    const double inertia = 1.0 / p.inv_inertia[i];
    l[0] += inertia * p.wx[i], l[1] += inertia * p.wy[i], l[2] += inertia * p.wz[i];
  }
  r.dx = c.max(r.dx), r.dv = c.max(r.dv), r.dw = c.max(r.dw);
  c.sum(l);
  for (std::size_t j = 0; j < serial.size(); ++j) {
    const double inertia = 1.0 / serial.inv_inertia[j];
    r.w_scale = std::max(
        {r.w_scale, std::abs(serial.wx[j]), std::abs(serial.wy[j]), std::abs(serial.wz[j])});
    l[0] -= inertia * serial.wx[j], l[1] -= inertia * serial.wy[j], l[2] -= inertia * serial.wz[j];
    r.l_scale += inertia * std::hypot(serial.wx[j], serial.wy[j], serial.wz[j]);
  }
  r.dl = std::max({std::abs(l[0]), std::abs(l[1]), std::abs(l[2])});
  const std::array<double, 3> p1 = momentum();
  for (int a = 0; a < 3; ++a)
    r.dp = std::max(r.dp, std::abs(p1[a] - p0[a]));
  const auto m0 = demtest::measure_now(all);
  r.p_scale = std::sqrt(2.0 * m0.kinetic_energy * mass0);
  r.builds = s.neighbor_builds();
  r.regrids = static_cast<std::int64_t>(s.regrids().size());
  r.migrated = s.history_migrations();
  r.loaded_contacts = c.sum(static_cast<std::int64_t>(s.contact_history().size()));
  EXPECT_EQ(s.pair_evaluations(), ref.pair_evaluations());
  EXPECT_EQ(s.neighbor_builds(), ref.neighbor_builds());
  return r;
}

// Round-off bound as for the frictionless scheme (distributed_explicit_test.cpp): forces differ
// from the serial ones only in summation order (~1e-16 relative), which the collisions amplify
// by far less than 1e6 over these runs: 1e-9 of a diameter, of the speed and spin scales.
constexpr double kPositionBound = 1e-9 * 100e-6;

TEST(DistributedFriction, FrictionalGasMatchesSerialAndConservesMomentum) {
  const Compared r = run_and_compare(kGas, 3000);
  EXPECT_LT(r.dx, kPositionBound);
  EXPECT_LT(r.dv, 1e-9 * 0.2);
  EXPECT_GT(r.w_scale, 100.0); // friction did spin the particles up
  EXPECT_LT(r.dw, 1e-9 * r.w_scale);
  // Periodic gas: tangential forces are equal and opposite, so momentum stays at round-off.
  EXPECT_LT(r.dp, 1e-12 * r.p_scale);
  // The spin exchanged by the contacts (torques) is the serial run's, to round-off.
  EXPECT_LT(r.dl, 1e-9 * r.l_scale);
  EXPECT_GT(r.builds, 2);
  if (comm().size() > 1) {
    EXPECT_GT(r.regrids, 1); // one rank has no decomposition
    EXPECT_GT(r.migrated, 0);
  }
  if (comm().rank() == 0)
    std::printf("frictional gas: |dx| %.3g m, |dv| %.3g m/s, |dw| %.3g rad/s (max |w| %.3g), "
                "|dP| %.3g (scale %.3g), |dL_spin| %.3g (scale %.3g), builds %lld, history "
                "records migrated %lld, live contacts %lld\n",
                r.dx, r.dv, r.dw, r.w_scale, r.dp, r.p_scale, r.dl, r.l_scale,
                static_cast<long long>(r.builds), static_cast<long long>(r.migrated),
                static_cast<long long>(r.loaded_contacts));
}

TEST(DistributedFriction, FrictionalPileWithWallsMatchesSerial) {
  const Compared r = run_and_compare(kPile, 4000);
  EXPECT_LT(r.dx, kPositionBound);
  EXPECT_LT(r.dv, 1e-9 * 1.0);
  EXPECT_LT(r.dw, 1e-9 * r.w_scale);
  EXPECT_GT(r.loaded_contacts, 150); // a pile: contacts with a loaded spring at the end
  // Particles changed rank while in contact: their history had to travel.
  if (comm().size() > 1) {
    EXPECT_GT(r.migrated, 50);
  }
  if (comm().rank() == 0)
    std::printf("frictional pile: |dx| %.3g m, |dv| %.3g m/s, |dw| %.3g rad/s (max |w| %.3g), "
                "builds %lld, regrids %lld, history records migrated %lld, live contacts %lld\n",
                r.dx, r.dv, r.dw, r.w_scale, static_cast<long long>(r.builds),
                static_cast<long long>(r.regrids), static_cast<long long>(r.migrated),
                static_cast<long long>(r.loaded_contacts));
}

// Checkpoint/restart as the app does it: canonicalize, then a fresh scheme on any split of the
// gathered particles, restored with every rank's history records, continues bit for bit; the
// same restart without the history does not (the history matters to this run).
TEST(DistributedFriction, RestartWithContactHistoryIsBitwise) {
  const Communicator c = comm();
  const Scene scene = scene_from(kPile);
  ParticleStore all = make_initial_particles(scene);
  const dem::StepModel model = dem::make_step_model(scene, all);
  ParticleStore p = share(all, c.rank(), c.size());
  PhaseTimer timer;
  dem::ExplicitScheme s(scene, p, model, &c, timer);
  s.start();
  for (int k = 0; k < 2500; ++k)
    s.step();
  s.canonicalize();
  const ParticleStore saved = gather_owned(p, s.owned());
  const dem::ContactHistory mine = s.contact_history();
  dem::ContactHistory h;
  h.owner = all_gather<std::int64_t>(mine.owner);
  h.partner = all_gather<std::int64_t>(mine.partner);
  h.hx = all_gather<double>(mine.hx), h.hy = all_gather<double>(mine.hy);
  h.hz = all_gather<double>(mine.hz);
  ASSERT_GT(h.size(), 100U);
  const auto counters = s.counters();
  constexpr int kMore = 300;
  for (int k = 0; k < kMore; ++k)
    s.step();
  const ParticleStore full = gather_owned(p, s.owned());
  auto resume = [&](const dem::ContactHistory& with) {
    ParticleStore q = share(saved, (c.rank() + 1) % c.size(), c.size()); // another split
    PhaseTimer t;
    dem::ExplicitScheme r(scene, q, model, &c, t);
    r.restore(counters, with);
    for (int k = 0; k < kMore; ++k)
      r.step();
    EXPECT_EQ(r.steps_taken(), s.steps_taken());
    return gather_owned(q, r.owned());
  };
  const ParticleStore again = resume(h);
  EXPECT_TRUE(again.id == full.id && again.x == full.x && again.y == full.y && again.z == full.z &&
              again.vx == full.vx && again.vy == full.vy && again.vz == full.vz &&
              again.wx == full.wx && again.wy == full.wy && again.wz == full.wz);
  const ParticleStore forgot = resume({});
  EXPECT_FALSE(forgot.x == full.x && forgot.wx == full.wx);
}

TEST(DistributedFriction, BitwiseIndependentOfThreadCount) {
  const ParticleStore a = run_explicit_with_threads(kGas, 1, 100),
                      b = run_explicit_with_threads(kGas, 2, 100);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_TRUE(a.x == b.x && a.y == b.y && a.z == b.z && a.vx == b.vx && a.vy == b.vy &&
              a.vz == b.vz && a.wx == b.wx && a.wy == b.wy && a.wz == b.wz && a.id == b.id);
  double w = 0.0;
  for (const double v : a.wx)
    w = std::max(w, std::abs(v));
  EXPECT_GT(comm().max(w), 0.0); // contacts did spin particles
}

} // namespace
} // namespace cfddem
