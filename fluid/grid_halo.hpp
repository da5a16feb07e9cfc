// The halo of a distributed MAC grid: the ghost layers of cell- and face-centred GridFields
// copied from the boxes (ranks) that own those points, periodic images, edges and corners
// included, and ghosts added back into their owners (deposition); plus the grid's reductions
// over the ranks. Built once per decomposition from the list of boxes (O(R) data); the plans
// hold O(ghost points) per rank.
#pragma once

#include <array>
#include <span>
#include <vector>

#include "core/cell_box.hpp"
#include "core/communicator.hpp"
#include "core/halo_exchange.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/grid_field.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::fluid {

// Where a field's values sit: cell centres, or the faces normal to an axis.
inline constexpr int kCellCentred = -1;

class GridHalo {
public:
  // boxes[r] is rank r's box (all ranks pass the same list); grid is this rank's box of the
  // grid (grid.box() == boxes[comm.rank()]). Throws std::invalid_argument otherwise.
  GridHalo(const MacGrid& grid, std::vector<CellBox> boxes, const Communicator& comm);

  // Ghost points that lie in a box (after periodic wrapping) get the owner's value: the points
  // outside a non-periodic domain face are left to the boundary conditions. centring:
  // kCellCentred or the axis of the faces. Face n of a box on an internal or periodic side is a
  // ghost: the neighbour's face 0 (one value per face, whichever box computed it).
  void fill(GridField& f, int centring) const;
  void fill(std::span<GridField* const> fields, int centring) const;
  // Every exchanged ghost point's value added into its owner's point (reverse of fill), and the
  // ghost zeroed. Adds arrive in rank order: deterministic for a given decomposition.
  void add_ghosts_to_owners(GridField& f, int centring) const;

  [[nodiscard]] double sum(double v) const {
    comm_.sum(std::span<double>(&v, 1));
    return v;
  }
  void sum(std::span<double> v) const { comm_.sum(v); }
  [[nodiscard]] double max(double v) const { return comm_.max(v); }

  [[nodiscard]] const Communicator& comm() const { return comm_; }
  [[nodiscard]] const std::vector<CellBox>& boxes() const { return boxes_; }
  [[nodiscard]] const HaloExchange& plan(int centring) const {
    return plans_[static_cast<std::size_t>(centring + 1)];
  }

private:
  Communicator comm_;
  std::vector<CellBox> boxes_;
  std::array<HaloExchange, 4> plans_; // cells, faces normal to x, y, z
};

// Ghosts of a field of a distributed grid: the halo exchange, then the boundary conditions on
// the domain faces the box touches (the physical ghosts read exchanged points at edges and
// corners, so the exchange goes first). halo == nullptr: the undistributed fill of ghost_fill.
void fill_cell_ghosts(const MacGrid& grid, const GridHalo* halo, GridField& q, CellGhosts mode);
void fill_velocity_ghosts(const MacGrid& grid, const GridHalo* halo, std::array<GridField, 3>& u);
void fill_velocity_ghosts(const MacGrid& grid, const GridHalo* halo, int comp, GridField& f);

} // namespace cfddem::fluid
