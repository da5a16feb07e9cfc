#include "apps/derived_numbers.hpp"

#include <cmath>
#include <numbers>

#include <fmt/format.h>

#include "dem/contact_damping.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/granular_diagnostics.hpp"

namespace cfddem::apps {

DerivedNumbers derive(const Scene& s, const ParticleStore& p) {
  DerivedNumbers d;
  d.particles = p.size();
  if (p.size() == 0) { // an empty scene still runs to run.end_time (with the scene's dt)
    d.dt = dem::make_step_model(s, p).dt;
    d.steps = std::llround(s.run.end_time / d.dt);
    return d;
  }
  const auto model = dem::make_step_model(s, p);
  double vol = 0, dsum = 0, mmin = INFINITY;
  for (std::size_t i = 0; i < p.size(); ++i) {
    vol += (4.0 / 3.0) * std::numbers::pi * std::pow(p.radius[i], 3);
    dsum += 2 * p.radius[i];
    mmin = std::min(mmin, p.mass[i]);
  }
  d.mean_diameter = dsum / p.size();
  d.min_mass = mmin;
  d.dt = model.dt;
  d.tau_p = std::sqrt(mmin / std::max(s.dem.spring_constant, s.dem.wall_spring_constant));
  d.solid_fraction = vol / s.domain.volume();
  const double phi = d.solid_fraction;
  d.g0 = (1 - phi / 2) / std::pow(1 - phi, 3);
  const auto st = dem::measure({p.x, p.y, p.z, p.vx, p.vy, p.vz, p.mass});
  d.granular_temperature = st.granular_temperature;
  const double sqrtT = std::sqrt(st.granular_temperature);
  // nu = (24/sqrt(pi)) phi g0 sqrt(T)/d ; 1/t_H = (4/sqrt(pi)) (1-e^2) phi g0 sqrt(T0)/d.
  d.collision_frequency = 24.0 / std::sqrt(std::numbers::pi) * phi * d.g0 * sqrtT / d.mean_diameter;
  const double e = s.dem.restitution;
  const double rate = 4.0 / std::sqrt(std::numbers::pi) * (1 - e * e) * phi * d.g0 * sqrtT /
                      d.mean_diameter;
  d.haff_time = rate > 0 ? 1.0 / rate : INFINITY;
  d.contact_duration = dem::contact_duration(s.dem.spring_constant, e, mmin / 2);
  d.dt_per_contact = d.contact_duration / d.dt;
  d.steps = std::llround(s.run.end_time / d.dt);
  return d;
}

std::vector<std::pair<std::string, std::string>> DerivedNumbers::table() const {
  return {
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
}

} // namespace cfddem::apps
