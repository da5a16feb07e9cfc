#include "apps/derived_numbers.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>

#include <fmt/format.h>

#include "apps/particle_inlet.hpp"
#include "core/error.hpp"
#include "dem/contact_damping.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/granular_diagnostics.hpp"
#include "dem/verlet_list.hpp"
#include "fluid/drag_law.hpp"

namespace cfddem::apps {

namespace {

// Sums over the particles: solid volume, diameters and mass.
std::array<double, 3> particle_sums(const ParticleStore& p) {
  double vol = 0, dsum = 0, mass = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    vol += (4.0 / 3.0) * std::numbers::pi * std::pow(p.radius[i], 3);
    dsum += 2 * p.radius[i];
    mass += p.mass[i];
  }
  return {vol, dsum, mass};
}

// m / beta of a particle of mass m and radius r at eps_g = 1 and no slip; +inf without a drag.
double still_gas_drag_time(const Scene& s, fluid::DragLaw law, double m, double r) {
  const double beta = fluid::drag_beta(law, 1.0, 2.0 * r, 0.0, s.fluid.density, s.fluid.viscosity);
  return beta > 0.0 ? m / beta : std::numeric_limits<double>::infinity();
}

// The shortest of those over the particles (DerivedNumbers); +inf for none, or without a gas.
double still_gas_drag_time(const Scene& s, const ParticleStore& p) {
  double tau = std::numeric_limits<double>::infinity();
  if (!s.fluid.enabled)
    return tau;
  const fluid::DragLaw law = fluid::parse_drag_law(s.fluid.drag);
  for (std::size_t i = 0; i < p.size(); ++i)
    tau = std::min(tau, still_gas_drag_time(s, law, p.mass[i], p.radius[i]));
  return tau;
}

// The same for the smallest particle an inlet adds (inlet.mass_rate; its drag time is shortest:
// m / beta grows as rho d^2 in still gas); +inf for none.
double inlet_drag_time(const Scene& s, const ParticleInlet& in) {
  const double r = in.smallest_radius();
  if (!s.fluid.enabled || !(r > 0.0))
    return std::numeric_limits<double>::infinity();
  return still_gas_drag_time(s, fluid::parse_drag_law(s.fluid.drag),
                             ParticleStore::sphere_mass(s.inlet.density, r), r);
}

// The gas's drag on a particle is held over a fluid step with the particle's velocity frozen
// (forward Euler on its relaxation), which grows the slip every step once the step is twice the
// drag time m / beta. A fixed fluid.dt that long for a particle in still gas, the longest drag
// time it can have, can run no step right: refused, naming the keys. (A dense bed's drag times
// are shorter; the run stops on those, apps/coupled_step.cpp.)
void refuse_unstable_drag(const Scene& s, double tau, bool inlet) {
  const double dt_f = s.fluid.dt;
  if (!s.fluid.enabled || !(dt_f > 0.0) || dt_f < 2.0 * tau)
    return;
  throw ConfigError(
      "scene key 'fluid.dt'",
      fmt::format("{:g} s is {:.3g} times the shortest drag time m / beta of a particle in still "
                  "gas, {:.3g} s ({}; drag law \"{}\", fluid.viscosity = {:g} Pa s): the drag, "
                  "held over a fluid step with the particle's velocity frozen, reverses and grows "
                  "its slip every step beyond twice the drag time, and a bed's drag times are "
                  "shorter still; lower fluid.dt below {:.3g} s (a tenth of the drag time keeps "
                  "it accurate), set fluid.dt = 0 (adaptive: it follows the drag time), or check "
                  "fluid.viscosity, {}.diameter and {}.density",
                  dt_f, dt_f / tau, tau,
                  inlet ? "the smallest particle inlet.mass_rate adds"
                        : "the particles at the start",
                  s.fluid.drag, s.fluid.viscosity, 2.0 * tau, inlet ? "inlet" : "particles",
                  inlet ? "inlet" : "particles"));
}

// A step of 0 s (the lightest particle's mass, or dem.dt_factor, below what a double holds) can
// take no run anywhere: refused, naming the keys that made it.
void refuse_zero_step(const Scene& s, double dt, double m_min) {
  if (dt > 0.0 && std::isfinite(dt))
    return;
  if (!(m_min > 0.0))
    throw ConfigError(s.particles.file.empty()
                          ? "scene keys 'particles.diameter' and 'particles.density'"
                          : s.particles.file,
                      fmt::format("the lightest particle's mass is {:.3g} kg, so the particle "
                                  "step dt = dem.dt_factor x sqrt(m/k) is {:.3g} s: particles "
                                  "this small cannot be stepped in double precision",
                                  m_min, dt));
  throw ConfigError("scene key 'dem.dt_factor'",
                    fmt::format("{} makes the particle step dt = {:.3g} s: set dem.dt_factor "
                                "(0.02 is the paper's) or dem.dt",
                                s.dem.dt_factor, dt));
}

// Steps of `step` seconds to run.end_time, refused when a run cannot count them. `keys` names the
// keys that set the step, `what` the step.
void refuse_uncountable(const Scene& s, double step, const char* keys, const std::string& what,
                        const char* advice) {
  const double n = s.run.end_time / step;
  if (n <= kMaxCountableSteps)
    return;
  throw ConfigError(fmt::format("scene keys 'run.end_time' and {}", keys),
                    fmt::format("run.end_time = {:g} s in {} of {:.4g} s needs {:.3g} steps, "
                                "more than a run can count ({:.3g}); {} or shorten run.end_time",
                                s.run.end_time, what, step, n, kMaxCountableSteps, advice));
}

// Every step count of the run: particle steps of dt, sub-iterations of the adaptive schemes
// without a gas, fluid steps with one.
void refuse_uncountable_steps(const Scene& s, double dt) {
  const bool by_dt = s.dem.dt > 0.0;
  refuse_uncountable(s, dt, by_dt ? "'dem.dt'" : "'dem.dt_factor'",
                     by_dt ? "particle steps (dem.dt)"
                           : "particle steps (dt = dem.dt_factor x tau_p)",
                     by_dt ? "raise dem.dt" : "raise dem.dt_factor");
  if (s.dem.subiterated() && !s.fluid.enabled)
    refuse_uncountable(
        s, s.dem.regrid_interval / static_cast<double>(s.dem.nsubit), "'dem.regrid_interval'",
        "sub-iterations (dt_sp = dem.regrid_interval / dem.nsubit)", "raise dem.regrid_interval");
  if (s.fluid.enabled && s.fluid.dt > 0.0)
    refuse_uncountable(s, s.fluid.dt, "'fluid.dt'", "fluid steps", "raise fluid.dt");
  if (s.fluid.enabled && !(s.fluid.dt > 0.0))
    refuse_uncountable(s, s.fluid.max_dt, "'fluid.max_dt'", "fluid steps of at most fluid.max_dt",
                       "raise fluid.max_dt");
}

// A Verlet list holds one periodic image of a neighbour at most: a skin (dem.neighbor_skin = 10
// m) reaching past half a periodic axis stopped the run at its first list (exit 3). Known here.
void refuse_skin_beyond_box(const Scene& s, const dem::ParticleRange& r, double skin) {
  int axis = 0;
  if (r.count == 0 ||
      dem::VerletList::skin_fits(dem::DomainGeometry(s.domain), r.r_max, skin, &axis))
    return;
  const bool given = s.dem.neighbor_skin > 0.0;
  throw ConfigError(
      given ? "scene key 'dem.neighbor_skin'" : "scene key 'domain.hi'",
      fmt::format("periodic axis {} is {:.6g} m long, not more than twice the "
                  "neighbor cutoff plus skin, {:.6g} m (the largest diameter {:.6g} m "
                  "and two skins of {:.6g} m): {}",
                  axis, s.domain.length(axis), 2 * r.r_max + 2 * skin, 2 * r.r_max, skin,
                  given ? "lower dem.neighbor_skin or enlarge the domain" : "enlarge the domain"));
}

// A particle the inlet can never place waits at the head of its queue for the rest of the run,
// and every particle behind it too: a region outside the cylinder (or thinner than a particle
// beside a wall) entered nothing, silently. The largest particle that may enter must fit: the
// inlet's largest, and with inlet.recycle the largest of the run's own.
void refuse_inlet_without_room(const ParticleInlet& in, const dem::ParticleRange& r) {
  if (!in.on())
    return;
  const double largest = std::max(in.largest_radius(), in.recycles() ? r.r_max : 0.0);
  if (!(largest > 0.0))
    return;
  if (const std::string why = in.no_room(largest); !why.empty())
    throw ConfigError("scene keys 'inlet.region_lo', 'inlet.region_hi'",
                      fmt::format("no particle can enter: {}", why));
}

// The numbers from the particles' count, range, sums and granular temperature.
DerivedNumbers derive_from(const Scene& s, const dem::ParticleRange& range,
                           std::array<double, 3> sums, double temperature, double drag_time) {
  DerivedNumbers d;
  const ParticleInlet in(s); // the sizes it adds bound the drag time and the impact speeds
  const double inlet = inlet_drag_time(s, in);
  d.still_gas_drag_time = std::min(drag_time, inlet);
  d.particles = static_cast<std::size_t>(range.count);
  if (s.domain.cylinder())
    d.shape = fmt::format("cylinder along {}, radius {:.6g} m, cross-section {:.6g} m^2",
                          "xyz"[s.domain.cylinder_axis], s.domain.cylinder_radius,
                          s.domain.cylinder_area());
  const auto model = dem::make_step_model(s, range);
  refuse_zero_step(s, model.dt, range.count == 0 ? 1.0 : range.m_min);
  refuse_uncountable_steps(s, model.dt);
  refuse_skin_beyond_box(s, range, model.skin);
  refuse_unstable_drag(s, d.still_gas_drag_time, inlet < drag_time);
  refuse_inlet_without_room(in, range);
  // The speeds the springs stop within dem.max_overlap (dem::impact_speed_held): the largest
  // particles hold the least (max_overlap r sqrt(k / m_eff) falls as 1 / sqrt(rho r)); those at
  // the start and those an inlet adds. Two alike meet with m_eff = m / 2.
  const auto holds = [&](double r, double m) {
    if (!(r > 0.0) || !(m > 0.0))
      return;
    const double delta = model.max_overlap * r;
    d.impact_speed_held =
        std::min(d.impact_speed_held, dem::impact_speed_held(model.pair.k, 0.5 * m, delta));
    d.impact_speed_held_wall =
        std::min(d.impact_speed_held_wall, dem::impact_speed_held(model.wall.k, m, delta));
  };
  if (range.count > 0)
    holds(range.r_max, range.m_max);
  if (in.largest_radius() > 0.0)
    holds(in.largest_radius(), ParticleStore::sphere_mass(s.inlet.density, in.largest_radius()));
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
  d.solid_fraction = vol / s.domain.particle_volume();
  d.solid_density = sums[2] / vol;
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
  d.list_cutoff = 2.0 * range.r_max + model.skin;
  const double per_volume = static_cast<double>(range.count) / s.domain.particle_volume();
  d.listed_neighbors =
      std::min(static_cast<double>(range.count) - 1.0,
               per_volume * 4.0 / 3.0 * std::numbers::pi * std::pow(d.list_cutoff, 3));
  return d;
}

} // namespace

DerivedNumbers derive(const Scene& s, const ParticleStore& p) {
  const double t =
      p.size() ? dem::measure({p.x, p.y, p.z, p.vx, p.vy, p.vz, p.mass}).granular_temperature : 0.0;
  DerivedNumbers d =
      derive_from(s, dem::particle_range(p), particle_sums(p), t, still_gas_drag_time(s, p));
  d.sizes = size_statistics(p.radius);
  return d;
}

DerivedNumbers derive(const Scene& s, const ParticleStore& p, const Communicator& comm,
                      dem::ParticleRange* range_out) {
  dem::ParticleRange r = dem::particle_range(p);
  r.count = comm.sum(r.count);
  // Minima as maxima of the negatives (an empty rank holds +inf minima and 0 maxima).
  std::array<double, 5> ext = {-r.m_min, r.m_max, -r.r_min, r.r_max, -still_gas_drag_time(s, p)};
  comm.max(ext);
  r.m_min = -ext[0], r.m_max = ext[1], r.r_min = -ext[2], r.r_max = ext[3];
  std::array<double, 3> sums = particle_sums(p);
  comm.sum(sums);
  const double t =
      dem::measure({p.x, p.y, p.z, p.vx, p.vy, p.vz, p.mass}, comm).granular_temperature;
  if (range_out)
    *range_out = r;
  return derive_from(s, r, sums, t, -ext[4]);
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
  if (std::isfinite(impact_speed_held)) {
    rows.emplace_back("impact_speed_held_m_s (pair, dem.max_overlap)",
                      fmt::format("{:.4g}", impact_speed_held));
    rows.emplace_back("impact_speed_held_m_s (wall, dem.max_overlap)",
                      fmt::format("{:.4g}", impact_speed_held_wall));
  }
  if (!shape.empty())
    rows.insert(rows.begin(), {"domain_shape", shape});
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
