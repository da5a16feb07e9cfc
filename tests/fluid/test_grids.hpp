// Small MAC grids shared by the fluid tests.
#pragma once

#include <array>
#include <cstddef>

#include "fluid/mac_grid.hpp"

namespace cfddem::fluid::test {

inline BoundaryCondition bc_of(BoundaryKind kind) {
  BoundaryCondition bc;
  bc.kind = kind;
  return bc;
}

// A box with the given cells and lengths and every face of one kind.
inline MacGridSpec box_spec(std::array<int, 3> cells, std::array<double, 3> extent,
                            BoundaryKind kind) {
  MacGridSpec spec;
  spec.cells = cells;
  spec.extent = extent;
  spec.bc.fill(bc_of(kind));
  return spec;
}

inline void set_axis(MacGridSpec& spec, std::size_t axis, BoundaryKind kind) {
  spec.bc[2 * axis] = bc_of(kind);
  spec.bc[2 * axis + 1] = bc_of(kind);
}

} // namespace cfddem::fluid::test
