// The block of cells a particle's interpolation/deposition kernel touches, and its weights.
#pragma once

#include <array>

namespace cfddem::fluid {

// Cells lo[a] .. lo[a] + size[a] - 1 along each axis (indices may fall outside the grid: the
// loop that uses the stencil wraps or folds them). Weight of cell (a, b, c) of the block is
// weights[a + size[0] (b + size[1] c)].
struct CellStencil {
  std::array<int, 3> lo{};
  std::array<int, 3> size{};
  [[nodiscard]] int count() const { return size[0] * size[1] * size[2]; }
};

} // namespace cfddem::fluid
