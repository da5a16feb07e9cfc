#include "dem/step_model.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <fmt/format.h>

#include "core/error.hpp"
#include "dem/contact_damping.hpp"

namespace cfddem::dem {

ParticleRange particle_range(const ParticleStore& p) {
  ParticleRange r;
  r.count = static_cast<std::int64_t>(p.size());
  r.m_min = r.r_min = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < p.size(); ++i) {
    r.m_min = std::min(r.m_min, p.mass[i]);
    r.m_max = std::max(r.m_max, p.mass[i]);
    r.r_min = std::min(r.r_min, p.radius[i]);
    r.r_max = std::max(r.r_max, p.radius[i]);
  }
  return r;
}

StepModel make_step_model(const Scene& s, const ParticleStore& p, const StepClock& clock) {
  return make_step_model(s, particle_range(p), clock);
}

StepModel make_step_model(const Scene& s, const ParticleRange& range, const StepClock& clock) {
  StepModel m;
  const auto& d = s.dem;
  m.gravity = s.gravity;
  m.pair = {d.spring_constant, dashpot_coefficient(d.spring_constant, d.restitution)};
  m.wall = {d.wall_spring_constant,
            dashpot_coefficient(d.wall_spring_constant, d.wall_restitution)};
  m.friction = d.friction > 0.0 || d.wall_friction > 0.0;
  m.pair_t = {d.tangential_stiffness_ratio * d.spring_constant,
              d.tangential_damping_ratio * m.pair.eta_coef, d.friction};
  m.wall_t = {d.tangential_stiffness_ratio * d.wall_spring_constant,
              d.tangential_damping_ratio * m.wall.eta_coef, d.wall_friction};
  m.max_overlap = d.max_overlap;
  const bool empty = range.count == 0;
  const double m_min = empty ? 1.0 : range.m_min;
  const double r_min = empty ? 1.0 : range.r_min, r_max = empty ? 1.0 : range.r_max;
  m.r_min = r_min;
  m.uniform_mass = !empty && range.m_min == range.m_max;
  m.uniform_radius = !empty && range.r_min == range.r_max;
  if (m.uniform_mass) {
    m.uniform_meff = 0.5 * range.m_min;
    m.uniform_eta = m.pair.eta_coef * std::sqrt(m.uniform_meff); // docs/theory.md §2: eta_n
  }
  const double k_max = std::max(d.spring_constant, d.wall_spring_constant);
  const double tau_p = std::sqrt(m_min / k_max);
  const bool fixed = clock.dt > 0.0 || d.dt > 0.0;
  m.dt = clock.dt > 0.0 ? clock.dt : d.dt > 0.0 ? d.dt : tau_p * d.dt_factor;
  m.interval = clock.interval > 0.0 ? clock.interval : d.regrid_interval;
  // Stiffest oscillator: two of the lightest particles (m_eff = m/2) or one against a wall.
  const double omega = std::max(std::sqrt(2.0 * d.spring_constant / m_min),
                                std::sqrt(d.wall_spring_constant / m_min));
  // Known before any step: a configuration error (exit 2), named by its keys.
  if (omega * m.dt >= 2.0)
    throw ConfigError(
        fixed ? "scene key 'dem.dt'" : "scene key 'dem.dt_factor'",
        fmt::format(
            "unstable time step: omega dt = {:.4g} >= 2 for the stiffest contact (dt = {:.4g} s, "
            "dem.dt_factor = {}, dem.dt = {}); velocity Verlet on a spring needs omega dt < 2, and "
            "accuracy needs far less (dem.dt_factor = 0.02 gives 0.028)",
            omega * m.dt, m.dt, d.dt_factor, d.dt));
  m.skin = d.neighbor_skin > 0 ? d.neighbor_skin : 0.5 * r_max; // 0.25 d_max (the peers' skin)
  return m;
}

} // namespace cfddem::dem
