// Connected components: against a brute-force flood fill on random graphs, independence of the
// edge order, and the degenerate inputs.
#include "partition/contact_islands.hpp"

#include <algorithm>
#include <random>
#include <stdexcept>

#include <gtest/gtest.h>

namespace cfddem::partition {
namespace {

// Flood fill over an adjacency matrix: component of every vertex, numbered by smallest vertex.
std::vector<std::uint32_t> flood(std::size_t n, const std::vector<std::uint32_t>& a,
                                 const std::vector<std::uint32_t>& b) {
  std::vector<std::vector<std::uint32_t>> adj(n);
  for (std::size_t q = 0; q < a.size(); ++q) adj[a[q]].push_back(b[q]), adj[b[q]].push_back(a[q]);
  std::vector<std::uint32_t> label(n, UINT32_MAX);
  std::uint32_t c = 0;
  for (std::size_t s = 0; s < n; ++s) {
    if (label[s] != UINT32_MAX) continue;
    std::vector<std::uint32_t> stack = {static_cast<std::uint32_t>(s)};
    label[s] = c;
    while (!stack.empty()) {
      const std::uint32_t v = stack.back();
      stack.pop_back();
      for (std::uint32_t w : adj[v])
        if (label[w] == UINT32_MAX) label[w] = c, stack.push_back(w);
    }
    ++c;
  }
  return label;
}

TEST(ContactIslands, MatchesFloodFillOnRandomGraphsWhateverTheEdgeOrder) {
  std::mt19937_64 rng(5);
  for (int trial = 0; trial < 50; ++trial) {
    const std::size_t n = 1 + rng() % 300;
    const std::size_t m = rng() % (2 * n);
    std::vector<std::uint32_t> a(m), b(m);
    for (std::size_t q = 0; q < m; ++q)
      a[q] = static_cast<std::uint32_t>(rng() % n), b[q] = static_cast<std::uint32_t>(rng() % n);
    const Islands isl = connected_components(n, a, b);
    EXPECT_EQ(isl.label, flood(n, a, b));
    // Members: each component's vertices in increasing order, sizes add up to n.
    ASSERT_EQ(isl.members.size(), n);
    for (std::uint32_t c = 0; c < isl.count(); ++c) {
      ASSERT_GT(isl.size(c), 0u);
      for (std::uint32_t k = isl.first[c]; k < isl.first[c + 1]; ++k) {
        EXPECT_EQ(isl.label[isl.members[k]], c);
        if (k > isl.first[c]) {
          EXPECT_LT(isl.members[k - 1], isl.members[k]);
        }
      }
    }
    // Reversed and shuffled edges, swapped ends: the same labels.
    std::vector<std::size_t> perm(m);
    for (std::size_t q = 0; q < m; ++q) perm[q] = q;
    std::shuffle(perm.begin(), perm.end(), rng);
    std::vector<std::uint32_t> a2(m), b2(m);
    for (std::size_t q = 0; q < m; ++q) a2[q] = b[perm[q]], b2[q] = a[perm[q]];
    EXPECT_EQ(connected_components(n, a2, b2).label, isl.label);
  }
}

TEST(ContactIslands, DegenerateInputs) {
  EXPECT_EQ(connected_components(0, {}, {}).count(), 0u);
  const Islands lone = connected_components(4, {}, {});
  EXPECT_EQ(lone.count(), 4u);
  const std::vector<std::uint32_t> self = {2}; // a self-loop joins nothing
  EXPECT_EQ(connected_components(3, self, self).count(), 3u);
  const std::vector<std::uint32_t> a = {0, 1, 2}, b = {1, 2, 3}; // a chain: one island
  const Islands chain = connected_components(4, a, b);
  EXPECT_EQ(chain.count(), 1u);
  EXPECT_EQ(chain.size(0), 4u);
  const std::vector<std::uint32_t> bad = {7};
  EXPECT_THROW((void)connected_components(3, bad, self), std::invalid_argument);
  EXPECT_THROW((void)connected_components(3, a, self), std::invalid_argument);
}

} // namespace
} // namespace cfddem::partition
