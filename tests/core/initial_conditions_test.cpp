// Initial conditions: seeded placement, exact granular temperature, CSV reading and its errors.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <stdexcept>

#include <gtest/gtest.h>

#include "core/diameter_distribution.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"
#include "core/scene_config.hpp"

using namespace cfddem;

namespace {

Scene gas(std::initializer_list<std::string> overrides) {
  auto c = SceneConfig::from_string(R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [2.0e-3, 2.0e-3, 2.0e-3]
[particles]
count = 500
diameter = 100.0e-6
density = 1000.0
temperature = 0.01
seed = 5
[dem]
spring_constant = 10.0
restitution = 0.8
[run]
end_time = 1.0e-3
)",
                                    "gas");
  for (const auto& o : overrides)
    c.apply_override(o);
  return read_scene(c, "gas");
}

std::string temp_file(const std::string& name, const std::string& text) {
  const std::string path = ::testing::TempDir() + name;
  std::ofstream(path) << text;
  return path;
}

} // namespace

TEST(InitialConditions, RandomPlacementSeededAndNonOverlapping) {
  const Scene s = gas({});
  const ParticleStore a = make_initial_particles(s), b = make_initial_particles(s);
  ASSERT_EQ(a.size(), 500u);
  EXPECT_EQ(a.x, b.x);
  EXPECT_EQ(a.vz, b.vz);
  EXPECT_NO_THROW(check_no_overlap(a, s.domain));
  const ParticleStore c = make_initial_particles(gas({"particles.seed=6"}));
  EXPECT_NE(a.x, c.x);
}

TEST(InitialConditions, ExactTemperatureAndZeroMomentum) {
  const ParticleStore p = make_initial_particles(gas({}));
  double px = 0, py = 0, pz = 0, sq = 0, scale = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    px += p.mass[i] * p.vx[i], py += p.mass[i] * p.vy[i], pz += p.mass[i] * p.vz[i];
    sq += p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
    scale += p.mass[i] * std::sqrt(p.vx[i] * p.vx[i]);
  }
  EXPECT_LT(std::abs(px) + std::abs(py) + std::abs(pz), 1e-13 * scale);
  EXPECT_NEAR(sq / (3.0 * p.size()), 0.01, 1e-14);
}

TEST(InitialConditions, LatticePlacementFillsRegion) {
  const ParticleStore p =
      make_initial_particles(gas({"particles.placement=lattice", "particles.count=6859"}));
  EXPECT_EQ(p.size(), 6859u); // 19^3: the spacing is kept strictly above d
  EXPECT_NO_THROW(check_no_overlap(p, gas({}).domain));
  EXPECT_THROW(make_initial_particles(gas({"particles.placement=lattice", "particles.count=6860"})),
               ConfigError);
}

TEST(InitialConditions, ImpossiblePackingIsAnError) {
  // 40% solids by random sequential addition is above its jamming limit (38%).
  EXPECT_THROW(make_initial_particles(gas({"particles.count=6200"})), ConfigError);
}

TEST(InitialConditions, CsvRoundTrip) {
  const std::string f = temp_file("ok.csv", "x,y,z,vx,vy,vz,diameter,density\n"
                                            "1e-4,2e-4,3e-4,0.1,0,0,1e-4,1000\n"
                                            "5e-4,5e-4,5e-4,0,-0.1,0,2e-4,2500\n");
  const ParticleStore p = read_particle_csv(f);
  ASSERT_EQ(p.size(), 2u);
  EXPECT_DOUBLE_EQ(p.radius[1], 1e-4);
  EXPECT_DOUBLE_EQ(p.vy[1], -0.1);
  EXPECT_NEAR(p.mass[1], 2500 * 4.0 / 3.0 * M_PI * 1e-12, 1e-22);
}

TEST(InitialConditions, CsvFromASpreadsheetReadsTheSame) {
  // A spreadsheet's "CSV UTF-8" export: a byte-order mark before the header, CRLF line ends.
  const std::string rows[2] = {"x,y,z,vx,vy,vz,diameter,density",
                               "1e-4,2e-4,3e-4,0.1,0,0,1e-4,1000"};
  const ParticleStore plain =
      read_particle_csv(temp_file("plain.csv", rows[0] + "\n" + rows[1] + "\n"));
  const ParticleStore p =
      read_particle_csv(temp_file("bom.csv", "\xEF\xBB\xBF" + rows[0] + "\r\n" + rows[1] + "\r\n"));
  ASSERT_EQ(p.size(), 1u);
  ASSERT_EQ(plain.size(), 1u);
  EXPECT_EQ(p.x[0], 1e-4);
  EXPECT_EQ(p.vx[0], 0.1);
  EXPECT_EQ(p.radius[0], plain.radius[0]);
  EXPECT_EQ(p.mass[0], plain.mass[0]);
}

TEST(InitialConditions, CsvErrorsNameFileAndLine) {
  auto message = [](const std::string& text) {
    try {
      read_particle_csv(temp_file("bad.csv", text));
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(message("x,y,z,vx,vy,vz,diameter\n").find("missing column 'density'"),
            std::string::npos);
  EXPECT_NE(message("x,y,z,vx,vy,vz,diameter,density\n1,2,3,4,5,6,7\n").find("line 2"),
            std::string::npos);
  EXPECT_NE(message("x,y,z,vx,vy,vz,diameter,density\n1,2,3,4,5,6,abc,1\n").find("'abc'"),
            std::string::npos);
  EXPECT_NE(message("x,y,z,vx,vy,vz,diameter,density\n1,2,3,4,5,6,-1,1\n").find("must be > 0"),
            std::string::npos);
  EXPECT_THROW(read_particle_csv("/nonexistent/file.csv"), ConfigError);
  // Found by fuzz/fuzz_particle_csv: a repeated column made each row read past its values.
  EXPECT_NE(message("x,y,z,vx,vy,vz,y,z,vx,vy,vz,diameter,density\n1,2,3,4,5,6,7,8\n")
                .find("column 'y' appears twice"),
            std::string::npos);
}

TEST(InitialConditions, OverlapNamesThePair) {
  ParticleStore p;
  p.add(1e-4, 1e-4, 1e-4, 0, 0, 0, 5e-5, 1000, 7);
  p.add(1.5e-4, 1e-4, 1e-4, 0, 0, 0, 5e-5, 1000, 9);
  DomainSpec d;
  d.lo = {0, 0, 0}, d.hi = {1e-3, 1e-3, 1e-3};
  try {
    check_no_overlap(p, d);
    FAIL();
  } catch (const ConfigError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("particles 7"), std::string::npos) << m;
    EXPECT_NE(m.find("and 9"), std::string::npos) << m;
  }
  // Across a periodic face too.
  ParticleStore q;
  q.add(0.2e-4, 5e-4, 5e-4, 0, 0, 0, 5e-5, 1000, 1);
  q.add(9.9e-4, 5e-4, 5e-4, 0, 0, 0, 5e-5, 1000, 2);
  EXPECT_THROW(check_no_overlap(q, d), ConfigError);
}

namespace {

// Every field of particle i of `a` equals particle j of `b`, bit for bit.
void expect_same_particle(const ParticleStore& a, std::size_t i, const ParticleStore& b,
                          std::size_t j) {
  for (auto f : {&ParticleStore::x, &ParticleStore::y, &ParticleStore::z, &ParticleStore::vx,
                 &ParticleStore::vy, &ParticleStore::vz, &ParticleStore::radius,
                 &ParticleStore::mass, &ParticleStore::inv_mass})
    EXPECT_EQ(std::memcmp(&(a.*f)[i], &(b.*f)[j], sizeof(double)), 0) << "particle " << a.id[i];
  EXPECT_EQ(a.id[i], b.id[j]);
}

// make_initial_share(s, r, R) holds exactly the particles k % R == r of the whole set, in id
// order, with the same bits, for R = 1..4.
void expect_shares_partition_the_set(const Scene& s) {
  const ParticleStore all = make_initial_particles(s);
  ASSERT_GT(all.size(), 10u);
  for (int ranks = 1; ranks <= 4; ++ranks) {
    std::size_t total = 0;
    for (int r = 0; r < ranks; ++r) {
      const ParticleStore p = make_initial_share(s, r, ranks);
      total += p.size();
      for (std::size_t i = 0; i < p.size(); ++i) {
        ASSERT_EQ(p.id[i] % ranks, r);
        ASSERT_TRUE(i == 0 || p.id[i] > p.id[i - 1]);
        ASSERT_LT(static_cast<std::size_t>(p.id[i]), all.size());
        expect_same_particle(p, i, all, static_cast<std::size_t>(p.id[i]));
      }
    }
    EXPECT_EQ(total, all.size()) << ranks << " ranks";
  }
}

} // namespace

TEST(InitialShare, LatticeWithThermalVelocities) {
  // The share is built alone (velocities from the re-drawn normal stream).
  expect_shares_partition_the_set(gas({"particles.placement=lattice", "particles.count=1001",
                                       "particles.velocity=[0.0, 0.5, 0.0]"}));
}

TEST(InitialShare, RandomPlacement) {
  expect_shares_partition_the_set(gas({}));
}

TEST(InitialShare, ParticleFileWithAndWithoutOverlapTest) {
  std::string text = "x,y,z,vx,vy,vz,diameter,density\n";
  for (int k = 0; k < 37; ++k)
    text += std::to_string(1e-4 + 4e-5 * k) + ",1e-3,1e-3," + std::to_string(0.01 * k) +
            ",0,0,3e-5," + std::to_string(1000 + k) + "\n";
  const std::string f = temp_file("share.csv", text);
  for (const char* overlap : {"false", "true"}) {
    auto c = SceneConfig::from_string(R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [2.0e-3, 2.0e-3, 2.0e-3]
[particles]
file = ")" + f + R"("
[dem]
spring_constant = 10.0
restitution = 0.8
[run]
end_time = 1.0e-3
)",
                                      "file");
    c.apply_override(std::string("particles.allow_overlap=") + overlap);
    expect_shares_partition_the_set(read_scene(c, "file"));
  }
}

TEST(InitialShare, ErrorsAsTheWholeSet) {
  EXPECT_THROW(
      make_initial_share(gas({"particles.placement=lattice", "particles.count=6860"}), 1, 2),
      ConfigError);
  EXPECT_THROW(make_initial_share(gas({}), 2, 2), std::invalid_argument);
}

// Polydisperse generation (core/diameter_distribution.hpp).
namespace {

Scene poly(const std::string& diameter, std::initializer_list<std::string> overrides = {}) {
  auto c = SceneConfig::from_string(R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [2.0e-3, 2.0e-3, 2.0e-3]
[particles]
count = 400
diameter = )" + diameter + R"(
density = 1000.0
temperature = 0.01
seed = 5
[dem]
spring_constant = 10.0
restitution = 0.8
[run]
end_time = 1.0e-3
)",
                                    "poly");
  for (const auto& o : overrides)
    c.apply_override(o);
  return read_scene(c, "poly");
}

const std::string kUniform3to1 = R"({ distribution = "uniform", min = 50.0e-6, max = 150.0e-6 })";

} // namespace

TEST(DiameterDistribution, DrawsFollowTheDistributionWithinItsBounds) {
  // Sample means and deviations within 5 standard errors of the (truncated) distribution's.
  const int n = 200000;
  {
    DiameterStream s({"uniform", 0.0, 0.0, 1.0, 3.0}, 7);
    double sum = 0, sq = 0;
    for (int k = 0; k < n; ++k) {
      const double d = s.next();
      ASSERT_TRUE(d >= 1.0 && d <= 3.0);
      sum += d, sq += d * d;
    }
    const double mean = sum / n, var = sq / n - mean * mean;
    EXPECT_NEAR(mean, 2.0, 5.0 * std::sqrt(1.0 / 3.0 / n));
    EXPECT_NEAR(var, 1.0 / 3.0, 5.0 * std::sqrt(4.0 / 45.0 / n)); // Var(X^2) = 4/45 for U(1,3)
  }
  {
    // Lognormal with mean 1, std 0.2, bounds far in the tails (mass outside ~1e-9): the
    // diameter's own mean and std come back.
    DiameterStream s({"lognormal", 1.0, 0.2, 0.2, 5.0}, 7);
    double sum = 0, sq = 0;
    for (int k = 0; k < n; ++k) {
      const double d = s.next();
      sum += d, sq += d * d;
    }
    const double mean = sum / n, sd = std::sqrt(sq / n - mean * mean);
    EXPECT_NEAR(mean, 1.0, 5.0 * 0.2 / std::sqrt(n));
    EXPECT_NEAR(sd, 0.2, 5.0 * 0.2 / std::sqrt(2.0 * n) * 1.3); // kurtosis of a lognormal: 1.3x
  }
  {
    // A normal truncated to [mean, mean + std]: every draw inside, none at a bound by clamping.
    DiameterStream s({"normal", 1.0, 0.5, 1.0, 1.5}, 3);
    int at_bound = 0;
    for (int k = 0; k < 10000; ++k) {
      const double d = s.next();
      ASSERT_TRUE(d >= 1.0 && d <= 1.5);
      at_bound += d == 1.0 || d == 1.5;
    }
    EXPECT_EQ(at_bound, 0);
  }
  // A range that holds nothing of the distribution is an error naming the key.
  DiameterStream far({"normal", 1.0, 0.01, 2.0, 3.0}, 1);
  try {
    far.next();
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("particles.diameter"), std::string::npos) << e.what();
  }
}

TEST(DiameterDistribution, SizeStatisticsByVolume) {
  // One particle of d = 2 and eight of d = 1: equal volumes. d10 = d50 = 1 (the small ones
  // hold half the volume), d90 = 2, d32 = (8 + 8) / (4 + 8) = 4/3.
  std::vector<double> r(8, 0.5);
  r.push_back(1.0);
  const SizeStatistics s = size_statistics(r);
  EXPECT_EQ(s.d_min, 1.0);
  EXPECT_EQ(s.d_max, 2.0);
  EXPECT_EQ(s.d10, 1.0);
  EXPECT_EQ(s.d50, 1.0);
  EXPECT_EQ(s.d90, 2.0);
  EXPECT_NEAR(s.d32, 4.0 / 3.0, 1e-15);
  const SizeStatistics one = size_statistics(std::vector<double>(5, 0.25));
  EXPECT_EQ(one.d10, 0.5);
  EXPECT_EQ(one.d90, 0.5);
  EXPECT_NEAR(one.d32, 0.5, 1e-16);
}

TEST(InitialConditions, PolydisperseRandomPlacementIsSeededNonOverlappingAndInIdOrder) {
  const Scene s = poly(kUniform3to1, {"domain.periodic=[false, false, false]"});
  EXPECT_EQ(s.particles.diameter, 150e-6); // the largest: cell sizes and margins
  const ParticleStore a = make_initial_particles(s), b = make_initial_particles(s);
  ASSERT_EQ(a.size(), 400u);
  EXPECT_EQ(a.radius, b.radius);
  EXPECT_EQ(a.x, b.x);
  EXPECT_NO_THROW(check_no_overlap(a, s.domain));
  DiameterStream stream(s.particles.diameters, s.particles.seed);
  double r_min = 1.0, r_max = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a.id[i], static_cast<std::int64_t>(i));
    EXPECT_EQ(2.0 * a.radius[i], stream.next()); // particle k has the k-th diameter drawn
    r_min = std::min(r_min, a.radius[i]), r_max = std::max(r_max, a.radius[i]);
    for (int ax = 0; ax < 3; ++ax) { // no sphere starts in a wall
      const double c = ax == 0 ? a.x[i] : ax == 1 ? a.y[i] : a.z[i];
      EXPECT_GE(c - a.radius[i], 0.0);
      EXPECT_LE(c + a.radius[i], 2.0e-3);
    }
  }
  EXPECT_LT(r_max / r_min, 3.0);
  EXPECT_GT(r_max / r_min, 2.5); // 400 draws span most of the 3:1 range
}

TEST(InitialShare, PolydisperseLatticeAndRandom) {
  expect_shares_partition_the_set(
      poly(kUniform3to1, {"particles.placement=lattice", "particles.count=300"}));
  expect_shares_partition_the_set(poly(
      R"({ distribution = "lognormal", mean = 80.0e-6, std = 20.0e-6, min = 40.0e-6, max = 160.0e-6 })"));
}

TEST(SceneConfig, DiameterDistributionKeysAreChecked) {
  auto bad = [](const std::string& diameter, const std::string& key) {
    try {
      poly(diameter);
      ADD_FAILURE() << "expected a ConfigError for " << diameter;
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(key), std::string::npos) << e.what();
    }
  };
  bad(R"({ distribution = "gamma", min = 1.0e-5, max = 2.0e-5 })",
      "particles.diameter.distribution");
  bad(R"({ distribution = "uniform", min = 2.0e-5, max = 1.0e-5 })", "particles.diameter.max");
  bad(R"({ distribution = "uniform", min = 1.0e-5, max = 2.0e-5, std = 1.0e-6 })",
      "particles.diameter.std");
  bad(R"({ distribution = "normal", min = 1.0e-5, max = 2.0e-5 })", "particles.diameter.mean");
  bad(R"({ distribution = "lognormal", mean = 1.5e-5, min = 1.0e-5, max = 2.0e-5 })",
      "particles.diameter.std");
  bad(R"({ distribution = "normal", mean = 1.5e-5, std = 1e-6, max = 2.0e-5 })",
      "particles.diameter.min");
  bad(R"({ distribution = "uniform", min = 1.0e-5, max = 2.0e-5, typo = 1 })",
      "particles.diameter.typo");
}

// A Scene set up in code (benchmarks, tests) may change only particles.diameter: a single size
// is that value, whatever particles.diameters held (it once read 0 there: radius 0, NaN forces).
TEST(InitialConditions, SingleSizeIsParticlesDiameterForASceneBuiltInCode) {
  Scene s = gas({"particles.placement=lattice", "particles.count=8"});
  s.particles.diameter = 50e-6;
  s.particles.diameters = DiameterDistribution{};
  for (const ParticleStore& p : {make_initial_particles(s), make_initial_share(s, 1, 2)})
    for (double r : p.radius)
      EXPECT_EQ(r, 25e-6);
}
