// A box of grid cells in global indices, and the cutting of a grid into one box per rank by
// orthogonal recursive bisection with cuts on cell faces (the fluid's owned boxes).
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <vector>

namespace cfddem {

// Cells lo[a] <= i < hi[a] along each axis.
struct CellBox {
  std::array<int, 3> lo{};
  std::array<int, 3> hi{};

  [[nodiscard]] int cells(int axis) const { return hi[axis] - lo[axis]; }
  [[nodiscard]] std::array<int, 3> cells() const { return {cells(0), cells(1), cells(2)}; }
  [[nodiscard]] std::int64_t count() const {
    return static_cast<std::int64_t>(cells(0)) * cells(1) * cells(2);
  }
  friend bool operator==(const CellBox&, const CellBox&) = default;
};

// One box per part, part p first in the recursion order (left before right): the longest axis
// (in cells; ties: the lowest axis) is cut at the face that splits the cells in the ratio of the
// parts on each side, moved to the nearest multiple of the coarsest granule of the axis's global
// cells (its multigrid ratios' products: 2, 4, 8, 16 while it halves, then x3 while 3 divides
// it, up to 54; 2, 4, 8, 16 on an axis that `halves_unevenly`, whose wall or inflow at the high
// side lets an odd count halve too) that keeps the left part within 1/16 of its exact share:
// every box then divides down the distributed multigrid's levels (core/cell_box.cpp). Without
// such a multiple the cut is the nearest face, so every part gets total/parts cells up to one
// slab. Every box is at
// least min_width cells wide along an axis it was cut on. Throws std::invalid_argument naming
// the grid when it is too small for the parts.
[[nodiscard]] std::vector<CellBox> orb_cell_boxes(const std::array<int, 3>& cells, int parts,
                                                  int min_width,
                                                  const std::array<bool, 3>& halves_unevenly = {});

// The cost of a box's slabs: slab_weights(box, axis)[s] is the weight of the cells of `box`
// whose index along `axis` is box.lo[axis] + s (box.cells(axis) values, none negative). A
// distributed caller sums its own cells' part over the ranks, so every rank gets the same
// values and makes the same cuts.
using SlabWeights = std::function<std::vector<double>(const CellBox& box, int axis)>;

// Weighted ORB (the fluid's share of a load-balancing regrid): as orb_cell_boxes, the same axes
// in the same order, but each cut falls on the face where the weight to its left is closest to
// the left parts' share of the box's weight (ties: the higher face, so that equal weights give
// orb_cell_boxes's boxes), within min_width of the box's ends, on the same granules (a face on
// a multiple of g whose weight is within 1/16 of the share, else a finer g). One slab_weights call per cut,
// in recursion order. A box of zero weight is cut by cell counts.
[[nodiscard]] std::vector<CellBox> orb_cell_boxes(const std::array<int, 3>& cells, int parts,
                                                  int min_width, const SlabWeights& slab_weights,
                                                  const std::array<bool, 3>& halves_unevenly = {});

} // namespace cfddem
