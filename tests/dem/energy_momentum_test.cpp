// Conservation laws of the explicit scheme: energy with e = 1, momentum to round-off, and the
// periodic wrap of a particle leaving through a face.
#include <cmath>

#include <gtest/gtest.h>

#include "dem_test_support.hpp"

using namespace cfddem;
using cfddem::demtest::scene_from;

namespace {

const char* kGas = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.2e-3, 1.2e-3, 1.2e-3]
periodic = [true, true, true]
[particles]
count = 700
diameter = 100.0e-6
density = 1000.0
temperature = 0.01
seed = 11
[dem]
spring_constant = 10.0
restitution = 1.0
[run]
end_time = 1.0e-3
)";

// Kinetic energy at the synchronised velocities plus the elastic energy 1/2 k delta^2 of every
// overlapping pair (all pairs, minimum image).
double total_energy(const ParticleStore& p, const dem::ExplicitScheme::Synchronised& s, double k,
                    double box) {
  double e = 0;
  for (std::size_t i = 0; i < p.size(); ++i)
    e += 0.5 * p.mass[i] * (s.vx[i] * s.vx[i] + s.vy[i] * s.vy[i] + s.vz[i] * s.vz[i]);
  for (std::size_t i = 0; i < p.size(); ++i)
    for (std::size_t j = i + 1; j < p.size(); ++j) {
      double d[3] = {s.x[j] - s.x[i], s.y[j] - s.y[i], s.z[j] - s.z[i]};
      for (double& c : d) c -= box * std::nearbyint(c / box);
      const double delta = p.radius[i] + p.radius[j] - std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      if (delta > 0) e += 0.5 * k * delta * delta;
    }
  return e;
}

// Largest relative energy error over a run of `steps` at the given dt factor, sampled every 25.
double energy_error(double dt_factor, int steps) {
  const Scene s = scene_from(kGas, {"dem.dt_factor=" + std::to_string(dt_factor)});
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  scheme.step(true);
  const double e0 = total_energy(p, scheme.synchronised_previous(), 10.0, 1.2e-3);
  double worst = 0;
  for (int k = 1; k <= steps; ++k) {
    const bool rec = k % 25 == 0;
    scheme.step(rec);
    if (rec)
      worst = std::max(worst, std::abs(total_energy(p, scheme.synchronised_previous(), 10.0,
                                                     1.2e-3) / e0 - 1.0));
  }
  return worst;
}

} // namespace

// e = 1 in a dense periodic gas (phi = 0.21, about 1 contact per particle per 40 steps): the total
// energy stays within 1e-4 at tau_p/50; velocity Verlet is second order, so halving dt should cut
// the error about 4x (we require at least 2x: the kink of the force at first touch adds an O(dt)
// part of random sign).
TEST(ElasticGas, EnergyConservedAndConvergesWithDt) {
  const double t_end_steps = 4000; // 4000 steps at tau_p/50 = 0.58 ms, ~15 collisions per particle
  const double err50 = energy_error(0.02, static_cast<int>(t_end_steps));
  const double err100 = energy_error(0.01, static_cast<int>(2 * t_end_steps));
  RecordProperty("energy_error_tau50", std::to_string(err50));
  RecordProperty("energy_error_tau100", std::to_string(err100));
  std::printf("energy error: tau/50 %.3e, tau/100 %.3e, ratio %.2f\n", err50, err100, err50 / err100);
  EXPECT_LT(err50, 1e-4);
  EXPECT_LT(err100, err50 / 2);
}

// Pair forces are exactly antisymmetric (the full list evaluates i-j and j-i with negated
// separations), so total momentum stays zero to round-off with dissipation.
TEST(DissipativeGas, MomentumConservedToRoundOff) {
  const Scene s = scene_from(kGas, {"dem.restitution=0.5"});
  ParticleStore p = make_initial_particles(s);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  double scale = 0; // sum of |m v|: the size of the terms that cancel
  for (std::size_t i = 0; i < p.size(); ++i)
    scale += p.mass[i] * std::sqrt(p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i]);
  for (int k = 0; k < 3000; ++k) scheme.step(false);
  const auto st = demtest::measure_now(p);
  for (int a = 0; a < 3; ++a) EXPECT_LT(std::abs(st.momentum[a]), 1e-13 * scale) << "axis " << a;
  EXPECT_GT(scheme.pair_evaluations(), 0);
}

// A particle that leaves through a periodic face comes back through the opposite one, at the
// position x0 + v t wrapped into the box.
TEST(PeriodicBoundary, CrossingParticleReappearsOnOtherSide) {
  const Scene s = scene_from(demtest::kPairScene);
  ParticleStore p;
  p.add(9.0e-4, 5e-4, 1.0e-4, 1.0, 0.0, -0.5, 50e-6, 1000.0, 0);
  PhaseTimer timer;
  dem::ExplicitScheme scheme(s, p, timer);
  scheme.start();
  const int steps = 20000;
  for (int k = 0; k < steps; ++k) scheme.step(false);
  const double t = steps * scheme.dt();
  auto wrapped = [](double v) { return v - 1e-3 * std::floor(v / 1e-3); };
  // The particle is re-wrapped at neighbor builds only, so compare modulo the box.
  EXPECT_NEAR(wrapped(p.x[0]), wrapped(9.0e-4 + 1.0 * t), 1e-12);
  EXPECT_NEAR(wrapped(p.z[0]), wrapped(1.0e-4 - 0.5 * t), 1e-12);
  EXPECT_GT(1.0 * t, 1e-3); // it did cross at least once
  EXPECT_GE(p.x[0], -1e-4);
  EXPECT_LE(p.x[0], 1.1e-3);
}
