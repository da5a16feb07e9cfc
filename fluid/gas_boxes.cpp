#include "fluid/gas_boxes.hpp"

#include "fluid/multigrid_poisson.hpp"
#include "fluid/pressure_projection.hpp"

namespace cfddem::fluid {

std::vector<CellBox> gas_cell_boxes(const MacGridSpec& spec, int parts) {
  return orb_cell_boxes(spec.cells, parts, kMinBoxWidth,
                        MultigridPoisson::halves_unevenly(poisson_sides(spec)));
}

std::vector<CellBox> gas_cell_boxes(const MacGridSpec& spec, int parts,
                                    const SlabWeights& slab_weights) {
  return orb_cell_boxes(spec.cells, parts, kMinBoxWidth, slab_weights,
                        MultigridPoisson::halves_unevenly(poisson_sides(spec)));
}

} // namespace cfddem::fluid
