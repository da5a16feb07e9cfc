#include "apps/setting_warnings.hpp"

#include <fmt/format.h>

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
  if (s.dem.scheme == "orb" || s.dem.scheme == "islands") {
    // Sub-iterated schemes write rows at whole sub-iterations of dt_sp (with a gas the fluid
    // step is the regrid interval).
    const double interval = s.fluid.enabled && s.fluid.dt > 0 ? s.fluid.dt : s.dem.regrid_interval;
    const double dt_sp = interval / static_cast<double>(s.dem.nsubit);
    if (s.output.interval < dt_sp * (1 - 1e-12))
      w.push_back(fmt::format("output.interval = {:g} s is shorter than the sub-iteration step "
                              "dt_sp = {:g} s of dem.scheme = \"{}\": rows come every dt_sp "
                              "instead",
                              s.output.interval, dt_sp, s.dem.scheme));
  }
  return w;
}

} // namespace cfddem::apps
