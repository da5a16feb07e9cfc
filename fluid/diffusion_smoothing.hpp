// Optional implicit diffusion of deposited fields, (I - D lap) q_new = q_old, over a length
// ~ sqrt(D) (MFIX-Exa's deposition diffusion; docs/theory.md §7). Conserves sum_cells q.
#pragma once

#include "fluid/grid_field.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::fluid {

struct SmoothingReport {
  int iterations = 0;
  double relative_residual = 0.0;
};

// Smooths the interior of q in place: periodic axes wrap, other faces carry no flux, so the
// cell sum is conserved to the solver tolerance. Conjugate gradients (the operator is SPD with
// eigenvalues in [1, 1 + 4 D sum 1/dx^2]). Throws std::invalid_argument for D < 0.
SmoothingReport smooth_implicit(const MacGrid& grid, double diffusion, GridField& q,
                                double tolerance = 1e-12, int max_iterations = 500);

} // namespace cfddem::fluid
