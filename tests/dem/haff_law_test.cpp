// Homogeneous cooling (docs/theory.md §3): T(t) against Haff's law, and against LAMMPS from the
// peers' identical initial state.
#include <cmath>
#include <fstream>
#include <numbers>
#include <sstream>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "dem_test_support.hpp"

using namespace cfddem;

namespace {

const char* kHcs = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [4.0e-3, 4.0e-3, 4.0e-3]
periodic = [true, true, true]
[particles]
count = 1222
diameter = 100.0e-6
density = 1000.0
temperature = 0.01
[dem]
spring_constant = 10.0
restitution = 0.8
[run]
end_time = 0.03
)";

// T(t)/T0 sampled every `every` steps up to t_end.
std::vector<std::pair<double, double>> cool(const Scene& s, ParticleStore p, long every) {
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  const long n_end = std::lround(s.run.end_time / scheme.dt());
  const double T0 = demtest::measure_now(p).granular_temperature; // v(-dt/2), close enough below
  std::vector<std::pair<double, double>> out;
  for (long k = 0; k <= n_end; ++k) {
    const bool rec = k > 0 && (k % every == 0 || k == n_end); // as LAMMPS: the last step too
    scheme.step(rec);
    if (rec) {
      const auto st = scheme.synchronised_previous();
      const auto g = dem::measure({st.x, st.y, st.z, st.vx, st.vy, st.vz, p.mass});
      out.emplace_back(k * scheme.dt(), g.granular_temperature);
    }
  }
  (void)T0;
  return out;
}

// Haff: sqrt(T0/T) - 1 = t/t_H; least squares through the origin gives t_H.
double fit_haff_time(const std::vector<std::pair<double, double>>& curve, double T0) {
  double stt = 0, sty = 0;
  for (auto [t, T] : curve) {
    const double y = std::sqrt(T0 / T) - 1.0;
    stt += t * t, sty += t * y;
  }
  return stt / sty;
}

} // namespace

// Ensemble of 8 independent 1222-particle boxes (seeds 1..8), 30 ms each. One box scatters 2.3%
// (1 sigma) in fitted t_H (docs/theory.md §3; the peers' 20-seed ensemble), so the mean of 8 has
// sigma 0.8%; the peers' ensemble found DEM 0.5% slower than the Enskog prediction, and the
// integrator's effective e = 0.7974 (not 0.8) shortens t_H by 1.1%. Tolerance: 3 sigma + 1.5%
// systematic = 4%. t_H = 120.06 ms for T0 = 0.01 (docs/theory.md §3).
TEST(HomogeneousCooling, FollowsHaffLawOverEnsemble) {
  tbb::global_control one(tbb::global_control::max_allowed_parallelism, 2);
  const double phi = 1222 * std::numbers::pi * 1e-12 / 6.0 / 64e-9;
  const double g0 = (1 - phi / 2) / std::pow(1 - phi, 3);
  const double t_h = 1.0 / (4.0 / std::sqrt(std::numbers::pi) * (1 - 0.64) * phi * g0 * 0.1 / 1e-4);
  ASSERT_NEAR(t_h, 0.12006, 1e-4);
  double sum = 0;
  const int seeds = 8;
  for (int seed = 1; seed <= seeds; ++seed) {
    const Scene s = demtest::scene_from(kHcs, {"particles.seed=" + std::to_string(seed)});
    ParticleStore p = make_initial_particles(s);
    const auto curve = cool(s, std::move(p), 691);
    sum += fit_haff_time(curve, 0.01);
  }
  const double mean = sum / seeds;
  std::printf("Haff: ensemble-mean fitted t_H = %.5f s, prediction %.5f s, ratio %.4f\n", mean,
              t_h, mean / t_h);
  EXPECT_NEAR(mean / t_h, 1.0, 0.04);
}

// The peers' initial state (scenes/data/hcs1222.csv = shared/peers/data/hcs1222.data) at the
// peers' dt (1.447203e-7 s). Same algorithm, same inputs: cfddem matches LAMMPS to the 8 printed
// digits while round-off differences have not yet grown (first 5 ms; measured agreement 1e-8),
// and after that the trajectories decorrelate (chaos) but the cooling does not: the difference
// stays within 3x the ensemble spread of T/T0 between independent boxes (0.0068 at 30 ms).
TEST(HomogeneousCooling, FollowsLammpsFromSameInitialState) {
  auto cfg = SceneConfig::from_string(R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [4.0e-3, 4.0e-3, 4.0e-3]
[particles]
file = ")" CFDDEM_SOURCE_DIR R"(/scenes/data/hcs1222.csv"
[dem]
spring_constant = 10.0
restitution = 0.8
dt = 1.447203e-07
[run]
end_time = 0.03
)", "peers");
  const Scene peers = read_scene(cfg, "peers");
  ParticleStore p = make_initial_particles(peers);
  const auto curve = cool(peers, std::move(p), 691);

  std::ifstream in(CFDDEM_SOURCE_DIR "/tests/data/T_hcs1222_seed1.dat");
  ASSERT_TRUE(in.good());
  std::vector<double> lammps;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    double t, T, ratio;
    ls >> t >> T >> ratio;
    lammps.push_back(ratio);
  }
  ASSERT_EQ(lammps.size(), curve.size() + 1); // LAMMPS includes t = 0
  double early = 0, late = 0;
  for (std::size_t k = 0; k < curve.size(); ++k) {
    const double d = std::abs(curve[k].second / 0.01 - lammps[k + 1]);
    (curve[k].first <= 5e-3 ? early : late) = std::max(curve[k].first <= 5e-3 ? early : late, d);
  }
  std::printf("vs LAMMPS: max |dT/T0| %.2e for t <= 5 ms, %.2e after\n", early, late);
  EXPECT_LT(early, 1e-7);
  EXPECT_LT(late, 3 * 0.0068);
}
