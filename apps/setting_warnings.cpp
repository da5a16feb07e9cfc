#include "apps/setting_warnings.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include <fmt/format.h>

#include "apps/gas_check.hpp"
#include "core/initial_conditions.hpp"

namespace cfddem::apps {

std::vector<std::string> setting_warnings(const Scene& s) {
  std::vector<std::string> w;
  const double end = s.run.end_time;
  const auto files = [&](double interval, const char* key, const char* what) {
    if (interval > 0.0 && end / interval > kManyFiles)
      w.push_back(fmt::format("{} = {:g} s writes up to {:.3g} {} files over run.end_time = {:g} s "
                              "(one per particle step at most)",
                              key, interval, end / interval, what, end));
  };
  files(s.output.snapshot_interval, "output.snapshot_interval", "snapshot");
  files(s.output.checkpoint_interval, "output.checkpoint_interval", "checkpoint");
  if (s.dem.dt > 0.0 && end / s.dem.dt > kManySteps)
    w.push_back(fmt::format("dem.dt = {:g} s makes {:.3g} steps to run.end_time = {:g} s: even "
                            "at 1e8 particle-steps/s that is {:.3g} years for one particle",
                            s.dem.dt, end / s.dem.dt, end,
                            end / s.dem.dt / 1e8 / (365.25 * 24 * 3600)));
  if (const auto adaptive = adaptive_step_warning(s))
    w.push_back(*adaptive);
  if (const auto driven = particle_driven_substeps_warning(s))
    w.push_back(*driven);
  if (s.fluid.enabled) {
    const std::array<double, 3> dx = cell_spacing(s);
    const auto [shortest, longest] = std::minmax({dx[0], dx[1], dx[2]});
    if (longest > kElongatedCells * shortest)
      w.push_back(
          fmt::format("fluid.cells makes gas cells of [{:.3g}, {:.3g}, {:.3g}] m, the "
                      "longest side {:.3g}x the shortest: the pressure solve may stop short "
                      "of fluid.tolerance (the bed's column did from 1250:1 on); cells "
                      "nearer cubes avoid it",
                      dx[0], dx[1], dx[2], longest / shortest));
  }
  // Sub-iterated schemes write rows at whole sub-iterations of dt_sp: the interval they divide is
  // the fixed fluid step with a gas, the regrid interval without. An adaptive fluid step's length
  // is not known before the run: no warning then, as for a fine nsubit (step_warnings). (It used
  // dem.regrid_interval, which a run with a gas never divides.)
  const bool adaptive_gas = s.fluid.enabled && !(s.fluid.dt > 0);
  if (s.dem.subiterated() && !adaptive_gas) {
    const double interval = s.fluid.enabled ? s.fluid.dt : s.dem.regrid_interval;
    const double dt_sp = interval / static_cast<double>(s.dem.nsubit);
    if (s.output.interval < dt_sp * (1 - 1e-12))
      w.push_back(fmt::format("output.interval = {:g} s is shorter than the sub-iteration step "
                              "dt_sp = {:g} s of dem.scheme = \"{}\": rows come every dt_sp "
                              "instead",
                              s.output.interval, dt_sp, s.dem.scheme));
  }
  return w;
}

std::vector<std::string> step_warnings(const Scene& s, const DerivedNumbers& d) {
  std::vector<std::string> w;
  const bool by_dt = s.dem.dt > 0.0;
  const std::string step =
      by_dt ? fmt::format("dem.dt = {:g} s", s.dem.dt)
            : fmt::format("dem.dt_factor = {:g} (dt = {:.4g} s)", s.dem.dt_factor, d.dt);
  if (d.particles > 0 && d.dt_per_contact < kFewStepsPerContact)
    w.push_back(fmt::format("{} resolves a contact of {:.3g} s in {:.3g} steps: below {:g} a "
                            "contact gains or loses energy it should not (the default "
                            "dem.dt_factor = 0.02 gives about 110)",
                            step, d.contact_duration, d.dt_per_contact, kFewStepsPerContact));
  // A fixed nsubit whose sub-iteration step dt_sp is shorter than the particle step: every
  // particle then steps at dt_sp, finer than any contact needs (a typed 1e9 made 1e9 passes a
  // fluid step of 1e-13 s each). The interval is the fixed fluid step or the regrid interval
  // (an adaptive fluid step's length is not known before the run). A scene without particles at
  // the start has no particle step to compare with (it read "nsubit up to 0").
  if (s.dem.subiterated() && !s.dem.nsubit_auto && d.particles > 0) {
    const bool gas_sets = s.fluid.enabled;
    const double interval = gas_sets ? s.fluid.dt : s.dem.regrid_interval;
    const double dt_sp = interval / static_cast<double>(s.dem.nsubit);
    if (interval > 0.0 && dt_sp < d.dt * (1.0 - 1e-12))
      w.push_back(fmt::format(
          "dem.nsubit = {} makes the sub-iteration step dt_sp = {:.3g} s ({} / nsubit) shorter "
          "than the particle step dt = {:.3g} s: every particle steps {:.3g}x as often as in the "
          "explicit scheme, finer than any contact needs (nsubit up to {:.0f} keeps dt_sp >= dt)",
          s.dem.nsubit, dt_sp, gas_sets ? "fluid.dt" : "dem.regrid_interval", d.dt, d.dt / dt_sp,
          std::floor(interval / d.dt * (1.0 + 1e-12))));
  }
  if (s.dem.neighbor_skin > 0.0 && d.listed_neighbors > kManyListedNeighbors)
    w.push_back(fmt::format(
        "dem.neighbor_skin = {:g} m lists about {:.3g} neighbours per particle (those within "
        "{:.3g} m, the largest diameter plus the skin, of {} particles in all), and every pair "
        "pass evaluates each of them: the default, a quarter of the largest diameter, lists a few",
        s.dem.neighbor_skin, d.listed_neighbors, d.list_cutoff, d.particles));
  // Speeds the scene gives that the springs cannot stop within dem.max_overlap: the initial
  // velocity toward a wall (every particle hits it at once: the run stops at the first impact),
  // and an inlet's into the particles already there.
  // head: what moves at what speed and which spring stops it; held: the speed it stops.
  const auto too_fast = [&](const std::string& head, double held, const char* impact,
                            const char* key) {
    w.push_back(fmt::format("{} within dem.max_overlap = {:g} only below {:.3g} m/s, and the run "
                            "stops at the first faster impact{} (exit 3); raise {} (the speed it "
                            "holds grows as sqrt(k)) or lower the velocity",
                            head, s.dem.max_overlap, held, impact, key));
  };
  const auto& v0 = s.particles.velocity;
  const double speed0 = std::hypot(v0[0], v0[1], v0[2]);
  bool toward_wall = false;
  for (std::size_t a = 0; a < 3; ++a)
    toward_wall = toward_wall || (v0[a] != 0.0 && !s.domain.periodic[a]);
  if (d.particles > 0 && toward_wall && speed0 > d.impact_speed_held_wall)
    too_fast(fmt::format("particles.velocity moves the particles at {:.3g} m/s toward a wall: the "
                         "wall's spring stops the largest of them",
                         speed0),
             d.impact_speed_held_wall, "", "dem.wall_spring_constant");
  const auto& vi = s.inlet.velocity;
  const double speed_in = std::hypot(vi[0], vi[1], vi[2]);
  if (s.inlet.enabled() && speed_in > d.impact_speed_held)
    too_fast(fmt::format("inlet.velocity = {:.3g} m/s: the spring stops a head-on impact of two "
                         "of the largest particles",
                         speed_in),
             d.impact_speed_held, " of an entering particle", "dem.spring_constant");
  // An inlet asked for more mass per fluid step than its region holds: random placement
  // saturates near 38% solids (kRandomSequentialLimit), so the rest waits, and the run falls
  // further behind every step (a region in the bed's packing placed 21% of its due).
  if (s.inlet.mass_rate > 0.0 && s.fluid.enabled && s.fluid.dt > 0.0) {
    double volume = 1.0;
    for (int a = 0; a < 3; ++a)
      volume *= s.inlet.region_hi[a] - s.inlet.region_lo[a];
    const double density = s.inlet.density; // resolved by the parser
    const double holds = kRandomSequentialLimit * volume * density;
    const double due = s.inlet.mass_rate * s.fluid.dt;
    if (density > 0.0 && due > holds)
      w.push_back(fmt::format(
          "inlet.mass_rate = {:g} kg/s brings {:.3g} kg in each fluid step of {:g} s, more than "
          "the inlet region holds at random packing ({:.3g} kg: {:.0f}% of its {:.3g} m^3): the "
          "rest waits, and the run reports what waits at its end (run.json \"inlet\")",
          s.inlet.mass_rate, due, s.fluid.dt, holds, 100.0 * kRandomSequentialLimit, volume));
  }
  // A fixed fluid step longer than a particle's drag time in still gas (twice it is refused,
  // derived_numbers.cpp): the drag held over the step overshoots, reversing the slip each step.
  if (s.fluid.enabled && s.fluid.dt > 0.0 && s.fluid.dt > d.still_gas_drag_time)
    w.push_back(fmt::format(
        "fluid.dt = {:g} s is {:.3g} times the shortest drag time m / beta of a particle in "
        "still gas, {:.3g} s: the drag, held over a fluid step with the particle's velocity "
        "frozen, overshoots (each step reverses the slip; beyond twice the drag time it would "
        "grow); a tenth of the drag time keeps it accurate, or fluid.dt = 0 follows it",
        s.fluid.dt, s.fluid.dt / d.still_gas_drag_time, d.still_gas_drag_time));
  // dem.dt's step count is known from the scene alone (setting_warnings).
  const double steps = s.run.end_time / d.dt;
  if (!by_dt && steps > kManySteps)
    w.push_back(fmt::format("{} makes {:.3g} steps to run.end_time = {:g} s: even at 1e8 "
                            "particle-steps/s that is {:.3g} years for one particle",
                            step, steps, s.run.end_time, steps / 1e8 / (365.25 * 24 * 3600)));
  return w;
}

} // namespace cfddem::apps
