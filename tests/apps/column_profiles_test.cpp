// Column profiles (apps/column_profiles.hpp): the exact slab volume of a sphere, the solids
// fraction of a lattice bed at rest in aligned and unaligned slabs, volume conservation on a
// periodic axis, slab means and granular temperature, and the gas columns of a still gas with
// an imposed pressure drop.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <vector>

#include "apps/column_profiles.hpp"
#include "fluid/gas_solver.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::apps {
namespace {

using std::numbers::pi;

TEST(ColumnProfiles, SphereSlabFractionIsTheCapVolume) {
  // A cap of height h = r/2 has volume pi h^2 (3r - h)/3 = 5 pi r^3 / 24: 5/32 of the sphere.
  const double r = 2e-3, c = 0.1;
  EXPECT_NEAR(sphere_slab_fraction(c, r, c + 0.5 * r, c + 10 * r), 5.0 / 32.0, 1e-15);
  EXPECT_NEAR(sphere_slab_fraction(c, r, c - 3 * r, c), 0.5, 1e-15);
  EXPECT_DOUBLE_EQ(sphere_slab_fraction(c, r, c + r, c + 2 * r), 0.0);
  // Slabs that cover the sphere add up to one.
  double sum = 0.0;
  for (int b = -7; b < 7; ++b)
    sum += sphere_slab_fraction(c, r, c + 0.3 * r * b + 0.01 * r, c + 0.3 * r * (b + 1) + 0.01 * r);
  EXPECT_NEAR(sum, 1.0, 1e-14);
}

struct Lattice {
  std::vector<double> x, y, z, vx, vy, vz, radius, mass;
  ProfileParticles view() const { return {x, y, z, vx, vy, vz, radius, mass}; }
};

// Simple cubic lattice of touching spheres of diameter d filling [0, n d]^3 (solids pi/6).
Lattice cubic_lattice(int n, double d) {
  Lattice l;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        l.x.push_back((i + 0.5) * d), l.y.push_back((j + 0.5) * d), l.z.push_back((k + 0.5) * d);
        l.vx.push_back(0.0), l.vy.push_back(0.0), l.vz.push_back(0.0);
        l.radius.push_back(0.5 * d), l.mass.push_back(1000.0 * pi / 6.0 * d * d * d);
      }
  return l;
}

TEST(ColumnProfiles, LatticeBedAtRestGivesItsSolidsFractionInAlignedSlabs) {
  const int n = 6;
  const double d = 1e-3, L = n * d;
  const Lattice bed = cubic_lattice(n, d);
  ProfileSpec spec{1, 3, 0.0, L, L * L, false}; // slabs of two layers each
  const auto rows = ColumnProfiles(spec, false).rows(0.5, bed.view(), nullptr, nullptr);
  ASSERT_EQ(rows.size(), 3u);
  for (const auto& row : rows) {
    EXPECT_EQ(row[0], 0.5);
    EXPECT_NEAR(row[3], pi / 6.0, 1e-13);
    EXPECT_EQ(row[4], 0.0);
    EXPECT_EQ(row[7], 0.0); // at rest
  }
}

// In slabs that cut through layers the solids fraction is the integral of the lattice's area
// fraction pi (r^2 - (y - c)^2) / d^2 over the slab: checked against a midpoint quadrature
// (error ~ 1e-10 with 2e5 points per slab), independent of the cap formula.
TEST(ColumnProfiles, LatticeBedInUnalignedSlabsMatchesTheAreaIntegral) {
  const int n = 5;
  const double d = 1e-3, r = 0.5 * d, L = n * d;
  const Lattice bed = cubic_lattice(n, d);
  const int bins = 7;
  ProfileSpec spec{1, bins, 0.0, L, L * L, false};
  const auto rows = ColumnProfiles(spec, false).rows(0.0, bed.view(), nullptr, nullptr);
  const double h = L / bins;
  double total = 0.0;
  for (int b = 0; b < bins; ++b) {
    const int q = 200000;
    double integral = 0.0;
    for (int s = 0; s < q; ++s) {
      const double y = (b + (s + 0.5) / q) * h;
      const double off = y - (std::floor(y / d) + 0.5) * d; // offset from the layer's centre
      integral += pi * (r * r - off * off) / (d * d);
    }
    integral /= q;
    EXPECT_NEAR(rows[static_cast<std::size_t>(b)][3], integral, 1e-9) << "slab " << b;
    total += rows[static_cast<std::size_t>(b)][3] * h;
  }
  EXPECT_NEAR(total / L, pi / 6.0, 1e-13); // every sphere's volume lands in some slab
}

TEST(ColumnProfiles, PeriodicAxisKeepsTheVolumeOfASphereAcrossTheEnd) {
  Lattice one;
  const double d = 1e-3, L = 4e-3;
  // A sphere whose centre sits 0.2 d below the top of a periodic column: 0.3 d of it re-enters
  // at the bottom. Also one whose centre has run past the top (not wrapped yet).
  for (double y : {L - 0.2 * d, L + 0.1 * d}) {
    one.x = {1e-3}, one.y = {y}, one.z = {1e-3}, one.vx = {0}, one.vy = {0}, one.vz = {0};
    one.radius = {0.5 * d}, one.mass = {1.0};
    ProfileSpec spec{1, 8, 0.0, L, 1e-6, true};
    const auto rows = ColumnProfiles(spec, false).rows(0.0, one.view(), nullptr, nullptr);
    double v = 0.0;
    for (const auto& row : rows)
      v += row[3] * spec.area * (L / 8);
    EXPECT_NEAR(v, pi / 6.0 * d * d * d, 1e-13 * d * d * d);
    const double wrapped = sphere_slab_fraction(y - L, 0.5 * d, 0.0, L / 8); // bottom slab
    EXPECT_NEAR(rows[0][3] * spec.area * (L / 8), wrapped * pi / 6.0 * d * d * d,
                1e-13 * d * d * d);
    EXPECT_GT(rows[0][3], 0.0);
  }
}

TEST(ColumnProfiles, SlabMeansAndGranularTemperature) {
  Lattice p;
  // Two equal particles well inside slab 1 moving at (1 +- u, 2, 0): mean (1, 2, 0), T = u^2/3.
  // Slab 0 and 2 are empty: NaN means, zero solids.
  const double u = 0.3;
  p.x = {0.5, 0.5}, p.y = {1.5, 1.5}, p.z = {0.5, 0.5};
  p.vx = {1 + u, 1 - u}, p.vy = {2, 2}, p.vz = {0, 0}, p.radius = {0.1, 0.1}, p.mass = {2, 2};
  ProfileSpec spec{1, 3, 0.0, 3.0, 1.0, false};
  const auto rows = ColumnProfiles(spec, false).rows(0.0, p.view(), nullptr, nullptr);
  EXPECT_NEAR(rows[1][4], 1.0, 1e-15);
  EXPECT_NEAR(rows[1][5], 2.0, 1e-15);
  EXPECT_NEAR(rows[1][6], 0.0, 1e-15);
  EXPECT_NEAR(rows[1][7], u * u / 3.0, 1e-14);
  EXPECT_NEAR(rows[1][3], 2 * 4.0 / 3.0 * pi * 1e-3, 1e-15);
  for (int b : {0, 2}) {
    EXPECT_EQ(rows[static_cast<std::size_t>(b)][3], 0.0);
    EXPECT_TRUE(std::isnan(rows[static_cast<std::size_t>(b)][4]));
    EXPECT_TRUE(std::isnan(rows[static_cast<std::size_t>(b)][7]));
  }
}

// A still gas in a periodic column with an imposed drop delp along y: the full pressure is
// p' - delp/L (y - y0), so each slab's mean is -delp/L at its centre (the slab holds whole cells
// symmetric about it); eps_g is the volume mean of what the coupling set, the velocity zero and
// the slip minus the particles' mean velocity.
TEST(ColumnProfiles, GasColumnsOfAStillGasWithAnImposedDrop) {
  fluid::MacGridSpec spec;
  spec.cells = {2, 8, 2};
  spec.extent = {1e-3, 4e-3, 1e-3};
  for (auto& bc : spec.bc)
    bc.kind = fluid::BoundaryKind::periodic;
  const double delp = 40.0;
  spec.pressure_drop[1] = delp;
  const fluid::MacGrid grid(spec);
  fluid::GasSolverSettings settings;
  settings.gas = {1.2, 1.8e-5, {0.0, 0.0, 0.0}};
  fluid::GasSolver gas(grid, settings);
  for (int k = 0; k < 2; ++k)
    for (int j = 0; j < 8; ++j)
      for (int i = 0; i < 2; ++i)
        gas.volume_fraction()(i, j, k) = j < 4 ? 0.6 : 0.9;
  Lattice p;
  p.x = {5e-4}, p.y = {5e-4}, p.z = {5e-4}, p.vx = {0}, p.vy = {-0.25}, p.vz = {0};
  p.radius = {5e-5}, p.mass = {1e-9};
  ProfileSpec ps{1, 4, 0.0, 4e-3, 1e-6, true};
  const auto rows = ColumnProfiles(ps, true).rows(0.0, p.view(), &gas, nullptr);
  ASSERT_EQ(rows[0].size(), ColumnProfiles(ps, true).columns().size());
  const double g = gas.background_pressure_gradient()[1];
  EXPECT_NEAR(g, -delp / 4e-3, 1e-9);
  for (int b = 0; b < 4; ++b) {
    const auto& row = rows[static_cast<std::size_t>(b)];
    EXPECT_NEAR(row[8], b < 2 ? 0.6 : 0.9, 1e-15);
    EXPECT_EQ(row[9], 0.0);
    EXPECT_EQ(row[10], 0.0);
    EXPECT_NEAR(row[12], g * (b + 0.5) * 1e-3, 1e-9);
  }
  EXPECT_NEAR(rows[0][14], 0.25, 1e-15); // slip_y = 0 - (-0.25) in the slab holding the particle
  EXPECT_TRUE(std::isnan(rows[2][14]));
}

} // namespace
} // namespace cfddem::apps
