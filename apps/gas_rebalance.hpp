// Load balance of a coupled run on R ranks: the gas boxes cut again by a weighted ORB (MFIX-Exa
// balances its fluid boxes by a knapsack of measured cost; cfddem recuts them so that the boxes
// stay one per rank and compact). A cell weighs partition.cell_weight (its fluid step, counted
// in particle steps) plus the particle steps of the particles in it.
#pragma once

#include <span>
#include <vector>

#include "apps/coupled_step.hpp"
#include "core/cell_box.hpp"
#include "core/communicator.hpp"

namespace cfddem::apps {

struct GasBalance {
  std::vector<CellBox> boxes;     // the weighted cut (the same on every rank)
  double imbalance_before = 1.0;  // max over ranks / mean of the load, current boxes
  double imbalance_after = 1.0;   // ... the same cells' weights over the new boxes
};

// x, y, z: the particles this rank's gas box deposits (wrapped positions), steps: each one's
// particle steps per fluid step. Collective: every rank gets the same result.
[[nodiscard]] GasBalance balance_gas_boxes(const GasCoupling& gas, std::span<const double> x,
                                           std::span<const double> y, std::span<const double> z,
                                           std::span<const double> steps, double cell_weight,
                                           const Communicator& comm);

} // namespace cfddem::apps
