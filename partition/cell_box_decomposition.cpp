#include "partition/cell_box_decomposition.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <stdexcept>
#include <vector>

namespace cfddem::partition {

namespace {

struct Builder {
  std::span<const CellBox> boxes;
  std::array<double, 3> origin{}, spacing{};
  int levels = 0;
  std::vector<OrbCut> cuts;
  std::vector<int> owner;

  [[nodiscard]] double face(int axis, double k) const { return origin[axis] + k * spacing[axis]; }

  // Node `node` (heap order) at `depth` covers `region` and holds the boxes `group`.
  void split(std::size_t node, int depth, const CellBox& region, const std::vector<int>& group) {
    const std::size_t leaves = std::size_t{1} << levels;
    if (depth == levels) {
      if (group.size() != 1) {
        throw std::invalid_argument("cell box decomposition: more boxes than leaves");
      }
      owner[node - (leaves - 1)] = group.front();
      return;
    }
    int best_axis = -1, best_face = 0;
    std::size_t best_low = 0;
    const std::size_t half = group.size() / 2;
    if (group.size() > 1) {
      // The separating face that splits the group most evenly (the bisection's own cut).
      for (int a = 0; a < 3; ++a) {
        for (const int b : group) {
          const int f = boxes[static_cast<std::size_t>(b)].hi[a];
          if (f >= region.hi[a]) {
            continue;
          }
          std::size_t low = 0;
          bool separates = true;
          for (const int c : group) {
            const CellBox& box = boxes[static_cast<std::size_t>(c)];
            low += box.hi[a] <= f ? 1 : 0;
            separates = separates && (box.hi[a] <= f || box.lo[a] >= f);
          }
          const auto gap = [&](std::size_t l) { return l > half ? l - half : half - l; };
          if (separates && (best_axis < 0 || gap(low) < gap(best_low))) {
            best_axis = a, best_face = f, best_low = low;
          }
        }
      }
      if (best_axis < 0) {
        throw std::invalid_argument(
            "cell box decomposition: the boxes are not a bisection (no face separates them)");
      }
    }
    std::vector<int> lo_group, hi_group;
    CellBox lo_region = region, hi_region = region;
    if (best_axis < 0) {
      // One box left: halve its longest side (both halves its owner's); a one-cell side is cut
      // at its centre, which is no cell face but then no particle search depends on it.
      int a = 0;
      for (int b = 1; b < 3; ++b) {
        a = region.cells(b) > region.cells(a) ? b : a;
      }
      const double k = region.lo[a] + 0.5 * region.cells(a);
      cuts[node] = OrbCut{a, face(a, region.cells(a) > 1 ? std::floor(k) : k)};
      split(2 * node + 1, depth + 1, region, group);
      split(2 * node + 2, depth + 1, region, group);
      return;
    }
    for (const int c : group) {
      (boxes[static_cast<std::size_t>(c)].hi[best_axis] <= best_face ? lo_group : hi_group)
          .push_back(c);
    }
    lo_region.hi[best_axis] = best_face;
    hi_region.lo[best_axis] = best_face;
    cuts[node] = OrbCut{best_axis, face(best_axis, best_face)};
    split(2 * node + 1, depth + 1, lo_region, lo_group);
    split(2 * node + 2, depth + 1, hi_region, hi_group);
  }
};

} // namespace

RankDecomposition decomposition_of_cell_boxes(std::span<const CellBox> boxes,
                                              const std::array<double, 3>& origin,
                                              const std::array<double, 3>& spacing,
                                              const Aabb& domain) {
  if (boxes.empty()) {
    throw std::invalid_argument("cell box decomposition: no boxes");
  }
  Builder b{boxes, origin, spacing, 0, {}, {}};
  while ((std::size_t{1} << b.levels) < boxes.size()) {
    ++b.levels;
  }
  const std::size_t leaves = std::size_t{1} << b.levels;
  b.cuts.resize(leaves - 1);
  b.owner.assign(leaves, -1);
  CellBox all = boxes.front();
  std::vector<int> group;
  for (std::size_t r = 0; r < boxes.size(); ++r) {
    for (int a = 0; a < 3; ++a) {
      all.lo[a] = std::min(all.lo[a], boxes[r].lo[a]);
      all.hi[a] = std::max(all.hi[a], boxes[r].hi[a]);
    }
    group.push_back(static_cast<int>(r));
  }
  b.split(0, 0, all, group);
  RankDecomposition d;
  d.tree = OrbTree::from_cuts({}, {}, {}, domain, b.levels, std::move(b.cuts));
  d.owner = std::move(b.owner);
  d.load.assign(boxes.size(), 0.0);
  return d;
}

} // namespace cfddem::partition
