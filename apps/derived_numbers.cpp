#include "apps/derived_numbers.hpp"

#include <array>
#include <cmath>
#include <numbers>

#include <fmt/format.h>

#include "dem/contact_damping.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/granular_diagnostics.hpp"

namespace cfddem::apps {

namespace {

// Sums over the particles: solid volume and diameters.
std::array<double, 2> volume_and_diameters(const ParticleStore& p) {
  double vol = 0, dsum = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    vol += (4.0 / 3.0) * std::numbers::pi * std::pow(p.radius[i], 3);
    dsum += 2 * p.radius[i];
  }
  return {vol, dsum};
}

// The numbers from the particles' count, range, sums and granular temperature.
DerivedNumbers derive_from(const Scene& s, const dem::ParticleRange& range,
                           std::array<double, 2> sums, double temperature) {
  DerivedNumbers d;
  d.particles = static_cast<std::size_t>(range.count);
  const auto model = dem::make_step_model(s, range);
  if (range.count == 0) { // an empty scene still runs to run.end_time (with the scene's dt)
    d.dt = model.dt;
    d.steps = std::llround(s.run.end_time / d.dt);
    return d;
  }
  const double vol = sums[0], dsum = sums[1], mmin = range.m_min;
  d.mean_diameter = dsum / static_cast<double>(range.count);
  d.min_mass = mmin;
  d.dt = model.dt;
  d.tau_p = std::sqrt(mmin / std::max(s.dem.spring_constant, s.dem.wall_spring_constant));
  d.solid_fraction = vol / s.domain.volume();
  const double phi = d.solid_fraction;
  d.g0 = (1 - phi / 2) / std::pow(1 - phi, 3);
  d.granular_temperature = temperature;
  const double sqrtT = std::sqrt(temperature);
  // nu = (24/sqrt(pi)) phi g0 sqrt(T)/d ; 1/t_H = (4/sqrt(pi)) (1-e^2) phi g0 sqrt(T0)/d.
  d.collision_frequency = 24.0 / std::sqrt(std::numbers::pi) * phi * d.g0 * sqrtT / d.mean_diameter;
  const double e = s.dem.restitution;
  const double rate =
      4.0 / std::sqrt(std::numbers::pi) * (1 - e * e) * phi * d.g0 * sqrtT / d.mean_diameter;
  d.haff_time = rate > 0 ? 1.0 / rate : INFINITY;
  d.contact_duration = dem::contact_duration(s.dem.spring_constant, e, mmin / 2);
  d.dt_per_contact = d.contact_duration / d.dt;
  d.steps = std::llround(s.run.end_time / d.dt);
  return d;
}

} // namespace

DerivedNumbers derive(const Scene& s, const ParticleStore& p) {
  const double t =
      p.size() ? dem::measure({p.x, p.y, p.z, p.vx, p.vy, p.vz, p.mass}).granular_temperature : 0.0;
  DerivedNumbers d = derive_from(s, dem::particle_range(p), volume_and_diameters(p), t);
  d.sizes = size_statistics(p.radius);
  return d;
}

DerivedNumbers derive(const Scene& s, const ParticleStore& p, const Communicator& comm,
                      dem::ParticleRange* range_out) {
  dem::ParticleRange r = dem::particle_range(p);
  r.count = comm.sum(r.count);
  // Minima as maxima of the negatives (an empty rank holds +inf minima and 0 maxima).
  std::array<double, 4> ext = {-r.m_min, r.m_max, -r.r_min, r.r_max};
  comm.max(ext);
  r.m_min = -ext[0], r.m_max = ext[1], r.r_min = -ext[2], r.r_max = ext[3];
  std::array<double, 2> sums = volume_and_diameters(p);
  comm.sum(sums);
  const double t =
      dem::measure({p.x, p.y, p.z, p.vx, p.vy, p.vz, p.mass}, comm).granular_temperature;
  if (range_out)
    *range_out = r;
  return derive_from(s, r, sums, t);
}

std::vector<std::pair<std::string, std::string>> DerivedNumbers::table() const {
  std::vector<std::pair<std::string, std::string>> rows = {
      {"particles", fmt::format("{}", particles)},
      {"mean_diameter_m", fmt::format("{:.6g}", mean_diameter)},
      {"particle_mass_kg (lightest)", fmt::format("{:.6e}", min_mass)},
      {"tau_p_s = sqrt(m/k)", fmt::format("{:.6e}", tau_p)},
      {"dt_s", fmt::format("{:.6e}", dt)},
      {"steps", fmt::format("{}", steps)},
      {"solid_fraction", fmt::format("{:.6g}", solid_fraction)},
      {"g0 (Carnahan-Starling)", fmt::format("{:.6g}", g0)},
      {"granular_temperature_m2_s2", fmt::format("{:.6g}", granular_temperature)},
      {"collision_frequency_per_particle_1_s (Enskog)", fmt::format("{:.6g}", collision_frequency)},
      {"haff_time_s (no gas)", fmt::format("{:.6g}", haff_time)},
      {"contact_duration_s", fmt::format("{:.6e}", contact_duration)},
      {"steps_per_contact", fmt::format("{:.4g}", dt_per_contact)},
  };
  if (sizes.d_max > sizes.d_min) {
    rows.insert(rows.begin() + 2,
                {{"diameter_min_max_m", fmt::format("{:.6g} {:.6g}", sizes.d_min, sizes.d_max)},
                 {"d10_d50_d90_m (by volume)",
                  fmt::format("{:.6g} {:.6g} {:.6g}", sizes.d10, sizes.d50, sizes.d90)},
                 {"sauter_mean_d32_m", fmt::format("{:.6g}", sizes.d32)}});
  }
  return rows;
}

} // namespace cfddem::apps
