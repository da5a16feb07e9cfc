// GasCoupling on its own (no run loop): the continuity source d(eps)/dt follows the particles.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

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

// The row's sums, taken as per-plane partials over TBB tasks, are the cells' sums: the gas
// momentum rho V sum eps u_cell and the pressure drop from the plane means next to the walls,
// against serial sums written out here (within the rounding of n terms), and bitwise the same
// on 1 and 4 threads.
TEST(GasCoupling, DiagnosticsAreTheCellSumsOnAnyThreadCount) {
  const Scene scene = slab_scene();
  ParticleStore p = make_initial_particles(scene);
  GasCoupling gas(scene, p);
  gas.step(p, 1e-4);
  for (double& y : p.y)
    y += 5e-6; // the slab rises: the gas moves and the pressure varies along y
  gas.step(p, 1e-4);
  const auto at = [&](int threads) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(threads));
    return gas.diagnostics();
  };
  const FluidDiagnostics one = at(1), four = at(4);
  for (int a = 0; a < 3; ++a)
    EXPECT_EQ(std::bit_cast<std::uint64_t>(one.gas_momentum[a]),
              std::bit_cast<std::uint64_t>(four.gas_momentum[a]))
        << a;
  EXPECT_EQ(std::bit_cast<std::uint64_t>(one.pressure_drop),
            std::bit_cast<std::uint64_t>(four.pressure_drop));
  EXPECT_EQ(std::bit_cast<std::uint64_t>(one.mass_residual),
            std::bit_cast<std::uint64_t>(four.mass_residual));

  const fluid::GasSolver& s = gas.solver();
  const fluid::MacGrid& g = s.grid();
  const auto& n = g.cells();
  const double rho = scene.fluid.density, vol = g.cell_volume();
  for (int a = 0; a < 3; ++a) {
    const int di = a == 0, dj = a == 1, dk = a == 2;
    const fluid::GridField& u = s.velocity()[a];
    double sum = 0.0, size = 0.0;
    for (int k = 0; k < n[2]; ++k)
      for (int j = 0; j < n[1]; ++j)
        for (int i = 0; i < n[0]; ++i) {
          const double term =
              s.volume_fraction()(i, j, k) * 0.5 * (u(i, j, k) + u(i + di, j + dj, k + dk));
          sum += term, size += std::abs(term);
        }
    const double cells = static_cast<double>(n[0]) * n[1] * n[2];
    EXPECT_NEAR(one.gas_momentum[a], rho * vol * sum, 2 * cells * 1e-16 * rho * vol * size) << a;
  }
  EXPECT_GT(std::abs(one.gas_momentum[1]), 0.0); // the slab's move set the gas moving along y
  // y has walls: the drop is the mean pressure extrapolated to the lower face less that at the
  // upper one (no gravity, no imposed gradient: p' is the pressure).
  std::vector<double> plane(static_cast<std::size_t>(n[1]), 0.0);
  double p_size = 0.0;
  for (int k = 0; k < n[2]; ++k)
    for (int j = 0; j < n[1]; ++j)
      for (int i = 0; i < n[0]; ++i) {
        plane[static_cast<std::size_t>(j)] += s.pressure()(i, j, k) / (n[0] * n[2]);
        p_size = std::max(p_size, std::abs(s.pressure()(i, j, k)));
      }
  const double drop =
      (1.5 * plane[0] - 0.5 * plane[1]) - (1.5 * plane[static_cast<std::size_t>(n[1] - 1)] -
                                           0.5 * plane[static_cast<std::size_t>(n[1] - 2)]);
  EXPECT_GT(std::abs(drop), 0.0);
  EXPECT_NEAR(one.pressure_drop, drop, 1e-12 * p_size);
}

// The coupling keeps the cell-centred gas velocity it interpolated the forces from and deposits
// the next step's drag from it while the gas has not moved. A change to the gas between steps
// through the solver's mutable access must not be missed: the step after it gives the bits of a
// coupling restarted from the changed state, which makes every field afresh, and they differ
// from the step without the change.
TEST(GasCoupling, NextDepositSeesAGasVelocityChangedBetweenSteps) {
  const Scene scene = slab_scene();
  ParticleStore p = make_initial_particles(scene);
  for (double& vx : p.vx)
    vx = 0.01; // a slip along x, so the drag law reads the gas velocity there
  const auto forces = [](const GasCoupling& gas) {
    std::vector<double> f;
    for (int a = 0; a < 3; ++a)
      f.insert(f.end(), gas.force(a).begin(), gas.force(a).end());
    return f;
  };
  GasCoupling changed(scene, p), unchanged(scene, p);
  changed.step(p, 1e-4);
  unchanged.step(p, 1e-4);
  for (double& u : changed.solver().velocity()[0].values())
    u += 0.05;
  const GasCoupling::State state = changed.save_state();
  GasCoupling restarted(scene, p);
  restarted.restore_state(state);
  changed.step(p, 1e-4);
  restarted.step(p, 1e-4);
  unchanged.step(p, 1e-4);
  const std::vector<double> f_changed = forces(changed), f_restarted = forces(restarted);
  ASSERT_EQ(f_changed.size(), f_restarted.size());
  for (std::size_t i = 0; i < f_changed.size(); ++i)
    ASSERT_EQ(std::bit_cast<std::uint64_t>(f_changed[i]),
              std::bit_cast<std::uint64_t>(f_restarted[i]))
        << i;
  EXPECT_NE(f_changed, forces(unchanged));
}

} // namespace
} // namespace cfddem::apps
