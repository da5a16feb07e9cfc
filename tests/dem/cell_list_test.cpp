// CellList (dem/cell_list.hpp), the cell list under every neighbour search: its two walks find
// every pair within the cutoff, the forward-pair walk each pair exactly once, on periodic and
// walled axes, with positions outside the periodic box (binned where they wrap to), on grids of
// three or more cells per axis and (for_each_around) of fewer.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include "core/scene.hpp"
#include "dem/cell_list.hpp"
#include "dem/domain_geometry.hpp"

namespace cfddem {
namespace {

struct Cloud {
  std::vector<double> x, y, z;
};

// n points in the box, shifted by a whole period on periodic axes for every third one (the orb
// scheme bins unwrapped positions and unshifted ghosts).
Cloud make_cloud(const dem::DomainGeometry& g, std::size_t n, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Cloud c;
  for (std::size_t i = 0; i < n; ++i) {
    double q[3];
    for (int a = 0; a < 3; ++a) {
      q[a] = g.lo[a] + u(rng) * g.length[a];
      if (g.periodic[a] && i % 3 == 0)
        q[a] += (i % 2 ? 1.0 : -1.0) * g.length[a];
    }
    c.x.push_back(q[0]), c.y.push_back(q[1]), c.z.push_back(q[2]);
  }
  return c;
}

double separation2(const dem::DomainGeometry& g, const Cloud& c, std::uint32_t i, std::uint32_t j) {
  const double d[3] = {g.wrap(c.x[j], 0) - g.wrap(c.x[i], 0), g.wrap(c.y[j], 1) - g.wrap(c.y[i], 1),
                       g.wrap(c.z[j], 2) - g.wrap(c.z[i], 2)};
  double s = 0.0;
  for (int a = 0; a < 3; ++a) {
    const double e = g.image(d[a], a);
    s += e * e;
  }
  return s;
}

using Pairs = std::set<std::pair<std::uint32_t, std::uint32_t>>;

Pairs brute_force(const dem::DomainGeometry& g, const Cloud& c, double cutoff) {
  Pairs out;
  const auto n = static_cast<std::uint32_t>(c.x.size());
  for (std::uint32_t i = 0; i < n; ++i)
    for (std::uint32_t j = i + 1; j < n; ++j)
      if (separation2(g, c, i, j) < cutoff * cutoff)
        out.insert({i, j});
  return out;
}

dem::DomainGeometry box(std::array<bool, 3> periodic, std::array<double, 3> hi) {
  DomainSpec d;
  d.lo = {0.0, 0.0, 0.0}, d.hi = hi, d.periodic = periodic;
  return dem::DomainGeometry(d);
}

void expect_walks_find_every_pair(const dem::DomainGeometry& g, std::size_t n, double cutoff,
                                  double per_particle, bool half_stencil) {
  const Cloud c = make_cloud(g, n, 11);
  dem::CellList cells;
  cells.bin<true>(g, dem::make_cell_grid(g, cutoff, n, per_particle), c.x.data(), c.y.data(),
                  c.z.data(), n);
  ASSERT_EQ(cells.grid().half_stencil(), half_stencil);
  const Pairs expected = brute_force(g, c, cutoff);
  ASSERT_GT(expected.size(), 10u); // the case tests something
  const auto items = cells.items();
  // for_each_around: every pair within the cutoff is seen from both ends; no slot twice.
  Pairs around;
  for (std::uint32_t i = 0; i < n; ++i) {
    std::multiset<std::uint32_t> seen;
    cells.for_each_around(cells.coord<true>(c.x[i], 0), cells.coord<true>(c.y[i], 1),
                          cells.coord<true>(c.z[i], 2), [&](std::uint32_t q) {
                            const std::uint32_t j = items[q];
                            seen.insert(j);
                            if (j > i && separation2(g, c, i, j) < cutoff * cutoff)
                              around.insert({i, j});
                          });
    for (const std::uint32_t j : seen)
      ASSERT_EQ(seen.count(j), 1u) << "particle " << j << " visited twice around " << i;
  }
  EXPECT_EQ(around, expected);
  if (!half_stencil)
    return;
  // for_each_forward_pair: each pair of slots at most once, and every pair within the cutoff.
  Pairs forward;
  std::size_t visits = 0;
  Pairs all_visited;
  for (int cz = 0; cz < cells.grid().n[2]; ++cz)
    cells.for_each_forward_pair(
        cz, [](std::size_t) { return true; },
        [&](std::uint32_t a, std::uint32_t b) {
          const std::uint32_t i = std::min(items[a], items[b]), j = std::max(items[a], items[b]);
          ++visits;
          all_visited.insert({i, j});
          if (separation2(g, c, i, j) < cutoff * cutoff)
            forward.insert({i, j});
        });
  EXPECT_EQ(visits, all_visited.size()) << "a pair was visited twice";
  EXPECT_EQ(forward, expected);
  // for_each_forward_pair_in_slots over ranges of slots that split cells (the Verlet list's
  // walk over occupied cells): the same pairs, each once, whatever the ranges.
  for (const std::size_t range : {std::size_t{7}, std::size_t{64}, n}) {
    Pairs in_slots, visited;
    std::size_t count = 0;
    for (std::size_t q = 0; q < n; q += range)
      cells.for_each_forward_pair_in_slots(
          q, std::min(n, q + range), [&](std::uint32_t a, std::uint32_t b) {
            const std::uint32_t i = std::min(items[a], items[b]), j = std::max(items[a], items[b]);
            ++count;
            visited.insert({i, j});
            if (separation2(g, c, i, j) < cutoff * cutoff)
              in_slots.insert({i, j});
          });
    EXPECT_EQ(count, visited.size()) << "ranges of " << range << ": a pair was visited twice";
    EXPECT_EQ(visited, all_visited) << "ranges of " << range;
    EXPECT_EQ(in_slots, expected) << "ranges of " << range;
  }
}

TEST(CellList, WalksFindEveryPairInAPeriodicBox) {
  expect_walks_find_every_pair(box({true, true, true}, {1.0, 1.2, 0.9}), 600, 0.12, 8.0, true);
}

TEST(CellList, WalksFindEveryPairWithWallsAndAPeriodicAxis) {
  expect_walks_find_every_pair(box({false, true, false}, {1.0, 0.8, 1.1}), 600, 0.12, 8.0, true);
}

TEST(CellList, DiluteGridOfSmallCellsStillFindsEveryPair) {
  // About 27 cells per particle (the VerletList rule allows 32): most cells are empty.
  expect_walks_find_every_pair(box({true, false, true}, {1.0, 1.0, 1.0}), 300, 0.05, 32.0, true);
}

TEST(CellList, FewerThanThreeCellsOnAnAxisCollapsesPeriodicImages) {
  // Two cells along x (periodic) and y (walled): the 27-cell stencil would name a cell twice.
  expect_walks_find_every_pair(box({true, false, true}, {0.5, 0.5, 2.0}), 200, 0.2, 8.0, false);
}

} // namespace
} // namespace cfddem
