// Projection onto div(eps u) = -d(eps)/dt with non-uniform eps: the constraint holds to the
// solver tolerance for closed, periodic and inflow/outflow boxes, with PFMG and SMG.
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

#include "fluid/ghost_fill.hpp"
#include "fluid/pressure_projection.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

using test::box_spec;
using test::set_axis;

double norm2(const MacGrid& grid, const GridField& div, const GridField& source) {
  return test::constraint_residual_norm(grid, div, source);
}

struct Case {
  const char* name;
  MacGridSpec spec;
  PoissonPreconditioner pc;
};

void check_projection(const Case& c) {
  SCOPED_TRACE(c.name);
  const MacGrid grid(c.spec);
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  std::uniform_real_distribution<double> frac(0.4, 1.0);
  std::array<GridField, 3> u = {grid.make_field(), grid.make_field(), grid.make_field()};
  std::array<GridField, 3> mobility = u;
  GridField eps = grid.make_field();
  GridField source = grid.make_field();
  const double dt = 1e-4;
  const double rho = 1.0;
  for (int k = 0; k < grid.cells(2); ++k) {
    for (int j = 0; j < grid.cells(1); ++j) {
      for (int i = 0; i < grid.cells(0); ++i) {
        eps(i, j, k) = frac(rng);
        source(i, j, k) = 0.1 * uni(rng) / dt; // d(eps)/dt of up to 0.1 per step
      }
    }
  }
  if (!grid.has_outflow()) {
    // A closed (or periodic) box conserves solids volume: sum of d(eps)/dt is zero.
    double mean = 0.0;
    for (int k = 0; k < grid.cells(2); ++k) {
      for (int j = 0; j < grid.cells(1); ++j) {
        for (int i = 0; i < grid.cells(0); ++i) {
          mean += source(i, j, k);
        }
      }
    }
    mean /= grid.cells(0) * grid.cells(1) * grid.cells(2);
    for (int k = 0; k < grid.cells(2); ++k) {
      for (int j = 0; j < grid.cells(1); ++j) {
        for (int i = 0; i < grid.cells(0); ++i) {
          source(i, j, k) -= mean;
        }
      }
    }
  }
  fill_cell_ghosts(grid, eps, CellGhosts::zero_gradient);
  for (int a = 0; a < 3; ++a) {
    for (double& v : u[a].values()) {
      v = uni(rng);
    }
    for (double& m : mobility[a].values()) {
      m = dt / (rho + dt * 1e4 * (1.0 + uni(rng))); // implicit drag varies the mobility
    }
  }
  fill_velocity_ghosts(grid, u);
  GridField div = grid.make_field();
  flux_divergence(grid, u, eps, div);
  const double before = norm2(grid, div, source);

  ProjectionSettings settings;
  settings.tolerance = 1e-9;
  settings.preconditioner = c.pc;
  settings.solver = PoissonSolver::hypre; // the multigrid: multigrid_poisson_test.cpp
  PressureProjection projection(grid, settings);
  GridField phi = grid.make_field();
  const ProjectionReport report = projection.project(u, eps, mobility, source, phi);
  fill_velocity_ghosts(grid, u);
  flux_divergence(grid, u, eps, div);
  const double after = norm2(grid, div, source);
  EXPECT_FALSE(report.used_fallback);
  EXPECT_LE(report.relative_residual, settings.tolerance);
  EXPECT_GT(report.iterations, 0);
  // hypre's residual is that of div(eps u) + d(eps)/dt: the same tolerance, up to rounding of
  // the recursive PCG residual.
  EXPECT_LE(after / before, 2.0 * settings.tolerance) << "before " << before << " after " << after;
}

// flux_divergence against the cell-by-cell formula (docs/theory.md §5): per cell, the x, y and z
// terms (eps_hi u_hi - eps_lo u_lo) / h in that order, eps of a face the mean of its two cells, or
// 1 on a velocity-inflow face (kInflowVolumeFraction). Inflow faces on every axis, including a
// one-cell x axis whose only cell touches two of them: equal bit for bit.
TEST(FluxDivergence, EqualsTheCellByCellFormulaWithInflowOnEveryAxis) {
  MacGridSpec a = box_spec({5, 4, 3}, {5e-4, 4e-4, 3e-4}, BoundaryKind::wall);
  a.bc[0].kind = BoundaryKind::inflow;  // x lo
  a.bc[3].kind = BoundaryKind::inflow;  // y hi
  a.bc[4].kind = BoundaryKind::inflow;  // z lo
  a.bc[1].kind = BoundaryKind::outflow; // every inflow needs an outlet
  MacGridSpec b = box_spec({1, 4, 3}, {1e-4, 4e-4, 3e-4}, BoundaryKind::wall);
  b.bc[0].kind = BoundaryKind::inflow;
  b.bc[1].kind = BoundaryKind::inflow;
  b.bc[5].kind = BoundaryKind::inflow; // z hi
  b.bc[2].kind = BoundaryKind::outflow;
  for (const MacGridSpec& spec : {a, b}) {
    const MacGrid grid(spec);
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> uni(-1.0, 1.0);
    std::uniform_real_distribution<double> frac(0.4, 1.0);
    std::array<GridField, 3> u = {grid.make_field(), grid.make_field(), grid.make_field()};
    GridField eps = grid.make_field();
    for (double& v : eps.values()) {
      v = frac(rng);
    }
    for (GridField& f : u) {
      for (double& v : f.values()) {
        v = uni(rng);
      }
    }
    GridField div = grid.make_field();
    flux_divergence(grid, u, eps, div);
    const auto& n = grid.cells();
    for (int k = 0; k < n[2]; ++k) {
      for (int j = 0; j < n[1]; ++j) {
        for (int i = 0; i < n[0]; ++i) {
          const std::array<int, 3> c = {i, j, k};
          double expected = 0.0;
          for (int ax = 0; ax < 3; ++ax) {
            std::array<int, 3> below = c;
            std::array<int, 3> above = c;
            --below[ax];
            ++above[ax];
            const double eps_lo = c[ax] == 0 && grid.inflow_face(ax, 0)
                                      ? kInflowVolumeFraction
                                      : 0.5 * (eps(i, j, k) + eps(below[0], below[1], below[2]));
            const double eps_hi = c[ax] == n[ax] - 1 && grid.inflow_face(ax, 1)
                                      ? kInflowVolumeFraction
                                      : 0.5 * (eps(above[0], above[1], above[2]) + eps(i, j, k));
            expected += (eps_hi * u[ax](above[0], above[1], above[2]) - eps_lo * u[ax](i, j, k)) /
                        grid.spacing(ax);
          }
          EXPECT_EQ(div(i, j, k), expected) << "cell " << i << " " << j << " " << k;
        }
      }
    }
  }
}

TEST(PressureProjection, DivergenceConstraintHoldsWithNonUniformEps) {
  MacGridSpec closed = box_spec({10, 12, 8}, {1e-3, 1.2e-3, 0.8e-3}, BoundaryKind::wall);
  MacGridSpec periodic = box_spec({8, 12, 6}, {1e-3, 1.5e-3, 0.9e-3}, BoundaryKind::periodic);
  MacGridSpec bed = box_spec({6, 14, 4}, {6e-4, 1.4e-3, 4e-4}, BoundaryKind::periodic);
  set_axis(bed, 1, BoundaryKind::wall);
  bed.bc[2].kind = BoundaryKind::inflow;
  bed.bc[2].velocity = {0.0, 0.015, 0.0};
  bed.bc[3].kind = BoundaryKind::outflow;
  bed.bc[3].pressure = 3.0;
  MacGridSpec odd = bed; // odd periodic period: PFMG copes, hypre's SMG does not converge
  odd.cells[2] = 5;
  odd.extent[2] = 5e-4;
  for (const PoissonPreconditioner pc : {PoissonPreconditioner::pfmg, PoissonPreconditioner::smg}) {
    for (const Case& c : {Case{"closed box", closed, pc}, Case{"periodic box", periodic, pc},
                          Case{"inflow/outflow bed", bed, pc}}) {
      check_projection(c);
    }
  }
  check_projection({"odd periodic bed", odd, PoissonPreconditioner::pfmg});
}

// An odd periodic count: SMG is refused up front (hypre 2.26's SMG set-up fails there, on R
// ranks inside MPI), and a PFMG solve that misses the tolerance stops with a message naming the
// grid and the axis instead of falling back to SMG.
TEST(PressureProjection, OddPeriodicAxisRefusesSmgAndExplainsAPfmgFailure) {
  MacGridSpec spec = box_spec({8, 12, 5}, {1e-3, 1.2e-3, 5e-4}, BoundaryKind::periodic);
  const MacGrid grid(spec);
  EXPECT_EQ(smg_blocking_axis(grid), 2);
  EXPECT_EQ(smg_blocking_axis(
                MacGrid(box_spec({8, 12, 6}, {1e-3, 1.2e-3, 6e-4}, BoundaryKind::periodic))),
            -1);
  ProjectionSettings settings;
  settings.solver = PoissonSolver::hypre;
  settings.preconditioner = PoissonPreconditioner::smg;
  try {
    PressureProjection refused(grid, settings);
    ADD_FAILURE() << "SMG accepted on an odd periodic axis";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("fluid.preconditioner"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("axis z has 5 cells"), std::string::npos) << e.what();
  }
  settings.preconditioner = PoissonPreconditioner::pfmg;
  settings.max_iterations = 1; // one iteration cannot reach 1e-12 from a random right-hand side
  settings.tolerance = 1e-12;
  PressureProjection projection(grid, settings);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  std::array<GridField, 3> u = {grid.make_field(), grid.make_field(), grid.make_field()};
  std::array<GridField, 3> mobility = {grid.make_field(1e-4), grid.make_field(1e-4),
                                       grid.make_field(1e-4)};
  for (auto& f : u) {
    for (double& v : f.values()) {
      v = uni(rng);
    }
  }
  fill_velocity_ghosts(grid, u);
  GridField eps = grid.make_field(0.8);
  GridField source = grid.make_field();
  GridField phi = grid.make_field();
  try {
    (void)projection.project(u, eps, mobility, source, phi);
    ADD_FAILURE() << "one PFMG iteration reached 1e-12";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("periodic axis z has an odd cell count (5)"),
              std::string::npos)
        << e.what();
  }
}

TEST(PressureProjection, OutflowPressureSetsLevel) {
  // Nothing to correct: phi equals the outflow pressure everywhere.
  MacGridSpec spec = box_spec({4, 6, 4}, {4e-4, 6e-4, 4e-4}, BoundaryKind::wall);
  spec.bc[3].kind = BoundaryKind::outflow;
  spec.bc[3].pressure = 7.5;
  const MacGrid grid(spec);
  std::array<GridField, 3> u = {grid.make_field(), grid.make_field(), grid.make_field()};
  std::array<GridField, 3> mobility = {grid.make_field(1e-4), grid.make_field(1e-4),
                                       grid.make_field(1e-4)};
  GridField eps = grid.make_field(0.7);
  GridField source = grid.make_field();
  GridField phi = grid.make_field();
  PressureProjection projection(grid, ProjectionSettings{});
  (void)projection.project(u, eps, mobility, source, phi);
  for (int j = 0; j < 6; ++j) {
    EXPECT_NEAR(phi(2, j, 1), 7.5, 1e-8);
  }
}

} // namespace
} // namespace cfddem::fluid
