// GasCoupling on its own (no run loop): the continuity source d(eps)/dt follows the particles.
#include <cmath>
#include <string>

#include <gtest/gtest.h>

#include "apps/coupled_step.hpp"
#include "core/initial_conditions.hpp"
#include "core/scene.hpp"
#include "core/scene_config.hpp"

namespace cfddem::apps {
namespace {

// A slab of 100 um particles across a column of gas at rest: x and z periodic, walls at y_lo and
// y_hi, no gravity. The slab is uniform in x and z, so the gas moves along y only, and the gas
// volume flux through a plane is fixed by continuity alone: the gas volume the slab's move freed
// below that plane, per second (zero below the slab; inside it, the gas flows down through the
// rising slab into the room it leaves behind).
const char* kSlab = R"(
name = "slab"
gravity = [0.0, 0.0, 0.0]
[domain]
lo = [0.0, 0.0, 0.0]
hi = [1.0e-3, 4.0e-3, 1.0e-3]
periodic = [true, false, true]
[particles]
count = 100
diameter = 100.0e-6
density = 1000.0
placement = "lattice"
region_lo = [0.0, 1.6e-3, 0.0]
region_hi = [1.0e-3, 2.0e-3, 1.0e-3]
[dem]
spring_constant = 10.0
restitution = 0.8
[fluid]
cells = [4, 16, 4]
density = 1.0
viscosity = 2.0e-5
dt = 1.0e-4
solver = "multigrid"
tolerance = 1e-12
[run]
end_time = 1.0e-3
)";

Scene slab_scene() {
  auto cfg = SceneConfig::from_string(kSlab, "slab scene");
  return read_scene(cfg, "slab");
}

// The gas volume flux sum eps_f u_f A_f through the face plane j along y [m^3/s].
double plane_flux(const GasCoupling& gas, int j) {
  const fluid::GasSolver& s = gas.solver();
  const fluid::MacGrid& g = s.grid();
  const fluid::GridField& eps = s.volume_fraction();
  const fluid::GridField& v = s.velocity()[1];
  double flux = 0.0;
  for (int k = 0; k < g.cells()[2]; ++k)
    for (int i = 0; i < g.cells()[0]; ++i)
      flux += 0.5 * (eps(i, j, k) + eps(i, j - 1, k)) * v(i, j, k);
  return flux * g.spacing(0) * g.spacing(2);
}

struct AfterLift {
  double flux;          // through the plane at y = 1.75 mm (in the slab) [m^3/s]
  double mass_residual; // of the step after the lift
};

// The slab moves up by `lift` while the particles take `moved` seconds; the fluid step after it
// is `next` long.
AfterLift after_lift(double lift, double moved, double next) {
  const Scene scene = slab_scene();
  ParticleStore p = make_initial_particles(scene);
  GasCoupling gas(scene, p);
  gas.step(p, moved); // the particles then move over this fluid step
  for (double& y : p.y)
    y += lift;
  gas.step(p, next);
  return {plane_flux(gas, 7), gas.diagnostics().mass_residual};
}

// The gas flow a slab's move drives depends on how long the particles took to move, not on how
// long the gas's next step is: with a variable dt_f (an adaptive step, a short last step) the
// displacement of the previous fluid step must not be divided by the current one.
TEST(GasCoupling, ContinuitySourceIsTheRateOverTheIntervalTheParticlesMoved) {
  const double lift = 5e-6, moved = 1e-4;
  const double same = after_lift(lift, moved, moved).flux;
  const AfterLift short_step = after_lift(lift, moved, moved / 8);
  const double short_next = short_step.flux;
  const double long_next = after_lift(lift, moved, moved * 2).flux;
  // The slab rising at lift/moved draws gas down through it at the solid volume flux, phi_s A
  // lift/moved, within the deposition's smoothing of the slab's edges. A lattice slab of 100
  // particles in 1 x 0.4 x 1 mm^3 has phi_s = 0.131.
  const double solid_rate = 100 * M_PI / 6 * 1e-12 / moved * lift / 0.4e-3; // phi_s A v
  EXPECT_LT(same, -0.5 * solid_rate);
  EXPECT_GT(same, -1.5 * solid_rate);
  // The projection solves to 1e-12: the fluxes agree far below the 8x and 2x a wrong interval
  // would give.
  EXPECT_NEAR(short_next, same, 1e-6 * std::abs(same));
  EXPECT_NEAR(long_next, same, 1e-6 * std::abs(same));
  // The mass residual uses the same interval: the step satisfied continuity.
  EXPECT_LT(short_step.mass_residual, 1e-9);
}

} // namespace
} // namespace cfddem::apps
