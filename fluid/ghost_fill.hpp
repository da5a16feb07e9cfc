// Ghost layers and boundary face values of MAC-grid fields from the face boundary conditions:
// periodic wrap, no-slip wall, velocity inflow, pressure outflow.
#pragma once

#include <array>
#include <memory>

#include "fluid/grid_field.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::fluid {

// Cell index i of an axis of n cells, taken periodically into [0, n).
inline int wrap_index(int i, int n) {
  return ((i % n) + n) % n;
}

enum class CellGhosts {
  zero_gradient, // eps_g, drag fields: even reflection at every non-periodic face
  pressure       // p': value p_out on outflow faces (odd reflection), zero gradient elsewhere
};

void fill_cell_ghosts(const MacGrid& grid, GridField& q, CellGhosts mode);

// Sets the prescribed boundary faces (wall: 0, inflow: the inflow velocity, periodic: face n is
// face 0) and every ghost of the three face-velocity components. Tangential ghosts reflect so
// that the wall (inflow) value holds on the face; outflow ghosts have zero gradient.
void fill_velocity_ghosts(const MacGrid& grid, std::array<GridField, 3>& u);
// The same for one component (comp = the axis of its faces).
void fill_velocity_ghosts(const MacGrid& grid, int comp, GridField& f);

struct FillPlan;

// One component's velocity fill in two parts, for a sweep that finishes a z-plane at a time and
// fills its ghosts while the plane is still in the caches: fill_plane(f, k) applies the maps
// along x and y to z-plane k (any padded plane, -kGhostLayers .. n_z + kGhostLayers), which read
// and write that plane only; fill_z(f) then applies the maps along z (whole planes from whole
// planes). fill_plane on every padded plane, in any order, then fill_z is
// fill_velocity_ghosts(grid, comp, f) bit for bit.
class PlaneGhostFill {
public:
  PlaneGhostFill(const MacGrid& grid, int comp);
  ~PlaneGhostFill();
  PlaneGhostFill(const PlaneGhostFill&) = delete;
  PlaneGhostFill& operator=(const PlaneGhostFill&) = delete;

  void fill_plane(GridField& f, int k) const;
  void fill_z(GridField& f) const;

private:
  GridLayout layout_;
  std::unique_ptr<const FillPlan> plan_;
};

} // namespace cfddem::fluid
