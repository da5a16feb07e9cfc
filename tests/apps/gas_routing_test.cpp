// The gas routing (apps/gas_routing.hpp) under mpirun with 1, 2 and 3 ranks: every particle's copy
// reaches the rank whose gas box holds its wrapped centre, none is lost or duplicated, and the
// force computed there comes back to the owner in the owner's order.
#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "apps/gas_routing.hpp"
#include "core/cell_box.hpp"
#include "core/communicator.hpp"
#include "partition/cell_box_decomposition.hpp"

using namespace cfddem;

namespace {

// A periodic 1 x 2 x 1 box cut into one gas box per rank on a 10 x 20 x 10 grid.
struct GasBoxes {
  DomainSpec domain;
  partition::RankDecomposition boxes;
};

GasBoxes make_setup(const Communicator& comm) {
  GasBoxes s;
  s.domain.lo = {0.0, 0.0, 0.0};
  s.domain.hi = {1.0, 2.0, 1.0};
  s.domain.periodic = {true, true, true};
  const std::vector<CellBox> cells = orb_cell_boxes({10, 20, 10}, comm.size(), 2);
  s.boxes = partition::decomposition_of_cell_boxes(cells, {0.0, 0.0, 0.0}, {0.1, 0.1, 0.1},
                                                   {s.domain.lo, s.domain.hi});
  return s;
}

// This rank's share of 500 particles (every R-th), some of them one period outside the box.
ParticleStore share(const Communicator& comm) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  ParticleStore p;
  for (std::int64_t i = 0; i < 500; ++i) {
    const double x = u(rng), y = 2.0 * u(rng), z = u(rng);
    if (i % comm.size() != comm.rank())
      continue;
    const double shift = i % 5 == 0 ? 1.0 : 0.0; // an unwrapped image
    const std::size_t k =
        p.add(x + shift, y, z - shift, 0.1 * x, 0.2 * y, 0.3 * z, 0.01, 1000.0, i);
    p.set_mass(k, 1e-3 * static_cast<double>(i + 1)); // each its own: a copy carries its own
  }
  return p;
}

// The force a gas box "computes" for a routed particle: a function of what arrived.
double force_of(const ParticleStore& b, std::size_t q, int a) {
  return static_cast<double>(b.id[q]) + (a == 0 ? b.x[q] : a == 1 ? b.vy[q] : b.radius[q]);
}

} // namespace

TEST(GasRouting, EveryParticleReachesItsBoxAndItsForceComesBack) {
  const Communicator comm = Communicator::world();
  const GasBoxes s = make_setup(comm);
  const dem::DomainGeometry geom(s.domain);
  apps::GasRouting routing(comm, s.boxes, geom);
  ParticleStore p = share(comm);
  // The owner's store in descending id order: the box store must still come out in id order
  // (the deposit order depends on the particles only) and the forces in the owner's order.
  std::vector<std::uint32_t> reverse(p.size());
  for (std::size_t i = 0; i < p.size(); ++i)
    reverse[i] = static_cast<std::uint32_t>(p.size() - 1 - i);
  p.permute(reverse);
  const ParticleStore& box = routing.route(p, p.size());
  for (std::size_t q = 1; q < box.size(); ++q)
    EXPECT_LT(box.id[q - 1], box.id[q]);
  // None lost or duplicated: the ids over the ranks are 0..499 once each.
  const std::vector<std::int64_t> all = comm.gather(std::span<const std::int64_t>(box.id));
  if (comm.rank() == 0) {
    std::vector<std::int64_t> sorted = all;
    std::sort(sorted.begin(), sorted.end());
    ASSERT_EQ(sorted.size(), 500u);
    for (std::int64_t i = 0; i < 500; ++i)
      EXPECT_EQ(sorted[static_cast<std::size_t>(i)], i);
  }
  // Each copy is in this rank's box, wrapped, with its velocity, radius and mass (the drag time
  // m / beta that caps an adaptive fluid step reads 1/m: left zero, it was infinite on R ranks).
  for (std::size_t q = 0; q < box.size(); ++q) {
    EXPECT_EQ(s.boxes.owner_of(box.x[q], box.y[q], box.z[q]), comm.rank());
    EXPECT_GE(box.x[q], 0.0);
    EXPECT_LT(box.x[q], 1.0);
    EXPECT_EQ(box.radius[q], 0.01);
    const double m = 1e-3 * static_cast<double>(box.id[q] + 1);
    EXPECT_EQ(box.mass[q], m);
    EXPECT_EQ(box.inv_mass[q], 1.0 / m);
  }
  std::array<std::vector<double>, 3> f;
  for (int a = 0; a < 3; ++a)
    for (std::size_t q = 0; q < box.size(); ++q)
      f[a].push_back(force_of(box, q, a));
  routing.return_force({f[0], f[1], f[2]});
  // Back in the owner's order, each the value computed from its own copy.
  for (std::size_t i = 0; i < p.size(); ++i) {
    EXPECT_EQ(routing.force(0)[i], static_cast<double>(p.id[i]) + geom.wrap(p.x[i], 0));
    EXPECT_EQ(routing.force(1)[i], static_cast<double>(p.id[i]) + p.vy[i]);
    EXPECT_EQ(routing.force(2)[i], static_cast<double>(p.id[i]) + p.radius[i]);
  }
  const std::int64_t away = comm.sum(static_cast<std::int64_t>(routing.sent_away()));
  if (comm.size() > 1) {
    EXPECT_GT(away, 0);
  }
}

// Particles already owned by their gas box's rank (the explicit scheme's ownership): nothing
// travels and the box store is the owned particles in their order.
TEST(GasRouting, IsTheIdentityForGasBoxOwners) {
  const Communicator comm = Communicator::world();
  const GasBoxes s = make_setup(comm);
  const dem::DomainGeometry geom(s.domain);
  apps::GasRouting routing(comm, s.boxes, geom);
  ParticleStore p;
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (std::int64_t i = 0; i < 400; ++i) {
    const double x = u(rng), y = 2.0 * u(rng), z = u(rng);
    if (s.boxes.owner_of(x, y, z) == comm.rank())
      p.add(x, y, z, 0.0, 0.0, 0.0, 0.01, 1000.0, i);
  }
  const ParticleStore& box = routing.route(p, p.size());
  EXPECT_EQ(routing.sent_away(), 0u);
  ASSERT_EQ(box.size(), p.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    EXPECT_EQ(box.id[i], p.id[i]);
    EXPECT_EQ(box.x[i], p.x[i]);
  }
}
