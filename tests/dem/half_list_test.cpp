// The explicit scheme computes each pair's contact once over a half list and adds it to both
// particles (dem/verlet_passes.hpp). Its claim: every particle's force and torque are bit for bit
// what a full list gives, each particle summing its own row (partners inside the box by index,
// then partners across a periodic face by index). The oracle here is that full-row sum written
// out over all pairs, on an overlapping polydisperse packing with random velocities and spins.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <unordered_map>
#include <vector>

#include "core/phase_timer.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/linear_spring_dashpot.hpp"
#include "dem_test_support.hpp"

namespace cfddem {
namespace {

constexpr double kBox = 1.2e-3;

// The periodic box of the packings below: the shared pair scene (particles added by hand) in a
// box of side kBox.
const std::string kBoxHi = "domain.hi=[1.2e-3,1.2e-3,1.2e-3]";

// Particles of radius 40-60 um dropped into a periodic box up to phi ~ 0.33, most of them pressed
// against an earlier one (a random direction, up to 2% of the smaller radius into it), each kept
// if it overlaps no earlier one by more than 4% of the smaller radius: many contacts at t = 0,
// some across the periodic faces.
ParticleStore overlapping_packing(std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const dem::DomainGeometry g([] {
    DomainSpec d;
    d.lo = {0, 0, 0}, d.hi = {kBox, kBox, kBox}, d.periodic = {true, true, true};
    return d;
  }());
  ParticleStore p;
  double volume = 0.0;
  for (int attempt = 0; attempt < 200000 && volume < 0.33 * kBox * kBox * kBox; ++attempt) {
    const double r = 40e-6 + 20e-6 * u(rng);
    double q[3] = {kBox * u(rng), kBox * u(rng), kBox * u(rng)};
    if (p.size() > 0 && u(rng) < 0.8) {
      const auto j = static_cast<std::size_t>(u(rng) * static_cast<double>(p.size()));
      const double e[3] = {u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5};
      const double len = std::sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
      const double at = r + p.radius[j] - 0.02 * u(rng) * std::min(r, p.radius[j]);
      const double c[3] = {p.x[j], p.y[j], p.z[j]};
      for (int a = 0; a < 3; ++a)
        q[a] = g.wrap(c[a] + at * e[a] / len, a);
    }
    bool ok = true;
    for (std::size_t j = 0; j < p.size() && ok; ++j) {
      const double d[3] = {g.image(p.x[j] - q[0], 0), g.image(p.y[j] - q[1], 1),
                           g.image(p.z[j] - q[2], 2)};
      const double dist = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      ok = r + p.radius[j] - dist < 0.04 * std::min(r, p.radius[j]);
    }
    if (!ok)
      continue;
    p.add(q[0], q[1], q[2], 0.3 * (u(rng) - 0.5), 0.3 * (u(rng) - 0.5), 0.3 * (u(rng) - 0.5), r,
          1000.0, static_cast<std::int64_t>(p.size()));
    volume += 4.0 / 3.0 * M_PI * r * r * r;
  }
  return p;
}

struct Oracle {
  std::vector<double> f[3], t[3];
  int contacts = 0;
};

// Full-row sums at t = 0 (dt = 0: a new contact's tangential spring is zero, F_t is the dashpot
// capped by Coulomb), in the store's order, with velocities and spins `v`, `w` by store index.
Oracle full_rows(const ParticleStore& p, const std::vector<double> (&v)[3],
                 const std::vector<double> (&w)[3], const dem::StepModel& m,
                 const dem::DomainGeometry& g) {
  const std::size_t n = p.size();
  Oracle o;
  for (int a = 0; a < 3; ++a)
    o.f[a].assign(n, 0.0), o.t[a].assign(n, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    double ax = 0, ay = 0, az = 0, tx = 0, ty = 0, tz = 0;
    for (int crossing = 0; crossing < 2; ++crossing) {
      for (std::size_t j = 0; j < n; ++j) {
        if (j == i)
          continue;
        const double raw[3] = {p.x[j] - p.x[i], p.y[j] - p.y[i], p.z[j] - p.z[i]};
        bool crosses = false;
        for (int a = 0; a < 3; ++a)
          crosses = crosses || std::abs(raw[a]) > g.half[a];
        if (crosses != (crossing == 1))
          continue;
        const double dx = g.image(raw[0], 0), dy = g.image(raw[1], 1), dz = g.image(raw[2], 2);
        const double r2 = dx * dx + dy * dy + dz * dz;
        const double ri = p.radius[i], rj = p.radius[j], rs = ri + rj;
        if (r2 >= rs * rs)
          continue;
        ++o.contacts;
        const double dist = std::sqrt(r2);
        const double inv = 1.0 / dist;
        const double nx = dx * inv, ny = dy * inv, nz = dz * inv;
        const double dvx = v[0][i] - v[0][j], dvy = v[1][i] - v[1][j], dvz = v[2][i] - v[2][j];
        const double vn = dvx * nx + dvy * ny + dvz * nz;
        const double meff = dem::contact_meff(m, p.mass[i], p.mass[j]);
        const double fn = dem::contact_normal_force(m, meff, rs - dist, vn);
        ax -= fn * nx, ay -= fn * ny, az -= fn * nz;
        if (!m.friction)
          continue;
        const double sx = ri * w[0][i] + rj * w[0][j], sy = ri * w[1][i] + rj * w[1][j],
                     sz = ri * w[2][i] + rj * w[2][j];
        const double rv[3] = {dvx + (sy * nz - sz * ny), dvy + (sz * nx - sx * nz),
                              dvz + (sx * ny - sy * nx)};
        const double rvn = rv[0] * nx + rv[1] * ny + rv[2] * nz;
        const double nv[3] = {nx, ny, nz};
        const double vt[3] = {rv[0] - rvn * nx, rv[1] - rvn * ny, rv[2] - rvn * nz};
        double xi[3] = {0, 0, 0}, ft[3];
        dem::tangential_force(m.pair_t, meff, 0.0, std::abs(fn), nv, vt, xi, ft);
        ax += ft[0], ay += ft[1], az += ft[2];
        tx += ri * (ny * ft[2] - nz * ft[1]);
        ty += ri * (nz * ft[0] - nx * ft[2]);
        tz += ri * (nx * ft[1] - ny * ft[0]);
      }
    }
    o.f[0][i] = ax, o.f[1][i] = ay, o.f[2][i] = az;
    o.t[0][i] = tx, o.t[1][i] = ty, o.t[2][i] = tz;
  }
  return o;
}

void expect_full_row_forces(double mu) {
  const Scene scene =
      demtest::scene_from(demtest::kPairScene, {kBoxHi, "dem.friction=" + std::to_string(mu)});
  ParticleStore p = overlapping_packing(11);
  ASSERT_GT(p.size(), 1000U);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(scene, p, timer);
  // Spins after the constructor (which gives the store rotation when there is friction).
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-2000.0, 2000.0);
  std::unordered_map<std::int64_t, std::array<double, 6>> vel;
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (mu > 0)
      p.wx[i] = u(rng), p.wy[i] = u(rng), p.wz[i] = u(rng);
    vel[p.id[i]] = {p.vx[i],
                    p.vy[i],
                    p.vz[i],
                    mu > 0 ? p.wx[i] : 0.0,
                    mu > 0 ? p.wy[i] : 0.0,
                    mu > 0 ? p.wz[i] : 0.0};
  }
  scheme.start(); // sorts the store by cell, then evaluates the forces at t = 0
  std::vector<double> v[3], w[3];
  for (int a = 0; a < 3; ++a)
    v[a].resize(p.size()), w[a].resize(p.size());
  for (std::size_t i = 0; i < p.size(); ++i)
    for (int a = 0; a < 3; ++a)
      v[a][i] = vel[p.id[i]][a], w[a][i] = vel[p.id[i]][3 + a];
  const Oracle o = full_rows(p, v, w, scheme.model(), dem::DomainGeometry(scene.domain));
  EXPECT_GT(o.contacts, static_cast<int>(p.size())); // not vacuous: over one contact each
  std::size_t differ = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    differ += p.fx[i] != o.f[0][i] || p.fy[i] != o.f[1][i] || p.fz[i] != o.f[2][i];
    if (mu > 0)
      differ += p.tx[i] != o.t[0][i] || p.ty[i] != o.t[1][i] || p.tz[i] != o.t[2][i];
  }
  EXPECT_EQ(differ, 0U) << "particles whose force or torque differs from the full-row sum";
}

// A checkpoint written before the half list holds full rows: each pair in both rows, the
// partner's history negated. Restoring one continues bit for bit as the half-row state does.
TEST(HalfList, AFullRowCheckpointContinuesBitForBit) {
  const Scene scene = demtest::scene_from(demtest::kPairScene, {kBoxHi, "dem.friction=0.4"});
  ParticleStore p = overlapping_packing(3);
  PhaseTimer timer;
  dem::ExplicitScheme a(scene, p, timer);
  a.start();
  for (int k = 0; k < 200; ++k)
    a.step();
  const dem::ExplicitScheme::State half = a.save_state();
  // The same list as full rows: row i = its lower partners (ascending), then its own entries.
  const std::size_t n = p.size();
  std::vector<std::vector<std::uint32_t>> rows(n);
  std::vector<std::vector<std::array<double, 3>>> hist(n);
  std::size_t live = 0;
  for (std::size_t i = 0; i < n; ++i)
    for (std::uint32_t k = half.offsets[i]; k < half.offsets[i + 1]; ++k) {
      const std::uint32_t j = half.neighbors[k];
      rows[j].push_back(static_cast<std::uint32_t>(i));
      hist[j].push_back({-half.hx[k], -half.hy[k], -half.hz[k]});
      live += half.hx[k] != 0.0;
    }
  ASSERT_GT(live, 10U); // contacts with a spring are carried
  dem::ExplicitScheme::State full = half;
  full.offsets.assign(1, 0);
  full.neighbors.clear(), full.hx.clear(), full.hy.clear(), full.hz.clear();
  for (std::size_t i = 0; i < n; ++i) {
    for (std::uint32_t k = half.offsets[i]; k < half.offsets[i + 1]; ++k) {
      rows[i].push_back(half.neighbors[k]);
      hist[i].push_back({half.hx[k], half.hy[k], half.hz[k]});
    }
    for (std::size_t q = 0; q < rows[i].size(); ++q) {
      full.neighbors.push_back(rows[i][q]);
      full.hx.push_back(hist[i][q][0]), full.hy.push_back(hist[i][q][1]);
      full.hz.push_back(hist[i][q][2]);
    }
    full.offsets.push_back(static_cast<std::uint32_t>(full.neighbors.size()));
  }
  ASSERT_EQ(full.neighbors.size(), 2 * half.neighbors.size());
  ParticleStore q = p;
  dem::ExplicitScheme b(scene, q, timer);
  b.restore_state(full);
  for (int k = 0; k < 300; ++k)
    a.step(), b.step();
  EXPECT_EQ(p.x, q.x);
  EXPECT_EQ(p.vx, q.vx);
  EXPECT_EQ(p.wz, q.wz);
  EXPECT_EQ(a.pair_evaluations(), b.pair_evaluations());
}

TEST(HalfList, FrictionlessForcesAreTheFullRowSumsBitForBit) {
  expect_full_row_forces(0.0);
}
TEST(HalfList, FrictionalForcesAndTorquesAreTheFullRowSumsBitForBit) {
  expect_full_row_forces(0.4);
}

} // namespace
} // namespace cfddem
