// Space-filling curves: Morton's z-pattern, Hilbert's face adjacency, stable ordering.
#include "partition/space_filling_curve.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <random>
#include <vector>

namespace cfddem::partition {
namespace {

using Cell = std::array<std::uint32_t, 3>;

// All cells of the 2^k grid listed in key order.
std::vector<Cell> cells_in_key_order(CurveKind kind, int k, int bits) {
  const std::uint32_t n = 1u << k;
  std::vector<std::pair<std::uint64_t, Cell>> keyed;
  for (std::uint32_t x = 0; x < n; ++x) {
    for (std::uint32_t y = 0; y < n; ++y) {
      for (std::uint32_t z = 0; z < n; ++z) {
        keyed.push_back({curve_key(kind, {x, y, z}, bits), {x, y, z}});
      }
    }
  }
  std::sort(keyed.begin(), keyed.end());
  std::vector<Cell> out;
  for (std::size_t i = 0; i < keyed.size(); ++i) {
    // Keys of the 2^k cube are exactly 0 .. 8^k - 1: both curves fill it before leaving it.
    EXPECT_EQ(keyed[i].first, i) << "k = " << k << " bits = " << bits;
    out.push_back(keyed[i].second);
  }
  return out;
}

TEST(SpaceFillingCurve, MortonOrderOfTwoCubeIsZPattern) {
  const std::vector<Cell> expected{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0},
                                   {0, 0, 1}, {1, 0, 1}, {0, 1, 1}, {1, 1, 1}};
  EXPECT_EQ(cells_in_key_order(CurveKind::morton, 1, 1), expected);
  EXPECT_EQ(cells_in_key_order(CurveKind::morton, 1, kCurveBits), expected);
}

TEST(SpaceFillingCurve, MortonInterleavesAllTwentyOneBits) {
  const std::uint32_t all = (1u << 21) - 1;
  EXPECT_EQ(morton_key({all, 0, 0}), 0x1249249249249249ULL);
  EXPECT_EQ(morton_key({0, all, 0}), 0x1249249249249249ULL << 1);
  EXPECT_EQ(morton_key({0, 0, all}), 0x1249249249249249ULL << 2);
  EXPECT_EQ(morton_key({all, all, all}), (std::uint64_t{1} << 63) - 1);
  EXPECT_THROW((void)morton_key({1u << 21, 0, 0}), std::invalid_argument);
}

TEST(SpaceFillingCurve, HilbertNeighboursInKeyOrderAreFaceAdjacent) {
  for (const int bits_extra : {0, 1}) {
    for (int k = 1; k <= 5; ++k) {
      const int bits = bits_extra == 0 ? k : kCurveBits;
      const std::vector<Cell> path = cells_in_key_order(CurveKind::hilbert, k, bits);
      EXPECT_EQ(path.front(), (Cell{0, 0, 0}));
      for (std::size_t i = 1; i < path.size(); ++i) {
        int manhattan = 0;
        for (int a = 0; a < 3; ++a) {
          manhattan += std::abs(static_cast<int>(path[i][a]) - static_cast<int>(path[i - 1][a]));
        }
        ASSERT_EQ(manhattan, 1) << "k = " << k << " bits = " << bits << " step " << i;
      }
    }
  }
}

TEST(SpaceFillingCurve, HilbertKeysAreDistinctOnRandomCells) {
  std::mt19937_64 rng(1);
  std::uniform_int_distribution<std::uint32_t> u(0, (1u << 21) - 1);
  std::vector<std::uint64_t> keys;
  std::vector<Cell> cells;
  for (int i = 0; i < 20000; ++i) {
    cells.push_back({u(rng), u(rng), u(rng)});
  }
  std::sort(cells.begin(), cells.end());
  cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
  for (const Cell& c : cells) {
    keys.push_back(hilbert_key(c));
    EXPECT_LT(keys.back(), std::uint64_t{1} << 63);
  }
  std::sort(keys.begin(), keys.end());
  EXPECT_EQ(std::adjacent_find(keys.begin(), keys.end()), keys.end());
}

TEST(SpaceFillingCurve, CurveCellClampsTheHiFaceIntoTheLastCell) {
  const Aabb d{{-1.0, 0.0, 10.0}, {1.0, 4.0, 11.0}};
  EXPECT_EQ(curve_cell(d, {-1.0, 0.0, 10.0}), (Cell{0, 0, 0}));
  const std::uint32_t last = (1u << 21) - 1;
  EXPECT_EQ(curve_cell(d, {1.0, 4.0, 11.0}), (Cell{last, last, last}));
  EXPECT_EQ(curve_cell(d, {0.0, 2.0, 10.5}, 1), (Cell{1, 1, 1}));
  EXPECT_EQ(curve_cell(d, {-0.01, 1.99, 10.49}, 1), (Cell{0, 0, 0}));
  EXPECT_THROW((void)curve_cell(d, {1.01, 0.0, 10.0}), std::invalid_argument);
}

TEST(SpaceFillingCurve, SfcOrderOfBoxCentresFollowsTheCurve) {
  // Centres of a 2x2x2 block listed z-major: Morton must reorder them x-fastest.
  std::vector<std::array<double, 3>> centres;
  for (int x = 0; x < 2; ++x) {
    for (int y = 0; y < 2; ++y) {
      for (int z = 0; z < 2; ++z) {
        centres.push_back({x + 0.5, y + 0.5, z + 0.5});
      }
    }
  }
  const Aabb d{{0.0, 0.0, 0.0}, {2.0, 2.0, 2.0}};
  const std::vector<std::uint32_t> morton = sfc_order(centres, d, CurveKind::morton);
  EXPECT_EQ(morton, (std::vector<std::uint32_t>{0, 4, 2, 6, 1, 5, 3, 7}));
  const std::vector<std::uint32_t> hilbert = sfc_order(centres, d, CurveKind::hilbert);
  for (std::size_t i = 1; i < hilbert.size(); ++i) {
    double dist = 0.0;
    for (int a = 0; a < 3; ++a) {
      dist += std::abs(centres[hilbert[i]][a] - centres[hilbert[i - 1]][a]);
    }
    EXPECT_EQ(dist, 1.0) << "step " << i;
  }
}

TEST(SpaceFillingCurve, SfcOrderIsAStablePermutation) {
  std::mt19937_64 rng(2);
  std::uniform_int_distribution<int> u(0, 3);
  std::vector<std::array<double, 3>> centres;
  for (int i = 0; i < 500; ++i) {
    centres.push_back({u(rng) * 1.0, u(rng) * 1.0, u(rng) * 1.0});
  }
  for (const CurveKind kind : {CurveKind::morton, CurveKind::hilbert}) {
    const std::vector<std::uint32_t> order = sfc_order(centres, kind);
    std::vector<std::uint32_t> sorted = order;
    std::sort(sorted.begin(), sorted.end());
    for (std::uint32_t i = 0; i < sorted.size(); ++i) {
      ASSERT_EQ(sorted[i], i);
    }
    for (std::size_t k = 1; k < order.size(); ++k) {
      // Equal centres (equal keys) keep their input order.
      if (centres[order[k]] == centres[order[k - 1]]) {
        EXPECT_LT(order[k - 1], order[k]);
      }
    }
  }
  EXPECT_TRUE(sfc_order(std::vector<std::array<double, 3>>{}, CurveKind::hilbert).empty());
}

} // namespace
} // namespace cfddem::partition
