// ORB build: level by level over one work array of point copies (x, y, z, index), so the whole
// build allocates O(N + 2^L) once and costs O(N L) expected (nth_element per node).
#include "partition/orb_tree.hpp"
#include "partition/orb_cut_rules.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace cfddem::partition {
namespace {

using detail::FaceRange;
using detail::MedianStats;

constexpr int kMaxLevels = 24;

// A point as the build moves it: all three coordinates travel with the index, so no level has
// to gather coordinates through the permutation (a cache miss per point).
struct Keyed {
  std::array<double, 3> p;
  std::uint32_t i;
};

// Order along one axis. The index breaks ties so that the order is total and the median element
// is the same whatever nth_element does with equal coordinates.
struct KeyLess {
  int axis;
  bool operator()(const Keyed& a, const Keyed& b) const {
    return a.p[axis] < b.p[axis] || (a.p[axis] == b.p[axis] && a.i < b.i);
  }
};

struct PointSet {
  std::array<std::span<const double>, 3> coord;
  std::span<const double> weights;

  [[nodiscard]] double weight(std::uint32_t i) const { return weights.empty() ? 1.0 : weights[i]; }
};

struct NodeWork {
  Aabb box;
  std::uint32_t begin;
  std::uint32_t end;
};

// Position k in [b, e) of the weighted median in key order: weight before k < W/2 <= weight up
// to and including k. Afterwards items[b, k) < items[k] <= items(k, e) in key order.
std::uint32_t weighted_median(std::span<Keyed> items, int axis, std::uint32_t b, std::uint32_t e,
                              double total, const PointSet& pts, bool unit) {
  const KeyLess key_less{axis};
  auto at = [&](std::uint32_t k) { return items.begin() + k; };
  if (unit) {
    const std::uint32_t n = e - b;
    const std::uint32_t k = b + (n + 1) / 2 - 1;
    std::nth_element(at(b), at(k), at(e), key_less);
    return k;
  }
  // Quickselect by weight with nth_element as the partition step: each round halves the range,
  // so the expected cost stays O(n).
  const double half = 0.5 * total;
  double acc = 0.0; // weight of everything before lo
  std::uint32_t lo = b;
  std::uint32_t hi = e;
  while (hi - lo > 1) {
    const std::uint32_t m = lo + (hi - lo) / 2;
    std::nth_element(at(lo), at(m), at(hi), key_less);
    double wl = 0.0;
    for (std::uint32_t k = lo; k < m; ++k) {
      wl += pts.weight(items[k].i);
    }
    const double wm = pts.weight(items[m].i);
    if (acc + wl >= half) {
      hi = m;
    } else if (acc + wl + wm >= half) {
      return m;
    } else {
      acc += wl + wm;
      lo = m + 1;
    }
  }
  // Every round left [lo, hi) between smaller and larger keys, so a one-element range is in
  // place; an empty one means rounding missed W/2 by an ulp, and its left neighbour is the median.
  return lo < hi ? lo : hi - 1;
}

struct Split {
  OrbCut cut;
  std::uint32_t mid; // first point of the upper child
};

// Chooses the cut of one node and partitions its points around it.
Split split_node(std::span<Keyed> items, const NodeWork& node, const PointSet& pts,
                 const std::optional<Grid>& snap) {
  const Aabb& box = node.box;
  const std::uint32_t b = node.begin;
  const std::uint32_t e = node.end;

  FaceRange faces{0, -1};
  int axis = detail::cut_axis(box, snap, faces);
  if (axis < 0) {
    // No face to cut on: an empty lower sibling of zero width, every point goes up.
    axis = box.longest_axis();
    return {{axis, box.lo[axis]}, b};
  }
  double position = 0.0;
  const double mid_box = box.lo[axis] + 0.5 * box.extent(axis);
  if (b == e) {
    // No points: halve the space so later particles find sensible boxes.
    position = snap ? snap->face(axis, detail::nearest_face(*snap, axis, faces, mid_box)) : mid_box;
  } else {
    double total = 0.0;
    if (!pts.weights.empty()) {
      for (std::uint32_t k = b; k < e; ++k) {
        total += pts.weight(items[k].i);
      }
    }
    // All-zero measured cost carries no information: balance the counts instead.
    const bool unit = pts.weights.empty() || !(total > 0.0);
    auto weight = [&](std::uint32_t k) { return unit ? 1.0 : pts.weight(items[k].i); };
    if (unit) {
      total = static_cast<double>(e - b);
    }
    const double half = 0.5 * total;

    const std::uint32_t km = weighted_median(items, axis, b, e, total, pts, unit);
    const double cm = items[km].p[axis];

    if (!snap) {
      MedianStats st;
      st.cm = cm;
      st.half = half;
      for (std::uint32_t k = b; k < e; ++k) {
        const double c = items[k].p[axis];
        if (c < cm) {
          st.w_less += weight(k);
          st.prev = std::max(st.prev, c);
        } else if (c == cm) {
          st.w_eq += weight(k);
        } else {
          st.next = std::min(st.next, c);
        }
      }
      position = detail::free_cut(st, box.lo[axis], box.hi[axis]);
    } else {
      std::int64_t k0 = 0;
      std::int64_t k1 = 0;
      detail::faces_around(*snap, axis, faces, cm, k0, k1);
      const double f0 = snap->face(axis, k0);
      const double f1 = snap->face(axis, k1);
      double w0 = 0.0;
      double w1 = 0.0;
      for (std::uint32_t k = b; k < e; ++k) {
        const double c = items[k].p[axis];
        if (c < f0) {
          w0 += weight(k);
        }
        if (c < f1) {
          w1 += weight(k);
        }
      }
      position = detail::snapped_cut(f0, f1, w0, w1, half, cm);
    }
  }

  // Same comparison as locate(): strictly below the cut is lower, on or above is upper.
  auto first_upper = std::partition(items.begin() + b, items.begin() + e,
                                    [&](const Keyed& q) { return q.p[axis] < position; });
  return {{axis, position}, static_cast<std::uint32_t>(first_upper - items.begin())};
}

void check_inputs(const PointSet& pts, std::size_t n, const Aabb& domain,
                  const OrbOptions& options) {
  if (pts.coord[1].size() != n || pts.coord[2].size() != n) {
    throw std::invalid_argument("OrbTree::build: x, y, z must have the same size");
  }
  if (n >= std::numeric_limits<std::uint32_t>::max()) {
    throw std::invalid_argument("OrbTree::build: more than 2^32-2 points");
  }
  if (!pts.weights.empty() && pts.weights.size() != n) {
    throw std::invalid_argument("OrbTree::build: weights must be empty or one per point");
  }
  if (options.levels < 0 || options.levels > kMaxLevels) {
    throw std::invalid_argument("OrbTree::build: levels must be in [0, 24], got " +
                                std::to_string(options.levels));
  }
  for (int a = 0; a < 3; ++a) {
    if (!(domain.hi[a] > domain.lo[a]) || !std::isfinite(domain.extent(a))) {
      throw std::invalid_argument("OrbTree::build: domain needs lo < hi on every axis");
    }
    if (options.snap && !(options.snap->spacing[a] > 0.0)) {
      throw std::invalid_argument("OrbTree::build: snap spacing must be > 0");
    }
  }
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) {
      const double c = pts.coord[a][i];
      // Written so that NaN fails too.
      if (!(domain.lo[a] <= c && c <= domain.hi[a])) {
        throw std::invalid_argument("OrbTree::build: point " + std::to_string(i) +
                                    " lies outside the domain");
      }
    }
    if (!pts.weights.empty() && !(pts.weights[i] >= 0.0 && std::isfinite(pts.weights[i]))) {
      throw std::invalid_argument("OrbTree::build: weight of point " + std::to_string(i) +
                                  " is negative or not finite");
    }
  }
}

// Depth-first walk collecting the leaves whose box touches `q`.
void collect_touching(const OrbTree& tree, const Aabb& q, int node, const Aabb& box,
                      std::array<int, 3> shift, std::vector<LeafImage>& out) {
  const int first_leaf = (1 << tree.levels()) - 1;
  if (node >= first_leaf) {
    out.push_back({node - first_leaf, shift});
    return;
  }
  const OrbCut& cut = tree.cuts()[static_cast<std::size_t>(node)];
  Aabb lower = box;
  Aabb upper = box;
  lower.hi[cut.axis] = cut.position;
  upper.lo[cut.axis] = cut.position;
  if (lower.touches(q)) {
    collect_touching(tree, q, 2 * node + 1, lower, shift, out);
  }
  if (upper.touches(q)) {
    collect_touching(tree, q, 2 * node + 2, upper, shift, out);
  }
}

// The levels below `root` (a node whose points are items[root.begin, root.end)), level by
// level: each node's cut into `cuts` in heap order relative to the root (node k has children
// 2k+1 and 2k+2). Returns the leaves' work ranges, lower child first.
std::vector<NodeWork> cut_levels(std::span<Keyed> items, const PointSet& pts, const NodeWork& root,
                                 int levels, const std::optional<Grid>& snap,
                                 std::vector<OrbCut>& cuts) {
  const std::size_t n_leaves = std::size_t{1} << levels;
  cuts.resize(n_leaves - 1);
  std::vector<NodeWork> level{root};
  std::vector<NodeWork> next;
  level.reserve(n_leaves);
  next.reserve(n_leaves);
  for (int l = 0; l < levels; ++l) {
    next.resize(2 * level.size());
    const std::size_t first = level.size() - 1; // heap index of the level's first node
    for (std::size_t j = 0; j < level.size(); ++j) {
      const NodeWork& node = level[j];
      const Split s = split_node(items, node, pts, snap);
      cuts[first + j] = s.cut;
      NodeWork lower = node;
      NodeWork upper = node;
      lower.box.hi[s.cut.axis] = s.cut.position;
      lower.end = s.mid;
      upper.box.lo[s.cut.axis] = s.cut.position;
      upper.begin = s.mid;
      next[2 * j] = lower;
      next[2 * j + 1] = upper;
    }
    level.swap(next);
  }
  return level;
}

} // namespace

std::vector<OrbCut> orb_subtree_cuts(std::span<const double> x, std::span<const double> y,
                                     std::span<const double> z, std::span<const double> weights,
                                     const Aabb& box, const OrbOptions& options) {
  const PointSet pts{{x, y, z}, weights};
  const std::size_t n = x.size();
  if (y.size() != n || z.size() != n || (!weights.empty() && weights.size() != n) ||
      n >= std::numeric_limits<std::uint32_t>::max() || options.levels < 0 ||
      options.levels > kMaxLevels)
    throw std::invalid_argument("orb_subtree_cuts: sizes or levels out of range");
  const auto n32 = static_cast<std::uint32_t>(n);
  std::vector<Keyed> items(n);
  for (std::uint32_t i = 0; i < n32; ++i) {
    items[i] = {{x[i], y[i], z[i]}, i};
  }
  std::vector<OrbCut> cuts;
  cut_levels(items, pts, {box, 0, n32}, options.levels, options.snap, cuts);
  return cuts;
}

OrbTree OrbTree::build(std::span<const double> x, std::span<const double> y,
                       std::span<const double> z, std::span<const double> weights,
                       const Aabb& domain, const OrbOptions& options) {
  const PointSet pts{{x, y, z}, weights};
  const std::size_t n = x.size();
  check_inputs(pts, n, domain, options);
  const auto n32 = static_cast<std::uint32_t>(n);

  OrbTree tree;
  tree.levels_ = options.levels;
  tree.domain_ = domain;
  const std::size_t n_leaves = std::size_t{1} << options.levels;

  std::vector<Keyed> items(n);
  for (std::uint32_t i = 0; i < n32; ++i) {
    items[i] = {{x[i], y[i], z[i]}, i};
  }

  const std::vector<NodeWork> level =
      cut_levels(items, pts, {domain, 0, n32}, options.levels, options.snap, tree.cuts_);

  // The leaf sets are fixed by the cuts; listing each leaf's points by original index (a stable
  // counting sort) makes order() independent of how nth_element arranged them.
  std::vector<std::uint32_t> leaf_of(n);
  tree.leaves_.resize(n_leaves);
  std::vector<std::uint32_t> cursor(n_leaves);
  for (std::size_t j = 0; j < n_leaves; ++j) {
    const NodeWork& node = level[j];
    for (std::uint32_t k = node.begin; k < node.end; ++k) {
      leaf_of[items[k].i] = static_cast<std::uint32_t>(j);
    }
    tree.leaves_[j] = {node.box, node.begin, node.end, static_cast<int>(j), 0.0};
    cursor[j] = node.begin;
  }
  items = {}; // release before the order array is filled
  tree.order_.resize(n);
  for (std::uint32_t i = 0; i < n32; ++i) {
    const std::uint32_t leaf = leaf_of[i];
    tree.order_[cursor[leaf]++] = i;
    tree.leaves_[leaf].weight += pts.weight(i);
  }
  return tree;
}

OrbTree OrbTree::from_cuts(std::span<const double> x, std::span<const double> y,
                           std::span<const double> z, const Aabb& domain, int levels,
                           std::vector<OrbCut> cuts) {
  if (levels < 0 || levels > kMaxLevels || cuts.size() != (std::size_t{1} << levels) - 1) {
    throw std::invalid_argument("OrbTree::from_cuts: need 2^levels - 1 cuts");
  }
  OrbTree tree;
  tree.levels_ = levels;
  tree.domain_ = domain;
  tree.cuts_ = std::move(cuts);
  const std::size_t n_leaves = std::size_t{1} << levels;
  // Leaf boxes: walk the heap, narrowing the box at each cut.
  std::vector<Aabb> boxes(2 * n_leaves - 1);
  boxes[0] = domain;
  for (std::size_t node = 0; node + 1 < n_leaves; ++node) {
    const OrbCut& cut = tree.cuts_[node];
    boxes[2 * node + 1] = boxes[node];
    boxes[2 * node + 1].hi[cut.axis] = cut.position;
    boxes[2 * node + 2] = boxes[node];
    boxes[2 * node + 2].lo[cut.axis] = cut.position;
  }
  const std::size_t n = x.size();
  std::vector<std::uint32_t> leaf_of(n);
  std::vector<std::uint32_t> count(n_leaves + 1, 0);
  for (std::size_t i = 0; i < n; ++i) {
    const int leaf = tree.locate(x[i], y[i], z[i]);
    if (leaf < 0) {
      throw std::invalid_argument("OrbTree::from_cuts: point " + std::to_string(i) +
                                  " lies outside the domain");
    }
    leaf_of[i] = static_cast<std::uint32_t>(leaf);
    ++count[static_cast<std::size_t>(leaf) + 1];
  }
  for (std::size_t j = 0; j < n_leaves; ++j) {
    count[j + 1] += count[j];
  }
  tree.leaves_.resize(n_leaves);
  for (std::size_t j = 0; j < n_leaves; ++j) {
    tree.leaves_[j] = {boxes[n_leaves - 1 + j], count[j], count[j + 1], static_cast<int>(j),
                       static_cast<double>(count[j + 1] - count[j])};
  }
  tree.order_.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    tree.order_[count[leaf_of[i]]++] = static_cast<std::uint32_t>(i);
  }
  return tree;
}

int OrbTree::locate(double x, double y, double z) const {
  const std::array<double, 3> p{x, y, z};
  if (!domain_.contains_closed(p)) {
    return -1;
  }
  std::size_t node = 0;
  const std::size_t first_leaf = cuts_.size();
  while (node < first_leaf) {
    const OrbCut& cut = cuts_[node];
    node = 2 * node + (p[cut.axis] < cut.position ? 1 : 2);
  }
  return static_cast<int>(node - first_leaf);
}

std::vector<LeafImage> OrbTree::leaf_images_overlapping(const Aabb& query,
                                                        std::array<bool, 3> periodic) const {
  // Image s on axis a shifts the query by s * extent; keep the shifts that can reach the domain
  // (more than +-1 when the query is wider than the domain). One extra shift each side absorbs
  // the rounding of the division; the touch test below decides.
  std::array<std::int64_t, 3> smin{0, 0, 0};
  std::array<std::int64_t, 3> smax{0, 0, 0};
  for (int a = 0; a < 3; ++a) {
    if (!periodic[a]) {
      continue;
    }
    const double len = domain_.extent(a);
    const double from = std::ceil((domain_.lo[a] - query.hi[a]) / len) - 1.0;
    const double to = std::floor((domain_.hi[a] - query.lo[a]) / len) + 1.0;
    if (!(from <= to) || to - from > 1e6) {
      throw std::invalid_argument("OrbTree: halo query is not finite or spans > 1e6 images");
    }
    smin[a] = static_cast<std::int64_t>(from);
    smax[a] = static_cast<std::int64_t>(to);
  }
  std::vector<LeafImage> out;
  for (std::int64_t sz = smin[2]; sz <= smax[2]; ++sz) {
    for (std::int64_t sy = smin[1]; sy <= smax[1]; ++sy) {
      for (std::int64_t sx = smin[0]; sx <= smax[0]; ++sx) {
        const std::array<std::int64_t, 3> s{sx, sy, sz};
        Aabb q = query;
        for (int a = 0; a < 3; ++a) {
          const double d = static_cast<double>(s[a]) * domain_.extent(a);
          q.lo[a] += d;
          q.hi[a] += d;
        }
        if (!q.touches(domain_)) {
          continue;
        }
        collect_touching(*this, q, 0, domain_,
                         {static_cast<int>(sx), static_cast<int>(sy), static_cast<int>(sz)}, out);
      }
    }
  }
  return out;
}

std::vector<int> OrbTree::leaves_overlapping(const Aabb& query,
                                             std::array<bool, 3> periodic) const {
  std::vector<int> ids;
  for (const LeafImage& li : leaf_images_overlapping(query, periodic)) {
    ids.push_back(li.leaf);
  }
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  return ids;
}

} // namespace cfddem::partition
