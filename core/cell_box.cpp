#include "core/cell_box.hpp"

#include <cmath>
#include <stdexcept>
#include <utility>

#include <fmt/format.h>

namespace cfddem {

namespace {

// The face (cells of the left part) where the cut falls: the weighted rule of the header, or
// the share of the cells in proportion to the parts when there are no weights. -1: the box is
// too narrow along this axis.
int cut_face(const CellBox& box, int axis, int parts, int left, int min_width,
             const SlabWeights* slab_weights) {
  const int n = box.cells(axis);
  if (n < 2 * min_width) {
    return -1;
  }
  if (slab_weights != nullptr) {
    const std::vector<double> w = (*slab_weights)(box, axis);
    if (static_cast<int>(w.size()) != n) {
      throw std::invalid_argument(fmt::format(
          "fluid grid: {} slab weights for a box {} cells long along axis {}", w.size(), n, axis));
    }
    double total = 0.0;
    for (const double v : w) {
      total += v;
    }
    if (total > 0.0) {
      // Compare left * total with parts * (weight left of the face): exact for integer weights,
      // so equal weights tie exactly where the cell-count rule rounds half up.
      const double target = static_cast<double>(left) * total;
      double prefix = 0.0;
      int best = -1;
      double best_gap = 0.0;
      for (int s = 0; s < n - min_width; ++s) {
        prefix += w[static_cast<std::size_t>(s)];
        const int face = s + 1;
        if (face < min_width) {
          continue;
        }
        const double gap = std::abs(static_cast<double>(parts) * prefix - target);
        if (best < 0 || gap <= best_gap) {
          best = face, best_gap = gap;
        }
      }
      return best;
    }
  }
  // Cells of the left part in proportion to its share of the parts, rounded to nearest.
  const auto share = static_cast<int>((static_cast<std::int64_t>(n) * left * 2 + parts) /
                                      (2 * static_cast<std::int64_t>(parts)));
  if (share < min_width || n - share < min_width) {
    return -1;
  }
  return share;
}

// Cuts `box` into `parts` boxes appended to `out` in recursion order.
void bisect(const CellBox& box, int parts, int min_width, const SlabWeights* slab_weights,
            std::vector<CellBox>& out) {
  if (parts == 1) {
    out.push_back(box);
    return;
  }
  const int left = parts / 2;
  // Axes by decreasing cell count: the longest cut keeps boxes compact (least halo surface).
  std::array<int, 3> order = {0, 1, 2};
  for (int i = 0; i < 3; ++i) {
    for (int j = i + 1; j < 3; ++j) {
      if (box.cells(order[j]) > box.cells(order[i])) {
        std::swap(order[i], order[j]);
      }
    }
  }
  for (const int axis : order) {
    const int share = cut_face(box, axis, parts, left, min_width, slab_weights);
    if (share < 0) {
      continue;
    }
    CellBox lo_box = box;
    CellBox hi_box = box;
    lo_box.hi[axis] = box.lo[axis] + share;
    hi_box.lo[axis] = lo_box.hi[axis];
    bisect(lo_box, left, min_width, slab_weights, out);
    bisect(hi_box, parts - left, min_width, slab_weights, out);
    return;
  }
  throw std::invalid_argument(fmt::format(
      "fluid grid: a box of {} x {} x {} cells cannot be cut into {} parts of at least {} "
      "cells along the cut (use fewer ranks or more fluid cells)",
      box.cells(0), box.cells(1), box.cells(2), parts, min_width));
}

} // namespace

std::vector<CellBox> orb_cell_boxes(const std::array<int, 3>& cells, int parts, int min_width) {
  if (parts < 1) {
    throw std::invalid_argument(fmt::format("fluid grid: {} parts (need at least 1)", parts));
  }
  std::vector<CellBox> boxes;
  boxes.reserve(static_cast<std::size_t>(parts));
  bisect(CellBox{{0, 0, 0}, cells}, parts, min_width, nullptr, boxes);
  return boxes;
}

std::vector<CellBox> orb_cell_boxes(const std::array<int, 3>& cells, int parts, int min_width,
                                    const SlabWeights& slab_weights) {
  if (parts < 1) {
    throw std::invalid_argument(fmt::format("fluid grid: {} parts (need at least 1)", parts));
  }
  std::vector<CellBox> boxes;
  boxes.reserve(static_cast<std::size_t>(parts));
  bisect(CellBox{{0, 0, 0}, cells}, parts, min_width, &slab_weights, boxes);
  return boxes;
}

} // namespace cfddem
