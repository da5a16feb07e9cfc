// Settings that are legal but almost surely a mistake: a warning each, printed by `cfddem run`
// and `cfddem check` before anything runs (the run goes on).
#pragma once

#include <string>
#include <vector>

#include "core/scene.hpp"

namespace cfddem::apps {

// More than this many snapshot or checkpoint files, or particle steps, earns a warning.
inline constexpr double kManyFiles = 1000;
inline constexpr double kManySteps = 1e10;

std::vector<std::string> setting_warnings(const Scene& scene);

} // namespace cfddem::apps
