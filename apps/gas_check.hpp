// What `cfddem check` says about the gas of a scene: cells per particle diameter, the fluid steps
// to run.end_time, the minimum fluidization velocity of a bed (Wen & Yu), and a rough cost per
// fluid step and for the run; with warnings where a setting is almost surely a mistake.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "apps/derived_numbers.hpp"
#include "core/scene.hpp"

namespace cfddem::apps {

struct GasCheck {
  std::vector<std::pair<std::string, std::string>> table;
  std::vector<std::string> warnings;
};

// A scene with a gas (scene.fluid.enabled); `derived` from the scene's initial particles.
GasCheck check_gas(const Scene& scene, const DerivedNumbers& derived);

// Wen & Yu (1966), Chem. Eng. Prog. Symp. Ser. 62, 100: Re_mf = sqrt(33.7^2 + 0.0408 Ar) - 33.7,
// Ar = d^3 rho_g (rho_p - rho_g) g / mu^2, U_mf = Re_mf mu / (rho_g d).
double minimum_fluidization_velocity(double d, double rho_p, double rho_g, double mu, double g);

} // namespace cfddem::apps
