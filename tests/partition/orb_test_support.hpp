// Shared fixtures of the ORB tests: random point clouds and the invariants every tree must keep.
#pragma once

#include "partition/orb_tree.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <random>
#include <vector>

namespace cfddem::partition::test {

struct Cloud {
  std::vector<double> x, y, z, w;
  [[nodiscard]] std::size_t size() const { return x.size(); }
  void push(double px, double py, double pz) {
    x.push_back(px);
    y.push_back(py);
    z.push_back(pz);
  }
  [[nodiscard]] std::array<double, 3> at(std::size_t i) const { return {x[i], y[i], z[i]}; }
};

inline const Aabb kUnitCube{{0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}};

inline Cloud uniform_cloud(std::size_t n, const Aabb& box, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  Cloud c;
  std::array<std::uniform_real_distribution<double>, 3> d{
      std::uniform_real_distribution<double>(box.lo[0], box.hi[0]),
      std::uniform_real_distribution<double>(box.lo[1], box.hi[1]),
      std::uniform_real_distribution<double>(box.lo[2], box.hi[2])};
  for (std::size_t i = 0; i < n; ++i) {
    c.push(d[0](rng), d[1](rng), d[2](rng));
  }
  return c;
}

inline OrbTree build(const Cloud& c, const Aabb& domain, const OrbOptions& opt) {
  return OrbTree::build(c.x, c.y, c.z, c.w, domain, opt);
}

// Box of internal node `node` (heap numbering), found by applying the cuts from the root.
inline Aabb node_box(const OrbTree& t, std::size_t node) {
  std::vector<std::size_t> path;
  for (std::size_t n = node; n > 0; n = (n - 1) / 2) {
    path.push_back(n);
  }
  Aabb box = t.domain();
  std::size_t parent = 0;
  for (auto it = path.rbegin(); it != path.rend(); ++it) {
    const OrbCut& cut = t.cuts()[parent];
    if (*it == 2 * parent + 1) {
      box.hi[cut.axis] = cut.position;
    } else {
      box.lo[cut.axis] = cut.position;
    }
    parent = *it;
  }
  return box;
}

// Leaves under node `node` at depth `depth`: [first, first + count).
inline std::pair<int, int> leaf_span(int levels, std::size_t node) {
  int depth = 0;
  while (((std::size_t{1} << (depth + 1)) - 1) <= node) {
    ++depth;
  }
  const std::size_t first_at_depth = (std::size_t{1} << depth) - 1;
  const int count = 1 << (levels - depth);
  return {static_cast<int>(node - first_at_depth) * count, count};
}

// Every invariant a built tree promises, checked point by point.
inline void expect_valid_tree(const OrbTree& t, const Cloud& c) {
  const std::size_t n = c.size();
  const auto order = t.order();
  const auto leaves = t.leaves();
  ASSERT_EQ(order.size(), n);
  ASSERT_EQ(leaves.size(), std::size_t{1} << t.levels());
  ASSERT_EQ(t.cuts().size(), leaves.size() - 1);

  std::vector<int> seen(n, 0);
  for (const std::uint32_t i : order) {
    ASSERT_LT(i, n);
    ++seen[i];
  }
  EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](int s) { return s == 1; }))
      << "order is not a permutation";

  std::uint32_t expected_begin = 0;
  double volume = 0.0;
  for (std::size_t j = 0; j < leaves.size(); ++j) {
    const OrbLeaf& leaf = leaves[j];
    EXPECT_EQ(leaf.id, static_cast<int>(j));
    EXPECT_EQ(leaf.begin, expected_begin) << "leaf " << j << " does not follow its predecessor";
    ASSERT_LE(leaf.begin, leaf.end);
    expected_begin = leaf.end;
    volume += leaf.box.volume();
    double weight = 0.0;
    for (std::uint32_t k = leaf.begin; k < leaf.end; ++k) {
      const std::uint32_t i = order[k];
      weight += c.w.empty() ? 1.0 : c.w[i];
      EXPECT_TRUE(owns_point(leaf.box, t.domain(), c.at(i)))
          << "point " << i << " outside the box of its leaf " << j;
      EXPECT_EQ(t.locate(c.x[i], c.y[i], c.z[i]), static_cast<int>(j))
          << "locate disagrees with the ranges for point " << i;
      if (k > leaf.begin) {
        EXPECT_LT(order[k - 1], i) << "leaf " << j << " not by index";
      }
    }
    EXPECT_DOUBLE_EQ(leaf.weight, weight);
  }
  EXPECT_EQ(expected_begin, n);
  EXPECT_NEAR(volume, t.domain().volume(), 1e-12 * t.domain().volume()) << "leaves do not tile";
}

} // namespace cfddem::partition::test
