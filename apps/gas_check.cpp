#include "apps/gas_check.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <optional>
#include <string>

#include <fmt/format.h>
#include <unistd.h>

#include "apps/coupled_step.hpp"
#include "apps/particle_inlet.hpp"
#include "core/error.hpp"
#include "core/particle_store.hpp"
#include "fluid/fluid_step_rule.hpp"
#include "fluid/gas_solver.hpp"

namespace cfddem::apps {

namespace {

// A rough rate for the cost estimate: particle steps per second per thread, as measured for
// small explicit runs on the development machine (hcs_small: 5e6 on 2 threads). The estimate
// is an order of magnitude, stated as such.
constexpr double kParticleStepsPerSecond = 2.5e6;

// The gas cells of the grid's plane normal to axis `a` at cell index `at` (a column's
// staircase: its solid cells are left out).
std::int64_t gas_cells_on_plane(const fluid::MacGrid& grid, int a, int at) {
  const int p = a == 0 ? 1 : 0, q = a == 2 ? 1 : 2; // the plane's axes
  std::int64_t open = 0;
  for (int i = 0; i < grid.cells(p); ++i)
    for (int j = 0; j < grid.cells(q); ++j) {
      std::array<int, 3> cell{};
      cell[static_cast<std::size_t>(a)] = at;
      cell[static_cast<std::size_t>(p)] = i;
      cell[static_cast<std::size_t>(q)] = j;
      open += grid.solid_cell(cell[0], cell[1], cell[2]) ? 0 : 1;
    }
  return open;
}

// What drives the scene's gas: per axis its speed (the initial or the inflow velocity, whichever
// is larger) and the body force per unit mass it sees (gravity less the background pressure
// gradient over rho_g, fluid::background_pressure_gradient).
struct GasDrive {
  std::array<double, 3> speed{}, body{};
};
GasDrive gas_drive(const Scene& s) {
  const auto& f = s.fluid;
  GasDrive d;
  std::array<double, 3> length{};
  for (std::size_t a = 0; a < 3; ++a) {
    d.speed[a] = std::max(std::abs(f.velocity[a]), std::abs(f.inflow_velocity[a]));
    length[a] = s.domain.length(static_cast<int>(a));
  }
  const auto gp0 = fluid::background_pressure_gradient(s.domain.periodic, f.pressure_drop, length,
                                                       f.density, s.gravity);
  for (std::size_t a = 0; a < 3; ++a)
    d.body[a] = s.gravity[a] - gp0[a] / f.density;
  return d;
}

} // namespace

std::array<double, 3> cell_spacing(const Scene& s) {
  std::array<double, 3> dx{};
  for (std::size_t a = 0; a < 3; ++a)
    dx[a] = s.fluid.cell_size[a] > 0
                ? s.fluid.cell_size[a]
                : s.domain.length(static_cast<int>(a)) / static_cast<double>(s.fluid.cells[a]);
  return dx;
}

namespace {

// The gas sub-steps a fixed fluid step takes at per-axis gas speeds `speed` and fluid.cfl (the
// advective rate alone: the viscous number is bounded apart), and each sub-step's length.
struct GasSubsteps {
  double count, length;
};
// The viscous term counts in the gas's Courant rate where it is explicit throughout
// (fluid.implicit_viscosity = false; "auto" takes it implicit where that saves sub-steps).
bool explicit_viscosity(const Scene& s) {
  return !s.fluid.implicit_viscosity && !s.fluid.implicit_viscosity_auto;
}

GasSubsteps gas_substeps(const Scene& s, const std::array<double, 3>& speed) {
  const auto& f = s.fluid;
  const double length =
      fluid::courant_step(fluid::fluid_step_rates(speed, cell_spacing(s), f.viscosity / f.density,
                                                  explicit_viscosity(s), {0.0, 0.0, 0.0},
                                                  fluid::advection_named(f.advection)),
                          f.cfl);
  return {f.dt / length, length};
}

} // namespace

AdaptiveStart adaptive_start(const Scene& s, double drag_time) {
  const auto& f = s.fluid;
  const GasDrive drive = gas_drive(s);
  fluid::FluidStepCaps caps; // no previous step
  caps.max_dt = f.max_dt;
  caps.drag_time = drag_time;
  // The viscous rate only where the Laplacian is explicit, as the run's step rule takes it.
  const fluid::FluidStepRates rates = fluid::fluid_step_rates(
      drive.speed, cell_spacing(s), f.viscosity / f.density, explicit_viscosity(s), drive.body,
      fluid::advection_named(f.advection));
  AdaptiveStart out;
  out.first = fluid::next_fluid_step(rates, f.cfl, caps, s.run.end_time);
  out.steps = s.run.end_time / out.first;
  out.body = std::hypot(drive.body[0], drive.body[1], drive.body[2]);
  return out;
}

std::optional<std::string> adaptive_step_warning(const Scene& s) {
  if (!s.fluid.enabled || s.fluid.dt > 0.0)
    return std::nullopt;
  const AdaptiveStart start = adaptive_start(s);
  if (!(start.steps > kManyFluidSteps) || start.steps > kMaxCountableSteps)
    return std::nullopt; // the latter is refused (check_gas_numbers)
  return fmt::format("fluid.cfl = {:g} starts the adaptive fluid step at {:.3g} s at the scene's "
                     "gas speeds and body force: about {:.3g} fluid steps to run.end_time = {:g} s "
                     "if the gas keeps them",
                     s.fluid.cfl, start.first, start.steps, s.run.end_time);
}

std::optional<std::string> particle_driven_substeps_warning(const Scene& s) {
  const auto& f = s.fluid;
  if (!f.enabled || !(f.dt > 0.0) || s.particles.count == 0)
    return std::nullopt;
  // The particles drive the gas toward their velocities: their mean and, per axis, the thermal
  // speed sqrt(T) estimate what their drag gives a gas at rest (hcs_gas, at rest with particles
  // at T = 0.1 m^2/s^2, showed no progress line in 15 s at cfl 1e-6, nor in 40 s at 1e-9).
  const double thermal = std::sqrt(std::max(0.0, s.particles.temperature));
  std::array<double, 3> speed{};
  for (std::size_t a = 0; a < 3; ++a)
    speed[a] = std::abs(s.particles.velocity[a]) + thermal;
  const double substeps = gas_substeps(s, speed).count;
  if (!(substeps > fluid::kMaxSubstepsPerInterval))
    return std::nullopt;
  return fmt::format(
      "fluid.cfl = {:g}: once the particles (up to {:.3g} m/s along an axis) set "
      "the gas moving, it may take up to {:.3g} sub-steps in each fluid step of {:g} "
      "s, for which a run shows no progress; the gas step is stable up to cfl {:g}",
      f.cfl, *std::max_element(speed.begin(), speed.end()), substeps, f.dt,
      fluid::max_stable_courant(fluid::advection_named(f.advection)));
}

double gas_memory_bytes(const Scene& s) {
  const auto& c = s.fluid.cells;
  return static_cast<double>(c[0]) * static_cast<double>(c[1]) * static_cast<double>(c[2]) *
         kGasBytesPerCell;
}

void check_gas_memory(const Scene& s, int ranks) {
  if (!s.fluid.enabled)
    return;
  const double memory = static_cast<double>(::sysconf(_SC_PHYS_PAGES)) *
                        static_cast<double>(::sysconf(_SC_PAGE_SIZE));
  const double share = gas_memory_bytes(s) / static_cast<double>(std::max(ranks, 1));
  if (memory > 0 && share > memory)
    throw ConfigError(
        "scene key 'fluid.cells'",
        fmt::format("[{}, {}, {}] cells need about {:.3g} GB for the gas ({:.3g} KB a cell){}, "
                    "more than this machine's {:.3g} GB of memory: use fewer cells{}",
                    s.fluid.cells[0], s.fluid.cells[1], s.fluid.cells[2], gas_memory_bytes(s) / 1e9,
                    kGasBytesPerCell / 1e3,
                    ranks > 1 ? fmt::format(", {:.3g} GB on each of {} ranks", share / 1e9, ranks)
                              : std::string(),
                    memory / 1e9, ranks > 1 ? "" : ", or more ranks on more machines"));
}

void check_gas_numbers(const Scene& s) {
  const auto& f = s.fluid;
  if (!f.enabled)
    return;
  const std::array<double, 3> spacing = cell_spacing(s);
  const double dx = *std::min_element(spacing.begin(), spacing.end());
  const GasDrive drive = gas_drive(s);
  const double speed = *std::max_element(drive.speed.begin(), drive.speed.end());
  const double dt_f = f.dt > 0.0 ? f.dt : f.max_dt;
  const char* step = f.dt > 0.0 ? "fluid.dt" : "fluid.max_dt";
  const auto advection = fluid::advection_named(f.advection);
  if (f.dt > 0.0) {
    // A fixed fluid step: the gas takes sub-steps in it at the scene's gas speeds, or at the
    // speed the body force gives a gas at rest in one fluid step where that is more (the riser
    // starts at rest); the advective rate alone (the viscous number is bounded below).
    const double courant = speed * f.dt / dx;
    if (courant > kMaxCourantPerFluidStep)
      throw ConfigError(
          "scene keys 'fluid.velocity' and 'fluid.inflow_velocity'",
          fmt::format("a gas speed of {:.3g} m/s crosses {:.3g} cells of {:.3g} m in a fluid step "
                      "of {:.3g} s (fluid.dt): the gas would take {:.3g} sub-steps (at fluid.cfl "
                      "= {:g}) every fluid step, beyond the Courant number {:g} a run can take; "
                      "lower the velocity or fluid.dt",
                      speed, courant, dx, f.dt, courant / f.cfl, f.cfl, kMaxCourantPerFluidStep));
    std::array<double, 3> axis_speed{};
    for (std::size_t a = 0; a < 3; ++a)
      axis_speed[a] = std::max(drive.speed[a], std::abs(drive.body[a]) * f.dt);
    const auto [substeps, substep] = gas_substeps(s, axis_speed);
    if (substeps > fluid::kMaxSubstepsPerInterval)
      throw ConfigError(
          "scene key 'fluid.cfl'",
          fmt::format("{:g} makes the gas take {:.3g} sub-steps of {:.3g} s in every fluid step of "
                      "{:g} s (fluid.dt) at the gas speed of {:.3g} m/s{} on cells of {:.3g} m, "
                      "beyond the {:g} a run can take; raise fluid.cfl (the gas step is stable up "
                      "to {:g})",
                      f.cfl, substeps, substep, f.dt,
                      *std::max_element(axis_speed.begin(), axis_speed.end()),
                      explicit_viscosity(s)
                          ? fmt::format(" with the viscous term explicit (nu = {:.3g} m^2/s)",
                                        f.viscosity / f.density)
                          : std::string(),
                      dx, fluid::kMaxSubstepsPerInterval, fluid::max_stable_courant(advection)));
  } else {
    // An adaptive fluid step takes no sub-steps: the step rule shortens it to the gas's Courant
    // number, however long fluid.max_dt is. Refused only where a run could not count its steps
    // at its first length; a merely long run warns (adaptive_step_warning).
    const AdaptiveStart start = adaptive_start(s);
    if (start.steps > kMaxCountableSteps)
      throw ConfigError(
          "scene keys 'fluid.cfl', 'fluid.velocity' and 'fluid.inflow_velocity'",
          fmt::format("the adaptive fluid step starts at {:.3g} s (fluid.cfl = {:g}, a gas speed "
                      "of {:.3g} m/s and a body force of {:.3g} m/s^2 on cells of {:.3g} m): "
                      "run.end_time = {:g} s needs {:.3g} such steps, more than a run can count "
                      "({:.3g}); lower the velocity or raise fluid.cfl",
                      start.first, f.cfl, speed, start.body, dx, s.run.end_time, start.steps,
                      kMaxCountableSteps));
  }
  const double nu = f.viscosity / f.density;
  const double viscous = nu * dt_f / (dx * dx);
  if (viscous > kMaxViscousNumber)
    throw ConfigError(
        "scene keys 'fluid.viscosity' and 'fluid.density'",
        fmt::format("the kinematic viscosity mu / rho_g = {:.3g} m^2/s makes the viscous number "
                    "nu dt_f / dx^2 = {:.3g} in a fluid step of {:.3g} s ({}) on cells of {:.3g} "
                    "m, beyond the {:g} at which the gas's solves stop converging; raise "
                    "fluid.density, lower fluid.viscosity or {}, or use coarser cells",
                    nu, viscous, dt_f, step, dx, kMaxViscousNumber, step));
}

double minimum_fluidization_velocity(double d, double rho_p, double rho_g, double mu, double g) {
  const double ar = d * d * d * rho_g * (rho_p - rho_g) * g / (mu * mu);
  const double re = std::sqrt(33.7 * 33.7 + 0.0408 * ar) - 33.7;
  return re * mu / (rho_g * d);
}

GasCheck check_gas(const Scene& s, const DerivedNumbers& derived) {
  GasCheck out;
  const auto& f = s.fluid;
  auto& t = out.table;
  const std::array<double, 3> dx = cell_spacing(s);
  const double cells = static_cast<double>(f.cells[0] * f.cells[1] * f.cells[2]);
  t.emplace_back("gas_cells", fmt::format("{:.0f}", cells));
  t.emplace_back("cell_size_m", fmt::format("[{:.4g}, {:.4g}, {:.4g}]", dx[0], dx[1], dx[2]));
  const fluid::MacGrid grid(fluid_grid_spec(s)); // its gas cells (a column's solid ones)
  if (s.domain.cylinder()) {
    // The gas's column is the staircase of cells whose centre lies inside R (docs/theory.md
    // §13): its cross-section against pi R^2 is the wall's error at this resolution. Counted on
    // the first plane across the axis by the grid's own test (every plane is the same).
    const auto [u, w] = s.domain.cross_axes();
    const std::int64_t inside = gas_cells_on_plane(grid, s.domain.cylinder_axis, 0);
    const double area = static_cast<double>(inside) * dx[static_cast<std::size_t>(u)] *
                        dx[static_cast<std::size_t>(w)];
    // The gas's column and the particles' differ by the staircase: its area sets the gas's
    // superficial velocity and the pressure drop a bed's weight makes.
    if (std::abs(area / s.domain.cylinder_area() - 1.0) > 0.05)
      out.warnings.push_back(fmt::format(
          "the gas's column is a staircase of {} whole cells whose area is {:.3f} pi R^2: the gas "
          "sees a column {:+.1f}% off in area (the particles see pi R^2); use more cells across "
          "the diameter",
          inside, area / s.domain.cylinder_area(),
          100.0 * (area / s.domain.cylinder_area() - 1.0)));
    t.emplace_back("gas_column (staircase of whole cells)",
                   fmt::format("{} of {} cells across, area {:.4f} pi R^2", inside,
                               f.cells[static_cast<std::size_t>(u)] *
                                   f.cells[static_cast<std::size_t>(w)],
                               area / s.domain.cylinder_area()));
  }
  t.emplace_back("gas_memory_gb (estimate, all ranks)",
                 fmt::format("{:.3g}", gas_memory_bytes(s) / 1e9));
  const double d = derived.mean_diameter;
  if (d > 0) {
    const double ratio = *std::min_element(dx.begin(), dx.end()) / d;
    t.emplace_back("cell_size / particle diameter (smallest)", fmt::format("{:.3g}", ratio));
    // Below 1 by more than rounding: elutriation's 0.8 mm / 8 cells is its 0.1 mm particle.
    if (ratio < 1.0 - 1e-9 && f.deposition == "trilinear")
      out.warnings.push_back(fmt::format(
          "a gas cell ({:.3g} m) is narrower than a particle ({:.3g} m) and fluid.deposition = "
          "\"trilinear\" puts each particle's volume in the 8 cells around its centre: the solid "
          "fraction of a cell can exceed what is physical; use fluid.deposition = \"dpvm\" or "
          "coarser cells",
          *std::min_element(dx.begin(), dx.end()), d));
  }
  const double end = s.run.end_time;
  double fluid_steps = 0;
  if (f.dt > 0) {
    fluid_steps = std::ceil(end / f.dt * (1 - 1e-12));
    t.emplace_back("fluid_steps", fmt::format("{:.0f} (fluid.dt = {:g} s)", fluid_steps, f.dt));
    if (derived.particles > 0 && std::isfinite(derived.still_gas_drag_time))
      t.emplace_back("drag_time_s (shortest, still gas)",
                     fmt::format("{:.4g} (fluid.dt is {:.3g} of it; stable below 2)",
                                 derived.still_gas_drag_time, f.dt / derived.still_gas_drag_time));
    if (s.dem.subiterated())
      t.emplace_back("dt_sp_s", s.dem.nsubit_auto
                                    ? fmt::format("fluid.dt / m, m chosen per fluid step "
                                                  "(dem.nsubit = \"auto\", starting at {})",
                                                  s.dem.nsubit)
                                    : fmt::format("{:.4g} (fluid.dt / dem.nsubit = {})",
                                                  f.dt / static_cast<double>(s.dem.nsubit),
                                                  s.dem.nsubit));
  } else {
    // The adaptive dt_f's range (fluid/fluid_step_rule.hpp): its first step from the initial
    // and inflow gas velocities and the body force, its cap from fluid.max_dt and the still-gas
    // drag time of the lightest particle (a dense bed's drag time is shorter: the run takes it from
    // the drag law at each fluid step).
    const double drag_time = derived.particles > 0 ? derived.still_gas_drag_time
                                                   : std::numeric_limits<double>::infinity();
    const double first = adaptive_start(s, drag_time).first;
    const double cap = std::min(f.max_dt, fluid::kDragStepFraction * drag_time);
    fluid_steps = std::ceil(end / cap * (1 - 1e-12));
    t.emplace_back(
        "fluid_dt_s (adaptive)",
        fmt::format("first {:.3g}, growing at most {:g}x per step up to {:.3g} (fluid.max_dt "
                    "{:g} s; {:g} of the still-gas drag time {:.3g} s); below it where the gas's "
                    "Courant number (cfl {:g}) asks",
                    first, fluid::kMaxFluidStepGrowth, cap, f.max_dt, fluid::kDragStepFraction,
                    drag_time, f.cfl));
    t.emplace_back("fluid_steps", fmt::format("at least {:.0f} (adaptive)", fluid_steps));
    if (s.dem.subiterated())
      t.emplace_back("dt_sp_s (adaptive)",
                     s.dem.nsubit_auto
                         ? fmt::format("the length dem.nsubit = \"auto\" chooses for the first "
                                       "fluid step (starting at 1/{} of it), kept over the others",
                                       s.dem.nsubit)
                         : fmt::format("each fluid step / dem.nsubit = {}: first {:.3g}, at most "
                                       "{:.3g}",
                                       s.dem.nsubit, first / static_cast<double>(s.dem.nsubit),
                                       cap / static_cast<double>(s.dem.nsubit)));
  }
  // A bed: particles under gravity along a walled axis.
  int axis = 0;
  for (int a = 1; a < 3; ++a)
    if (std::abs(s.gravity[static_cast<std::size_t>(a)]) >
        std::abs(s.gravity[static_cast<std::size_t>(axis)]))
      axis = a;
  const double g = std::abs(s.gravity[static_cast<std::size_t>(axis)]);
  if (derived.particles > 0 && g > 0 && !s.domain.periodic[static_cast<std::size_t>(axis)] &&
      f.viscosity > 0) {
    // The material's density and, for a size distribution, the Sauter mean d32: the diameter
    // with the bed's volume-to-surface ratio, which sets its drag (Kunii & Levenspiel 1991,
    // ch. 3). The lightest particle's mass over the mean diameter's volume put U_mf of a
    // polydisperse bed 5x low (a density of 222 kg/m^3 for 2500).
    const double d_mf = derived.sizes.d32 > 0 ? derived.sizes.d32 : d;
    const char* name = derived.sizes.d_max > derived.sizes.d_min
                           ? "minimum_fluidization_velocity_m_s (Wen & Yu, d32)"
                           : "minimum_fluidization_velocity_m_s (Wen & Yu)";
    if (derived.solid_density <= f.density) {
      // No bed to fluidize: Wen & Yu's Archimedes number is <= 0 (it gave a negative U_mf and
      // an inflow of -1e4 U_mf for particles of 0.5 kg/m^3 in the bed's gas).
      t.emplace_back(name, fmt::format("none: the particles ({:.4g} kg/m^3) are no denser than "
                                       "the gas ({:.4g} kg/m^3)",
                                       derived.solid_density, f.density));
    } else {
      const double umf =
          minimum_fluidization_velocity(d_mf, derived.solid_density, f.density, f.viscosity, g);
      t.emplace_back(name, fmt::format("{:.4g}", umf));
      const double u_in = std::abs(f.inflow_velocity[static_cast<std::size_t>(axis)]);
      if (u_in > 0)
        t.emplace_back("inflow_velocity / U_mf", fmt::format("{:.3g}", u_in / umf));
    }
  }
  // The gas entering through inflow faces: u_in over the face's open area, the faces of its gas
  // cells (in a column, the staircase: docs/theory.md §13).
  {
    static constexpr const char* kFaceNames[] = {"x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi"};
    std::string rates;
    for (std::size_t k = 0; k < 6; ++k) {
      if (f.bc[k] != "inflow")
        continue;
      const int a = static_cast<int>(k / 2);
      const std::int64_t open = gas_cells_on_plane(grid, a, k % 2 == 0 ? 0 : grid.cells(a) - 1);
      const double area = static_cast<double>(open) * grid.spacing(a == 0 ? 1 : 0) *
                          grid.spacing(a == 2 ? 1 : 2);
      const double q = std::abs(f.inflow_velocity[static_cast<std::size_t>(a)]) * area;
      rates += fmt::format("{}{}: {:.4g} m^3/s, {:.4g} kg/s", rates.empty() ? "" : "; ",
                           kFaceNames[k], q, q * f.density);
    }
    if (!rates.empty())
      t.emplace_back("gas_inflow (volume, mass per second)", rates);
  }
  // Particles at the outflow faces (apps/particle_outflow.hpp).
  {
    static constexpr const char* kFaces[] = {"x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi"};
    std::string faces;
    for (std::size_t k = 0; k < 6; ++k)
      if (f.bc[k] == "outflow")
        faces += (faces.empty() ? "" : ", ") + std::string(kFaces[k]);
    if (!faces.empty())
      t.emplace_back("particles_at_outflow_faces",
                     s.particles.outflow == "remove"
                         ? fmt::format("removed at {} when they would reach the face within the "
                                       "next fluid step (docs/theory.md §12)",
                                       faces)
                         : fmt::format("held back by a wall at {} (particles.outflow = \"wall\")",
                                       faces));
  }
  // The inlet (apps/particle_inlet.hpp): what it adds.
  if (s.inlet.enabled()) {
    std::string what = s.inlet.recycle ? "the particles that leave enter again" : "";
    if (s.inlet.mass_rate > 0.0) {
      const double d_in = ParticleInlet(s).mean_diameter();
      const double m = ParticleStore::sphere_mass(s.inlet.density, 0.5 * d_in);
      what += fmt::format("{}{:.4g} kg/s of new particles ({:.4g} per second of {:.3g} m; {:.3g} "
                          "per fluid step of {:.3g} s)",
                          what.empty() ? "" : "; and ", s.inlet.mass_rate, s.inlet.mass_rate / m,
                          d_in, s.inlet.mass_rate / m * f.dt, f.dt);
    }
    t.emplace_back("particles_entering (inlet)",
                   fmt::format("{}, placed where they fit in [{:.4g}, {:.4g}] x [{:.4g}, {:.4g}] "
                               "x [{:.4g}, {:.4g}] m (docs/theory.md §12)",
                               what, s.inlet.region_lo[0], s.inlet.region_hi[0],
                               s.inlet.region_lo[1], s.inlet.region_hi[1], s.inlet.region_lo[2],
                               s.inlet.region_hi[2]));
  }
  // Cost: a cell step is partition.cell_weight particle steps (measured on hcs_gas).
  const double sub = derived.dt > 0 && f.dt > 0 ? std::max(1.0, std::ceil(f.dt / derived.dt))
                                                : 1.0;
  const double per_step = cells * s.partition.cell_weight +
                          static_cast<double>(derived.particles) * sub;
  t.emplace_back("cost_per_fluid_step (particle-step equivalents)", fmt::format("{:.3g}", per_step));
  t.emplace_back("cost_of_run_s (rough, one thread)",
                 fmt::format("{:.2g} (at {:.1e} particle-steps/s)",
                             per_step * fluid_steps / kParticleStepsPerSecond,
                             kParticleStepsPerSecond));
  return out;
}

} // namespace cfddem::apps
