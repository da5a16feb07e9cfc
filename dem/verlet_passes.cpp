#include "dem/verlet_passes.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include <fmt/format.h>

#include "dem/contact_damping.hpp"

namespace cfddem::dem {

std::string wall_passage(const ParticleStore& p, std::size_t i, const StepModel& m) {
  // As the overlap stop's words at a wall (describe_fault): the particle's own mass and radius.
  const double held = impact_speed_held(m.wall.k, p.mass[i], m.max_overlap * p.radius[i]);
  return fmt::format(
      ", at a speed of {:.3g} m/s: the wall's spring (dem.wall_spring_constant = {:g} N/m) stops "
      "an impact of this particle within dem.max_overlap = {:g} only below about {:.3g} m/s, and "
      "holds a load there only up to {:.3g} N; raise it, or lower the speeds or loads that drive "
      "the particle",
      std::hypot(p.vx[i], p.vy[i], p.vz[i]), m.wall.k, m.max_overlap, held,
      m.wall.k * m.max_overlap * p.radius[i]);
}

std::string describe_fault(const ParticleStore& p, const StepReport& r, const StepModel& m) {
  const std::uint32_t i = r.bad;
  const std::string who =
      fmt::format("particle {} at ({:.6g}, {:.6g}, {:.6g}) m", p.id[i], p.x[i], p.y[i], p.z[i]);
  std::string why;
  switch (r.fault) {
  case StepFault::nan:
    why = "position or velocity is not finite (NaN/inf): the step is unstable";
    break;
  case StepFault::overlap: {
    // The speed a head-on impact may have for the spring to stop it within the bound, with the
    // pair's m_eff and smaller radius, or the particle's own mass and radius at a wall.
    const bool wall = r.partner == kNoParticle;
    const std::uint32_t j = wall ? i : r.partner;
    const double m_eff = wall ? p.mass[i] : p.mass[i] * p.mass[j] / (p.mass[i] + p.mass[j]);
    const double radius = std::min(p.radius[i], p.radius[j]);
    const double k = wall ? m.wall.k : m.pair.k;
    const double held = impact_speed_held(k, m_eff, m.max_overlap * radius);
    const double dvx = p.vx[i] - (wall ? 0.0 : p.vx[j]), dvy = p.vy[i] - (wall ? 0.0 : p.vy[j]),
                 dvz = p.vz[i] - (wall ? 0.0 : p.vz[j]);
    const std::string what =
        wall ? fmt::format("overlap with a wall is {:.3g} of its radius", r.value)
             : fmt::format("overlap with particle {} is {:.3g} of the smaller radius",
                           p.id[r.partner], r.value);
    const double speed = std::sqrt(dvx * dvx + dvy * dvy + dvz * dvz);
    const char* key = wall ? "dem.wall_spring_constant" : "dem.spring_constant";
    // Slower than the spring holds: not an impact but a load pressing them together (a column
    // under a strong body force), which the spring holds within the bound up to k delta_max.
    const std::string cause =
        speed >= held
            ? fmt::format("the impact is too fast for the spring, which stops a head-on impact {} "
                          "within that overlap only below about {:.3g} m/s ({} = {:g} N/m; the "
                          "speed it holds grows as sqrt(k))",
                          wall ? "on the wall" : "of the two", held, key, k)
            : fmt::format("the spring is too soft for the load pressing {} together: it holds "
                          "at most k x the bound = {:.3g} N within that overlap ({} = {:g} N/m)",
                          wall ? "it and the wall" : "them", k * m.max_overlap * radius, key, k);
    why = fmt::format("{} (dem.max_overlap = {}), at a relative speed of {:.3g} m/s: {}: raise {}, "
                      "lower the speeds or loads that drive the contact, or, with dt near its "
                      "stability limit, lower dem.dt_factor",
                      what, m.max_overlap, speed, cause, key);
    break;
  }
  case StepFault::speed:
    why = fmt::format("speed {:.4g} m/s moves it more than the smallest radius in one step "
                      "(dt = {:.4g} s): contacts could be missed (tunnelling); a step that "
                      "follows it is below {:.3g} s (dem.dt_factor, or dem.dt; a fixed fluid.dt "
                      "bounds it too), or the speed comes from a setting to look at",
                      r.value, m.dt, m.r_min / r.value);
    break;
  case StepFault::left_domain:
    why = fmt::format("left the domain through a wall (coordinate {:.6g} m){}", r.value,
                      wall_passage(p, i, m));
    break;
  case StepFault::none:
    break;
  }
  return who + ": " + why;
}

} // namespace cfddem::dem
