// ORB tree on degenerate inputs: no levels, no points, more leaves than points, one cluster,
// everything on the domain's hi face.
#include "orb_test_support.hpp"

namespace cfddem::partition {
namespace {

using test::build;
using test::Cloud;
using test::kUnitCube;
using test::uniform_cloud;

TEST(OrbTreeDegenerate, ZeroLevelsGivesOneLeafSpanningTheDomain) {
  const Cloud c = uniform_cloud(50, kUnitCube, 1);
  const OrbTree t = build(c, kUnitCube, {0, std::nullopt});
  test::expect_valid_tree(t, c);
  ASSERT_EQ(t.leaves().size(), 1u);
  EXPECT_EQ(t.leaves()[0].box, kUnitCube);
  EXPECT_EQ(t.leaves()[0].size(), 50u);
  EXPECT_TRUE(t.cuts().empty());
  EXPECT_EQ(t.locate(1.0, 1.0, 1.0), 0);
  EXPECT_EQ(t.leaves_overlapping(kUnitCube, {false, false, false}), std::vector<int>{0});
}

TEST(OrbTreeDegenerate, NoPointsStillTilesTheDomain) {
  const OrbTree t = build(Cloud{}, kUnitCube, {4, std::nullopt});
  test::expect_valid_tree(t, Cloud{});
  for (const OrbLeaf& leaf : t.leaves()) {
    EXPECT_EQ(leaf.size(), 0u);
    // Empty nodes are halved geometrically: 16 equal boxes.
    EXPECT_DOUBLE_EQ(leaf.box.volume(), 1.0 / 16.0);
  }
}

TEST(OrbTreeDegenerate, MoreLeavesThanPoints) {
  const Cloud c = uniform_cloud(5, kUnitCube, 2);
  const OrbTree t = build(c, kUnitCube, {6, std::nullopt});
  test::expect_valid_tree(t, c);
  int non_empty = 0;
  for (const OrbLeaf& leaf : t.leaves()) {
    EXPECT_LE(leaf.size(), 1u);
    non_empty += leaf.size() > 0 ? 1 : 0;
  }
  EXPECT_EQ(non_empty, 5);
}

TEST(OrbTreeDegenerate, IdenticalPointsStayTogetherInOneLeaf) {
  Cloud c;
  for (int i = 0; i < 1000; ++i) {
    c.push(0.3, 0.7, 0.3);
  }
  const OrbTree t = build(c, kUnitCube, {5, std::nullopt});
  test::expect_valid_tree(t, c);
  const int leaf = t.locate(0.3, 0.7, 0.3);
  EXPECT_EQ(t.leaves()[leaf].size(), 1000u);
}

TEST(OrbTreeDegenerate, ClusterPlusOutliersKeepsEveryPointInItsLeaf) {
  Cloud c = uniform_cloud(64, kUnitCube, 3);
  for (int i = 0; i < 500; ++i) {
    c.push(0.5, 0.5, 0.5); // right on the first geometric cut
  }
  const OrbTree t = build(c, kUnitCube, {6, std::nullopt});
  test::expect_valid_tree(t, c);
}

TEST(OrbTreeDegenerate, AllPointsOnTheDomainHiCornerClampIntoTheLastLeaf) {
  Cloud c;
  for (int i = 0; i < 20; ++i) {
    c.push(1.0, 1.0, 1.0);
  }
  const OrbTree t = build(c, kUnitCube, {3, std::nullopt});
  test::expect_valid_tree(t, c);
  EXPECT_EQ(t.leaves().back().size(), 20u);
  for (const OrbLeaf& leaf : t.leaves()) {
    EXPECT_GT(leaf.box.volume(), 0.0);
  }
}

TEST(OrbTreeDegenerate, PointsOnTheHiFaceMixedWithInteriorPoints) {
  Cloud c = uniform_cloud(200, kUnitCube, 4);
  for (int i = 0; i < 200; ++i) {
    c.push(1.0, c.y[i], c.z[i]);
  }
  const OrbTree t = build(c, kUnitCube, {4, std::nullopt});
  test::expect_valid_tree(t, c);
}

TEST(OrbTreeDegenerate, SnappedSingleCellDomain) {
  const Grid g{{0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}};
  const Cloud c = uniform_cloud(30, kUnitCube, 5);
  const OrbTree t = build(c, kUnitCube, {3, g});
  test::expect_valid_tree(t, c);
  // No cell face to cut on: every point ends in the last leaf, the rest are flat and empty.
  EXPECT_EQ(t.leaves().back().size(), 30u);
  EXPECT_EQ(t.leaves().back().box, kUnitCube);
}

TEST(OrbTreeDegenerate, ZeroWeightPointsAmongHeavyOnes) {
  Cloud c = uniform_cloud(400, kUnitCube, 6);
  for (std::size_t i = 0; i < c.size(); ++i) {
    c.w.push_back(i % 4 == 0 ? 1.0 : 0.0);
  }
  const OrbTree t = build(c, kUnitCube, {3, std::nullopt});
  test::expect_valid_tree(t, c);
  for (const OrbLeaf& leaf : t.leaves()) {
    EXPECT_NEAR(leaf.weight, 100.0 / 8.0, 1.0);
  }
}

} // namespace
} // namespace cfddem::partition
