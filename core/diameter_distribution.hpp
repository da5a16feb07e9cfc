// Particle diameters of a generated scene: one size, or a distribution (uniform, normal or
// lognormal) truncated to [min, max]. Diameters are drawn in id order from their own seeded
// stream, so particle k has the same diameter however the set is generated (whole, or one rank's
// share that still draws every diameter before it), and a single-size scene draws nothing (its
// positions and velocities are those of before distributions existed).
//
// Truncation redraws a value outside [min, max] (the truncated distribution), rather than moving
// it to the bound (which would pile particles up at min and max). Lognormal: `mean` and `std` are
// those of the diameter itself (as a sieve analysis reports them, and as MFIX-Exa's lognormal
// input takes them), so the underlying normal has s^2 = ln(1 + std^2/mean^2) and
// mu = ln(mean) - s^2/2 (Johnson, Kotz & Balakrishnan, Continuous Univariate Distributions,
// vol. 1, ch. 14).
#pragma once

#include <cstdint>
#include <random>
#include <span>
#include <string>

namespace cfddem {

struct DiameterDistribution {
  std::string kind = "fixed";  // "fixed" | "uniform" | "normal" | "lognormal"
  // normal, lognormal: the diameter's mean; a "fixed" stream returns it for every particle (a
  // scene's single size is ParticleSpec::diameter; the generator hands it in here).
  double mean = 0.0;           // [m]
  double std = 0.0;            // normal, lognormal [m]
  double min = 0.0, max = 0.0; // truncation (uniform: the range) [m]
  std::string key = "particles.diameter"; // the scene key it comes from (messages)
  [[nodiscard]] bool fixed() const { return kind == "fixed"; }
};

// Diameters in id order: next() is particle 0's, then 1's, ...
class DiameterStream {
public:
  DiameterStream(const DiameterDistribution& dist, std::uint64_t seed);
  // Throws ConfigError (scene key particles.diameter) when [min, max] holds so little of the
  // distribution that 1000 draws in a row fall outside it.
  double next();

private:
  DiameterDistribution dist_;
  std::mt19937_64 rng_;
  double mu_ = 0.0, sigma_ = 0.0; // of the normal drawn (ln d for lognormal)
};

// Size statistics of a set of particles (from their radii): d10, d50, d90 by volume (the
// diameters below which 10%, 50%, 90% of the solids volume lies, as sieve and laser sizing
// report them) and the Sauter mean d32 = sum d^3 / sum d^2 (the diameter with the set's
// volume-to-surface ratio, the one drag correlations of a polydisperse bed use).
struct SizeStatistics {
  double d_min = 0.0, d_max = 0.0, d10 = 0.0, d50 = 0.0, d90 = 0.0, d32 = 0.0;
};
SizeStatistics size_statistics(std::span<const double> radius);

} // namespace cfddem
