// What `cfddem check` says about the gas of a scene: cells per particle diameter, the fluid steps
// to run.end_time, the minimum fluidization velocity of a bed (Wen & Yu), and a rough cost per
// fluid step and for the run; with warnings where a setting is almost surely a mistake.
#pragma once

#include <array>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "apps/derived_numbers.hpp"
#include "core/scene.hpp"
#include "fluid/fluid_step_rule.hpp"

namespace cfddem::apps {

struct GasCheck {
  std::vector<std::pair<std::string, std::string>> table;
  std::vector<std::string> warnings;
};

// The gas cells' spacing per axis: fluid.cell_size, or the domain's extent over fluid.cells.
std::array<double, 3> cell_spacing(const Scene& scene);

// An adaptive fluid step's first length at the scene's gas speeds and body force (the step rule
// of fluid/fluid_step_rule.hpp, capped by fluid.max_dt and a tenth of `drag_time`, the particles'
// shortest drag time), the steps to run.end_time at that length, and the body force's magnitude
// [m/s^2].
struct AdaptiveStart {
  double first = 0.0, steps = 0.0, body = 0.0;
};
AdaptiveStart adaptive_start(const Scene& scene,
                             double drag_time = std::numeric_limits<double>::infinity());
// More adaptive fluid steps than this to run.end_time earns a warning: at a millisecond a fluid
// step (the small grids) that is more than a day.
inline constexpr double kManyFluidSteps = 1e8;
// The warning for an adaptive fluid step whose first length makes more than kManyFluidSteps to
// run.end_time (a tiny fluid.cfl); none for a fixed step, or one refused as uncountable.
std::optional<std::string> adaptive_step_warning(const Scene& scene);

// With a fixed fluid step: a warning when the particles' speeds (particles.velocity and the
// thermal sqrt(T) per axis), to which their drag sets a gas at rest moving, would make the gas
// take more than fluid::kMaxSubstepsPerInterval sub-steps at fluid.cfl. The speeds the gas is given
// are refused by check_gas_numbers; those the particles give it are an estimate: a warning.
std::optional<std::string> particle_driven_substeps_warning(const Scene& scene);

// The gas's memory estimate for the whole grid (scene.fluid.cells, kGasBytesPerCell each), in
// bytes.
double gas_memory_bytes(const Scene& scene);

// Throws ConfigError naming fluid.cells and the estimate when the gas cannot fit in this
// machine's memory: the whole grid on one rank, one rank's share on `ranks` (which may run on
// several machines). A grid of 1000^3 passed `check` and grew until the kernel killed the run.
void check_gas_memory(const Scene& scene, int ranks);

// The gas's derived numbers per fluid step dt_f (fluid.dt, or fluid.max_dt when adaptive) on the
// smallest cell dx, and the most a run can take of each: the Courant number |u| dt_f / dx of the
// initial and inflow velocities (the predictor's sub-steps are it over fluid.cfl), and the
// viscous number nu dt_f / dx^2, nu = mu / rho_g (the conditioning of the implicit viscous and
// the drag-coupled pressure solves grows with it: 8.9e5 on scenes/settling.toml stops the
// projection short of its tolerance at once, 8.9e7 runs 10 s before stopping, 1e299 hung).
inline constexpr double kMaxCourantPerFluidStep = 1e4;
// The gas sub-steps of a fixed fluid step are bounded by fluid::kMaxSubstepsPerInterval, the
// bound GasSolver::advance stops at: it takes dt_f in sub-steps of Courant number fluid.cfl, so
// a tiny cfl (1e-9 on the bed: 3e7 sub-steps) would make the first fluid step never end, with
// no progress line. The set-up refuses what it can foresee; at cfl >= 0.1 the Courant bound
// above is met first.
inline constexpr double kMaxViscousNumber = 1e8;

// Throws ConfigError naming the key and the number when one is beyond what can run (extreme
// gas values made the first fluid step run 20-60 s with no progress line).
void check_gas_numbers(const Scene& scene);

// A scene with a gas (scene.fluid.enabled); `derived` from the scene's initial particles.
GasCheck check_gas(const Scene& scene, const DerivedNumbers& derived);

// Wen & Yu (1966), Chem. Eng. Prog. Symp. Ser. 62, 100: Re_mf = sqrt(33.7^2 + 0.0408 Ar) - 33.7,
// Ar = d^3 rho_g (rho_p - rho_g) g / mu^2, U_mf = Re_mf mu / (rho_g d).
double minimum_fluidization_velocity(double d, double rho_p, double rho_g, double mu, double g);

} // namespace cfddem::apps
