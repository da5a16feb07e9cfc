// The fluid's boxes (one per rank, core/cell_box.hpp) as the particles' rank decomposition, so
// that in a coupled run a particle is owned by the rank whose fluid box holds it: a complete
// ORB tree whose cuts are the boxes' faces (a box that needs no further cut is split in two
// leaves of the same owner), so locate() and the halo searches work unchanged.
#pragma once

#include <array>
#include <span>

#include "core/cell_box.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::partition {

// boxes[r]: rank r's box of cells (they tile the grid and come from a bisection, as
// orb_cell_boxes makes them); cell faces at origin + k spacing; domain: the grid's extent.
// Throws std::invalid_argument if no cut along a box face separates some group of boxes.
[[nodiscard]] RankDecomposition decomposition_of_cell_boxes(std::span<const CellBox> boxes,
                                                            const std::array<double, 3>& origin,
                                                            const std::array<double, 3>& spacing,
                                                            const Aabb& domain);

} // namespace cfddem::partition
