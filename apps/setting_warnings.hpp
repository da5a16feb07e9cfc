// Settings that are legal but almost surely a mistake: a warning each, printed by `cfddem run`
// and `cfddem check` before anything runs (the run goes on).
#pragma once

#include <string>
#include <vector>

#include "apps/derived_numbers.hpp"
#include "core/scene.hpp"

namespace cfddem::apps {

// More than this many snapshot or checkpoint files, or particle steps, earns a warning.
inline constexpr double kManyFiles = 1000;
inline constexpr double kManySteps = 1e10;
// Fewer particle steps than this per contact is an under-resolved contact: velocity Verlet keeps
// omega dt < 2 stable, but a contact of 2.5 steps gains energy (an elastic gas heated 8% in 30
// ms); the paper's tau_p/50 gives about 110.
inline constexpr double kFewStepsPerContact = 10;
// A skin that lists more neighbours than this per particle (the default lists about 9 in a packed
// bed): each pair pass evaluates every listed pair.
inline constexpr double kManyListedNeighbors = 1000;

// Gas cells whose longest side is more than this many times their shortest: the pressure
// solve's round-off floor rises with the ratio, and on the fluidized bed's column the projection
// stopped short of fluid.tolerance = 1e-10 at 1250:1 and 2000:1 (it converged at 625:1 and
// 1000:1).
inline constexpr double kElongatedCells = 500;

std::vector<std::string> setting_warnings(const Scene& scene);
// The same for the particle step once the particles are known (dt from dem.dt_factor needs the
// lightest mass): a contact resolved in few steps, or a step count no run finishes; alike for
// dem.dt and dem.dt_factor.
std::vector<std::string> step_warnings(const Scene& scene, const DerivedNumbers& derived);

} // namespace cfddem::apps
