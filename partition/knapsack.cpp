// Linear partition by binary search on the bottleneck: the smallest load B for which the greedy
// probe (each rank takes the longest chunk with load <= B, found by binary search on the prefix
// sums) covers all items with R ranks. The search runs over the bit patterns of non-negative
// doubles, which order like the values, so it ends on the exact optimum in <= 64 probes of
// O(R log n) each, with no tolerance to tune.
#include "partition/knapsack.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace cfddem::partition {
namespace {

// Largest j in [i, n] with prefix[j] - prefix[i] <= bound (rounded subtraction is monotone in
// prefix[j], and prefix is non-decreasing, so the predicate flips once).
std::size_t longest_chunk_end(std::span<const double> prefix, std::size_t i, double bound) {
  std::size_t lo = i; // satisfies the predicate
  std::size_t hi = prefix.size();
  while (hi - lo > 1) {
    const std::size_t mid = lo + (hi - lo) / 2;
    if (prefix[mid] - prefix[i] <= bound) {
      lo = mid;
    } else {
      hi = mid;
    }
  }
  return lo;
}

bool fits(std::span<const double> prefix, int ranks, double bound) {
  const std::size_t n = prefix.size() - 1;
  std::size_t i = 0;
  for (int r = 0; r < ranks && i < n; ++r) {
    const std::size_t j = longest_chunk_end(prefix, i, bound);
    if (j == i) {
      return false; // one item alone is heavier than bound
    }
    i = j;
  }
  return i == n;
}

} // namespace

KnapsackAssignment knapsack_contiguous(std::span<const double> weights, int ranks) {
  if (ranks < 1) {
    throw std::invalid_argument("knapsack: ranks must be >= 1, got " + std::to_string(ranks));
  }
  const std::size_t n = weights.size();
  if (n >= std::numeric_limits<std::uint32_t>::max()) {
    throw std::invalid_argument("knapsack: more than 2^32-2 items");
  }
  std::vector<double> prefix(n + 1, 0.0);
  for (std::size_t k = 0; k < n; ++k) {
    if (!(weights[k] >= 0.0 && std::isfinite(weights[k]))) {
      throw std::invalid_argument("knapsack: weight of item " + std::to_string(k) +
                                  " is negative or not finite");
    }
    prefix[k + 1] = prefix[k] + weights[k];
  }
  const double total = prefix[n];
  if (!std::isfinite(total)) {
    throw std::invalid_argument("knapsack: total weight overflows");
  }

  // Smallest feasible bound; `total` (one chunk) always fits.
  std::uint64_t lo = 0;
  auto hi = std::bit_cast<std::uint64_t>(total);
  while (lo < hi) {
    const std::uint64_t mid = lo + (hi - lo) / 2;
    if (fits(prefix, ranks, std::bit_cast<double>(mid))) {
      hi = mid;
    } else {
      lo = mid + 1;
    }
  }
  const auto bottleneck = std::bit_cast<double>(hi);

  KnapsackAssignment out;
  const auto r_count = static_cast<std::size_t>(ranks);
  out.owner.assign(n, 0);
  out.first.assign(r_count + 1, static_cast<std::uint32_t>(n));
  out.load.assign(r_count, 0.0);
  std::size_t i = 0;
  for (std::size_t r = 0; r < r_count; ++r) {
    out.first[r] = static_cast<std::uint32_t>(i);
    const std::size_t left = n - i;
    const std::size_t ranks_after = r_count - r - 1;
    std::size_t j = longest_chunk_end(prefix, i, bottleneck);
    // Stop short so every later rank still gets an item: each item alone is <= bottleneck,
    // so the rest stays feasible, and no rank idles while items remain.
    if (left > ranks_after) {
      j = std::min(j, n - ranks_after);
    } else {
      j = std::min(j, i + (left > 0 ? 1 : 0));
    }
    for (std::size_t k = i; k < j; ++k) {
      out.owner[k] = static_cast<int>(r);
    }
    out.load[r] = prefix[j] - prefix[i];
    i = j;
  }
  out.max_load = *std::max_element(out.load.begin(), out.load.end());
  out.mean_load = total / static_cast<double>(ranks);
  out.imbalance = out.mean_load > 0.0 ? out.max_load / out.mean_load : 1.0;
  return out;
}

KnapsackAssignment knapsack_along_curve(std::span<const double> weights,
                                        std::span<const std::uint32_t> curve_order, int ranks) {
  if (curve_order.size() != weights.size()) {
    throw std::invalid_argument("knapsack: curve order and weights differ in size");
  }
  std::vector<double> along(weights.size());
  std::vector<bool> seen(weights.size(), false);
  for (std::size_t k = 0; k < curve_order.size(); ++k) {
    const std::uint32_t item = curve_order[k];
    if (item >= weights.size() || seen[item]) {
      throw std::invalid_argument("knapsack: curve order is not a permutation");
    }
    seen[item] = true;
    along[k] = weights[item];
  }
  KnapsackAssignment out = knapsack_contiguous(along, ranks);
  std::vector<int> owner(weights.size());
  for (std::size_t k = 0; k < curve_order.size(); ++k) {
    owner[curve_order[k]] = out.owner[k];
  }
  out.owner = std::move(owner);
  return out;
}

} // namespace cfddem::partition
