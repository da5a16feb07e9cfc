// Orthogonal recursive bisection (ORB) of a weighted point set into 2^L boxes: the serial
// decomposition every box, TBB task and knapsack item of cfddem comes from.
#pragma once

#include "partition/aabb.hpp"

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

namespace cfddem::partition {

// Cell faces of a uniform grid: origin + k * spacing, k integer. Cuts snapped to these
// keep every box a whole number of fluid cells.
struct Grid {
  std::array<double, 3> origin{0.0, 0.0, 0.0};
  std::array<double, 3> spacing{1.0, 1.0, 1.0};

  [[nodiscard]] double face(int axis, std::int64_t k) const {
    return origin[axis] + static_cast<double>(k) * spacing[axis];
  }
};

struct OrbOptions {
  int levels = 0;           // the tree has 2^levels leaves; 0 <= levels <= 24
  std::optional<Grid> snap; // when set, every cut lies on a face of this grid
};

// The cut of one internal node: points with coordinate[axis] < position go to the lower child.
struct OrbCut {
  int axis = 0;
  double position = 0.0;
};

struct OrbLeaf {
  Aabb box;                // half-open, closed on the domain's hi faces (see owns_point)
  std::uint32_t begin = 0; // [begin, end) into OrbTree::order()
  std::uint32_t end = 0;
  int id = 0;          // 0..2^L-1, depth first, lower child first
  double weight = 0.0; // sum of the weights of its points

  [[nodiscard]] std::uint32_t size() const { return end - begin; }
};

// A leaf seen through one periodic image: a halo point p of the query maps to the leaf's
// frame as p + shift[a] * domain.extent(a).
struct LeafImage {
  int leaf = 0;
  std::array<int, 3> shift{0, 0, 0};
};

class OrbTree {
public:
  // Bisects `domain` `options.levels` times. Each cut is along the box's longest extent (with
  // `snap`: the longest one that has an interior cell face) at the weighted median; points on a
  // cut go to the upper side, points on the domain's hi face into the last leaf.
  // Preconditions (std::invalid_argument otherwise): x, y, z of equal size < 2^32; weights
  // empty (each point weighs 1) or of that size, finite and >= 0; every point in the closed
  // domain; domain with positive extent on every axis; snap spacing > 0.
  // Postconditions: leaves() tiles the domain; leaf i owns order()[begin, end), listed in
  // increasing original index. Same input, same result bitwise, whatever the thread count or
  // machine: medians are taken in the total order (coordinate, index). With unit weights the
  // result does not even depend on the standard library's nth_element; with measured weights
  // the partial sums do, so use one build of the library across ranks.
  static OrbTree build(std::span<const double> x, std::span<const double> y,
                       std::span<const double> z, std::span<const double> weights,
                       const Aabb& domain, const OrbOptions& options);

  // The tree of given cuts (heap order, as cuts() returns them) over a local point set: what
  // each rank builds from the cuts the parallel ORB agreed on (parallel_orb.hpp). Leaves own
  // the local points that locate() puts in them, listed by increasing local index.
  static OrbTree from_cuts(std::span<const double> x, std::span<const double> y,
                           std::span<const double> z, const Aabb& domain, int levels,
                           std::vector<OrbCut> cuts);

  [[nodiscard]] int levels() const { return levels_; }
  [[nodiscard]] const Aabb& domain() const { return domain_; }
  // Internal nodes in heap order: node n has children 2n+1 (lower) and 2n+2 (upper);
  // leaf i is node 2^L - 1 + i.
  [[nodiscard]] std::span<const OrbCut> cuts() const { return cuts_; }
  [[nodiscard]] std::span<const OrbLeaf> leaves() const { return leaves_; }
  // order()[k] = original index of the k-th point once grouped by leaf.
  [[nodiscard]] std::span<const std::uint32_t> order() const { return order_; }

  // Leaf owning the point (same comparisons as build, so it agrees with the ranges);
  // -1 when the point lies outside the closed domain or is NaN. O(L).
  [[nodiscard]] int locate(double x, double y, double z) const;

  // Leaves whose box touches `query` or one of its periodic images (closed overlap, so the
  // answer is conservative). Sorted, no duplicates. The domain is the tree's own.
  [[nodiscard]] std::vector<int> leaves_overlapping(const Aabb& query,
                                                    std::array<bool, 3> periodic) const;
  // Same search, one entry per (leaf, image) pair, ordered by image then leaf: what a ghost
  // exchange needs to shift the copies it sends.
  [[nodiscard]] std::vector<LeafImage> leaf_images_overlapping(const Aabb& query,
                                                               std::array<bool, 3> periodic) const;

private:
  int levels_ = 0;
  Aabb domain_;
  std::vector<OrbCut> cuts_;
  std::vector<OrbLeaf> leaves_;
  std::vector<std::uint32_t> order_;
};

// The cuts build() makes below a node, over that node's points alone (heap order relative to
// the node: cut k has children 2k+1 and 2k+2): the cut rules depend only on a node's box and
// points, so these are the serial tree's cuts of that subtree. What a rank cuts alone once a
// subtree's points are all on it (parallel_orb.cpp). `box` may be thin (a zero-width sibling);
// the points must lie in it (not checked).
[[nodiscard]] std::vector<OrbCut> orb_subtree_cuts(std::span<const double> x,
                                                   std::span<const double> y,
                                                   std::span<const double> z,
                                                   std::span<const double> weights,
                                                   const Aabb& box, const OrbOptions& options);

} // namespace cfddem::partition
