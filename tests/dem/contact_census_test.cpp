// The contact census (dem/contact_census.hpp) against packings whose contacts are known exactly:
// a pair across a periodic face, compressed FCC lattices (12 contacts each), walls, and a random
// polydisperse gas against a search over all pairs. Counts are exact; overlap means within the
// census's fixed-point quantisation (2^-32 of the diameter per contact: kQuantum), maxima to a few
// ulps; the contact durations are the values docs/theory.md §1 tabulates for the paper's
// particle.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "dem/contact_census.hpp"

namespace cfddem::dem {
namespace {

constexpr double kD = 100e-6;                                            // the paper's particle
constexpr double kMass = 1000.0 * std::numbers::pi / 6.0 * kD * kD * kD; // rho = 1000
// docs/theory.md §1: k = 10 N/m, e = 0.8, m_eff = m/2; and the wall with e_w = 1, m_eff = m.
constexpr double kTc = 1.611488e-5, kTcWall = 2.273260e-5;
constexpr CensusLaws kLaws{10.0, 0.8, 10.0, 1.0};
constexpr double kQuantum = 1.0 / 4294967296.0; // 2^-32: the census's fixed-point sums

struct Cloud {
  std::vector<double> x, y, z, r, m;
  void add(double px, double py, double pz, double radius = 0.5 * kD, double mass = kMass) {
    x.push_back(px), y.push_back(py), z.push_back(pz), r.push_back(radius), m.push_back(mass);
  }
  CensusParticles spans() const { return {x, y, z, r, m}; }
};

DomainGeometry box(double l0, double l1, double l2, std::array<bool, 3> periodic) {
  DomainSpec d;
  d.lo = {0.0, 0.0, 0.0};
  d.hi = {l0, l1, l2};
  d.periodic = periodic;
  return DomainGeometry(d);
}

TEST(ContactCensus, PairAcrossAPeriodicFace) {
  // 0.03 mm from the lo face and 0.05 mm from the hi face: 0.08 mm apart through the face, an
  // overlap of 0.02 mm = 0.2 d. A third particle touches nobody.
  Cloud c;
  c.add(0.03e-3, 0.5e-3, 0.5e-3);
  c.add(0.95e-3, 0.5e-3, 0.5e-3);
  c.add(0.5e-3, 0.2e-3, 0.7e-3);
  const ContactCensus s = take_census(c.spans(), box(1e-3, 1e-3, 1e-3, {true, true, true}), kLaws);
  EXPECT_EQ(s.particles, 3);
  EXPECT_EQ(s.pair_contacts, 1);
  EXPECT_EQ(s.wall_contacts, 0);
  EXPECT_NEAR(s.pair_overlap_mean, 0.2, kQuantum);
  EXPECT_NEAR(s.pair_overlap_max, 0.2, 1e-12);
  EXPECT_EQ(s.coordination[0], 1);
  EXPECT_EQ(s.coordination[1], 2);
  // f = 2 N_c / (N t_c): one contact among three particles.
  EXPECT_NEAR(s.collision_frequency, 2.0 / (3.0 * kTc), 1e-6 * 2.0 / (3.0 * kTc));
  EXPECT_EQ(s.wall_collision_frequency, 0.0);
}

// Compressed FCC: nearest neighbours at 0.99 d (12 each, overlap 0.01 d), the next shell at
// 1.40 d. Boxes of 2 and 3 conventional cells: the 2-cell box has only 2 search cells per axis,
// where a cell's left and right neighbours are the same cell.
TEST(ContactCensus, CompressedFccHasTwelveContactsEach) {
  for (int cells : {2, 3}) {
    const double a = 0.99 * kD * std::numbers::sqrt2;
    Cloud c;
    const double basis[4][3] = {{0, 0, 0}, {0.5, 0.5, 0}, {0.5, 0, 0.5}, {0, 0.5, 0.5}};
    for (int i = 0; i < cells; ++i)
      for (int j = 0; j < cells; ++j)
        for (int k = 0; k < cells; ++k)
          for (const auto& b : basis)
            c.add((i + b[0] + 0.25) * a, (j + b[1] + 0.25) * a, (k + b[2] + 0.25) * a);
    const double l = cells * a;
    const ContactCensus s = take_census(c.spans(), box(l, l, l, {true, true, true}), kLaws);
    const auto n = static_cast<std::int64_t>(c.x.size());
    EXPECT_EQ(s.pair_contacts, 6 * n) << cells;
    EXPECT_EQ(s.coordination[kCoordinationBins - 1], n) << cells; // 12: the last bin
    EXPECT_NEAR(s.pair_overlap_mean, 0.01, kQuantum) << cells;
    EXPECT_NEAR(s.pair_overlap_max, 0.01, 1e-12) << cells;
    EXPECT_NEAR(s.collision_frequency, 12.0 / kTc, 1e-6 * 12.0 / kTc) << cells;

    // The order of the particles does not change a bit of the census.
    Cloud shuffled = c;
    std::vector<std::size_t> perm(c.x.size());
    for (std::size_t q = 0; q < perm.size(); ++q)
      perm[q] = q;
    std::shuffle(perm.begin(), perm.end(), std::mt19937(7));
    for (std::size_t q = 0; q < perm.size(); ++q) {
      shuffled.x[q] = c.x[perm[q]], shuffled.y[q] = c.y[perm[q]], shuffled.z[q] = c.z[perm[q]];
    }
    const ContactCensus t = take_census(shuffled.spans(), box(l, l, l, {true, true, true}), kLaws);
    EXPECT_EQ(t.pair_overlap_mean, s.pair_overlap_mean);
    EXPECT_EQ(t.collision_frequency, s.collision_frequency);
    EXPECT_EQ(t.coordination, s.coordination);
  }
}

TEST(ContactCensus, WallsCountedApartFromPairs) {
  // Closed 1 mm box. One particle 0.4 d from the lo x wall (overlap r - 0.4 d = 0.1 of its
  // diameter); one in the hi x-y edge, 0.45 d and 0.3 d from the walls (0.05 and 0.2).
  Cloud c;
  c.add(0.4 * kD, 0.5e-3, 0.5e-3);
  c.add(1e-3 - 0.45 * kD, 1e-3 - 0.3 * kD, 0.5e-3);
  c.add(0.5e-3, 0.5e-3, 0.5e-3);
  const ContactCensus s =
      take_census(c.spans(), box(1e-3, 1e-3, 1e-3, {false, false, false}), kLaws);
  EXPECT_EQ(s.pair_contacts, 0);
  EXPECT_EQ(s.wall_contacts, 3);
  EXPECT_NEAR(s.wall_overlap_mean, (0.1 + 0.05 + 0.2) / 3.0, kQuantum);
  EXPECT_NEAR(s.wall_overlap_max, 0.2, 1e-12);
  EXPECT_EQ(s.coordination[0], 3); // walls do not count in the coordination number
  const double f_wall = 3.0 / (3.0 * kTcWall);
  EXPECT_NEAR(s.wall_collision_frequency, f_wall, 1e-6 * f_wall);
  EXPECT_EQ(s.collision_frequency, 0.0);

  // The same box periodic in x: only the second particle's y wall contact is left.
  const ContactCensus p =
      take_census(c.spans(), box(1e-3, 1e-3, 1e-3, {true, false, false}), kLaws);
  EXPECT_EQ(p.wall_contacts, 1);
  EXPECT_NEAR(p.wall_overlap_mean, 0.2, kQuantum);
}

TEST(ContactCensus, NoSpringOrCriticalDampingGivesNoFrequency) {
  Cloud c;
  c.add(0.3e-3, 0.5e-3, 0.5e-3);
  c.add(0.3e-3 + 0.9 * kD, 0.5e-3, 0.5e-3);
  const ContactCensus s =
      take_census(c.spans(), box(1e-3, 1e-3, 1e-3, {true, true, true}), {10.0, 0.0, 0.0, 0.0});
  EXPECT_EQ(s.pair_contacts, 1);
  EXPECT_EQ(s.collision_frequency, 0.0); // e = 0: t_c is infinite (docs: an estimate)
}

// A polydisperse gas (d in [60, 140] um) in a box periodic in x and z with walls in y, dense
// enough for many contacts: counts exactly, sums to round-off, against every pair.
TEST(ContactCensus, MatchesASearchOverAllPairs) {
  const double l = 0.8e-3;
  const DomainGeometry g = box(l, l, l, {true, false, true});
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Cloud c;
  for (int q = 0; q < 600; ++q) {
    const double d = kD * (0.6 + 0.8 * u(rng));
    c.add(u(rng) * l, u(rng) * l, u(rng) * l, 0.5 * d, kMass * std::pow(d / kD, 3));
  }
  std::int64_t pairs = 0, walls = 0;
  double overlap = 0.0, overlap_max = 0.0, rate = 0.0;
  std::vector<int> z(c.x.size(), 0);
  const auto tc = [](double k, double e, double m) {
    const double zeta =
        -std::log(e) / std::sqrt(std::numbers::pi * std::numbers::pi + std::log(e) * std::log(e));
    return std::numbers::pi / (std::sqrt(k / m) * std::sqrt(1.0 - zeta * zeta));
  };
  for (std::size_t i = 0; i < c.x.size(); ++i) {
    for (std::size_t j = i + 1; j < c.x.size(); ++j) {
      const double dx = g.image(c.x[j] - c.x[i], 0), dy = c.y[j] - c.y[i],
                   dz = g.image(c.z[j] - c.z[i], 2);
      const double reach = c.r[i] + c.r[j], dist = std::sqrt(dx * dx + dy * dy + dz * dz);
      if (dist >= reach)
        continue;
      ++pairs, ++z[i], ++z[j];
      overlap += (reach - dist) / reach;
      overlap_max = std::max(overlap_max, (reach - dist) / reach);
      rate += 1.0 / tc(10.0, 0.8, c.m[i] * c.m[j] / (c.m[i] + c.m[j]));
    }
    walls += (c.y[i] < c.r[i]) + (l - c.y[i] < c.r[i]);
  }
  const ContactCensus s = take_census(c.spans(), g, kLaws);
  ASSERT_GT(pairs, 100);
  EXPECT_EQ(s.pair_contacts, pairs);
  EXPECT_EQ(s.wall_contacts, walls);
  EXPECT_NEAR(s.pair_overlap_mean, overlap / static_cast<double>(pairs), kQuantum);
  EXPECT_EQ(s.pair_overlap_max, overlap_max);
  // Each contact's rate is rounded to 2^-32 of the lightest pair's, which is at most 4.6 times
  // (the mass ratio 2.33^3 of d = 140 and 60 um, square-rooted) the mean rate.
  EXPECT_NEAR(s.collision_frequency, 2.0 * rate / 600.0, 5.0 * kQuantum * 2.0 * rate / 600.0);
  for (int b = 0; b < kCoordinationBins; ++b)
    EXPECT_EQ(s.coordination[b],
              std::count_if(z.begin(), z.end(),
                            [b](int k) { return b == kCoordinationBins - 1 ? k >= b : k == b; }))
        << "coordination " << b;
}

} // namespace
} // namespace cfddem::dem
