#include "fluid/mac_grid.hpp"

#include <cmath>
#include <stdexcept>

#include <fmt/format.h>

namespace cfddem::fluid {

std::string_view face_name(int face) {
  static constexpr std::array<std::string_view, kFaces> names = {"x_lo", "x_hi", "y_lo",
                                                                 "y_hi", "z_lo", "z_hi"};
  return names.at(static_cast<std::size_t>(face));
}

std::string_view boundary_kind_name(BoundaryKind kind) {
  switch (kind) {
  case BoundaryKind::periodic:
    return "periodic";
  case BoundaryKind::wall:
    return "wall";
  case BoundaryKind::inflow:
    return "inflow";
  case BoundaryKind::outflow:
    break;
  }
  return "outflow";
}

std::vector<std::string> check_mac_grid(const MacGridSpec& spec) {
  std::vector<std::string> problems;
  static constexpr std::array<char, 3> axis_name = {'x', 'y', 'z'};
  for (int a = 0; a < 3; ++a) {
    const char name = axis_name[a];
    if (spec.cells[a] < 1) {
      problems.push_back(fmt::format("{}: {} cells (need at least 1)", name, spec.cells[a]));
      continue;
    }
    if (!(spec.extent[a] > 0.0)) {
      problems.push_back(
          fmt::format("{}: domain length {} m is not positive", name, spec.extent[a]));
      continue;
    }
    if (spec.spacing[a] < 0.0) {
      problems.push_back(fmt::format("{}: cell size {} m is negative", name, spec.spacing[a]));
    } else if (spec.spacing[a] > 0.0) {
      const double covered = spec.cells[a] * spec.spacing[a];
      if (std::abs(covered - spec.extent[a]) > 1e-9 * spec.extent[a]) {
        problems.push_back(
            fmt::format("{}: {} cells of {:g} m cover {:g} m but the domain is {:g} m long (cells "
                        "must tile the domain)",
                        name, spec.cells[a], spec.spacing[a], covered, spec.extent[a]));
      }
    }
    const std::size_t lo_face = 2 * static_cast<std::size_t>(a);
    const BoundaryKind lo = spec.bc[lo_face].kind;
    const BoundaryKind hi = spec.bc[lo_face + 1].kind;
    if ((lo == BoundaryKind::periodic) != (hi == BoundaryKind::periodic)) {
      problems.push_back(fmt::format("{}: periodic on one side only ({} is {}, {} is {})", name,
                                     face_name(2 * a), boundary_kind_name(lo), face_name(2 * a + 1),
                                     boundary_kind_name(hi)));
    }
    if (spec.pressure_drop[a] != 0.0 && lo != BoundaryKind::periodic) {
      problems.push_back(
          fmt::format("{}: pressure drop {} Pa needs a periodic axis (faces are {} and {})", name,
                      spec.pressure_drop[a], boundary_kind_name(lo), boundary_kind_name(hi)));
    }
  }
  std::string inflows;
  bool outlet = false;
  for (int f = 0; f < kFaces; ++f) {
    const BoundaryCondition& bc = spec.bc[f];
    if (bc.kind == BoundaryKind::outflow) {
      outlet = true;
    }
    if (bc.kind != BoundaryKind::inflow) {
      continue;
    }
    inflows += (inflows.empty() ? "" : ", ") + std::string(face_name(f));
    const int axis = f / 2;
    const double inward = (f % 2 == 0) ? bc.velocity[axis] : -bc.velocity[axis];
    if (inward < 0.0) {
      problems.push_back(fmt::format("{}: inflow velocity {} m/s points out of the domain",
                                     face_name(f), bc.velocity[axis]));
    }
  }
  if (spec.cylinder_axis >= 0) {
    const int axis = spec.cylinder_axis;
    if (axis > 2) {
      problems.push_back(fmt::format("cylinder axis {} is not 0, 1 or 2", axis));
    } else {
      for (int a = 0; a < 3; ++a) {
        if (a == axis || spec.cells[a] < 1 || !(spec.extent[a] > 0.0)) {
          continue;
        }
        if (spec.bc[2 * static_cast<std::size_t>(a)].kind == BoundaryKind::periodic) {
          problems.push_back(fmt::format(
              "{}: periodic across the cylinder (its wall closes the axis)", axis_name[a]));
        }
        const double h = spec.spacing[a] > 0.0 ? spec.spacing[a] : spec.extent[a] / spec.cells[a];
        // A staircase column needs cells across it: below 4 per diameter a fluid cell may have
        // no gas neighbour across the axis, and the projection would see islands of gas.
        if (!(spec.cylinder_radius > 0.0) ||
            spec.cylinder_radius > 0.5 * spec.extent[a] * (1.0 + 1e-12)) {
          problems.push_back(fmt::format(
              "{}: cylinder radius {:g} m is not in (0, {:g} m], half the box's width", axis_name[a],
              spec.cylinder_radius, 0.5 * spec.extent[a]));
        } else if (2.0 * spec.cylinder_radius < 4.0 * h) {
          problems.push_back(fmt::format("{}: the cylinder's diameter {:g} m spans fewer than 4 "
                                         "cells of {:g} m (the gas needs at least 4 across it)",
                                         axis_name[a], 2.0 * spec.cylinder_radius, h));
        }
      }
    }
  }
  if (!inflows.empty() && !outlet) {
    std::string others;
    for (int f = 0; f < kFaces; ++f) {
      if (spec.bc[f].kind != BoundaryKind::inflow) {
        others += fmt::format("{}{} ({})", others.empty() ? "" : ", ", face_name(f),
                              boundary_kind_name(spec.bc[f].kind));
      }
    }
    problems.push_back(
        fmt::format("inflow at {} has no outlet: the other faces are {}; make one an outflow",
                    inflows, others.empty() ? std::string("none") : others));
  }
  return problems;
}

MacGrid::MacGrid(const MacGridSpec& spec) : spec_(spec) {
  const std::vector<std::string> problems = check_mac_grid(spec);
  if (!problems.empty()) {
    std::string message = "invalid fluid grid:";
    for (const std::string& p : problems) {
      message += "\n  " + p;
    }
    throw std::invalid_argument(message);
  }
  for (int a = 0; a < 3; ++a) {
    spacing_[a] = spec.spacing[a] > 0.0 ? spec.spacing[a] : spec.extent[a] / spec.cells[a];
  }
  box_ = CellBox{{0, 0, 0}, spec.cells};
  cells_ = spec.cells;
  layout_ = GridLayout(spec.cells);
}

MacGrid::MacGrid(const MacGridSpec& spec, const CellBox& box) : MacGrid(spec) {
  std::string problems;
  for (int a = 0; a < 3; ++a) {
    const int n = spec.cells[a];
    if (box.lo[a] < 0 || box.hi[a] > n || box.cells(a) < 1) {
      problems += fmt::format("\n  axis {}: box cells {}..{} are not inside 0..{}", a, box.lo[a],
                              box.hi[a] - 1, n - 1);
    } else if (box.cells(a) < n && box.cells(a) < kMinBoxWidth) {
      problems += fmt::format("\n  axis {}: box is {} cells wide, a cut box needs {}", a,
                              box.cells(a), kMinBoxWidth);
    }
  }
  if (!problems.empty()) {
    throw std::invalid_argument("invalid fluid box:" + problems);
  }
  box_ = box;
  cells_ = box.cells();
  distributed_ = true;
  for (int a = 0; a < 3; ++a) {
    exchanged_[2 * a] = periodic(a) || box.lo[a] > 0;
    exchanged_[2 * a + 1] = periodic(a) || box.hi[a] < spec.cells[a];
  }
  layout_ = GridLayout(cells_);
}

bool MacGrid::has_outflow() const {
  for (const BoundaryCondition& bc : spec_.bc) {
    if (bc.kind == BoundaryKind::outflow) {
      return true;
    }
  }
  return false;
}

bool MacGrid::solid_cell(int i, int j, int k) const {
  if (!has_solid()) {
    return false;
  }
  const std::array<int, 3> cell = {i, j, k};
  double r2 = 0.0;
  for (int a = 0; a < 3; ++a) {
    if (a == spec_.cylinder_axis) {
      continue;
    }
    const double d = cell_centre(a, cell[static_cast<std::size_t>(a)]) -
                     (spec_.origin[a] + 0.5 * spec_.extent[a]);
    r2 += d * d;
  }
  // At or beyond the radius: a centre on the wall is solid, as the particles' wall holds it.
  return !(r2 < spec_.cylinder_radius * spec_.cylinder_radius);
}

} // namespace cfddem::fluid
