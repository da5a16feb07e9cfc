// Interpolation and deposition (docs/theory.md §7): weights, conservation, exactness for linear
// fields, and eps_g in (0, 1] for cells smaller than a particle with the wide dpvm kernel.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "fluid/deposition.hpp"
#include "fluid/diffusion_smoothing.hpp"
#include "fluid/dpvm_weights.hpp"
#include "fluid/trilinear_weights.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

using test::box_spec;

struct Cloud {
  std::vector<double> x, y, z, r;
  [[nodiscard]] ParticlePositions view() const { return {x, y, z, r}; }
  [[nodiscard]] double volume() const {
    double v = 0.0;
    for (const double ri : r) {
      v += 4.0 / 3.0 * std::numbers::pi * ri * ri * ri;
    }
    return v;
  }
};

Cloud random_cloud(const MacGrid& grid, int count, double radius, unsigned seed) {
  std::mt19937_64 rng(seed);
  Cloud c;
  for (int n = 0; n < count; ++n) {
    std::array<std::vector<double>*, 3> axes = {&c.x, &c.y, &c.z};
    for (int a = 0; a < 3; ++a) {
      std::uniform_real_distribution<double> u(grid.origin(a), grid.origin(a) + grid.length(a));
      axes[a]->push_back(u(rng));
    }
    c.r.push_back(radius);
  }
  return c;
}

double interior_sum(const MacGrid& grid, const GridField& f) {
  double s = 0.0;
  for (int k = 0; k < grid.cells(2); ++k) {
    for (int j = 0; j < grid.cells(1); ++j) {
      for (int i = 0; i < grid.cells(0); ++i) {
        s += f(i, j, k);
      }
    }
  }
  return s;
}

TEST(TrilinearWeights, SumToOneAndReproduceLinearPositions) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1e-3);
  const std::array<double, 3> origin = {0.0, 0.0, 0.0};
  const std::array<double, 3> dx = {1e-4, 2e-4, 5e-5};
  std::array<double, 8> w{};
  for (int n = 0; n < 100; ++n) {
    const std::array<double, 3> x = {u(rng), u(rng), u(rng)};
    const CellStencil s = trilinear_weights(x, origin, dx, w);
    double sum = 0.0;
    std::array<double, 3> centroid{};
    std::size_t m = 0;
    for (int c = 0; c < 2; ++c) {
      for (int b = 0; b < 2; ++b) {
        for (int a = 0; a < 2; ++a) {
          const double wi = w[m++];
          EXPECT_GE(wi, 0.0);
          sum += wi;
          const std::array<int, 3> cell = {s.lo[0] + a, s.lo[1] + b, s.lo[2] + c};
          for (int ax = 0; ax < 3; ++ax) {
            centroid[ax] += wi * (origin[ax] + (cell[ax] + 0.5) * dx[ax]);
          }
        }
      }
    }
    EXPECT_NEAR(sum, 1.0, 1e-14);
    for (int ax = 0; ax < 3; ++ax) {
      EXPECT_NEAR(centroid[ax], x[ax], 1e-15);
    }
  }
}

TEST(DpvmWeights, SumToOneForCubeAndSphereSmallerAndLargerThanCells) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1e-3);
  const std::array<double, 3> origin = {0.0, 0.0, 0.0};
  const std::array<double, 3> dx = {5e-5, 5e-5, 5e-5};
  for (const double r : {2e-5, 5e-5, 1.3e-4}) {
    std::vector<double> w(static_cast<std::size_t>(std::pow(dpvm_max_cells(r, 5e-5), 3)));
    for (const DpvmShape shape : {DpvmShape::cube, DpvmShape::sphere}) {
      for (int n = 0; n < 20; ++n) {
        const std::array<double, 3> x = {u(rng), u(rng), u(rng)};
        const CellStencil s = dpvm_weights(x, r, origin, dx, shape, w);
        double sum = 0.0;
        for (int m = 0; m < s.count(); ++m) {
          EXPECT_GE(w[static_cast<std::size_t>(m)], 0.0);
          sum += w[static_cast<std::size_t>(m)];
        }
        EXPECT_NEAR(sum, 1.0, 1e-13);
      }
    }
  }
}

// A kernel centred within an ulp below a cell face, r = dx: x/dx + r/dx rounds up onto the
// integer while x/dx - r/dx does not, so the stencil spans ceil(2 r/dx) + 2 cells. The buffer
// dpvm_max_cells sizes must hold it (scenes/cylinder_bed.toml wrote past it before).
TEST(DpvmWeights, StencilFitsTheBufferWhenRoundingWidensIt) {
  const std::array<double, 3> origin = {0.0, 0.0, 0.0};
  const std::array<double, 3> dx = {1e-4, 2e-4, 1e-4};
  const double r = 1e-4;
  const std::array<double, 3> x = {std::nextafter(8e-4, 0.0), 5.6e-4, 9.07e-4};
  std::size_t capacity = 1;
  for (int a = 0; a < 3; ++a) {
    capacity *= static_cast<std::size_t>(dpvm_max_cells(r, dx[static_cast<std::size_t>(a)]));
  }
  std::vector<double> w(capacity);
  const CellStencil s = dpvm_weights(x, r, origin, dx, DpvmShape::cube, w);
  EXPECT_EQ(s.size[0], 4); // the case: one more cell than ceil(2 r/dx) + 1
  ASSERT_LE(static_cast<std::size_t>(s.count()), capacity);
  double sum = 0.0;
  for (int m = 0; m < s.count(); ++m) {
    sum += w[static_cast<std::size_t>(m)];
  }
  EXPECT_NEAR(sum, 1.0, 1e-14);
}

TEST(DpvmWeights, SphereFractionsApproachExactOctants) {
  // A sphere centred on a cell corner puts 1/8 of its volume in each of the 8 cells.
  const std::array<double, 3> origin = {0.0, 0.0, 0.0};
  const std::array<double, 3> dx = {1e-4, 1e-4, 1e-4};
  std::vector<double> w(27);
  const CellStencil s =
      dpvm_weights({1e-4, 1e-4, 1e-4}, 4e-5, origin, dx, DpvmShape::sphere, w, 32);
  double inside = 0.0;
  for (int m = 0; m < s.count(); ++m) {
    const double wm = w[static_cast<std::size_t>(m)];
    if (wm > 0.0) {
      EXPECT_NEAR(wm, 0.125, 1e-12);
      inside += wm;
    }
  }
  EXPECT_NEAR(inside, 1.0, 1e-12);
}

class DepositionConservation : public ::testing::TestWithParam<DepositionKernel> {};

TEST_P(DepositionConservation, SolidVolumeEqualsParticleVolume) {
  for (const BoundaryKind kind : {BoundaryKind::periodic, BoundaryKind::wall}) {
    const MacGrid grid(box_spec({6, 5, 4}, {6e-4, 5e-4, 4e-4}, kind));
    const Cloud cloud = random_cloud(grid, 200, 5e-5, 3);
    DepositionSettings settings;
    settings.kernel = GetParam();
    settings.width = 3.0; // r* = 3 r_p = 1.5 cells: wraps/folds at every boundary
    Deposition deposition(grid, settings, 5e-5);
    GridField eps_s = grid.make_field();
    deposition.deposit_solid_fraction(cloud.view(), eps_s);
    EXPECT_NEAR(interior_sum(grid, eps_s) * grid.cell_volume(), cloud.volume(),
                1e-12 * cloud.volume());
    // Smoothing keeps the total.
    (void)smooth_implicit(grid, 1e-8, eps_s);
    EXPECT_NEAR(interior_sum(grid, eps_s) * grid.cell_volume(), cloud.volume(),
                1e-10 * cloud.volume());
  }
}

INSTANTIATE_TEST_SUITE_P(Kernels, DepositionConservation,
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

// In a round column (docs/theory.md §13) the particles' volume lands on gas cells only, all of
// it: particles packed against the wall (their kernels reach into the solid cells and beyond the
// box) still deposit exactly their volume, and no solid cell receives any.
TEST_P(DepositionConservation, ColumnKeepsTheVolumeOnGasCells) {
  MacGridSpec spec = box_spec({10, 4, 10}, {1e-3, 4e-4, 1e-3}, BoundaryKind::wall);
  spec.cylinder_axis = 1;
  spec.cylinder_radius = 5e-4;
  const MacGrid grid(spec);
  const double rp = 5e-5;
  Cloud cloud;
  for (int n = 0; n < 60; ++n) { // round the wall, touching it
    const double angle = 0.1047 * n;
    const double rho = spec.cylinder_radius - rp;
    cloud.x.push_back(5e-4 + rho * std::cos(angle));
    cloud.y.push_back(5e-5 + 5e-6 * n);
    cloud.z.push_back(5e-4 + rho * std::sin(angle));
    cloud.r.push_back(rp);
  }
  DepositionSettings settings;
  settings.kernel = GetParam();
  settings.width = 3.0;
  Deposition deposition(grid, settings, rp);
  GridField eps_s = grid.make_field();
  deposition.deposit_solid_fraction(cloud.view(), eps_s);
  EXPECT_NEAR(interior_sum(grid, eps_s) * grid.cell_volume(), cloud.volume(),
              1e-12 * cloud.volume());
  double in_solid = 0.0;
  for (int k = 0; k < 10; ++k) {
    for (int j = 0; j < 4; ++j) {
      for (int i = 0; i < 10; ++i) {
        if (grid.solid_cell(i, j, k)) {
          in_solid += std::abs(eps_s(i, j, k));
        }
      }
    }
  }
  EXPECT_EQ(in_solid, 0.0);
}

// Random inputs in [-1, 1) for the passes of a step: four values per particle (a deposit of four
// fields) and six cell fields (an interpolation of six), drawn in that order from `seed`.
std::pair<std::array<std::vector<double>, 4>, std::array<GridField, 6>>
random_passes_inputs(const MacGrid& grid, std::size_t particles, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  std::pair<std::array<std::vector<double>, 4>, std::array<GridField, 6>> in;
  for (auto& v : in.first) {
    for (std::size_t q = 0; q < particles; ++q) {
      v.push_back(uni(rng));
    }
  }
  for (GridField& f : in.second) {
    f = grid.make_field();
    for (double& v : f.values()) {
      v = uni(rng);
    }
  }
  return in;
}

// A plan's passes (Deposition::plan: the kernels stored as axis factors once, for several passes)
// give bit for bit what the passes computing every kernel give: the solid fraction, a deposit of
// four fields and an interpolation of six, on 1 and 2 threads, on a periodic and a walled grid
// (kernels wrapping and folding), in a round column (no plan: kernels computed), with a particle
// larger than the declared maximum and particles on cell faces (weights of 0 skipped).
TEST_P(DepositionConservation, APlanGivesThePassesBitwise) {
  std::vector<MacGridSpec> specs = {box_spec({6, 5, 4}, {6e-4, 5e-4, 4e-4}, BoundaryKind::periodic),
                                    box_spec({6, 5, 4}, {6e-4, 5e-4, 4e-4}, BoundaryKind::wall),
                                    box_spec({10, 4, 10}, {1e-3, 4e-4, 1e-3}, BoundaryKind::wall)};
  specs[2].cylinder_axis = 1;
  specs[2].cylinder_radius = 5e-4;
  const char* names[3] = {"periodic", "walls", "column"};
  for (std::size_t g = 0; g < specs.size(); ++g) {
    const MacGrid grid(specs[g]);
    SCOPED_TRACE(names[g]);
    Cloud cloud = random_cloud(grid, 300, 4e-5, 17);
    cloud.r[7] = 1.6e-4;                           // larger than the declared 5e-5
    cloud.x[11] = grid.origin(0) + 2 * 1e-4;       // on a cell face
    cloud.y[12] = grid.origin(1) + 2.5 * 1e-4;     // on a cell centre (trilinear: a 0 weight)
    cloud.z[13] = grid.origin(2) + grid.length(2); // on the domain's high face
    DepositionSettings settings;
    settings.kernel = GetParam();
    settings.width = 3.0;
    auto [value, field] = random_passes_inputs(grid, cloud.r.size(), 29);
    for (const int threads : {1, 2}) {
      SCOPED_TRACE(threads);
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                                static_cast<std::size_t>(threads));
      Deposition deposition(grid, settings, 5e-5);
      TransferPlan plan;
      deposition.plan(cloud.view(), plan);
      EXPECT_EQ(plan.separable, GetParam() != DepositionKernel::dpvm_sphere && !grid.has_solid());
      // The trilinear plan takes the walk with fixed loop counts (the passes below check its bits).
      EXPECT_EQ(plan.fixed_cells,
                plan.separable && GetParam() == DepositionKernel::trilinear ? 2 : 0);
      // Each pass twice: from the positions (a), from the plan (b).
      std::array<GridField, 2> eps_s = {grid.make_field(), grid.make_field()};
      deposition.deposit_solid_fraction(cloud.view(), eps_s[0]);
      deposition.deposit_solid_fraction(plan, eps_s[1]);
      EXPECT_TRUE(test::same_bits(eps_s[0], eps_s[1]));
      std::array<std::array<GridField, 4>, 2> cells;
      std::array<std::array<GridField*, 4>, 2> out{};
      for (int m = 0; m < 2; ++m) {
        for (int f = 0; f < 4; ++f) {
          cells[m][f] = grid.make_field();
          out[m][f] = &cells[m][f];
        }
      }
      const std::span<const double> values[4] = {value[0], value[1], value[2], value[3]};
      deposition.deposit(cloud.view(), values, out[0]);
      deposition.deposit(plan, values, out[1]);
      for (int f = 0; f < 4; ++f) {
        EXPECT_TRUE(test::same_bits(cells[0][f], cells[1][f])) << "field " << f;
      }
      std::array<std::array<std::vector<double>, 6>, 2> gathered;
      std::array<std::array<std::span<double>, 6>, 2> outs;
      const GridField* in[6];
      for (int f = 0; f < 6; ++f) {
        in[f] = &field[f];
        for (int m = 0; m < 2; ++m) {
          gathered[m][f].assign(cloud.r.size(), 0.0);
          outs[m][f] = gathered[m][f];
        }
      }
      deposition.interpolate(cloud.view(), in, outs[0]);
      deposition.interpolate(plan, in, outs[1]);
      EXPECT_EQ(gathered[0], gathered[1]);
      // A pass with more values than the plan has particles is refused.
      std::vector<double> longer(cloud.r.size() + 1, 1.0);
      const std::span<const double> wrong[1] = {longer};
      GridField* one[1] = {out[1][0]};
      EXPECT_THROW(deposition.deposit(plan, wrong, one), std::invalid_argument);
    }
  }
  // A kernel wider than a plan keeps (16 cells along an axis) is computed by every pass.
  const MacGrid grid(specs[0]);
  Cloud wide = random_cloud(grid, 5, 4e-5, 31);
  wide.r[2] = 3e-4; // r* = 9e-4 m: 19-20 cells along each axis
  DepositionSettings settings;
  settings.kernel = GetParam();
  settings.width = 3.0;
  Deposition deposition(grid, settings, 5e-5);
  TransferPlan plan;
  deposition.plan(wide.view(), plan);
  EXPECT_EQ(plan.separable, GetParam() == DepositionKernel::trilinear);
  std::array<GridField, 2> eps_s = {grid.make_field(), grid.make_field()};
  deposition.deposit_solid_fraction(wide.view(), eps_s[0]);
  deposition.deposit_solid_fraction(plan, eps_s[1]);
  EXPECT_TRUE(test::same_bits(eps_s[0], eps_s[1]));
}

// The wide kernels' row loops (dpvm: the gathers' lanes, the deposits' four-wide rows) give the
// baseline's bits at every instruction set this CPU runs, and the kernels computed cell by cell
// give the planned ones' bits: cells half a particle wide as in scenes/fluidized_bed.toml (rows
// of 5 cells, and of 4 for the smaller particles), on walls (rows folded: the scalar walk) and
// periodic axes (rows wrapped), on 1 and 2 threads.
TEST(Deposition, EveryInstructionSetGivesTheWideKernelsTheBaselinesBits) {
  const SimdLevel cpu = cpu_simd_level();
  for (const BoundaryKind kind : {BoundaryKind::wall, BoundaryKind::periodic}) {
    SCOPED_TRACE(kind == BoundaryKind::wall ? "walls" : "periodic");
    const MacGrid grid(box_spec({12, 10, 8}, {6e-4, 5e-4, 4e-4}, kind));
    Cloud cloud = random_cloud(grid, 400, 5e-5, 41);
    for (std::size_t q = 0; q < cloud.r.size(); q += 2) {
      cloud.r[q] = 3.75e-5; // r* = 1.5 cells: rows of 4
    }
    DepositionSettings settings;
    settings.kernel = DepositionKernel::dpvm_cube;
    settings.width = 2.0;
    auto [value, field] = random_passes_inputs(grid, cloud.r.size(), 43);
    const GridField* in[6];
    for (std::size_t f = 0; f < field.size(); ++f) {
      in[f] = &field[f];
    }
    struct Passes {
      GridField eps_s;
      std::array<GridField, 4> drag;
      std::array<std::vector<double>, 6> gathered;
    };
    // The three passes at `level`, from a plan or from the positions.
    const auto run = [&](SimdLevel level, bool planned) {
      Deposition deposition(grid, settings, 5e-5);
      deposition.use_simd_level(level);
      TransferPlan plan;
      deposition.plan(cloud.view(), plan);
      EXPECT_TRUE(plan.separable);
      EXPECT_EQ(plan.fixed_cells, 0);
      Passes out;
      out.eps_s = grid.make_field();
      std::array<GridField*, 4> cells{};
      for (std::size_t f = 0; f < 4; ++f) {
        out.drag[f] = grid.make_field();
        cells[f] = &out.drag[f];
      }
      const std::span<const double> values[4] = {value[0], value[1], value[2], value[3]};
      std::array<std::span<double>, 6> outs;
      for (std::size_t f = 0; f < 6; ++f) {
        out.gathered[f].assign(cloud.r.size(), 0.0);
        outs[f] = out.gathered[f];
      }
      if (planned) {
        deposition.deposit_solid_fraction(plan, out.eps_s);
        deposition.deposit(plan, values, cells);
        deposition.interpolate(plan, in, outs);
      } else {
        deposition.deposit_solid_fraction(cloud.view(), out.eps_s);
        deposition.deposit(cloud.view(), values, cells);
        deposition.interpolate(cloud.view(), in, outs);
      }
      return out;
    };
    for (const int threads : {1, 2}) {
      SCOPED_TRACE(threads);
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                                static_cast<std::size_t>(threads));
      const Passes base = run(SimdLevel::x86_64, false);
      for (int l = 0; l <= static_cast<int>(cpu); ++l) {
        const auto level = static_cast<SimdLevel>(l);
        SCOPED_TRACE(std::string(simd_level_name(level)));
        const Passes copy = run(level, true);
        EXPECT_TRUE(test::same_bits(base.eps_s, copy.eps_s));
        for (std::size_t f = 0; f < 4; ++f) {
          EXPECT_TRUE(test::same_bits(base.drag[f], copy.drag[f])) << "drag field " << f;
        }
        for (std::size_t f = 0; f < 6; ++f) {
          EXPECT_EQ(base.gathered[f], copy.gathered[f]) << "gathered field " << f;
        }
      }
    }
  }
}

TEST(Deposition, ParticleLargerThanDeclaredMaxRadiusStillConserves) {
  const MacGrid grid(box_spec({8, 8, 8}, {4e-4, 4e-4, 4e-4}, BoundaryKind::periodic));
  const Cloud cloud = random_cloud(grid, 20, 1.2e-4, 13);
  DepositionSettings settings;
  settings.kernel = DepositionKernel::dpvm_sphere;
  Deposition deposition(grid, settings, 1e-5); // declared far too small: the buffer grows
  GridField eps_s = grid.make_field();
  deposition.deposit_solid_fraction(cloud.view(), eps_s);
  EXPECT_NEAR(interior_sum(grid, eps_s) * grid.cell_volume(), cloud.volume(),
              1e-12 * cloud.volume());
}

// FCC lattice of 100 um spheres at phi = 0.6 (lattice constant (4 V_p/0.6)^(1/3) = 151.7 um,
// neighbours 107 um apart: no overlap), jittered, in a periodic box of 4^3 unit cells with
// 12^3 cells of 50.6 um: cells smaller than a particle (the paper's fluidized bed).
Cloud dense_fcc_bed(const MacGrid& grid, double d) {
  const double a = grid.length(0) / 4.0;
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> jitter(-3e-6, 3e-6);
  const std::array<std::array<double, 3>, 4> basis = {
      {{0.0, 0.0, 0.0}, {0.5, 0.5, 0.0}, {0.5, 0.0, 0.5}, {0.0, 0.5, 0.5}}};
  Cloud c;
  for (int k = 0; k < 4; ++k) {
    for (int j = 0; j < 4; ++j) {
      for (int i = 0; i < 4; ++i) {
        for (const auto& b : basis) {
          // Shift by an irrational-ish offset so particles do not sit on cell faces.
          c.x.push_back((i + b[0] + 0.137) * a + jitter(rng));
          c.y.push_back((j + b[1] + 0.291) * a + jitter(rng));
          c.z.push_back((k + b[2] + 0.413) * a + jitter(rng));
          c.r.push_back(0.5 * d);
        }
      }
    }
  }
  return c;
}

std::pair<double, double> eps_gas_range(const MacGrid& grid, const GridField& eps_s) {
  double lo = 1e300;
  double hi = -1e300;
  for (int k = 0; k < grid.cells(2); ++k) {
    for (int j = 0; j < grid.cells(1); ++j) {
      for (int i = 0; i < grid.cells(0); ++i) {
        lo = std::min(lo, 1.0 - eps_s(i, j, k));
        hi = std::max(hi, 1.0 - eps_s(i, j, k));
      }
    }
  }
  return {lo, hi};
}

TEST(DenseBedDeposition, WideKernelKeepsGasFractionInUnitIntervalWhereTrilinearFails) {
  const double d = 100e-6;
  const double vp = std::numbers::pi * d * d * d / 6.0;
  const double a = std::cbrt(4.0 * vp / 0.6);
  const MacGrid grid(box_spec({12, 12, 12}, {4 * a, 4 * a, 4 * a}, BoundaryKind::periodic));
  ASSERT_LT(grid.spacing(0), d); // cells smaller than a particle
  const Cloud bed = dense_fcc_bed(grid, d);
  EXPECT_NEAR(bed.volume() / std::pow(4 * a, 3), 0.6, 1e-12);

  DepositionSettings trilinear;
  Deposition narrow(grid, trilinear, 0.5 * d);
  GridField eps_s = grid.make_field();
  narrow.deposit_solid_fraction(bed.view(), eps_s);
  const auto [tri_lo, tri_hi] = eps_gas_range(grid, eps_s);
  // One particle (5.2e-13 m^3) into 2x2x2 cells of 1.3e-13 m^3: eps_g goes negative.
  EXPECT_LT(tri_lo, 0.0) << "trilinear min eps_g " << tri_lo << " max " << tri_hi;

  // Trilinear followed by the implicit diffusion over sqrt(D) = d_p also stays in (0, 1].
  DepositionSettings smoothed;
  smoothed.diffusion = d * d;
  Deposition diffused(grid, smoothed, 0.5 * d);
  eps_s.fill(0.0);
  diffused.deposit_solid_fraction(bed.view(), eps_s);
  diffused.smooth(eps_s);
  const auto [diff_lo, diff_hi] = eps_gas_range(grid, eps_s);
  EXPECT_GT(diff_lo, 0.0);
  EXPECT_LE(diff_hi, 1.0);
  RecordProperty("eps_g_range_trilinear", std::to_string(tri_lo) + " " + std::to_string(tri_hi));
  RecordProperty("eps_g_range_trilinear_diffused",
                 std::to_string(diff_lo) + " " + std::to_string(diff_hi));

  for (const DepositionKernel kernel :
       {DepositionKernel::dpvm_cube, DepositionKernel::dpvm_sphere}) {
    DepositionSettings wide;
    wide.kernel = kernel;
    wide.width = 2.0; // kernel diameter 2 d_p = 4 cells
    Deposition deposition(grid, wide, 0.5 * d);
    eps_s.fill(0.0);
    deposition.deposit_solid_fraction(bed.view(), eps_s);
    const auto [lo, hi] = eps_gas_range(grid, eps_s);
    EXPECT_GT(lo, 0.0) << "kernel " << static_cast<int>(kernel);
    EXPECT_LE(hi, 1.0) << "kernel " << static_cast<int>(kernel);
    RecordProperty("eps_g_range_dpvm" + std::to_string(static_cast<int>(kernel)),
                   std::to_string(lo) + " " + std::to_string(hi));
  }
}

TEST(Interpolation, ExactForLinearFields) {
  const MacGrid grid(box_spec({8, 6, 5}, {8e-4, 6e-4, 5e-4}, BoundaryKind::wall));
  GridField f = grid.make_field();
  const auto linear = [](double x, double y, double z) {
    return 1.0 + 2e3 * x - 3e3 * y + 5e2 * z;
  };
  for (int k = 0; k < 5; ++k) {
    for (int j = 0; j < 6; ++j) {
      for (int i = 0; i < 8; ++i) {
        f(i, j, k) = linear(grid.cell_centre(0, i), grid.cell_centre(1, j), grid.cell_centre(2, k));
      }
    }
  }
  // Particles at least r* + dx/2 away from the walls (folding is zero-gradient, not linear).
  std::mt19937_64 rng(9);
  Cloud c;
  for (int n = 0; n < 50; ++n) {
    c.x.push_back(std::uniform_real_distribution<double>(2.5e-4, 5.5e-4)(rng));
    c.y.push_back(std::uniform_real_distribution<double>(2.5e-4, 3.5e-4)(rng));
    c.z.push_back(std::uniform_real_distribution<double>(2.5e-4, 2.5e-4 + 1e-9)(rng));
    c.r.push_back(5e-5);
  }
  // Trilinear is exact for linear fields; the dpvm cube is exact when its width 2 r* is a whole
  // number of cells (here 2 r* = 2 dx), since the cell-centre staircase then averages out.
  DepositionSettings tri;
  DepositionSettings cube;
  cube.kernel = DepositionKernel::dpvm_cube;
  cube.width = 2.0;
  for (const DepositionSettings& s : {tri, cube}) {
    Deposition deposition(grid, s, 5e-5);
    std::vector<double> out(c.x.size());
    deposition.interpolate(c.view(), f, out);
    for (std::size_t n = 0; n < out.size(); ++n) {
      EXPECT_NEAR(out[n], linear(c.x[n], c.y[n], c.z[n]), 1e-12);
    }
  }
}

TEST(DiffusionSmoothing, ConservesSumAndDampsPeak) {
  const MacGrid grid(box_spec({8, 8, 8}, {4e-4, 4e-4, 4e-4}, BoundaryKind::wall));
  GridField q = grid.make_field();
  q(3, 4, 5) = 1.0;
  const SmoothingReport report = smooth_implicit(grid, 2.5e-9, q); // sqrt(D) = one cell
  EXPECT_LE(report.relative_residual, 1e-12);
  EXPECT_NEAR(interior_sum(grid, q), 1.0, 1e-11);
  EXPECT_LT(q(3, 4, 5), 0.5);
  double lo = 1.0;
  for (int k = 0; k < 8; ++k) {
    for (int j = 0; j < 8; ++j) {
      for (int i = 0; i < 8; ++i) {
        lo = std::min(lo, q(i, j, k));
      }
    }
  }
  EXPECT_GE(lo, -1e-12); // (I - D lap)^-1 is a positive operator (M-matrix inverse)
}

} // namespace
} // namespace cfddem::fluid
