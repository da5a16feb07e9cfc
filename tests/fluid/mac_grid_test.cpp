// MAC grid validation (impossible boundary combinations, cells that do not tile) and ghost
// filling from the boundary conditions.
#include <algorithm>
#include <random>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "fluid/ghost_fill.hpp"
#include "fluid/mac_grid.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

using test::bc_of;
using test::box_spec;
using test::set_axis;

std::string error_of(const MacGridSpec& spec) {
  try {
    const MacGrid grid(spec);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

bool contains(const std::string& s, const std::string& part) {
  return s.find(part) != std::string::npos;
}

TEST(MacGridValidation, InflowWithEveryOtherFaceAWallHasNoOutlet) {
  MacGridSpec spec = box_spec({4, 8, 4}, {1e-3, 2e-3, 1e-3}, BoundaryKind::wall);
  spec.bc[2].kind = BoundaryKind::inflow; // y_lo
  spec.bc[2].velocity = {0.0, 0.015, 0.0};
  const std::string message = error_of(spec);
  EXPECT_TRUE(contains(message, "inflow at y_lo has no outlet")) << message;
  for (const char* face :
       {"x_lo (wall)", "x_hi (wall)", "y_hi (wall)", "z_lo (wall)", "z_hi (wall)"}) {
    EXPECT_TRUE(contains(message, face)) << message;
  }
  spec.bc[3].kind = BoundaryKind::outflow; // y_hi: the fluidized bed
  EXPECT_EQ(error_of(spec), "");
}

TEST(MacGridValidation, CellsMustTileTheDomain) {
  MacGridSpec spec = box_spec({12, 12, 12}, {6e-4, 6e-4, 6e-4}, BoundaryKind::periodic);
  spec.spacing = {5e-5, 5e-5, 5.1e-5};
  const std::string message = error_of(spec);
  EXPECT_TRUE(contains(message, "z: 12 cells")) << message;
  EXPECT_TRUE(contains(message, "tile")) << message;
  EXPECT_FALSE(contains(message, "x:")) << message;
  spec.spacing[2] = 5e-5;
  EXPECT_EQ(error_of(spec), "");
}

TEST(MacGridValidation, RejectsOneSidedPeriodicAndMisplacedPressureDrop) {
  MacGridSpec spec = box_spec({4, 4, 4}, {1e-3, 1e-3, 1e-3}, BoundaryKind::wall);
  spec.bc[0].kind = BoundaryKind::periodic;
  spec.pressure_drop[1] = 2.0;
  const std::string message = error_of(spec);
  EXPECT_TRUE(contains(message, "x: periodic on one side only")) << message;
  EXPECT_TRUE(contains(message, "y: pressure drop 2 Pa needs a periodic axis")) << message;
}

TEST(MacGridValidation, RejectsInflowPointingOut) {
  MacGridSpec spec = box_spec({4, 4, 4}, {1e-3, 1e-3, 1e-3}, BoundaryKind::wall);
  spec.bc[3].kind = BoundaryKind::inflow; // y_hi with +y velocity leaves the domain
  spec.bc[3].velocity = {0.0, 0.1, 0.0};
  spec.bc[2].kind = BoundaryKind::outflow;
  EXPECT_TRUE(contains(error_of(spec), "y_hi: inflow velocity 0.1 m/s points out"))
      << error_of(spec);
}

TEST(GhostFill, WallsHoldNoSlipAndPeriodicAxesWrap) {
  MacGridSpec spec = box_spec({4, 3, 2}, {4e-4, 3e-4, 2e-4}, BoundaryKind::wall);
  set_axis(spec, 0, BoundaryKind::periodic);
  spec.bc[5] = bc_of(BoundaryKind::inflow);
  spec.bc[5].velocity = {0.3, 0.0, -0.2}; // z_hi inflow with a tangential component
  spec.bc[4] = bc_of(BoundaryKind::outflow);
  const MacGrid grid(spec);
  std::array<GridField, 3> u = {grid.make_field(1.0), grid.make_field(2.0), grid.make_field(3.0)};
  fill_velocity_ghosts(grid, u);
  // x periodic: face 4 is face 0, ghost cells wrap.
  EXPECT_EQ(u[0](4, 1, 1), u[0](0, 1, 1));
  // y walls: normal velocity 0 on the wall faces, tangential mean 0 across the wall.
  EXPECT_EQ(u[1](1, 0, 1), 0.0);
  EXPECT_EQ(u[1](1, 3, 1), 0.0);
  EXPECT_EQ(0.5 * (u[0](1, -1, 1) + u[0](1, 0, 1)), 0.0);
  // z_hi inflow: normal = inflow, tangential u averages to 0.3 on the face.
  EXPECT_EQ(u[2](1, 1, 2), -0.2);
  EXPECT_DOUBLE_EQ(0.5 * (u[0](1, 1, 2) + u[0](1, 1, 1)), 0.3);
  // z_lo outflow: zero gradient.
  EXPECT_EQ(u[2](1, 1, -1), u[2](1, 1, 0));
  EXPECT_EQ(u[0](1, 1, -1), u[0](1, 1, 0));
}

// A grid above the fill's parallel threshold, with every kind of face: the planes and rows filled
// as tasks give the one-thread fill bit for bit, and the rules hold on every line, the other
// axes' ghost rows included (the z ghosts, filled last, only for z's rules).
TEST(GhostFill, TasksGiveTheOneThreadFillAndEveryLineKeepsItsRule) {
  MacGridSpec spec = box_spec({30, 34, 28}, {3e-3, 3.4e-3, 2.8e-3}, BoundaryKind::wall);
  set_axis(spec, 0, BoundaryKind::periodic);
  spec.bc[3] = bc_of(BoundaryKind::inflow);
  spec.bc[3].velocity = {0.1, -0.4, 0.05}; // y_hi inflow, pointing in
  spec.bc[4] = bc_of(BoundaryKind::outflow);
  spec.bc[4].pressure = 2.5;
  spec.bc[5] = bc_of(BoundaryKind::inflow);
  spec.bc[5].velocity = {0.3, 0.0, -0.2};
  const MacGrid grid(spec);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  std::array<GridField, 3> u0 = {grid.make_field(), grid.make_field(), grid.make_field()};
  GridField p0 = grid.make_field();
  for (auto* f : {&u0[0], &u0[1], &u0[2], &p0}) {
    for (double& v : f->values()) {
      v = uni(rng);
    }
  }
  const auto fill = [&](int threads) {
    const tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                                    static_cast<std::size_t>(threads));
    std::array<GridField, 3> u = u0;
    GridField p = p0;
    fill_velocity_ghosts(grid, u);
    fill_cell_ghosts(grid, p, CellGhosts::pressure);
    return std::pair{u, p};
  };
  const auto [u, p] = fill(1);
  const auto [u2, p2] = fill(2);
  for (int c = 0; c < 3; ++c) {
    EXPECT_TRUE(std::ranges::equal(u[c].values(), u2[c].values())) << "component " << c;
  }
  EXPECT_TRUE(std::ranges::equal(p.values(), p2.values()));
  const int nx = 30, ny = 34, nz = 28, g = kGhostLayers;
  for (int k = -g; k < nz + g; ++k) {
    for (int j = -g; j < ny + g; ++j) {
      // x periodic: both the normal (faces) and the tangential (cells) components wrap.
      EXPECT_EQ(u[0](nx, j, k), u[0](0, j, k));
      EXPECT_EQ(u[0](-1, j, k), u[0](nx - 1, j, k));
      EXPECT_EQ(u[1](-2, j, k), u[1](nx - 2, j, k));
      EXPECT_EQ(p(nx + 1, j, k), p(1, j, k));
    }
  }
  for (int k = 0; k < nz; ++k) { // the z ghosts follow z's rule (filled last)
    for (int i = -g; i < nx + g; ++i) {
      // y_lo wall: no flow through, no slip; y_hi inflow: its velocity on the face.
      EXPECT_EQ(u[1](i, 0, k), 0.0);
      EXPECT_EQ(u[0](i, -1, k), -u[0](i, 0, k));
      EXPECT_EQ(u[1](i, ny, k), -0.4);
      EXPECT_EQ(u[2](i, ny, k), 0.1 - u[2](i, ny - 1, k));
      EXPECT_EQ(p(i, -1, k), p(i, 0, k)); // zero gradient at a wall
    }
  }
  for (int j = -g; j < ny + g; ++j) {
    for (int i = -g; i < nx + g; ++i) {
      // z_lo outflow: zero gradient of u, p' odd about p_out; z_hi inflow.
      EXPECT_EQ(u[2](i, j, -1), u[2](i, j, 0));
      EXPECT_EQ(u[0](i, j, -2), u[0](i, j, 1));
      EXPECT_EQ(p(i, j, -1), 5.0 - p(i, j, 0));
      EXPECT_EQ(u[2](i, j, nz), -0.2);
      EXPECT_EQ(u[2](i, j, nz + 1), -0.4 - u[2](i, j, nz - 1));
    }
  }
}

} // namespace
} // namespace cfddem::fluid
