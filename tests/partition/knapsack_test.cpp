// Knapsack over ranks: optimal contiguous bottleneck, empty ranks, imbalance.
#include "partition/knapsack.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <numeric>
#include <random>
#include <stdexcept>
#include <vector>

namespace cfddem::partition {
namespace {

// Minimum over every split of n items into `ranks` contiguous (possibly empty) chunks of the
// largest chunk load, with loads as prefix-sum differences like the solver's.
double brute_force_bottleneck(const std::vector<double>& w, int ranks) {
  std::vector<double> prefix(w.size() + 1, 0.0);
  for (std::size_t k = 0; k < w.size(); ++k) {
    prefix[k + 1] = prefix[k] + w[k];
  }
  double best = std::numeric_limits<double>::infinity();
  std::vector<std::size_t> ends(static_cast<std::size_t>(ranks), 0);
  // Enumerate non-decreasing end positions; the last rank always ends at n.
  auto rec = [&](auto&& self, int r, std::size_t start, double worst) -> void {
    if (r == ranks - 1) {
      best = std::min(best, std::max(worst, prefix[w.size()] - prefix[start]));
      return;
    }
    for (std::size_t end = start; end <= w.size(); ++end) {
      self(self, r + 1, end, std::max(worst, prefix[end] - prefix[start]));
    }
  };
  rec(rec, 0, 0, 0.0);
  return best;
}

void expect_consistent(const KnapsackAssignment& a, const std::vector<double>& w, int ranks) {
  ASSERT_EQ(a.owner.size(), w.size());
  ASSERT_EQ(a.first.size(), static_cast<std::size_t>(ranks) + 1);
  ASSERT_EQ(a.load.size(), static_cast<std::size_t>(ranks));
  EXPECT_EQ(a.first.front(), 0u);
  EXPECT_EQ(a.first.back(), w.size());
  for (int r = 0; r < ranks; ++r) {
    ASSERT_LE(a.first[r], a.first[r + 1]);
    double load = 0.0;
    for (std::uint32_t k = a.first[r]; k < a.first[r + 1]; ++k) {
      EXPECT_EQ(a.owner[k], r);
      load += w[k];
    }
    EXPECT_NEAR(a.load[r], load, 1e-12 * (1.0 + load));
  }
  EXPECT_EQ(a.max_load, *std::max_element(a.load.begin(), a.load.end()));
  const double total = std::accumulate(w.begin(), w.end(), 0.0);
  EXPECT_NEAR(a.mean_load, total / ranks, 1e-12 * (1.0 + total));
  if (total > 0.0) {
    EXPECT_DOUBLE_EQ(a.imbalance, a.max_load / a.mean_load);
  }
}

TEST(Knapsack, BottleneckMatchesBruteForce) {
  std::mt19937_64 rng(1);
  std::uniform_int_distribution<int> n_dist(0, 9);
  std::uniform_int_distribution<int> r_dist(1, 5);
  std::uniform_real_distribution<double> real(0.0, 10.0);
  std::uniform_int_distribution<int> small_int(0, 4);
  for (int trial = 0; trial < 400; ++trial) {
    const int n = n_dist(rng);
    const int ranks = r_dist(rng);
    std::vector<double> w(static_cast<std::size_t>(n));
    // Integer weights make ties (several optimal partitions) common; reals make them rare.
    for (double& x : w) {
      x = (trial % 2 == 0) ? real(rng) : small_int(rng);
    }
    const KnapsackAssignment a = knapsack_contiguous(w, ranks);
    expect_consistent(a, w, ranks);
    EXPECT_EQ(a.max_load, brute_force_bottleneck(w, ranks)) << "trial " << trial;
  }
}

TEST(Knapsack, MoreRanksThanItemsLeavesTrailingRanksEmpty) {
  const std::vector<double> w{2.0, 1.0, 3.0};
  const KnapsackAssignment a = knapsack_contiguous(w, 5);
  expect_consistent(a, w, 5);
  EXPECT_EQ(a.owner, (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(a.load, (std::vector<double>{2.0, 1.0, 3.0, 0.0, 0.0}));
  EXPECT_EQ(a.max_load, 3.0);
  EXPECT_DOUBLE_EQ(a.imbalance, 3.0 / (6.0 / 5.0));
}

TEST(Knapsack, NoRankIdlesWhileItemsRemain) {
  // Greedy packing would give {1,1} {1,1} {}: same bottleneck, one rank idle.
  const std::vector<double> w{1.0, 1.0, 1.0, 1.0};
  const KnapsackAssignment a = knapsack_contiguous(w, 3);
  EXPECT_EQ(a.max_load, 2.0);
  for (int r = 0; r < 3; ++r) {
    EXPECT_LT(a.first[r], a.first[r + 1]) << "rank " << r;
  }
}

TEST(Knapsack, ImbalanceIsMaxOverMean) {
  const KnapsackAssignment even = knapsack_contiguous(std::vector<double>{4, 1, 1, 1, 1}, 2);
  EXPECT_EQ(even.max_load, 4.0);
  EXPECT_EQ(even.imbalance, 1.0);
  const KnapsackAssignment heavy = knapsack_contiguous(std::vector<double>{5, 1, 1, 1}, 2);
  EXPECT_EQ(heavy.max_load, 5.0);
  EXPECT_EQ(heavy.mean_load, 4.0);
  EXPECT_EQ(heavy.imbalance, 1.25);
}

TEST(Knapsack, SingleRankTakesEverything) {
  const std::vector<double> w{0.5, 2.5, 1.0};
  const KnapsackAssignment a = knapsack_contiguous(w, 1);
  EXPECT_EQ(a.owner, (std::vector<int>{0, 0, 0}));
  EXPECT_EQ(a.max_load, 4.0);
  EXPECT_EQ(a.imbalance, 1.0);
}

TEST(Knapsack, ZeroWeightsAndNoItems) {
  const std::vector<double> zeros(6, 0.0);
  const KnapsackAssignment a = knapsack_contiguous(zeros, 3);
  expect_consistent(a, zeros, 3);
  EXPECT_EQ(a.max_load, 0.0);
  EXPECT_EQ(a.imbalance, 1.0);
  for (int r = 0; r < 3; ++r) {
    EXPECT_LT(a.first[r], a.first[r + 1]) << "rank " << r;
  }

  const KnapsackAssignment none = knapsack_contiguous(std::vector<double>{}, 4);
  EXPECT_TRUE(none.owner.empty());
  EXPECT_EQ(none.first, (std::vector<std::uint32_t>(5, 0)));
  EXPECT_EQ(none.imbalance, 1.0);
}

TEST(Knapsack, OptimumWithinOneItemOfTheMean) {
  // Any optimal contiguous split has max <= mean + max item: the classic bound.
  std::mt19937_64 rng(2);
  std::lognormal_distribution<double> cost(0.0, 1.0);
  std::vector<double> w(100000);
  for (double& x : w) {
    x = cost(rng);
  }
  const KnapsackAssignment a = knapsack_contiguous(w, 64);
  expect_consistent(a, w, 64);
  const double w_max = *std::max_element(w.begin(), w.end());
  EXPECT_LE(a.max_load, a.mean_load + w_max);
  EXPECT_LT(a.imbalance, 1.01);
}

TEST(Knapsack, AlongCurveReportsOwnersByItem) {
  const std::vector<double> w{1.0, 10.0, 1.0, 10.0};
  const std::vector<std::uint32_t> curve{1, 3, 0, 2}; // heavy items first along the curve
  const KnapsackAssignment a = knapsack_along_curve(w, curve, 2);
  EXPECT_EQ(a.max_load, 12.0); // {10} {10, 1, 1} beats {10, 10} {1, 1}
  EXPECT_EQ(a.owner[1], 0);
  EXPECT_EQ(a.owner[3], 1);
  EXPECT_EQ(a.owner[0], 1);
  EXPECT_EQ(a.owner[2], 1);
  EXPECT_THROW((void)knapsack_along_curve(w, std::vector<std::uint32_t>{0, 0, 1, 2}, 2),
               std::invalid_argument);
}

TEST(Knapsack, RejectsInvalidInput) {
  EXPECT_THROW((void)knapsack_contiguous(std::vector<double>{1.0}, 0), std::invalid_argument);
  EXPECT_THROW((void)knapsack_contiguous(std::vector<double>{1.0, -1.0}, 2), std::invalid_argument);
  EXPECT_THROW(
      (void)knapsack_contiguous(std::vector<double>{std::numeric_limits<double>::quiet_NaN()}, 2),
      std::invalid_argument);
}

} // namespace
} // namespace cfddem::partition
