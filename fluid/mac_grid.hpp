// Geometry and boundary conditions of a uniform staggered (MAC) grid: pressure and eps_g at cell
// centres, velocity component a on the a-faces; validation of impossible set-ups.
#pragma once

#include <array>
#include <string>
#include <string_view>
#include <vector>

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

struct MacGridSpec {
  std::array<int, 3> cells{};
  std::array<double, 3> origin{};
  std::array<double, 3> extent{};  // domain lengths [m]
  std::array<double, 3> spacing{}; // cell sizes [m]; 0 on an axis means extent / cells
  std::array<BoundaryCondition, kFaces> bc{};
  // MFIX's delp: p(x + L) = p(x) - delp across a periodic axis; drives flow towards +axis.
  std::array<double, 3> pressure_drop{};
};

// Every problem with a spec, one message each (empty: valid).
[[nodiscard]] std::vector<std::string> check_mac_grid(const MacGridSpec& spec);

class MacGrid {
public:
  // Throws std::invalid_argument listing every problem check_mac_grid finds.
  explicit MacGrid(const MacGridSpec& spec);

  [[nodiscard]] const std::array<int, 3>& cells() const { return spec_.cells; }
  [[nodiscard]] int cells(int axis) const { return spec_.cells[axis]; }
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
  [[nodiscard]] double pressure_drop(int axis) const { return spec_.pressure_drop[axis]; }
  [[nodiscard]] bool has_outflow() const;
  [[nodiscard]] const GridLayout& layout() const { return layout_; }
  [[nodiscard]] const MacGridSpec& spec() const { return spec_; }

  // Positions: centre of cell i, and low face i, along an axis.
  [[nodiscard]] double cell_centre(int axis, int i) const {
    return spec_.origin[axis] + (i + 0.5) * spacing_[axis];
  }
  [[nodiscard]] double face_position(int axis, int i) const {
    return spec_.origin[axis] + i * spacing_[axis];
  }
  [[nodiscard]] GridField make_field(double value = 0.0) const { return GridField(layout_, value); }

private:
  MacGridSpec spec_;
  std::array<double, 3> spacing_{};
  GridLayout layout_;
};

} // namespace cfddem::fluid
