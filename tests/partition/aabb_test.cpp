#include "partition/aabb.hpp"

#include <gtest/gtest.h>

namespace cfddem::partition {
namespace {

const Aabb kUnit{{0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}};

TEST(Aabb, ContainsIsHalfOpen) {
  EXPECT_TRUE(kUnit.contains({0.0, 0.0, 0.0}));
  EXPECT_TRUE(kUnit.contains({0.5, 0.999, 0.0}));
  EXPECT_FALSE(kUnit.contains({1.0, 0.5, 0.5}));
  EXPECT_FALSE(kUnit.contains({0.5, 0.5, 1.0}));
  EXPECT_FALSE(kUnit.contains({-1e-300, 0.5, 0.5}));
  EXPECT_TRUE(kUnit.contains_closed({1.0, 1.0, 1.0}));
}

TEST(Aabb, NeighbouringBoxesNeverShareAPoint) {
  const Aabb left{{0.0, 0.0, 0.0}, {0.5, 1.0, 1.0}};
  const Aabb right{{0.5, 0.0, 0.0}, {1.0, 1.0, 1.0}};
  for (const double x : {0.0, 0.25, 0.5, 0.75}) {
    EXPECT_NE(left.contains({x, 0.5, 0.5}), right.contains({x, 0.5, 0.5})) << x;
  }
}

TEST(Aabb, OwnsPointClosesOnlyTheDomainHiFaces) {
  const Aabb left{{0.0, 0.0, 0.0}, {0.5, 1.0, 1.0}};
  const Aabb right{{0.5, 0.0, 0.0}, {1.0, 1.0, 1.0}};
  EXPECT_TRUE(owns_point(right, kUnit, {1.0, 1.0, 1.0}));
  EXPECT_FALSE(owns_point(left, kUnit, {0.5, 1.0, 0.2}));
  EXPECT_TRUE(owns_point(left, kUnit, {0.2, 1.0, 1.0}));
}

TEST(Aabb, ExtentCentreAndLongestAxis) {
  const Aabb b{{1.0, -2.0, 0.0}, {2.0, 2.0, 4.0}};
  EXPECT_EQ(b.extent(1), 4.0);
  EXPECT_EQ(b.centre()[0], 1.5);
  EXPECT_EQ(b.centre()[1], 0.0);
  EXPECT_EQ(b.volume(), 16.0);
  EXPECT_EQ(b.longest_axis(), 1); // ties between y and z go to the lower axis
  EXPECT_EQ((Aabb{{0, 0, 0}, {1, 1, 3}}).longest_axis(), 2);
}

TEST(Aabb, TouchesCountsSharedFaces) {
  const Aabb right{{1.0, 0.0, 0.0}, {2.0, 1.0, 1.0}};
  EXPECT_TRUE(kUnit.touches(right));
  EXPECT_FALSE(kUnit.touches(Aabb{{1.5, 0.0, 0.0}, {2.0, 1.0, 1.0}}));
  EXPECT_TRUE(kUnit.grown(0.5).touches(Aabb{{1.5, 0.0, 0.0}, {2.0, 1.0, 1.0}}));
}

} // namespace
} // namespace cfddem::partition
