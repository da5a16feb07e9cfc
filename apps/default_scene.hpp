// The scene `cfddem run` uses when no scene file is given: the paper's homogeneous cooling system
// (HCS) with the peers' parameters (docs/theory.md §1, §3), particles generated in place.
// scenes/hcs.toml is the same scene started from the peers' exact initial state.
#pragma once

namespace cfddem::apps {

inline constexpr const char* kDefaultScene = R"(# Homogeneous cooling system (Sitaraman & Grout; MFIX-Exa DEM07 without gas)
name = "hcs"
gravity = [0.0, 0.0, 0.0]

[domain]
lo = [0.0, 0.0, 0.0]
hi = [4.0e-3, 4.0e-3, 4.0e-3]
periodic = [true, true, true]

[particles]
count = 1222
diameter = 100.0e-6
density = 1000.0
temperature = 0.01
seed = 1

[dem]
scheme = "explicit"
spring_constant = 10.0
restitution = 0.8
friction = 0.0
dt_factor = 0.02

[run]
end_time = 0.030

[output]
interval = 1.0e-4
)";

} // namespace cfddem::apps
