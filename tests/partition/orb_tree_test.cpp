// ORB tree on ordinary inputs: tiling, balance, locate, snapping, determinism.
#include "orb_test_support.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <numeric>

namespace cfddem::partition {
namespace {

using test::build;
using test::Cloud;
using test::kUnitCube;
using test::uniform_cloud;

const Aabb kSlab{{-1.0, 0.0, 2.0}, {3.0, 1.0, 3.5}};

TEST(OrbTree, EveryPointInExactlyOneLeaf) {
  for (const int levels : {1, 3, 6}) {
    const Cloud c = uniform_cloud(5000, kSlab, 11 + levels);
    const OrbTree t = build(c, kSlab, {levels, std::nullopt});
    test::expect_valid_tree(t, c);
  }
}

// Each cut leaves |lower - upper| <= the heaviest point of the node, so sibling subtrees never
// differ by more than that, whatever the level.
void expect_siblings_balanced(const OrbTree& t, const Cloud& c) {
  double w_max = 1.0;
  if (!c.w.empty()) {
    w_max = *std::max_element(c.w.begin(), c.w.end());
  }
  const auto leaves = t.leaves();
  for (std::size_t node = 0; node < t.cuts().size(); ++node) {
    const auto [first, count] = test::leaf_span(t.levels(), node);
    double lower = 0.0;
    double upper = 0.0;
    for (int j = 0; j < count / 2; ++j) {
      lower += leaves[first + j].weight;
    }
    for (int j = count / 2; j < count; ++j) {
      upper += leaves[first + j].weight;
    }
    EXPECT_LE(std::abs(lower - upper), w_max * (1.0 + 1e-9)) << "node " << node;
  }
}

TEST(OrbTree, LeafCountsBalancedWithinOnePoint) {
  for (const std::size_t n : {1000u, 1001u, 4099u}) {
    const Cloud c = uniform_cloud(n, kUnitCube, n);
    const OrbTree t = build(c, kUnitCube, {6, std::nullopt});
    expect_siblings_balanced(t, c);
    for (const OrbLeaf& leaf : t.leaves()) {
      EXPECT_LE(std::abs(leaf.weight - static_cast<double>(n) / 64.0), 1.0);
    }
  }
}

TEST(OrbTree, LeafWeightsBalancedWithinMaxPointWeight) {
  Cloud c = uniform_cloud(3000, kSlab, 5);
  std::mt19937_64 rng(6);
  std::exponential_distribution<double> cost(1.0);
  for (std::size_t i = 0; i < c.size(); ++i) {
    c.w.push_back(cost(rng));
  }
  const OrbTree t = build(c, kSlab, {5, std::nullopt});
  test::expect_valid_tree(t, c);
  expect_siblings_balanced(t, c);
}

TEST(OrbTree, MeasuredCostMovesTheCut) {
  // Cost 3 on x < 0.5 and 1 above: half the total lies below x = 1/3.
  Cloud c = uniform_cloud(20000, kUnitCube, 7);
  for (const double x : c.x) {
    c.w.push_back(x < 0.5 ? 3.0 : 1.0);
  }
  const OrbTree t = build(c, kUnitCube, {1, std::nullopt});
  ASSERT_EQ(t.cuts()[0].axis, 0);
  EXPECT_NEAR(t.cuts()[0].position, 1.0 / 3.0, 0.02);
}

TEST(OrbTree, AllZeroWeightsBalanceCounts) {
  Cloud c = uniform_cloud(1024, kUnitCube, 8);
  c.w.assign(c.size(), 0.0);
  const OrbTree t = build(c, kUnitCube, {3, std::nullopt});
  for (const OrbLeaf& leaf : t.leaves()) {
    EXPECT_EQ(leaf.size(), 128u);
  }
}

TEST(OrbTree, CutsAlongLongestExtent) {
  const Aabb rod{{0.0, 0.0, 0.0}, {1.0, 8.0, 1.0}};
  const Cloud c = uniform_cloud(4000, rod, 9);
  const OrbTree t = build(c, rod, {3, std::nullopt});
  // y is 8 long: the first three cuts halve it (8 -> 4 -> 2 -> 1), never x or z.
  for (const OrbCut& cut : t.cuts()) {
    EXPECT_EQ(cut.axis, 1);
  }
}

TEST(OrbTree, LocateAgreesWithRangesForRandomPoints) {
  const Cloud c = uniform_cloud(2000, kSlab, 12);
  const OrbTree t = build(c, kSlab, {5, std::nullopt});
  // Fresh points not in the build: the leaf located must own them geometrically.
  const Cloud probe = uniform_cloud(5000, kSlab, 13);
  for (std::size_t i = 0; i < probe.size(); ++i) {
    const int leaf = t.locate(probe.x[i], probe.y[i], probe.z[i]);
    ASSERT_GE(leaf, 0);
    EXPECT_TRUE(owns_point(t.leaves()[leaf].box, t.domain(), probe.at(i))) << i;
  }
}

TEST(OrbTree, PointsOnACutGoToTheUpperSide) {
  const Cloud c = uniform_cloud(3000, kUnitCube, 14);
  const OrbTree t = build(c, kUnitCube, {4, std::nullopt});
  for (std::size_t node = 0; node < t.cuts().size(); ++node) {
    const OrbCut cut = t.cuts()[node];
    const Aabb box = test::node_box(t, node);
    std::array<double, 3> p = box.centre();
    p[cut.axis] = cut.position;
    const int leaf = t.locate(p[0], p[1], p[2]);
    const auto [first, count] = test::leaf_span(t.levels(), node);
    EXPECT_GE(leaf, first + count / 2) << "node " << node << " sent its cut point down";
    EXPECT_LT(leaf, first + count);
    EXPECT_TRUE(owns_point(t.leaves()[leaf].box, t.domain(), p));
  }
}

TEST(OrbTree, LocateAgreesWithRangesForPointsOnCutsAndFaces) {
  // A lattice that includes both domain faces: medians fall on lattice planes, so many points
  // lie exactly on cuts and on the hi faces.
  Cloud c;
  for (int i = 0; i <= 8; ++i) {
    for (int j = 0; j <= 8; ++j) {
      for (int k = 0; k <= 8; ++k) {
        c.push(i / 8.0, j / 8.0, k / 8.0);
      }
    }
  }
  const OrbTree t = build(c, kUnitCube, {6, std::nullopt});
  test::expect_valid_tree(t, c);
  int on_cut = 0;
  for (std::size_t i = 0; i < c.size(); ++i) {
    for (const OrbCut& cut : t.cuts()) {
      on_cut += (c.at(i)[cut.axis] == cut.position) ? 1 : 0;
    }
  }
  EXPECT_GT(on_cut, 0) << "the lattice was meant to put points on cuts";
}

TEST(OrbTree, DomainFacesAndCornersLocateIntoTheTree) {
  const Cloud c = uniform_cloud(1000, kSlab, 15);
  const OrbTree t = build(c, kSlab, {5, std::nullopt});
  const int last = (1 << 5) - 1;
  for (int corner = 0; corner < 8; ++corner) {
    std::array<double, 3> p{};
    for (int a = 0; a < 3; ++a) {
      p[a] = ((corner >> a) & 1) ? kSlab.hi[a] : kSlab.lo[a];
    }
    const int leaf = t.locate(p[0], p[1], p[2]);
    ASSERT_GE(leaf, 0);
    EXPECT_TRUE(owns_point(t.leaves()[leaf].box, kSlab, p));
  }
  EXPECT_EQ(t.locate(kSlab.hi[0], kSlab.hi[1], kSlab.hi[2]), last);
  EXPECT_EQ(t.locate(kSlab.lo[0], kSlab.lo[1], kSlab.lo[2]), 0);
  EXPECT_EQ(t.locate(std::nextafter(kSlab.hi[0], 10.0), 0.5, 3.0), -1);
  EXPECT_EQ(t.locate(0.0, -1e-12, 3.0), -1);
  EXPECT_EQ(t.locate(std::nan(""), 0.5, 3.0), -1);
}

TEST(OrbTree, SnappedCutsLieOnCellFaces) {
  // Grid not aligned with the domain's lo corner: faces at 0.05 + k * 0.1 (x) etc.
  const Grid g{{0.05, 0.0, 2.0}, {0.1, 0.125, 0.05}};
  const Cloud c = uniform_cloud(4000, kSlab, 16);
  const OrbTree t = build(c, kSlab, {6, g});
  test::expect_valid_tree(t, c);
  for (std::size_t node = 0; node < t.cuts().size(); ++node) {
    const OrbCut cut = t.cuts()[node];
    const double k = std::round((cut.position - g.origin[cut.axis]) / g.spacing[cut.axis]);
    EXPECT_EQ(cut.position, g.face(cut.axis, static_cast<std::int64_t>(k))) << "node " << node;
    const Aabb box = test::node_box(t, node);
    EXPECT_GT(cut.position, box.lo[cut.axis]) << "node " << node;
    EXPECT_LT(cut.position, box.hi[cut.axis]) << "node " << node;
  }
}

TEST(OrbTree, SnappedCutsStillBalanceToACellLayer) {
  // 64 cells per axis, 8 leaves: each leaf count within one cell layer of the exact share.
  const Grid g{{0.0, 0.0, 0.0}, {1.0 / 64, 1.0 / 64, 1.0 / 64}};
  const Cloud c = uniform_cloud(40000, kUnitCube, 17);
  const OrbTree t = build(c, kUnitCube, {3, g});
  for (const OrbLeaf& leaf : t.leaves()) {
    EXPECT_NEAR(leaf.weight, 5000.0, 0.06 * 5000.0);
  }
}

TEST(OrbTree, SnappedOneCellWideAlongLongestAxisCutsAnotherAxis) {
  const Aabb domain{{0.0, 0.0, 0.0}, {10.0, 2.0, 1.0}};
  const Grid g{{0.0, 0.0, 0.0}, {10.0, 1.0, 1.0}};
  const Cloud c = uniform_cloud(100, domain, 18);
  const OrbTree t = build(c, domain, {1, g});
  EXPECT_EQ(t.cuts()[0].axis, 1);
  EXPECT_EQ(t.cuts()[0].position, 1.0);
  test::expect_valid_tree(t, c);
}

TEST(OrbTree, SnappedNoInteriorFaceGivesEmptySibling) {
  const Aabb domain{{0.0, 0.0, 0.0}, {2.0, 1.0, 1.0}};
  const Grid g{{0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}};
  const Cloud c = uniform_cloud(100, domain, 19);
  const OrbTree t = build(c, domain, {2, g});
  test::expect_valid_tree(t, c);
  EXPECT_EQ(t.cuts()[0].position, 1.0);
  // Each one-cell half keeps its points in the upper child and gets an empty, flat sibling.
  for (const int empty_leaf : {0, 2}) {
    EXPECT_EQ(t.leaves()[empty_leaf].size(), 0u);
    EXPECT_EQ(t.leaves()[empty_leaf].box.volume(), 0.0);
  }
  EXPECT_EQ(t.leaves()[1].size() + t.leaves()[3].size(), 100u);
}

TEST(OrbTree, SameInputGivesBitwiseSameTree) {
  Cloud c = uniform_cloud(20000, kSlab, 20);
  std::mt19937_64 rng(21);
  std::uniform_real_distribution<double> cost(0.5, 2.0);
  for (std::size_t i = 0; i < c.size(); ++i) {
    c.w.push_back(cost(rng));
  }
  const OrbTree a = build(c, kSlab, {6, std::nullopt});
  const OrbTree b = build(c, kSlab, {6, std::nullopt});
  ASSERT_EQ(a.cuts().size(), b.cuts().size());
  for (std::size_t n = 0; n < a.cuts().size(); ++n) {
    EXPECT_EQ(a.cuts()[n].axis, b.cuts()[n].axis);
    EXPECT_EQ(std::bit_cast<std::uint64_t>(a.cuts()[n].position),
              std::bit_cast<std::uint64_t>(b.cuts()[n].position));
  }
  EXPECT_TRUE(std::equal(a.order().begin(), a.order().end(), b.order().begin()));
}

TEST(OrbTree, CutsDoNotDependOnInputOrderForDistinctPoints) {
  const Cloud c = uniform_cloud(5000, kSlab, 22);
  std::vector<std::size_t> perm(c.size());
  std::iota(perm.begin(), perm.end(), 0);
  std::shuffle(perm.begin(), perm.end(), std::mt19937_64(23));
  Cloud shuffled;
  for (const std::size_t i : perm) {
    shuffled.push(c.x[i], c.y[i], c.z[i]);
  }
  const OrbTree a = build(c, kSlab, {6, std::nullopt});
  const OrbTree b = build(shuffled, kSlab, {6, std::nullopt});
  for (std::size_t n = 0; n < a.cuts().size(); ++n) {
    EXPECT_EQ(a.cuts()[n].axis, b.cuts()[n].axis);
    EXPECT_EQ(a.cuts()[n].position, b.cuts()[n].position);
  }
}

TEST(OrbTree, RejectsInvalidInput) {
  const Cloud c = uniform_cloud(10, kUnitCube, 24);
  const std::vector<double> short_y(c.y.begin(), c.y.end() - 1);
  EXPECT_THROW((void)OrbTree::build(c.x, short_y, c.z, {}, kUnitCube, {1, std::nullopt}),
               std::invalid_argument);
  const std::vector<double> w_bad(c.size(), -1.0);
  EXPECT_THROW((void)OrbTree::build(c.x, c.y, c.z, w_bad, kUnitCube, {1, std::nullopt}),
               std::invalid_argument);
  Cloud outside = c;
  outside.x[3] = 1.5;
  EXPECT_THROW((void)build(outside, kUnitCube, {1, std::nullopt}), std::invalid_argument);
  Cloud nan = c;
  nan.z[2] = std::nan("");
  EXPECT_THROW((void)build(nan, kUnitCube, {1, std::nullopt}), std::invalid_argument);
  EXPECT_THROW((void)build(c, kUnitCube, {25, std::nullopt}), std::invalid_argument);
  EXPECT_THROW((void)build(c, kUnitCube, {-1, std::nullopt}), std::invalid_argument);
  const Aabb flat{{0.0, 0.0, 0.0}, {1.0, 1.0, 0.0}};
  EXPECT_THROW((void)build(Cloud{}, flat, {1, std::nullopt}), std::invalid_argument);
}

} // namespace
} // namespace cfddem::partition
