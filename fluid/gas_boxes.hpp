// The gas grid cut into one box per rank: orb_cell_boxes (core/cell_box.hpp) with the fluid's
// narrowest box and the cuts on the granules of the pressure multigrid's ratios, including the
// uneven halving of an odd axis whose high side is a wall or an inflow
// (MultigridPoisson::halves_unevenly). Every caller that needs a run's boxes (the coupled step,
// the gas side, a checkpoint's block, a gas regrid) cuts them here, so they agree.
#pragma once

#include <vector>

#include "core/cell_box.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::fluid {

// Throws std::invalid_argument naming the grid when it is too small for the parts.
[[nodiscard]] std::vector<CellBox> gas_cell_boxes(const MacGridSpec& spec, int parts);
// Weighted (a gas regrid): orb_cell_boxes' weighted rule on the same granules.
[[nodiscard]] std::vector<CellBox> gas_cell_boxes(const MacGridSpec& spec, int parts,
                                                  const SlabWeights& slab_weights);

} // namespace cfddem::fluid
