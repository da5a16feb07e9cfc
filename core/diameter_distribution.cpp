#include "core/diameter_distribution.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include <fmt/format.h>

#include "core/error.hpp"

namespace cfddem {

namespace {
// The diameter stream's own seed, apart from the placement's and the velocities' streams.
constexpr std::uint64_t kDiameterStream = 0xd1a3e7e55eed5a17ULL;
} // namespace

DiameterStream::DiameterStream(const DiameterDistribution& dist, std::uint64_t seed)
    : dist_(dist), rng_(seed ^ kDiameterStream) {
  if (dist_.kind == "normal") {
    mu_ = dist_.mean, sigma_ = dist_.std;
  } else if (dist_.kind == "lognormal") {
    const double s2 = std::log1p(dist_.std * dist_.std / (dist_.mean * dist_.mean));
    mu_ = std::log(dist_.mean) - 0.5 * s2, sigma_ = std::sqrt(s2);
  }
}

double DiameterStream::next() {
  if (dist_.fixed())
    return dist_.mean;
  for (int attempt = 0; attempt < 1000; ++attempt) {
    double d = 0.0;
    if (dist_.kind == "uniform") {
      d = std::uniform_real_distribution<double>(dist_.min, dist_.max)(rng_);
    } else {
      const double z = std::normal_distribution<double>(mu_, sigma_)(rng_);
      d = dist_.kind == "lognormal" ? std::exp(z) : z;
    }
    if (d >= dist_.min && d <= dist_.max)
      return d;
  }
  throw ConfigError(fmt::format("scene key '{}'", dist_.key),
                    fmt::format("1000 {} draws in a row (mean {} m, std {} m) fell outside "
                                "[min, max] = [{}, {}] m: widen the range or move the mean into it",
                                dist_.kind, dist_.mean, dist_.std, dist_.min, dist_.max));
}

SizeStatistics size_statistics(std::span<const double> radius) {
  SizeStatistics s;
  if (radius.empty())
    return s;
  std::vector<double> d(radius.size());
  for (std::size_t i = 0; i < d.size(); ++i)
    d[i] = 2.0 * radius[i];
  std::sort(d.begin(), d.end());
  s.d_min = d.front(), s.d_max = d.back();
  double v_total = 0.0, a_total = 0.0;
  for (double x : d)
    v_total += x * x * x, a_total += x * x;
  s.d32 = v_total / a_total;
  // Cumulative volume fraction; the quantile is the first diameter at which it reaches q (the
  // empirical distribution's inverse, no interpolation: exact for a single size).
  const double qs[3] = {0.1, 0.5, 0.9};
  double* out[3] = {&s.d10, &s.d50, &s.d90};
  double cum = 0.0;
  std::size_t next = 0;
  for (double x : d) {
    cum += x * x * x;
    while (next < 3 && cum >= qs[next] * v_total)
      *out[next++] = x;
  }
  while (next < 3)
    *out[next++] = d.back();
  return s;
}

} // namespace cfddem
