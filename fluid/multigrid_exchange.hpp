// The ranks' side of a distributed multigrid level (fluid/multigrid_poisson.hpp). Each rank holds
// its box of the level's cells padded by one ghost layer, index (i + 1) + (n0 + 2) ((j + 1) +
// (n1 + 2) (k + 1)) in the box's own cells n. The exchange copies the face ghosts (the only ones
// the level's kernels read) from the boxes that own those cells, periodic images included; it
// sums over the ranks; and it gathers a level's cells onto rank 0 (and scatters them back) for
// the coarse solve there. Built once per hierarchy from the list of boxes.
#pragma once

#include <array>
#include <span>
#include <vector>

#include "core/cell_box.hpp"
#include "core/communicator.hpp"
#include "core/halo_exchange.hpp"

namespace cfddem::fluid {

class MultigridExchange {
public:
  // cells: the level's global cells; boxes[r]: rank r's box of them (all ranks pass the same
  // list; the boxes tile the grid). Throws std::invalid_argument when they do not.
  MultigridExchange(std::array<int, 3> cells, std::array<bool, 3> periodic,
                    std::vector<CellBox> boxes, const Communicator& comm);

  // The face ghosts of v (this box's padded layout) get the owners' values; ghosts outside a
  // non-periodic domain face are left alone. Collective.
  void fill(std::span<double> v) const { plan_.forward(v); }

  // In-place sums over the ranks (the same order on every call for a given set of ranks).
  void sum(std::span<double> v) const { comm_.sum(v); }
  [[nodiscard]] double sum(double v) const {
    comm_.sum(std::span<double>(&v, 1));
    return v;
  }
  [[nodiscard]] double max(double v) const { return comm_.max(v); }

  // Rank 0 gets every box's cells in `all` (the global grid's cells, i fastest); `mine` is this
  // box's cells, i fastest. Elsewhere `all` is not touched. Collective.
  void gather(std::span<const double> mine, std::span<double> all) const;
  // The reverse: every rank's `mine` from rank 0's `all`. Collective.
  void scatter(std::span<const double> all, std::span<double> mine) const;

  [[nodiscard]] const CellBox& box() const { return boxes_[static_cast<std::size_t>(rank())]; }
  [[nodiscard]] const std::vector<CellBox>& boxes() const { return boxes_; }
  [[nodiscard]] const std::array<int, 3>& cells() const { return cells_; }
  [[nodiscard]] int rank() const { return comm_.rank(); }
  [[nodiscard]] const HaloExchange& plan() const { return plan_; }

private:
  Communicator comm_;
  std::array<int, 3> cells_{};
  std::vector<CellBox> boxes_;
  HaloExchange plan_;
  std::vector<int> counts_, offsets_;  // cells per box, and where each starts in the gather
  mutable std::vector<double> by_box_; // rank 0: the boxes' cells one after another
};

} // namespace cfddem::fluid
