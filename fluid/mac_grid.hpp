// Geometry and boundary conditions of a uniform staggered (MAC) grid: pressure and eps_g at cell
// centres, velocity component a on the a-faces; validation of impossible set-ups.
#pragma once

#include <array>
#include <string>
#include <string_view>
#include <vector>

#include "core/cell_box.hpp"
#include "fluid/grid_field.hpp"

namespace cfddem::fluid {

enum class BoundaryKind { periodic, wall, inflow, outflow };

// Faces in the order x_lo, x_hi, y_lo, y_hi, z_lo, z_hi: face = 2 axis + side (side 1 = high).
inline constexpr int kFaces = 6;
[[nodiscard]] std::string_view face_name(int face);
[[nodiscard]] std::string_view boundary_kind_name(BoundaryKind kind);

struct BoundaryCondition {
  BoundaryKind kind = BoundaryKind::wall;
  std::array<double, 3> velocity{}; // inflow: gas velocity on the face [m/s]
  double pressure = 0.0;            // outflow: p' on the face [Pa]
};

// eps_g on the plane of a velocity-inflow face (the face itself and the cell edges in it): the
// incoming gas is pure, so the superficial velocity eps_g u through the face is the prescribed
// u. MFIX-Exa's mass inflow likewise sets the boundary's gas volume fraction to that of the
// incoming stream (ep_g = 1 for gas alone). Inside the domain, and on wall and outflow faces,
// eps_g on a face or edge is the mean of the cells around it (zero-gradient ghosts).
inline constexpr double kInflowVolumeFraction = 1.0;

struct MacGridSpec {
  std::array<int, 3> cells{};
  std::array<double, 3> origin{};
  std::array<double, 3> extent{};  // domain lengths [m]
  std::array<double, 3> spacing{}; // cell sizes [m]; 0 on an axis means extent / cells
  std::array<BoundaryCondition, kFaces> bc{};
  // MFIX's delp: p(x + L) = p(x) - delp across a periodic axis; drives flow towards +axis.
  std::array<double, 3> pressure_drop{};
  // A round column (domain.shape = "cylinder"): along cylinder_axis through the centre of the
  // box's cross-section, radius cylinder_radius [m]. A cell whose centre lies at or beyond the
  // radius is solid: the gas does not enter it (a staircase wall, fluid/solid_mask.hpp).
  // -1: no column, every cell is gas.
  int cylinder_axis = -1;
  double cylinder_radius = 0.0;
};

// Every problem with a spec, one message each (empty: valid).
[[nodiscard]] std::vector<std::string> check_mac_grid(const MacGridSpec& spec);

// Narrowest box along an axis it shares with another box: a box's physical ghost layers mirror
// its own cells (ghost_fill.cpp), and a ghost near a prescribed face is then filled by the box
// that also holds that face.
inline constexpr int kMinBoxWidth = kGhostLayers + 1;

// The whole grid (one rank), or one box of it (distributed: fields hold the box's cells plus
// ghost layers, indices local to the box; the ghosts on the box's internal and periodic faces
// come from a GridHalo, the physical boundary conditions act on the domain faces it touches).
class MacGrid {
public:
  // Throws std::invalid_argument listing every problem check_mac_grid finds.
  explicit MacGrid(const MacGridSpec& spec);
  // The box `box` (global cell indices) of the grid, for a distributed solver; throws
  // std::invalid_argument if it is not inside the grid or narrower than kMinBoxWidth along a
  // cut axis.
  MacGrid(const MacGridSpec& spec, const CellBox& box);

  // Cells of this grid's box (all cells when not distributed).
  [[nodiscard]] const std::array<int, 3>& cells() const { return cells_; }
  [[nodiscard]] int cells(int axis) const { return cells_[axis]; }
  [[nodiscard]] const std::array<int, 3>& global_cells() const { return spec_.cells; }
  [[nodiscard]] const CellBox& box() const { return box_; }
  [[nodiscard]] bool distributed() const { return distributed_; }
  // This side of the box gets its ghosts from the halo exchange (an internal face, or any face
  // of a periodic axis when distributed); otherwise its boundary condition fills them (and a
  // periodic axis of an undistributed grid wraps onto itself).
  [[nodiscard]] bool exchanged(int axis, int side) const {
    return exchanged_[static_cast<std::size_t>(2 * axis + side)];
  }
  [[nodiscard]] double spacing(int axis) const { return spacing_[axis]; }
  [[nodiscard]] double origin(int axis) const { return spec_.origin[axis]; }
  [[nodiscard]] double length(int axis) const { return spec_.extent[axis]; }
  [[nodiscard]] double cell_volume() const { return spacing_[0] * spacing_[1] * spacing_[2]; }
  [[nodiscard]] const BoundaryCondition& bc(int face) const {
    return spec_.bc[static_cast<std::size_t>(face)];
  }
  [[nodiscard]] const BoundaryCondition& bc(int axis, int side) const {
    return bc(2 * axis + side);
  }
  [[nodiscard]] bool periodic(int axis) const {
    return bc(2 * axis).kind == BoundaryKind::periodic;
  }
  // This side of the box is a velocity-inflow face of the domain (filled by its boundary
  // condition, not by a halo).
  [[nodiscard]] bool inflow_face(int axis, int side) const {
    return !exchanged(axis, side) && bc(axis, side).kind == BoundaryKind::inflow;
  }
  [[nodiscard]] double pressure_drop(int axis) const { return spec_.pressure_drop[axis]; }
  [[nodiscard]] bool has_outflow() const;
  // Whether some cells are solid (a cylinder), and whether local cell (i, j, k) is one (by its
  // centre's distance to the axis; any index).
  [[nodiscard]] bool has_solid() const { return spec_.cylinder_axis >= 0; }
  [[nodiscard]] bool solid_cell(int i, int j, int k) const;
  [[nodiscard]] const GridLayout& layout() const { return layout_; }
  [[nodiscard]] const MacGridSpec& spec() const { return spec_; }

  // Positions: centre of local cell i, and its low face, along an axis.
  [[nodiscard]] double cell_centre(int axis, int i) const {
    return spec_.origin[axis] + (box_.lo[axis] + i + 0.5) * spacing_[axis];
  }
  [[nodiscard]] double face_position(int axis, int i) const {
    return spec_.origin[axis] + (box_.lo[axis] + i) * spacing_[axis];
  }
  [[nodiscard]] GridField make_field(double value = 0.0) const { return GridField(layout_, value); }

private:
  MacGridSpec spec_;
  CellBox box_;
  std::array<int, 3> cells_{};
  bool distributed_ = false;
  std::array<bool, kFaces> exchanged_{};
  std::array<double, 3> spacing_{};
  GridLayout layout_;
};

} // namespace cfddem::fluid
