#include "core/cell_box.hpp"

#include <stdexcept>
#include <utility>

#include <fmt/format.h>

namespace cfddem {

namespace {

// Cuts `box` into `parts` boxes appended to `out` in recursion order.
void bisect(const CellBox& box, int parts, int min_width, std::vector<CellBox>& out) {
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
    const int n = box.cells(axis);
    // Cells of the left part in proportion to its share of the parts, rounded to nearest.
    const auto share = static_cast<int>((static_cast<std::int64_t>(n) * left * 2 + parts) /
                                        (2 * static_cast<std::int64_t>(parts)));
    if (share < min_width || n - share < min_width) {
      continue;
    }
    CellBox lo_box = box;
    CellBox hi_box = box;
    lo_box.hi[axis] = box.lo[axis] + share;
    hi_box.lo[axis] = lo_box.hi[axis];
    bisect(lo_box, left, min_width, out);
    bisect(hi_box, parts - left, min_width, out);
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
  bisect(CellBox{{0, 0, 0}, cells}, parts, min_width, boxes);
  return boxes;
}

} // namespace cfddem
