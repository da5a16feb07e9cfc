// The gas solver distributed over MPI ranks (one ORB box per rank, halo exchange, hypre on the
// communicator) against the same problem on one grid, which every rank also solves: the
// solutions agree to round-off (the ranks sum dot products and means in another order), the
// constraint holds to the solver tolerance, and the boxes share the cells evenly.
#include <algorithm>
#include <cmath>
#include <functional>
#include <memory>
#include <numbers>
#include <string>

#include <gtest/gtest.h>

#include "core/cell_box.hpp"
#include "core/communicator.hpp"
#include "fluid/gas_boxes.hpp"
#include "fluid/gas_solver.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/grid_move.hpp"
#include "fluid/pressure_projection.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

using test::box_spec;
using test::set_axis;
using test::set_field;

constexpr double kRho = 1.0;
constexpr double kMu = 2e-5;

// Differences between the distributed and the one-grid solution, relative to the field's
// largest value. Both solve each projection and each implicit-viscosity CG to a relative
// residual of 1e-12 (the settings below). The ranks sum dot products, norms and means in
// another order, so the iterates differ by round-off (~1e-16 relative per operation; measured
// 2e-16 .. 2e-14 after tens of steps while both take the same iterations). When that round-off
// moves a CG stopping test by an iteration, the two answers differ by up to the solver
// tolerance instead (measured 3e-12, Taylor-Green with implicit viscosity). Bound: ten times
// the tolerance.
constexpr double kRoundOff = 1e-11;

struct Split {
  Communicator comm = Communicator::world();
  std::vector<CellBox> boxes;
  std::unique_ptr<MacGrid> grid;
  std::shared_ptr<const GridHalo> halo;

  explicit Split(const MacGridSpec& spec) {
    boxes = orb_cell_boxes(spec.cells, comm.size(), kMinBoxWidth);
    grid = std::make_unique<MacGrid>(spec, boxes[static_cast<std::size_t>(comm.rank())]);
    halo = std::make_shared<GridHalo>(*grid, boxes, comm);
  }
};

// max |local - global| over the box's cells (faces 0..n along a face field's axis), and the
// largest |global| value, both over all ranks.
std::array<double, 2> compare(const MacGrid& local, const GridField& a, const GridField& b,
                              int centring, const Communicator& comm) {
  std::array<int, 3> hi = local.cells();
  if (centring >= 0) {
    hi[static_cast<std::size_t>(centring)] += 1;
  }
  const auto& lo = local.box().lo;
  std::array<double, 2> out{};
  for (int k = 0; k < hi[2]; ++k) {
    for (int j = 0; j < hi[1]; ++j) {
      for (int i = 0; i < hi[0]; ++i) {
        const double ref = b(i + lo[0], j + lo[1], k + lo[2]);
        out[0] = std::max(out[0], std::abs(a(i, j, k) - ref));
        out[1] = std::max(out[1], std::abs(ref));
      }
    }
  }
  comm.max(out);
  return out;
}

// Sets a solver's fields (both solvers get the same functions of position).
using FieldSetter = std::function<void(const MacGrid&, GasSolver&, int step)>;

struct Agreement {
  double velocity = 0.0; // max over components of max|du| / max|u|
  double pressure = 0.0; // max|dp| / max|p|
  int serial_iterations = 0;
  int distributed_iterations = 0;
};

// Boxes cut by a weighted ORB whose weights grow along the longest axis (a dense bottom):
// other cuts than orb_cell_boxes's, for moving a run to them (GridMove).
std::vector<CellBox> skewed_boxes(const MacGridSpec& spec, int parts) {
  const SlabWeights weights = [&](const CellBox& box, int axis) {
    std::vector<double> w(static_cast<std::size_t>(box.cells(axis)));
    for (int s = 0; s < box.cells(axis); ++s) {
      const int g = box.lo[axis] + s;
      // Cells per slab times a weight falling with the index along axis 1.
      const double per_cell = axis == 1 ? 1.0 + 8.0 * (g < spec.cells[1] / 3) : 1.0;
      double cells = 1.0;
      for (int b = 0; b < 3; ++b) {
        cells *= b == axis ? 1.0 : box.cells(b);
      }
      w[static_cast<std::size_t>(s)] = cells * per_cell;
    }
    if (axis != 1) {
      // The slab's cells weighted by their rows along axis 1.
      double rows = 0.0;
      for (int j = box.lo[1]; j < box.hi[1]; ++j) {
        rows += 1.0 + 8.0 * (j < spec.cells[1] / 3);
      }
      for (double& v : w) {
        v = v / box.cells(1) * rows;
      }
    }
    return w;
  };
  return orb_cell_boxes(spec.cells, parts, kMinBoxWidth, weights);
}

// Runs `steps` steps (dt > 0: fixed; 0: adaptive; interval > 0: advance(interval)) of the
// problem on one grid and on the ranks' boxes, `setup(grid, solver, s)` before step s. With
// rebox_at >= 0 the distributed run moves to skewed_boxes after that many steps.
Agreement run_both(const MacGridSpec& spec, const GasSolverSettings& settings, int steps, double dt,
                   double interval, const FieldSetter& setup, int rebox_at = -1) {
  Split split(spec);
  const MacGrid global(spec);
  GasSolver serial(global, settings);
  auto distributed = std::make_unique<GasSolver>(*split.grid, settings, split.halo);
  Agreement out;
  for (int s = 0; s < steps; ++s) {
    if (s == rebox_at) {
      const std::vector<CellBox> boxes = skewed_boxes(spec, split.comm.size());
      auto grid =
          std::make_unique<MacGrid>(spec, boxes[static_cast<std::size_t>(split.comm.rank())]);
      auto halo = std::make_shared<const GridHalo>(*grid, boxes, split.comm);
      auto moved = std::make_unique<GasSolver>(*grid, settings, halo);
      move_solver_state(*distributed, *moved,
                        GridMove(*split.grid, *grid, split.boxes, boxes, split.comm));
      if (split.comm.size() > 1) {
        EXPECT_NE(boxes, split.boxes) << "the rebox moves nothing";
      }
      split.boxes = boxes, split.grid = std::move(grid), split.halo = std::move(halo);
      distributed = std::move(moved);
    }
    setup(global, serial, s);
    setup(*split.grid, *distributed, s);
    const auto advance = [&](GasSolver& solver) {
      if (interval > 0.0) {
        return solver.advance(interval);
      }
      return dt > 0.0 ? solver.step(dt) : solver.step();
    };
    const GasStepReport rs = advance(serial);
    const GasStepReport rd = advance(*distributed);
    // dt from the Courant number: a max over the ranks, of fields equal to round-off.
    EXPECT_NEAR(rd.dt, rs.dt, kRoundOff * rs.dt);
    out.serial_iterations += rs.projection_iterations + rs.viscous_iterations;
    out.distributed_iterations += rd.projection_iterations + rd.viscous_iterations;
  }
  // Relative to the largest velocity component (a component that is zero in exact arithmetic
  // differs by round-off of the others).
  std::array<double, 2> du{};
  for (int a = 0; a < 3; ++a) {
    const auto d =
        compare(*split.grid, distributed->velocity()[a], serial.velocity()[a], a, split.comm);
    du = {std::max(du[0], d[0]), std::max(du[1], d[1])};
  }
  EXPECT_GT(du[1], 0.0) << "a case that tests nothing";
  out.velocity = du[0] / du[1];
  const auto d =
      compare(*split.grid, distributed->pressure(), serial.pressure(), kCellCentred, split.comm);
  out.pressure = d[1] > 0.0 ? d[0] / d[1] : d[0];
  return out;
}

void expect_round_off(const Agreement& a, const std::string& name) {
  ::testing::Test::RecordProperty(name + "_velocity", std::to_string(a.velocity));
  ::testing::Test::RecordProperty(name + "_pressure", std::to_string(a.pressure));
  if (Communicator::world().rank() == 0) {
    std::printf("[ measured ] %s on %d ranks: velocity %.3g, pressure %.3g (relative), "
                "iterations %d (one grid) / %d (ranks)\n",
                name.c_str(), Communicator::world().size(), a.velocity, a.pressure,
                a.serial_iterations, a.distributed_iterations);
  }
  EXPECT_LE(a.velocity, kRoundOff) << name;
  EXPECT_LE(a.pressure, kRoundOff) << name;
}

GasSolverSettings tight_settings(bool implicit_viscosity) {
  GasSolverSettings settings;
  settings.gas = {kRho, kMu, {0.0, 0.0, 0.0}};
  settings.projection.tolerance = 1e-12;
  settings.implicit_viscosity = implicit_viscosity;
  settings.viscous_tolerance = 1e-12;
  // The one grid runs the R-rank algorithms (hypre, Jacobi CG), so that the two agree to
  // round-off; the one-grid multigrid agrees with them to the solver tolerance only
  // (multigrid_poisson_test.cpp).
  settings.projection.solver = PoissonSolver::hypre;
  settings.viscous_multigrid = false;
  return settings;
}

class DistributedGas : public ::testing::TestWithParam<bool> {};

// A solids blob moving up through the box (its volume fraction set at each step s).
const FieldSetter kBlob = [](const MacGrid& g, GasSolver& solver, int s) {
  set_field(g, solver.volume_fraction(), kCellCentred, [&](double x, double y, double z) {
    const double yc = 4e-4 + 2e-5 * s;
    return 1.0 - 0.3 * std::exp(-std::pow((y - yc) / 1.5e-4, 2)) *
                     (1.0 + 0.2 * std::sin(1e4 * x) * std::cos(8e3 * z));
  });
  if (s == 0) {
    solver.reset_volume_fraction_history();
  }
};

// A walled column, inflow of 1.5 cm/s at the bottom, outflow at pressure p_out on top.
MacGridSpec outflow_column(double p_out) {
  MacGridSpec column = box_spec({6, 12, 5}, {6e-4, 1.2e-3, 5e-4}, BoundaryKind::wall);
  column.bc[2] = test::bc_of(BoundaryKind::inflow);
  column.bc[2].velocity = {0.0, 0.015, 0.0};
  column.bc[3] = test::bc_of(BoundaryKind::outflow);
  column.bc[3].pressure = p_out;
  return column;
}

// One cell along periodic z, walls along y, a pressure drop along periodic x; the disturbance
// kChannelStart sets at the first step.
MacGridSpec channel_2d() {
  MacGridSpec spec = box_spec({9, 12, 1}, {9e-4, 1.2e-3, 1e-4}, BoundaryKind::periodic);
  set_axis(spec, 1, BoundaryKind::wall);
  spec.pressure_drop[0] = 1e-3;
  return spec;
}
const FieldSetter kChannelStart = [](const MacGrid& g, GasSolver& solver, int s) {
  if (s == 0) {
    set_field(g, solver.velocity()[1], 1, [](double x, double y, double) {
      return 1e-3 * std::sin(2.0 * std::numbers::pi * x / 9e-4) *
             std::sin(std::numbers::pi * y / 1.2e-3);
    });
  }
};

TEST_P(DistributedGas, PlanePoiseuilleMatchesOneGrid) {
  // Channel between no-slip walls (y), pressure drop across periodic x, periodic z: the cuts
  // fall across the channel, so boxes meet both walls and internal faces.
  MacGridSpec spec = box_spec({4, 15, 3}, {1e-3, 1e-3, 1e-3}, BoundaryKind::periodic);
  set_axis(spec, 1, BoundaryKind::wall);
  spec.pressure_drop[0] = 1e-3;
  // From rest plus a cross-channel disturbance that the projection must remove.
  const FieldSetter start = [](const MacGrid& g, GasSolver& solver, int s) {
    if (s == 0) {
      set_field(g, solver.velocity()[1], 1, [](double x, double y, double) {
        return 1e-3 * std::sin(2.0 * std::numbers::pi * x / 1e-3) *
               std::sin(std::numbers::pi * y / 1e-3);
      });
    }
  };
  // dt = 0.4 of the explicit viscous limit 1/(4 nu sum 1/dx^2) = 5e-5 s.
  expect_round_off(run_both(spec, tight_settings(GetParam()), 30, 2e-5, 0.0, start),
                   GetParam() ? "poiseuille_implicit" : "poiseuille_explicit");
}

// The periodic 12 x 12 x 3 box of the Taylor-Green vortex and its start at Re = 20 (advection
// matters).
constexpr double kVortexLength = 1e-3;
MacGridSpec vortex_box() {
  return box_spec({12, 12, 3}, {kVortexLength, kVortexLength, kVortexLength / 4.0},
                  BoundaryKind::periodic);
}
const FieldSetter kVortexStart = [](const MacGrid& g, GasSolver& solver, int s) {
  if (s != 0) {
    return;
  }
  const double k = 2.0 * std::numbers::pi / kVortexLength;
  const double amplitude = 20.0 * kMu / (kRho * kVortexLength);
  set_field(g, solver.velocity()[0], 0, [&](double x, double y, double) {
    return amplitude * std::sin(k * x) * std::cos(k * y);
  });
  set_field(g, solver.velocity()[1], 1, [&](double x, double y, double) {
    return -amplitude * std::cos(k * x) * std::sin(k * y);
  });
};

TEST_P(DistributedGas, TaylorGreenMatchesOneGrid) {
  expect_round_off(run_both(vortex_box(), tight_settings(GetParam()), 20, 0.0, 0.0, kVortexStart),
                   GetParam() ? "taylor_green_implicit" : "taylor_green_explicit");
}

TEST_P(DistributedGas, PeriodicNonUniformVolumeFractionWithDragMatchesOneGrid) {
  // A riser-like periodic box: eps_g and the drag fields vary in space and time (d(eps)/dt
  // drives the projection's source), pressure drop along y, gravity; advance() sub-steps.
  const MacGridSpec spec = [] {
    MacGridSpec s = box_spec({9, 11, 7}, {9e-4, 1.1e-3, 7e-4}, BoundaryKind::periodic);
    s.pressure_drop[1] = 2e-2;
    return s;
  }();
  GasSolverSettings settings = tight_settings(GetParam());
  settings.gas.gravity = {0.0, -9.80665, 0.0};
  const double w = 2.0 * std::numbers::pi / 9e-4;
  const FieldSetter particles = [&](const MacGrid& g, GasSolver& solver, int s) {
    const double t = 1e-4 * s;
    set_field(g, solver.volume_fraction(), kCellCentred, [&](double x, double y, double z) {
      return 0.9 + 0.05 * std::sin(w * x + 3e3 * y + 1e4 * t) * std::cos(7e3 * z);
    });
    set_field(g, solver.drag_coefficient(), kCellCentred, [&](double x, double y, double) {
      return 1e3 * (1.0 + 0.5 * std::cos(w * x - 2e3 * y));
    });
    set_field(g, solver.drag_velocity_sum(1), kCellCentred, [&](double x, double, double z) {
      return 1e3 * 0.01 * (1.0 + std::sin(w * x) * std::cos(9e3 * z));
    });
    if (s == 0) {
      solver.reset_volume_fraction_history();
    }
  };
  expect_round_off(run_both(spec, settings, 8, 0.0, 1e-4, particles),
                   GetParam() ? "periodic_eps_implicit" : "periodic_eps_explicit");
}

TEST_P(DistributedGas, ClosedBoxAndOutflowColumnMatchOneGrid) {
  // Every boundary kind: a closed box under gravity with a moving solids blob (the pinned,
  // singular Poisson problem), and an inflow/outflow column with walls.
  GasSolverSettings settings = tight_settings(GetParam());
  settings.gas.gravity = {0.0, -9.80665, 0.0};
  const MacGridSpec closed = box_spec({7, 9, 6}, {7e-4, 9e-4, 6e-4}, BoundaryKind::wall);
  expect_round_off(run_both(closed, settings, 6, 1e-5, 0.0, kBlob),
                   GetParam() ? "closed_box_implicit" : "closed_box_explicit");

  const MacGridSpec column = outflow_column(0.5);
  expect_round_off(run_both(column, settings, 6, 1e-5, 0.0, kBlob),
                   GetParam() ? "column_implicit" : "column_explicit");
}

TEST_P(DistributedGas, MovedToOtherBoxesMidRunMatchesOneGrid) {
  // A load-balancing regrid of the gas: half-way through, every rank's owned cells and faces go
  // to the owners of a weighted cutting (GridMove) and the run goes on on the new boxes; it still
  // agrees with the undivided grid to round-off. The riser-like periodic box, and the column
  // with walls, inflow and outflow (owned high faces on the domain boundary).
  GasSolverSettings settings = tight_settings(GetParam());
  settings.gas.gravity = {0.0, -9.80665, 0.0};
  MacGridSpec periodic = box_spec({9, 11, 7}, {9e-4, 1.1e-3, 7e-4}, BoundaryKind::periodic);
  periodic.pressure_drop[1] = 2e-2;
  const double w = 2.0 * std::numbers::pi / 9e-4;
  const FieldSetter particles = [&](const MacGrid& g, GasSolver& solver, int s) {
    set_field(g, solver.volume_fraction(), kCellCentred, [&](double x, double y, double z) {
      return 0.9 + 0.05 * std::sin(w * x + 3e3 * y + 1e3 * s) * std::cos(7e3 * z);
    });
    set_field(g, solver.drag_coefficient(), kCellCentred, [&](double x, double y, double) {
      return 1e3 * (1.0 + 0.5 * std::cos(w * x - 2e3 * y));
    });
    if (s == 0) {
      solver.reset_volume_fraction_history();
    }
  };
  expect_round_off(run_both(periodic, settings, 8, 0.0, 1e-4, particles, 4),
                   GetParam() ? "moved_periodic_implicit" : "moved_periodic_explicit");
  const MacGridSpec column = outflow_column(0.5);
  expect_round_off(run_both(column, settings, 6, 1e-5, 0.0, kBlob, 3),
                   GetParam() ? "moved_column_implicit" : "moved_column_explicit");
}

TEST_P(DistributedGas, TwoDimensionalChannelWithOneCellPeriodicAxisMatchesOneGrid) {
  // One cell along periodic z (no flux: hypre's axis is left non-periodic, the exchange copies
  // the cell onto itself), walls along y, pressure drop along periodic x, a disturbance.
  const MacGridSpec spec = channel_2d();
  expect_round_off(run_both(spec, tight_settings(GetParam()), 10, 2e-5, 0.0, kChannelStart),
                   GetParam() ? "channel_2d_implicit" : "channel_2d_explicit");
}

// A round column (fluid/solid_mask.hpp): the inflow/outflow column with a cylinder along y, so
// the multigrid's empty rows (solid cells) lie on every rank's box and on the level gathered
// onto rank 0. hypre does not take solid cells, so both runs use the multigrid; on this grid its
// R-rank hierarchy (the fine levels over the boxes, the rest gathered) takes the one grid's
// iterations, and the two agree to round-off (measured 6.5e-16 on 2 ranks, 5.4e-16 on 3).
TEST_P(DistributedGas, CylinderMatchesOneGrid) {
  GasSolverSettings settings = tight_settings(GetParam());
  settings.projection.solver = PoissonSolver::multigrid;
  settings.gas.gravity = {0.0, -9.80665, 0.0};
  MacGridSpec column = outflow_column(0.5);
  column.cells = {10, 12, 10};
  column.extent = {1e-3, 1.2e-3, 1e-3};
  column.cylinder_axis = 1;
  column.cylinder_radius = 4.6e-4; // a rim of solid cells on every side
  const Agreement a = run_both(column, settings, 6, 1e-5, 0.0, kBlob);
  if (Communicator::world().rank() == 0) {
    std::printf("[ measured ] cylinder column (%s viscosity) on %d ranks: velocity %.3g, "
                "pressure %.3g\n",
                GetParam() ? "implicit" : "explicit", Communicator::world().size(), a.velocity,
                a.pressure);
  }
  EXPECT_LE(a.velocity, kRoundOff);
  EXPECT_LE(a.pressure, kRoundOff);
}

TEST_P(DistributedGas, SmgPreconditionedColumnMatchesOneGrid) {
  // hypre's SMG (the fallback preconditioner) on the communicator too.
  const MacGridSpec column = outflow_column(0.0);
  GasSolverSettings settings = tight_settings(GetParam());
  settings.projection.preconditioner = PoissonPreconditioner::smg;
  const FieldSetter none = [](const MacGrid&, GasSolver&, int) {};
  expect_round_off(run_both(column, settings, 5, 1e-5, 0.0, none),
                   GetParam() ? "column_smg_implicit" : "column_smg_explicit");
}

// fluid.viscous_step = "factored" over the ranks: the boxes cut the x, y and z lines into
// segments, and the interface system each line's boxes solve (one sum over the ranks per sweep)
// must give the one grid's direct line solves up to round-off: on walls, inflow and outflow
// (the column), across periodic lines (the channel's x, the vortex's x and y) and with the
// lines closed into a ring by a box alone along a periodic axis.
TEST(DistributedGasFactored, ColumnChannelAndVortexMatchOneGrid) {
  GasSolverSettings settings = tight_settings(true);
  settings.factored_viscosity = true;
  settings.gas.gravity = {0.0, -9.80665, 0.0};
  expect_round_off(run_both(outflow_column(0.5), settings, 6, 1e-5, 0.0, kBlob), "column_factored");
  settings.gas.gravity = {0.0, 0.0, 0.0};
  expect_round_off(run_both(channel_2d(), settings, 8, 2e-5, 0.0, kChannelStart),
                   "channel_factored");
  expect_round_off(run_both(vortex_box(), settings, 10, 4e-5, 0.0, kVortexStart),
                   "taylor_green_factored");
}

INSTANTIATE_TEST_SUITE_P(Viscosity, DistributedGas, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& param) {
                           return std::string(param.param ? "implicit" : "explicit");
                         });

TEST(DistributedGasMultigrid, ColumnClosedBoxAndChannelMatchOneGrid) {
  // The multigrid projection on the ranks and on one grid (explicit viscosity): outflow faces on
  // the boxes that touch them only (an internal side adds no p_out), a closed box's pinned-free
  // singular system, and a one-cell periodic axis. These grids are gathered whole onto rank 0
  // (fewer than MultigridSettings::gather_cells cells): the same V-cycle, sums in another order.
  // (Levels relaxed over the ranks: distributed_multigrid_test.cpp.)
  GasSolverSettings settings = tight_settings(false);
  settings.projection.solver = PoissonSolver::multigrid;
  settings.gas.gravity = {0.0, -9.80665, 0.0};
  const MacGridSpec column = outflow_column(0.5);
  expect_round_off(run_both(column, settings, 6, 1e-5, 0.0, kBlob), "column_multigrid");
  const MacGridSpec closed = box_spec({7, 9, 6}, {7e-4, 9e-4, 6e-4}, BoundaryKind::wall);
  expect_round_off(run_both(closed, settings, 6, 1e-5, 0.0, kBlob), "closed_box_multigrid");
  const MacGridSpec channel = channel_2d();
  settings.gas.gravity = {0.0, 0.0, 0.0};
  expect_round_off(run_both(channel, settings, 10, 2e-5, 0.0, kChannelStart),
                   "channel_2d_multigrid");
}

TEST(DistributedGasConstraint, VolumeFractionChangeDrivesDivergenceOnEveryBox) {
  // As GasSolverConstraint on one grid: after each step div(eps u) = -d(eps)/dt holds to the
  // projection tolerance relative to the source's norm, summed over every rank's cells.
  MacGridSpec spec = box_spec({10, 9, 8}, {1e-3, 9e-4, 8e-4}, BoundaryKind::periodic);
  spec.pressure_drop[1] = 1e-2;
  const Split split(spec);
  const MacGrid& grid = *split.grid;
  GasSolverSettings settings = tight_settings(false);
  settings.projection.tolerance = 1e-10;
  GasSolver solver(grid, settings, split.halo);
  const double dt = 1e-5;
  GridField old = grid.make_field();
  for (int step = 0; step < 4; ++step) {
    old = solver.volume_fraction();
    set_field(grid, solver.volume_fraction(), kCellCentred, [&](double x, double y, double z) {
      return 0.85 + 0.1 * std::sin(6e3 * x + 7e3 * y - 2e4 * dt * step) * std::cos(7.85e3 * z);
    });
    if (step == 0) {
      solver.reset_volume_fraction_history();
      continue;
    }
    (void)solver.step(dt);
    GridField& eps = solver.volume_fraction();
    fill_cell_ghosts(grid, split.halo.get(), eps, CellGhosts::zero_gradient);
    GridField div = grid.make_field();
    flux_divergence(grid, solver.velocity(), eps, div);
    std::array<double, 3> sums{}; // |div + s|^2, |s|^2, sum s
    for (int k = 0; k < grid.cells(2); ++k) {
      for (int j = 0; j < grid.cells(1); ++j) {
        for (int i = 0; i < grid.cells(0); ++i) {
          const double s = (eps(i, j, k) - old(i, j, k)) / dt;
          sums[0] += std::pow(div(i, j, k) + s, 2);
          sums[1] += s * s;
          sums[2] += s;
        }
      }
    }
    split.comm.sum(sums);
    ASSERT_GT(sums[1], 0.0);
    const double cells = 10.0 * 9.0 * 8.0;
    const double mean = sums[2] / cells; // the singular system's compatible part
    EXPECT_LE(std::sqrt(std::max(0.0, sums[0] - cells * mean * mean)) / std::sqrt(sums[1]), 2e-10);
  }
}

TEST(FluidBoxes, EveryRankOwnsAboutTotalOverRanksCells) {
  const Communicator comm = Communicator::world();
  const std::array<int, 5> all_parts = {comm.size(), 2, 3, 5, 8};
  for (std::size_t p = 0; p < all_parts.size(); ++p) {
    const int parts = all_parts[p];
    for (const std::array<int, 3> cells : {std::array<int, 3>{32, 50, 32}, {9, 11, 7}}) {
      if (parts == 8 && cells[2] == 7) {
        continue; // 7 cells cannot be cut twice into boxes of 3
      }
      const std::vector<CellBox> boxes = orb_cell_boxes(cells, parts, kMinBoxWidth);
      ASSERT_EQ(boxes.size(), static_cast<std::size_t>(parts));
      std::int64_t total = 0;
      for (const CellBox& b : boxes) {
        total += b.count();
      }
      EXPECT_EQ(total, static_cast<std::int64_t>(cells[0]) * cells[1] * cells[2]);
      const double mean = static_cast<double>(total) / parts;
      // Each of the ceil(log2 R) cuts rounds to the nearest cell face, moving a part's share by
      // at most half a cross-section of the box it cuts (at most the grid's largest), or to a
      // granule face within 1/16 of the share (core/cell_box.cpp): the part's share grows by at
      // most a factor 17/16 per cut.
      const double section = std::max({static_cast<double>(cells[0]) * cells[1],
                                       static_cast<double>(cells[1]) * cells[2],
                                       static_cast<double>(cells[0]) * cells[2]});
      const double levels = std::ceil(std::log2(static_cast<double>(parts)));
      const double bound = levels * 0.5 * section + mean * (std::pow(17.0 / 16.0, levels) - 1.0);
      std::int64_t largest = 0;
      for (const CellBox& b : boxes) {
        EXPECT_LE(std::abs(static_cast<double>(b.count()) - mean), bound)
            << b.count() << " cells against a mean of " << mean;
        largest = std::max(largest, b.count());
      }
      if (comm.rank() == 0 && p == 0) {
        std::printf("[ measured ] %d x %d x %d cells on %d ranks: largest box %lld cells, mean "
                    "%.0f\n",
                    cells[0], cells[1], cells[2], parts, static_cast<long long>(largest), mean);
      }
    }
  }
  EXPECT_THROW((void)orb_cell_boxes({4, 4, 4}, 3, kMinBoxWidth), std::invalid_argument);
}

// The cuts fall on multiples of the largest power of two (up to 16) dividing the axis where that
// keeps the part within 1/16 of its share, so the boxes divide down the multigrid's levels. The
// riser's 50-cell y axis is cut at 26, not 25 (1/25 off); the 1e5 riser's 88-cell z axis at 44
// (a multiple of 4; 48, on 8, is 1/11 off); a 9-cell axis (granule 1) at its nearest face; and
// every end of the 1e5 riser's boxes on 16 parts is even on every axis (on the nearest faces,
// 25 and 21 were among them).
TEST(FluidBoxes, CutsFallOnPowersOfTwoWithinASixteenthOfTheShare) {
  EXPECT_EQ(orb_cell_boxes({32, 50, 32}, 2, kMinBoxWidth)[0].hi, (std::array<int, 3>{32, 26, 32}));
  EXPECT_EQ(orb_cell_boxes({84, 50, 88}, 2, kMinBoxWidth)[0].hi, (std::array<int, 3>{84, 50, 44}));
  EXPECT_EQ(orb_cell_boxes({9, 11, 7}, 2, kMinBoxWidth)[0].hi, (std::array<int, 3>{9, 6, 7}));
  for (const CellBox& b : orb_cell_boxes({84, 50, 88}, 16, kMinBoxWidth)) {
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(b.lo[a] % 2, 0) << "axis " << a;
      EXPECT_EQ(b.hi[a] % 2, 0) << "axis " << a;
    }
  }
}

// A run's gas boxes (fluid::gas_cell_boxes) follow the grid's boundaries: the 1e5 bed's odd
// walled x and z (101 cells) are cut on powers of two (48 on 2 ranks; every interior end even, so
// they halve unevenly over the ranks), where the same counts between periodic faces, which
// cannot halve unevenly, are cut at the nearest face; the 1e6 riser's periodic 270 on multiples
// of 6 (halves, then thirds).
TEST(FluidBoxes, GasBoxesFollowTheMultigridsRatios) {
  MacGridSpec bed = box_spec({101, 50, 101}, {5.05e-3, 1e-2, 5.05e-3}, BoundaryKind::wall);
  bed.bc[2] = test::bc_of(BoundaryKind::inflow);
  bed.bc[3] = test::bc_of(BoundaryKind::outflow);
  EXPECT_EQ(gas_cell_boxes(bed, 2)[0].hi[0], 48);
  for (const CellBox& b : gas_cell_boxes(bed, 4)) {
    for (const int a : {0, 2}) {
      EXPECT_EQ(b.lo[a] % 2, 0);
      EXPECT_TRUE(b.hi[a] % 2 == 0 || b.hi[a] == 101);
    }
  }
  const MacGridSpec periodic =
      box_spec({101, 50, 101}, {5.05e-3, 1e-2, 5.05e-3}, BoundaryKind::periodic);
  EXPECT_EQ(gas_cell_boxes(periodic, 2)[0].hi[0], 51);
  const MacGridSpec riser =
      box_spec({270, 50, 270}, {5.0625e-2, 1e-2, 5.0625e-2}, BoundaryKind::periodic);
  for (const CellBox& b : gas_cell_boxes(riser, 16)) {
    EXPECT_EQ(b.lo[0] % 6, 0);
    EXPECT_EQ(b.hi[0] % 6, 0);
  }
}

// Global index of a local point, wrapped on periodic axes; false outside a non-periodic face.
bool global_point(const MacGrid& g, int centring, std::array<int, 3> l, std::array<int, 3>& out) {
  for (int a = 0; a < 3; ++a) {
    const int n = g.global_cells()[a];
    int x = g.box().lo[a] + l[a];
    if (g.periodic(a)) {
      x = ((x % n) + n) % n;
    } else if (x < 0 || x > (a == centring ? n : n - 1)) {
      return false;
    }
    out[a] = x;
  }
  return true;
}

TEST(GridHalo, GhostsHoldTheOwnersValuesWithPeriodicImages) {
  // x periodic, y walls, z periodic: every exchanged ghost (faces and edges and corners
  // included) gets the owner's value of the wrapped global point; ghosts outside a wall are
  // left alone.
  MacGridSpec spec = box_spec({10, 9, 7}, {1e-3, 9e-4, 7e-4}, BoundaryKind::periodic);
  set_axis(spec, 1, BoundaryKind::wall);
  const Split split(spec);
  const MacGrid& g = *split.grid;
  const auto code = [](const std::array<int, 3>& x) {
    return 1.0 + x[0] + 100.0 * x[1] + 10000.0 * x[2];
  };
  for (int centring = kCellCentred; centring < 3; ++centring) {
    GridField f = g.make_field(-1.0);
    std::array<int, 3> hi = g.cells();
    if (centring >= 0 && !g.exchanged(centring, 1)) {
      hi[static_cast<std::size_t>(centring)] += 1; // the owned last face
    }
    std::array<int, 3> x{};
    for (int k = 0; k < hi[2]; ++k) {
      for (int j = 0; j < hi[1]; ++j) {
        for (int i = 0; i < hi[0]; ++i) {
          ASSERT_TRUE(global_point(g, centring, {i, j, k}, x));
          f(i, j, k) = code(x);
        }
      }
    }
    split.halo->fill(f, centring);
    int wrong = 0;
    for (int k = -kGhostLayers; k <= g.cells(2) + kGhostLayers; ++k) {
      for (int j = -kGhostLayers; j <= g.cells(1) + kGhostLayers; ++j) {
        for (int i = -kGhostLayers; i <= g.cells(0) + kGhostLayers; ++i) {
          const double expected = global_point(g, centring, {i, j, k}, x) ? code(x) : -1.0;
          wrong += f(i, j, k) != expected ? 1 : 0;
        }
      }
    }
    EXPECT_EQ(split.comm.sum(static_cast<std::int64_t>(wrong)), 0) << "centring " << centring;
  }
}

TEST(GridHalo, ReverseAddPutsEveryGhostIntoItsOwner) {
  // Ones everywhere (owned and exchanged ghosts): after the reverse add the owned points sum
  // to the number of owned plus exchanged ghost points, over all ranks.
  const MacGridSpec spec = box_spec({8, 10, 6}, {8e-4, 1e-3, 6e-4}, BoundaryKind::periodic);
  const Split split(spec);
  const MacGrid& g = *split.grid;
  GridField f = g.make_field(1.0);
  split.halo->add_ghosts_to_owners(f, kCellCentred);
  double owned = 0.0;
  for (int k = 0; k < g.cells(2); ++k) {
    for (int j = 0; j < g.cells(1); ++j) {
      for (int i = 0; i < g.cells(0); ++i) {
        owned += f(i, j, k);
      }
    }
  }
  double ghosts = 0.0;
  for (const HaloExchange::Link& l : split.halo->plan(kCellCentred).links()) {
    ghosts += static_cast<double>(l.recv.size());
  }
  // Every padded point of a fully periodic grid is exchanged: (n + 5)^3 - n^3 per box.
  const auto& n = g.cells();
  const double padded = (n[0] + 5.0) * (n[1] + 5.0) * (n[2] + 5.0);
  EXPECT_EQ(ghosts, padded - static_cast<double>(g.box().count()));
  EXPECT_EQ(split.halo->sum(owned), split.halo->sum(static_cast<double>(g.box().count()) + ghosts));
}

} // namespace
} // namespace cfddem::fluid
