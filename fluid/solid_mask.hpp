// The gas's side of a round column (domain.shape = "cylinder", docs/theory.md §13): cells whose
// centre lies outside the column are solid, and the wall runs along their faces (a staircase).
// A face is open when both its cells are gas; a closed face carries no velocity, no flux and
// no pressure coupling (the projection's coefficient there is zero, so a solid cell's row of
// the Poisson problem is empty: fluid/multigrid_poisson.hpp skips such rows).
//
// No slip on the staircase: a velocity next to a closed face of its own component (a
// tangential neighbour across the wall) would see that neighbour as zero, which puts the wall
// at the solid cell's centre, half a cell too far out. The wall belongs on the closed face,
// where the neighbour's mirror image -u makes the velocity vanish (as the box's walls do with
// their ghost layers); the difference, -nu u / h_b^2 per such neighbour, is the wall's shear,
// which the gas step adds point-implicitly with the drag (wall_rate below). With it, laminar
// pipe flow meets Hagen-Poiseuille's centreline speed within 3% at 16 cells across (docs/
// theory.md §13 gives the measured errors).
#pragma once

#include <array>

#include "fluid/grid_field.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::fluid {

class SolidMask {
public:
  // grid.has_solid() (an empty mask otherwise: every cell gas, nothing closed).
  explicit SolidMask(const MacGrid& grid);

  [[nodiscard]] bool empty() const { return !active_; }
  // 1 on gas cells, 0 on solid ones (every index, ghost layers included).
  [[nodiscard]] const GridField& open_cells() const { return cells_; }
  // 1 on a-faces whose two cells are gas, 0 on the others (every index).
  [[nodiscard]] const GridField& open_faces(int axis) const { return faces_[axis]; }
  // Per open a-face: sum over the closed tangential neighbours inside the domain of 1 / h_b^2
  // [1/m^2]; the wall's shear on the face is -nu wall_rate u.
  [[nodiscard]] const GridField& wall_rate(int axis) const { return wall_[axis]; }
  // Per open a-face: sum over its closed neighbours along a (a-faces on the wall, where u_a = 0
  // is exact) of 1 / h_a^2. With the viscosity implicit the links to closed faces are cut
  // (fluid/implicit_viscosity.hpp), and the wall comes back on the diagonal as
  // nu (2 wall_rate + normal_rate).
  [[nodiscard]] const GridField& normal_rate(int axis) const { return normal_[axis]; }

  // u_a = 0 on every closed face (all indices).
  void close(std::array<GridField, 3>& u) const;
  // v = 0 on solid cells (their interior: the gas's cell fields there are not read).
  void clear_solid(GridField& v) const;

private:
  bool active_ = false;
  GridField cells_;
  std::array<GridField, 3> faces_, wall_, normal_;
};

} // namespace cfddem::fluid
