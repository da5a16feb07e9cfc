// The parallel ORB gives every rank the serial tree of the union of all ranks' points (run under
// mpirun with 1, 2 and 3 ranks by ctest).
#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>

#include <gtest/gtest.h>
#include <mpi.h>

#include "core/communicator.hpp"
#include "core/message_counts.hpp"
#include "partition/parallel_orb.hpp"
#include "partition/rank_decomposition.hpp"

using namespace cfddem::partition;

namespace {

int rank() {
  int r = 0;
  MPI_Comm_rank(MPI_COMM_WORLD, &r);
  return r;
}
int ranks() {
  int r = 1;
  MPI_Comm_size(MPI_COMM_WORLD, &r);
  return r;
}

struct Points {
  std::vector<double> x, y, z, w;
};

// The same global set on every rank (same seed); `clustered` puts half the points on one spot.
Points global_points(std::size_t n, unsigned seed, bool clustered, bool weighted) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Points p;
  for (std::size_t i = 0; i < n; ++i) {
    const bool c = clustered && i % 2 == 0;
    p.x.push_back(c ? 0.25 : u(rng) * 2.0);
    p.y.push_back(c ? 0.5 : u(rng));
    p.z.push_back(c ? 0.125 : u(rng) * 0.5);
    if (weighted) p.w.push_back(static_cast<double>(1 + i % 7)); // integers: exact sums
  }
  return p;
}

// This rank's share: points i with i % ranks == rank (interleaved, so no rank holds a region).
Points local_share(const Points& g) {
  Points l;
  for (std::size_t i = 0; i < g.x.size(); ++i) {
    if (static_cast<int>(i % ranks()) != rank()) continue;
    l.x.push_back(g.x[i]), l.y.push_back(g.y[i]), l.z.push_back(g.z[i]);
    if (!g.w.empty()) l.w.push_back(g.w[i]);
  }
  return l;
}

void expect_same_tree(std::size_t n, unsigned seed, bool clustered, bool weighted,
                      const OrbOptions& opt, int group_ranks = 8) {
  const Aabb domain{{0.0, 0.0, 0.0}, {2.0, 1.0, 0.5}};
  const Points g = global_points(n, seed, clustered, weighted);
  const Points l = local_share(g);
  const OrbTree serial = OrbTree::build(g.x, g.y, g.z, g.w, domain, opt);
  const ParallelOrb orb =
      parallel_orb_cuts(cfddem::Communicator::world(), l.x, l.y, l.z, l.w, domain, opt, group_ranks);
  const auto& cuts = orb.cuts;
  ASSERT_EQ(cuts.size(), serial.cuts().size());
  for (std::size_t k = 0; k < cuts.size(); ++k) {
    EXPECT_EQ(cuts[k].axis, serial.cuts()[k].axis) << "cut " << k;
    EXPECT_EQ(std::memcmp(&cuts[k].position, &serial.cuts()[k].position, sizeof(double)), 0)
        << "cut " << k << ": " << cuts[k].position << " vs " << serial.cuts()[k].position;
  }
  // Every rank's points land in the leaf the serial tree gives them.
  const OrbTree local = OrbTree::from_cuts(l.x, l.y, l.z, domain, opt.levels, cuts);
  std::vector<double> counts(local.leaves().size());
  for (std::size_t j = 0; j < counts.size(); ++j) counts[j] = local.leaves()[j].size();
  MPI_Allreduce(MPI_IN_PLACE, counts.data(), static_cast<int>(counts.size()), MPI_DOUBLE, MPI_SUM,
                MPI_COMM_WORLD);
  for (std::size_t j = 0; j < counts.size(); ++j)
    EXPECT_EQ(counts[j], serial.leaves()[j].size()) << "leaf " << j;
  // Past the shared levels every leaf has the rank that cut it, and a rank's load is the weight
  // of its leaves.
  if (orb.leaf_rank.empty()) return;
  ASSERT_EQ(orb.leaf_rank.size(), serial.leaves().size());
  std::vector<double> load(static_cast<std::size_t>(ranks()), 0.0);
  for (std::size_t j = 0; j < orb.leaf_rank.size(); ++j) {
    ASSERT_GE(orb.leaf_rank[j], 0) << "leaf " << j << " has no rank";
    ASSERT_LT(orb.leaf_rank[j], ranks());
    load[static_cast<std::size_t>(orb.leaf_rank[j])] += serial.leaves()[j].weight;
  }
  for (int r = 0; r < ranks(); ++r)
    EXPECT_EQ(orb.rank_load[static_cast<std::size_t>(r)], load[static_cast<std::size_t>(r)]);
}

} // namespace

TEST(ParallelOrb, SameCutsAsSerialUniform) { expect_same_tree(5000, 1, false, false, {6, {}}); }

TEST(ParallelOrb, SameCutsAsSerialClusteredAndMoreLeavesThanPoints) {
  expect_same_tree(4000, 2, true, false, {5, {}});
  expect_same_tree(20, 3, false, false, {6, {}});
  expect_same_tree(0, 4, false, false, {3, {}});
}

TEST(ParallelOrb, SameCutsAsSerialSnappedToCells) {
  expect_same_tree(3000, 5, false, false, {5, Grid{{0.0, 0.0, 0.0}, {0.1, 0.05, 0.05}}});
}

TEST(ParallelOrb, SameCutsAsSerialWithIntegerWeights) {
  expect_same_tree(3000, 6, false, true, {4, {}});
}

// Levels past the shared ones (3 on 1 rank, 4 on 2, 5 on 3) are cut by the rank that holds a
// subtree's points: still the serial tree, clustered, weighted, snapped, and with subtrees
// holding no point or a zero-width box (the clustered spot and 20 points under 9 levels).
TEST(ParallelOrb, SubtreesCutByOneRankGiveTheSerialTree) {
  ASSERT_LT(shared_orb_levels(ranks(), 8), 8);
  expect_same_tree(6000, 11, false, false, {8, {}});
  expect_same_tree(6000, 12, true, false, {8, {}});
  expect_same_tree(6000, 13, true, true, {8, {}});
  expect_same_tree(20, 14, false, false, {9, {}});
  expect_same_tree(5000, 15, false, true, {7, Grid{{0.0, 0.0, 0.0}, {0.1, 0.05, 0.05}}});
}

// Halvings first (groups of at most 1 or 2 ranks take the knapsack stage): on 2 and 4 ranks the
// groups halve down to them, each rank swapping points with its partner. Still the serial tree.
TEST(ParallelOrb, HalvingsGiveTheSerialTree) {
  for (const int group : {1, 2}) {
    expect_same_tree(6000, 21, false, false, {8, {}}, group);
    expect_same_tree(6000, 22, true, true, {8, {}}, group);
    expect_same_tree(20, 23, false, false, {9, {}}, group);
    expect_same_tree(5000, 24, false, true, {7, Grid{{0.0, 0.0, 0.0}, {0.1, 0.05, 0.05}}}, group);
    // Few levels: the halvings may reach the leaves (then a leaf's group deals it to one rank).
    for (const int levels : {0, 1, 2, 3}) expect_same_tree(500, 25, false, false, {levels, {}}, group);
  }
}

// What grows with the levels (the particles: a scene keeps some hundred per leaf) is only the
// cuts all-gathered at the end, 24 bytes per cut: the reductions stop at the shared levels.
TEST(ParallelOrb, CollectiveBytesGrowOnlyByTheSharedCuts) {
  const Aabb domain{{0.0, 0.0, 0.0}, {2.0, 1.0, 0.5}};
  const Points l = local_share(global_points(20000, 16, false, false));
  const int shared = shared_orb_levels(ranks(), 24);
  auto bytes = [&](int levels) {
    const std::int64_t before = cfddem::message_counts().collective_bytes;
    const ParallelOrb orb = parallel_orb_cuts(cfddem::Communicator::world(), l.x, l.y, l.z, {},
                                              domain, {levels, {}});
    EXPECT_LE(orb.shared_levels, shared);
    return cfddem::message_counts().collective_bytes - before;
  };
  const std::int64_t few = bytes(shared + 1), many = bytes(shared + 5);
  const std::int64_t cuts_added = (std::int64_t{1} << (shared + 5)) - (std::int64_t{1} << (shared + 1));
  EXPECT_EQ(many - few, 24 * cuts_added) << "few levels: " << few << " B, many: " << many << " B";
}

// decompose() with weights (the orb scheme's measured cost): the serial weighted tree on every
// rank, and the knapsack balances the weights, not the counts: each rank's load is the weight of
// its leaves, the loads add up to the total, and heavy clustered points do not land on one rank.
TEST(RankDecomposition, WeightsGiveTheSerialTreeAndAWeightedKnapsack) {
  const cfddem::Communicator comm = cfddem::Communicator::world();
  const Aabb domain{{0.0, 0.0, 0.0}, {2.0, 1.0, 0.5}};
  const Points g = global_points(3000, 8, true, true);
  const Points l = local_share(g);
  const int levels = 4;
  const RankDecomposition d = decompose(comm, l.x, l.y, l.z, l.w, domain, levels);
  const OrbTree serial = OrbTree::build(g.x, g.y, g.z, g.w, domain, {levels, {}});
  ASSERT_EQ(d.tree.cuts().size(), serial.cuts().size());
  for (std::size_t k = 0; k < serial.cuts().size(); ++k) {
    EXPECT_EQ(d.tree.cuts()[k].axis, serial.cuts()[k].axis);
    EXPECT_EQ(d.tree.cuts()[k].position, serial.cuts()[k].position);
  }
  std::vector<double> load(static_cast<std::size_t>(comm.size()), 0.0);
  double total = 0.0;
  for (std::size_t j = 0; j < serial.leaves().size(); ++j) {
    load[static_cast<std::size_t>(d.owner[j])] += serial.leaves()[j].weight;
    total += serial.leaves()[j].weight;
  }
  double sum = 0.0;
  for (int r = 0; r < comm.size(); ++r) {
    EXPECT_EQ(d.load[static_cast<std::size_t>(r)], load[static_cast<std::size_t>(r)]) << "rank " << r;
    sum += d.load[static_cast<std::size_t>(r)];
  }
  EXPECT_EQ(sum, total);
  // 16 leaves of nearly equal weight (the weighted medians): no rank holds more than its share
  // plus one leaf.
  const double leaf_max = [&] {
    double m = 0.0;
    for (const OrbLeaf& f : serial.leaves()) m = std::max(m, f.weight);
    return m;
  }();
  for (const double q : d.load) EXPECT_LE(q, total / comm.size() + leaf_max);
}

// decompose() past the shared levels: the knapsack deals whole subtrees, so every leaf of a
// subtree has one owner, the loads are the ranks' subtrees' weights, and no rank holds more than
// its share plus one subtree.
TEST(RankDecomposition, SubtreesBelowTheSharedLevelsKeepOneOwner) {
  const cfddem::Communicator comm = cfddem::Communicator::world();
  if (comm.size() == 1) GTEST_SKIP() << "one rank takes the serial build";
  const Aabb domain{{0.0, 0.0, 0.0}, {2.0, 1.0, 0.5}};
  const Points g = global_points(8000, 17, true, true);
  const Points l = local_share(g);
  const int levels = 8, shared = shared_orb_levels(comm.size(), levels);
  const RankDecomposition d = decompose(comm, l.x, l.y, l.z, l.w, domain, levels);
  const OrbTree serial = OrbTree::build(g.x, g.y, g.z, g.w, domain, {levels, {}});
  const std::size_t per = std::size_t{1} << (levels - shared);
  std::vector<double> load(static_cast<std::size_t>(comm.size()), 0.0), subtree(std::size_t{1} << shared, 0.0);
  double total = 0.0;
  for (std::size_t j = 0; j < serial.leaves().size(); ++j) {
    EXPECT_EQ(d.owner[j], d.owner[j / per * per]) << "leaf " << j;
    load[static_cast<std::size_t>(d.owner[j])] += serial.leaves()[j].weight;
    subtree[j / per] += serial.leaves()[j].weight;
    total += serial.leaves()[j].weight;
  }
  const double heaviest = *std::max_element(subtree.begin(), subtree.end());
  for (int r = 0; r < comm.size(); ++r) {
    EXPECT_EQ(d.load[static_cast<std::size_t>(r)], load[static_cast<std::size_t>(r)]) << "rank " << r;
    EXPECT_LE(load[static_cast<std::size_t>(r)], total / comm.size() + heaviest) << "rank " << r;
  }
  EXPECT_NEAR(d.imbalance, *std::max_element(load.begin(), load.end()) / (total / comm.size()), 1e-12);
}

// decompose() with a snapping grid (the distributed orb scheme with a gas): the serial OrbScheme's
// snapped tree on every rank, every cut on a cell face.
TEST(RankDecomposition, SnappedCutsAreTheSerialSnappedTree) {
  const cfddem::Communicator comm = cfddem::Communicator::world();
  const Aabb domain{{0.0, 0.0, 0.0}, {2.0, 1.0, 0.5}};
  const Points g = global_points(3000, 9, false, false);
  const Points l = local_share(g);
  const OrbOptions opt{5, Grid{{0.0, 0.0, 0.0}, {0.1, 0.05, 0.05}}};
  const RankDecomposition d = decompose(comm, l.x, l.y, l.z, {}, domain, opt);
  const OrbTree serial = OrbTree::build(g.x, g.y, g.z, {}, domain, opt);
  ASSERT_EQ(d.tree.cuts().size(), serial.cuts().size());
  for (std::size_t k = 0; k < serial.cuts().size(); ++k) {
    const OrbCut& c = d.tree.cuts()[k];
    EXPECT_EQ(c.axis, serial.cuts()[k].axis);
    EXPECT_EQ(c.position, serial.cuts()[k].position);
    const double cells = c.position / opt.snap->spacing[static_cast<std::size_t>(c.axis)];
    EXPECT_NEAR(cells, std::round(cells), 1e-9) << "cut " << k << " off the cell faces";
  }
}
