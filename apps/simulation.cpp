#include "apps/simulation.hpp"

#include "apps/coupled_step.hpp"
#include "apps/run_loop.hpp"
#include "apps/scheme_runs.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"

namespace cfddem::apps {

RunResult run_simulation(const Scene& scene, const RunOptions& opt, const ParallelEnv& env) {
  // The scene allows only these three schemes (core/scene.cpp).
  const std::string& s = scene.dem.scheme;
  if (scene.fluid.enabled)
    validate_fluid(scene);
  // One instantiation per scheme: the rank count is the run's (env.ranks()), read inside.
  if (s == "orb")
    return run_loop<OrbRun>(scene, opt, env);
  if (s == "islands")
    return run_loop<IslandsRun>(scene, opt, env);
  return run_loop<ExplicitRun<dem::ExplicitScheme>>(scene, opt, env);
}

} // namespace cfddem::apps
