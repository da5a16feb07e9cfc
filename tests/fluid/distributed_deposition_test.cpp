// Deposition and interpolation on the ranks' boxes against the one-grid run: each rank deposits
// the particles whose centres lie in its box, stencils reach into the ghost layers and the
// ghosts are added into their owners; interpolation reads halo-filled fields.
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "core/cell_box.hpp"
#include "core/communicator.hpp"
#include "fluid/deposition.hpp"
#include "fluid/grid_halo.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

struct Particles {
  std::vector<double> x, y, z, r, value;
  [[nodiscard]] ParticlePositions positions() const { return {x, y, z, r}; }
};

// Random particles in the domain, the same on every rank (fixed seed); radii up to r_max.
Particles random_particles(const MacGrid& g, int n, double r_max) {
  std::mt19937_64 rng(2024);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Particles p;
  for (int i = 0; i < n; ++i) {
    p.x.push_back(g.origin(0) + u(rng) * g.length(0));
    p.y.push_back(g.origin(1) + u(rng) * g.length(1));
    p.z.push_back(g.origin(2) + u(rng) * g.length(2));
    p.r.push_back(r_max * (0.5 + 0.5 * u(rng)));
    p.value.push_back(1.0 + u(rng));
  }
  return p;
}

// The particles whose centre cell lies in `box` (the rank that owns them).
Particles in_box(const MacGrid& global, const Particles& all, const CellBox& box) {
  Particles mine;
  for (std::size_t i = 0; i < all.x.size(); ++i) {
    const std::array<double, 3> x = {all.x[i], all.y[i], all.z[i]};
    bool inside = true;
    for (int a = 0; a < 3; ++a) {
      const int c =
          std::min(global.global_cells()[a] - 1,
                   static_cast<int>(std::floor((x[a] - global.origin(a)) / global.spacing(a))));
      inside = inside && c >= box.lo[a] && c < box.hi[a];
    }
    if (inside) {
      mine.x.push_back(all.x[i]);
      mine.y.push_back(all.y[i]);
      mine.z.push_back(all.z[i]);
      mine.r.push_back(all.r[i]);
      mine.value.push_back(all.value[i]);
    }
  }
  return mine;
}

class DistributedDeposition : public ::testing::TestWithParam<DepositionKernel> {};

TEST_P(DistributedDeposition, EqualsOneGridToRoundOffAndConservesTheSum) {
  // x periodic, y walls, z periodic; cells of 1e-4 m, radii up to 0.4 cells (dpvm width 2:
  // the kernel spans at most 0.8 cells each side of the centre, within the 2 ghost layers).
  MacGridSpec spec = test::box_spec({10, 9, 7}, {1e-3, 9e-4, 7e-4}, BoundaryKind::periodic);
  test::set_axis(spec, 1, BoundaryKind::wall);
  const Communicator comm = Communicator::world();
  const std::vector<CellBox> boxes = orb_cell_boxes(spec.cells, comm.size(), kMinBoxWidth);
  const MacGrid global(spec);
  const MacGrid local(spec, boxes[static_cast<std::size_t>(comm.rank())]);
  const GridHalo halo(local, boxes, comm);
  DepositionSettings settings;
  settings.kernel = GetParam();
  const double r_max = 4e-5;
  const Particles all = random_particles(global, 400, r_max);
  const Particles mine = in_box(global, all, local.box());

  Deposition serial(global, settings, r_max);
  Deposition distributed(local, settings, r_max, &halo);
  GridField a = global.make_field();
  GridField b = local.make_field();
  serial.deposit(all.positions(), all.value, a);
  distributed.deposit(mine.positions(), mine.value, b);
  // Twice: ghosts are zeroed after the reverse add, so a second deposit accumulates exactly.
  serial.deposit(all.positions(), all.value, a);
  distributed.deposit(mine.positions(), mine.value, b);

  // Cell values: the same weights, summed in another order (a cell gets its own rank's
  // particles first, then each neighbour's): round-off of a sum of a few terms, < 1e-15
  // relative to the largest cell value; allow 1e-13.
  const auto& lo = local.box().lo;
  std::array<double, 3> sums{}; // max |diff|, max |a|, sum of b
  for (int k = 0; k < local.cells(2); ++k) {
    for (int j = 0; j < local.cells(1); ++j) {
      for (int i = 0; i < local.cells(0); ++i) {
        const double ref = a(i + lo[0], j + lo[1], k + lo[2]);
        sums[0] = std::max(sums[0], std::abs(b(i, j, k) - ref));
        sums[1] = std::max(sums[1], std::abs(ref));
      }
    }
  }
  comm.max(std::span<double>(sums.data(), 2));
  double total = 0.0;
  for (int k = 0; k < local.cells(2); ++k) {
    for (int j = 0; j < local.cells(1); ++j) {
      for (int i = 0; i < local.cells(0); ++i) {
        total += b(i, j, k);
      }
    }
  }
  total = halo.sum(total) * local.cell_volume();
  double expected = 0.0;
  for (const double v : all.value) {
    expected += 2.0 * v;
  }
  ASSERT_GT(sums[1], 0.0);
  EXPECT_LE(sums[0] / sums[1], 1e-13);
  EXPECT_NEAR(total, expected, 1e-12 * expected) << "deposition conserves sum value";
  EXPECT_EQ(halo.sum(static_cast<double>(mine.x.size())), static_cast<double>(all.x.size()));
  // The same two deposits from a plan of the rank's particles: bitwise b.
  TransferPlan plan;
  distributed.plan(mine.positions(), plan);
  GridField c = local.make_field();
  const std::span<const double> values[1] = {mine.value};
  GridField* cells[1] = {&c};
  distributed.deposit(plan, values, cells);
  distributed.deposit(plan, values, cells);
  EXPECT_TRUE(test::same_bits(b, c));

  // Interpolation of a smooth field from halo-filled ghosts: the same cells and weights in the
  // same order as on one grid, so bitwise equal.
  GridField fa = global.make_field();
  GridField fb = local.make_field();
  const auto field = [](const MacGrid& g, GridField& f) {
    for (int k = 0; k < g.cells(2); ++k) {
      for (int j = 0; j < g.cells(1); ++j) {
        for (int i = 0; i < g.cells(0); ++i) {
          f(i, j, k) = std::sin(7e3 * g.cell_centre(0, i)) * std::cos(5e3 * g.cell_centre(1, j)) +
                       g.cell_centre(2, k) * 1e3;
        }
      }
    }
  };
  field(global, fa);
  field(local, fb);
  halo.fill(fb, kCellCentred);
  std::vector<double> ia(all.x.size());
  std::vector<double> ib(mine.x.size());
  serial.interpolate(all.positions(), fa, ia);
  distributed.interpolate(mine.positions(), fb, ib);
  std::vector<double> ic(mine.x.size());
  const GridField* planned_in[1] = {&fb};
  const std::span<double> planned_out[1] = {ic};
  distributed.interpolate(plan, planned_in, planned_out);
  EXPECT_EQ(ib, ic) << "a plan's interpolation is the computed kernels' bit for bit";
  const Particles serial_mine =
      in_box(global, Particles{all.x, all.y, all.z, all.r, ia}, local.box());
  ASSERT_EQ(serial_mine.value.size(), ib.size());
  int differ = 0;
  for (std::size_t i = 0; i < ib.size(); ++i) {
    differ += ib[i] != serial_mine.value[i] ? 1 : 0;
  }
  EXPECT_EQ(comm.sum(static_cast<std::int64_t>(differ)), 0);
}

INSTANTIATE_TEST_SUITE_P(Kernels, DistributedDeposition,
                         ::testing::Values(DepositionKernel::trilinear, DepositionKernel::dpvm_cube,
                                           DepositionKernel::dpvm_sphere),
                         [](const ::testing::TestParamInfo<DepositionKernel>& param) {
                           switch (param.param) {
                           case DepositionKernel::trilinear:
                             return std::string("trilinear");
                           case DepositionKernel::dpvm_cube:
                             return std::string("dpvm_cube");
                           case DepositionKernel::dpvm_sphere:
                             break;
                           }
                           return std::string("dpvm_sphere");
                         });

TEST(DistributedDeposition, KernelWiderThanTheGhostLayersIsAnError) {
  const MacGridSpec spec = test::box_spec({12, 9, 7}, {1.2e-3, 9e-4, 7e-4}, BoundaryKind::periodic);
  const Communicator comm = Communicator::world();
  const std::vector<CellBox> boxes = orb_cell_boxes(spec.cells, comm.size(), kMinBoxWidth);
  const MacGrid local(spec, boxes[static_cast<std::size_t>(comm.rank())]);
  const GridHalo halo(local, boxes, comm);
  DepositionSettings settings;
  settings.kernel = DepositionKernel::dpvm_cube;
  // r* = 2 x 1.5e-4 = 3 cells: beyond the 2 ghost layers.
  Deposition d(local, settings, 1.5e-4, &halo);
  const double x = local.cell_centre(0, 0);
  const std::vector<double> px = {x}, py = {local.cell_centre(1, 0)},
                            pz = {local.cell_centre(2, 0)}, pr = {1.5e-4}, v = {1.0};
  GridField f = local.make_field();
  EXPECT_THROW(d.deposit({px, py, pz, pr}, v, f), std::runtime_error);
}

} // namespace
} // namespace cfddem::fluid
