// Moving a distributed grid's fields from one cutting into boxes to another (a load-balancing
// regrid of the gas): every owned point goes from its old owner to its new one, copied once,
// bit for bit. Ghost layers are not moved: the new owner fills them (halo + boundary
// conditions) as after any step.
#pragma once

#include <array>
#include <span>
#include <vector>

#include "core/cell_box.hpp"
#include "core/communicator.hpp"
#include "core/halo_exchange.hpp"
#include "fluid/gas_solver.hpp"
#include "fluid/grid_field.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::fluid {

// The points a box owns along `axis` for a field of `centring` (kCellCentred = -1 or the axis of
// the faces), in global indices [lo, hi): its cells; for the faces normal to the axis also its
// high face where that is a non-periodic domain face (on an internal or periodic side the high
// face is the neighbour's face 0, as GridHalo has it).
[[nodiscard]] std::array<int, 2> owned_points(const MacGrid& grid, const CellBox& box, int axis,
                                              int centring);

class GridMove {
public:
  // from: this rank's grid under old_boxes, to: under new_boxes (same spec; all ranks pass the
  // same lists, rank r owning old_boxes[r] and then new_boxes[r]). Collective to use, not to
  // build. Throws std::invalid_argument if the grids do not match the lists.
  GridMove(const MacGrid& from, const MacGrid& to, const std::vector<CellBox>& old_boxes,
           const std::vector<CellBox>& new_boxes, const Communicator& comm);

  // The owned points of `to` get their old owners' values in `from` (padded arrays of the old
  // and the new grid's layout, GridField::values(), both of the given centring); the ghosts of
  // `to` are left as they were. Collective.
  void move(std::span<const double> from, std::span<double> to, int centring) const;
  void move(const GridField& from, GridField& to, int centring) const {
    move(from.values(), to.values(), centring);
  }

  // Values each rank sends to other ranks per field of each centring (cells, x, y, z faces).
  [[nodiscard]] std::size_t points_sent() const;

private:
  std::size_t from_size_ = 0, to_size_ = 0;
  std::array<HaloExchange, 4> plans_; // over [from values | to values], per centring
  mutable std::vector<double> buffer_;
};

// A solver's state (GasSolver::State: face velocities, p', eps_g and its previous value) moved
// from `from` (this rank's solver on the old boxes) into `to` (on the new boxes, built with its
// own halo), the ghost layers then filled as the solver fills them. A later step of `to` reads
// what `from`'s would have, so the run goes on as if undivided, to the round-off of reductions
// over differently cut boxes. Collective.
void move_solver_state(const GasSolver& from, GasSolver& to, const GridMove& move);

} // namespace cfddem::fluid
