// A box of grid cells in global indices, and the cutting of a grid into one box per rank by
// orthogonal recursive bisection with cuts on cell faces (the fluid's owned boxes).
#pragma once

#include <array>
#include <cstdint>
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
// parts on each side, so every part gets total/parts cells up to one slab. Every box is at
// least min_width cells wide along an axis it was cut on. Throws std::invalid_argument naming
// the grid when it is too small for the parts.
[[nodiscard]] std::vector<CellBox> orb_cell_boxes(const std::array<int, 3>& cells, int parts,
                                                  int min_width);

} // namespace cfddem
