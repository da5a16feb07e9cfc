#include "core/cell_box.hpp"

#include <array>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <utility>

#include <fmt/format.h>

namespace cfddem {

namespace {

// Cut faces fall, where the balance allows, on multiples of a granule of the global grid, so
// that every box divides down the distributed multigrid's levels: a level coarsens an axis over
// the ranks only where its ratio divides every box's ends there, and the first level that
// coarsens none is gathered onto rank 0 and solved there alone (docs/multigrid.md). Cut at the
// share's nearest face instead, the 1e5 riser's 84 x 50 x 88 cells on 16 ranks gathered
// 42 x 50 x 44 cells, a quarter of the grid, onto one rank. An axis's granules follow its
// one-grid ratios (fluid/multigrid_poisson.cpp): halvings while its count is even, then thirds
// while 3 divides it (270: 2, 6, 18, 54), the powers of two up to kMaxPowerOfTwo and the whole
// granule up to kMaxGranule.
constexpr int kMaxPowerOfTwo = 16;
constexpr int kMaxGranule = 54;
// A cut moved onto a granule may put at most this fraction of the left part's exact share more
// or fewer cells in it (an imbalance of the gas's fine-level work, against the serial coarse
// level it removes).
constexpr std::int64_t kGranuleSlack = 16; // 1/16

// An axis of n cells' granules, coarsest first, ending with 1 (each divides the one before).
// An axis that halves unevenly (its high side a wall or inflow: an odd count halves to
// (n + 1) / 2, the last coarse cell with one child) halves at every level, so its interior cuts
// want powers of two whatever n is.
std::vector<int> granules_of(int n, bool halves_unevenly) {
  std::vector<int> chain = {1};
  int g = 1;
  while (g < kMaxPowerOfTwo && (halves_unevenly || n % (2 * g) == 0)) {
    g *= 2;
    chain.push_back(g);
  }
  while ((n / g) % 2 != 0 && 3 * g <= kMaxGranule && n % (3 * g) == 0) {
    g *= 3;
    chain.push_back(g);
  }
  return {chain.rbegin(), chain.rend()};
}

// The face (cells of the left part) where the cut falls: the weighted rule of the header, or
// the share of the cells in proportion to the parts when there are no weights, each on the
// coarsest of the axis's granules (in global face indices) whose face stays within
// 1/kGranuleSlack of the exact share. -1: the box is too narrow along this axis.
int cut_face(const CellBox& box, int axis, int parts, int left, int min_width,
             const std::vector<int>& granules, const SlabWeights* slab_weights) {
  const int n = box.cells(axis);
  if (n < 2 * min_width) {
    return -1;
  }
  const int lo = box.lo[axis];
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
      for (const int g : granules) {
        double prefix = 0.0;
        int best = -1;
        double best_gap = 0.0;
        for (int s = 0; s < n - min_width; ++s) {
          prefix += w[static_cast<std::size_t>(s)];
          const int face = s + 1;
          if (face < min_width || (lo + face) % g != 0) {
            continue;
          }
          const double gap = std::abs(static_cast<double>(parts) * prefix - target);
          if (best < 0 || gap <= best_gap) {
            best = face, best_gap = gap;
          }
        }
        if (best >= 0 && (g == 1 || static_cast<double>(kGranuleSlack) * best_gap <= target)) {
          return best;
        }
      }
      return -1;
    }
  }
  // Cells of the left part in proportion to its share of the parts, rounded to nearest (half
  // up) on the granule: exact share x = n left / parts, face on multiples of g of the global
  // grid nearest to lo + x.
  const auto P = static_cast<std::int64_t>(parts);
  const std::int64_t exact = static_cast<std::int64_t>(n) * left; // x P
  for (const int g : granules) {
    const std::int64_t G = g;
    const std::int64_t at = 2 * (static_cast<std::int64_t>(lo) * P + exact) + G * P;
    const auto share = static_cast<int>(at / (2 * G * P) * G - lo);
    const std::int64_t miss = std::abs(static_cast<std::int64_t>(share) * P - exact);
    if (share < min_width || n - share < min_width ||
        (g > 1 && kGranuleSlack * miss > exact)) {
      continue;
    }
    return share;
  }
  return -1;
}

// Cuts `box` into `parts` boxes appended to `out` in recursion order.
void bisect(const CellBox& box, int parts, int min_width,
            const std::array<std::vector<int>, 3>& granules,
            const SlabWeights* slab_weights, std::vector<CellBox>& out) {
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
    const int share = cut_face(box, axis, parts, left, min_width,
                               granules[static_cast<std::size_t>(axis)], slab_weights);
    if (share < 0) {
      continue;
    }
    CellBox lo_box = box;
    CellBox hi_box = box;
    lo_box.hi[axis] = box.lo[axis] + share;
    hi_box.lo[axis] = lo_box.hi[axis];
    bisect(lo_box, left, min_width, granules, slab_weights, out);
    bisect(hi_box, parts - left, min_width, granules, slab_weights, out);
    return;
  }
  throw std::invalid_argument(fmt::format(
      "fluid grid: a box of {} x {} x {} cells cannot be cut into {} parts of at least {} "
      "cells along the cut (use fewer ranks or more fluid cells)",
      box.cells(0), box.cells(1), box.cells(2), parts, min_width));
}

std::array<std::vector<int>, 3> granules(const std::array<int, 3>& cells,
                                         const std::array<bool, 3>& halves_unevenly) {
  return {granules_of(cells[0], halves_unevenly[0]), granules_of(cells[1], halves_unevenly[1]),
          granules_of(cells[2], halves_unevenly[2])};
}

} // namespace

std::vector<CellBox> orb_cell_boxes(const std::array<int, 3>& cells, int parts, int min_width,
                                    const std::array<bool, 3>& halves_unevenly) {
  if (parts < 1) {
    throw std::invalid_argument(fmt::format("fluid grid: {} parts (need at least 1)", parts));
  }
  std::vector<CellBox> boxes;
  boxes.reserve(static_cast<std::size_t>(parts));
  bisect(CellBox{{0, 0, 0}, cells}, parts, min_width, granules(cells, halves_unevenly), nullptr,
         boxes);
  return boxes;
}

std::vector<CellBox> orb_cell_boxes(const std::array<int, 3>& cells, int parts, int min_width,
                                    const SlabWeights& slab_weights,
                                    const std::array<bool, 3>& halves_unevenly) {
  if (parts < 1) {
    throw std::invalid_argument(fmt::format("fluid grid: {} parts (need at least 1)", parts));
  }
  std::vector<CellBox> boxes;
  boxes.reserve(static_cast<std::size_t>(parts));
  bisect(CellBox{{0, 0, 0}, cells}, parts, min_width, granules(cells, halves_unevenly),
         &slab_weights, boxes);
  return boxes;
}

} // namespace cfddem
