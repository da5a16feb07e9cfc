#include "dem/verlet_passes.hpp"

#include <string>

#include <fmt/format.h>

namespace cfddem::dem {

std::string describe_fault(const ParticleStore& p, const StepReport& r, const StepModel& m) {
  const std::uint32_t i = r.bad;
  const std::string who =
      fmt::format("particle {} at ({:.6g}, {:.6g}, {:.6g}) m", p.id[i], p.x[i], p.y[i], p.z[i]);
  std::string why;
  switch (r.fault) {
  case StepFault::nan:
    why = "position or velocity is not finite (NaN/inf): the step is unstable";
    break;
  case StepFault::overlap:
    why = r.partner == kNoParticle
              ? fmt::format("overlap with a wall is {:.3g} of its radius (dem.max_overlap = {}): "
                            "the impact is too fast for the spring (raise k or lower dt)",
                            r.value, m.max_overlap)
              : fmt::format("overlap with particle {} is {:.3g} of the smaller radius "
                            "(dem.max_overlap = {}): the impact is too fast for the spring "
                            "(raise k or lower dt)",
                            p.id[r.partner], r.value, m.max_overlap);
    break;
  case StepFault::speed:
    why = fmt::format("speed {:.4g} m/s moves it more than the smallest radius in one step "
                      "(dt = {:.4g} s): contacts could be missed (tunnelling)",
                      r.value, m.dt);
    break;
  case StepFault::left_domain:
    why = fmt::format("left the domain through a wall (coordinate {:.6g} m)", r.value);
    break;
  case StepFault::none:
    break;
  }
  return who + ": " + why;
}

} // namespace cfddem::dem
