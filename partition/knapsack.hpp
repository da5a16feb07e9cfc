// Knapsack over ranks: cuts weighted boxes, listed along a space-filling curve, into R
// contiguous chunks with the smallest possible maximum load (the linear-partition problem).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

namespace cfddem::partition {

struct KnapsackAssignment {
  std::vector<int> owner; // rank of each item, indexed like the input weights
  std::vector<std::uint32_t>
      first;                // R+1 offsets along the curve: rank r has [first[r], first[r+1])
  std::vector<double> load; // per rank
  double max_load = 0.0;    // the bottleneck, optimal over all contiguous partitions
  double mean_load = 0.0;   // total / R
  double imbalance = 1.0;   // max_load / mean_load; 1 when every weight is zero
};

// Items in curve order. Optimal bottleneck (loads are differences of prefix sums, the same
// arithmetic the optimum is defined by). Among optimal partitions it picks one where no rank is
// empty while items remain; with R > items the last R - items ranks are empty.
// Throws std::invalid_argument for ranks < 1 or a negative / non-finite weight.
[[nodiscard]] KnapsackAssignment knapsack_contiguous(std::span<const double> weights, int ranks);

// Items in their own numbering, walked in `curve_order` (e.g. from sfc_order); owner is indexed
// by item, `first` by position along the curve.
[[nodiscard]] KnapsackAssignment knapsack_along_curve(std::span<const double> weights,
                                                      std::span<const std::uint32_t> curve_order,
                                                      int ranks);

} // namespace cfddem::partition
