// The gas phase of MFIX's model A on one MAC grid (docs/theory.md §5): explicit predictor (limited
// MUSCL advection, viscous stress, body force; optionally the viscous Laplacian implicit),
// point-implicit particle drag, and a projection onto div(eps u) = -d(eps)/dt (the corrector's
// alone by default; docs/gas_step.md).
// On one grid, or on one box of a grid distributed over ranks (with the grid's GridHalo).
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <vector>

#include "fluid/fluid_step_rule.hpp"
#include "fluid/grid_field.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/implicit_viscosity.hpp"
#include "fluid/mac_grid.hpp"
#include "fluid/momentum_rhs.hpp"
#include "fluid/muscl_kernels.hpp"
#include "fluid/pressure_projection.hpp"
#include "fluid/solid_mask.hpp"

namespace cfddem::fluid {

// The Courant number of a gas sub-step is C = dt (advective_rate + 2 nu sum_a 1/dx_a^2), the
// viscous part only when the viscosity is explicit; advective_rate (fluid/fluid_step_rule.hpp)
// and its bound max_stable_courant depend on the advection scheme (the diffusion part alone
// would allow 1 with explicit Euler stages).

// What a gas sub-step with the viscous Laplacian implicit costs against one without, for
// implicit_viscosity_auto: its six Helmholtz solves (three components, two stages) by Chebyshev
// iteration add 0.39x (hcs_gas, 20^3 cells) to 0.72x (riser, 32 x 50 x 32) of the rest of a
// sub-step (callgrind, docs/gas_step.md "Implicit viscosity by Chebyshev iteration"); the
// factored step costs the riser about as much (0.166 against 0.161 s over its first 2 ms,
// docs/performance.md), being cheaper only where the solve needs many iterations. The
// implicit treatment is taken for an interval when it needs n_i sub-steps and the explicit one
// n_e > kImplicitSubstepCost n_i.
inline constexpr double kImplicitSubstepCost = 1.6;

// Whether the first guess of an implicit viscous solve, (M - w dt L) u = M b (M the face
// mass with the drag gain, w the implicit weight), should take the implicit part at u^n, b + w dt
// L(u^n), rather than b alone. In a mode of L whose eigenvalue times -w dt per unit mass is lam,
// the exact solution is b / (1 + lam): b's error is lam / (1 + lam) of the mode, the guess with
// the term (b ~ u^n to O(dt)) errs by lam^2 / (1 + lam), which is smaller only while lam < 1. So
// the term pays while the largest lam, 4 w dt nu sum_a 1/dx_a^2 (Gershgorin, uniform eps; the drag
// gain only lowers it), is at most `limit` (1); past it the term amplifies the grid-scale modes
// the implicit step exists for, as an explicit viscous step past its monotone limit would. The
// fluidized bed's grid (lam = 3.3) took 22.5 Chebyshev iterations per solve with the term and
// 20.8 without (docs/gas_step.md, "The first guess"). w_dt_nu: w dt mu / rho.
[[nodiscard]] inline bool explicit_guess_pays(double w_dt_nu, const std::array<double, 3>& dx,
                                              double limit) {
  double sum = 0.0;
  for (const double h : dx) {
    sum += 1.0 / (h * h);
  }
  return 4.0 * w_dt_nu * sum <= limit;
}

struct GasSolverSettings {
  GasProperties gas;
  Limiter limiter = Limiter::van_leer;
  ProjectionSettings projection;
  double fixed_dt = 0.0; // > 0: step() uses it; 0: adaptive from cfl
  double cfl = 0.4; // target Courant number, in (0, max_stable_courant(advection)]
  // The single-stage Godunov step (one momentum right-hand side, one set of viscous solves, one
  // projection; time_order and projections do not apply) or the method of lines below.
  Advection advection = Advection::mol;
  // Laplacian part of the viscous stress backward Euler (predictor) / trapezoidal (corrector),
  // by CG: removes the viscous term from the Courant number (cells smaller than particles).
  bool implicit_viscosity = false;
  // Per advance() interval, the Laplacian implicit where that takes fewer sub-steps by enough to
  // pay for its solves (kImplicitSubstepCost); implicit_viscosity is then ignored.
  bool implicit_viscosity_auto = false;
  double viscous_tolerance = 1e-10;
  // The implicit Laplacian's system by one approximately factored step (three sweeps of line
  // solves, ImplicitViscosity::step_factored) instead of a solve to viscous_tolerance.
  bool factored_viscosity = false;
  // explicit_guess_pays' limit on lam (tests: 0 never takes the term, infinity always does).
  double viscous_guess_limit = 1.0;
  // One grid: the viscous solves preconditioned by the multigrid (false: Jacobi, as on R ranks).
  bool viscous_multigrid = true;
  // The step declares its eps_g to the implicit viscosity once, after its ghost fill, and the
  // viscous face coefficients are made once per step from it (ImplicitViscosity::declare_eps).
  // false: every viscous call compares eps_g against a kept copy instead (tests: a write to eps_g
  // between two viscous calls of a step would make the two paths differ).
  bool declare_eps = true;
  int time_order = 2; // method of lines: 1, Euler; 2, predictor-corrector (Heun)
  // Projections per step with time_order 2: 1, the predictor takes the last step's pressure
  // gradient instead of a projection of its own (the lagged-pressure predictor of Bell, Colella
  // & Glaz 1989, J. Comput. Phys. 85, 257: its divergence is O(dt^2), so the corrector, which
  // alone is projected, stays second order), half the pressure solves; 2, each stage projected.
  int projections = 1;
};

// Wall seconds a solver spent in each part of its steps, summed over them (this rank's).
struct GasStepSeconds {
  double momentum = 0.0;   // the momentum right-hand sides (and Godunov's edge-state prediction)
  double viscous = 0.0;    // the implicit viscous Laplacians, systems and solves
  double projection = 0.0; // the pressure projections
};

struct GasStepReport {
  double dt = 0.0;
  double courant = 0.0;
  int projection_iterations = 0;
  int viscous_iterations = 0; // CG iterations of the implicit viscosity (all components)
  double relative_residual = 0.0;
  bool used_fallback = false;
  bool implicit_viscosity = false; // the Laplacian was implicit in this step (interval)
};

// MFIX-Exa's gp0: -delp/L along an axis with an imposed periodic drop, rho_g g along non-periodic
// axes (hydrostatic), 0 on other periodic axes (docs/theory.md §4). The body force per unit mass
// the gas's momentum sees is gravity - gp0 / rho_g.
[[nodiscard]] std::array<double, 3> background_pressure_gradient(
    const std::array<bool, 3>& periodic, const std::array<double, 3>& pressure_drop,
    const std::array<double, 3>& length, double density, const std::array<double, 3>& gravity);

class GasSolver {
public:
  // Throws std::invalid_argument for impossible settings (cfl above the stable limit, ...).
  // Distributed: grid is this rank's box and halo its grid's halo (shared with the coupling);
  // every call below is then collective over the ranks, and every field holds the box's cells
  // (local indices) with ghost layers. Reductions (Courant number, means, dot products) are
  // global, so every rank takes the same steps.
  GasSolver(const MacGrid& grid, const GasSolverSettings& settings,
            std::shared_ptr<const GridHalo> halo = nullptr);

  [[nodiscard]] const MacGrid& grid() const { return grid_; }
  // The pressure projection (its solver, and on R ranks the multigrid's gathered level).
  [[nodiscard]] const PressureProjection& projection() const { return *projection_; }
  [[nodiscard]] const GridHalo* halo() const { return halo_.get(); }
  [[nodiscard]] const GasSolverSettings& settings() const { return settings_; }
  // The instruction set of the step's row kernels (core/simd_level.hpp: the drag's face factors,
  // the momentum rows, the Chebyshev rows, the multigrid's rows), simd_level() unless set: for
  // tests and side-by-side measurements (every level gives the same bits).
  void use_simd_level(SimdLevel level);

  // Face velocities u, v, w [m/s]; boundary faces are overwritten from the BCs on each step.
  // The mutable access counts as a change (velocity_version()).
  [[nodiscard]] std::array<GridField, 3>& velocity() {
    ++velocity_version_;
    return u_;
  }
  [[nodiscard]] const std::array<GridField, 3>& velocity() const { return u_; }
  // Changes whenever the face velocities may have: each step() and advance(), restore_state()
  // and each mutable velocity() access. A caller that keeps a field derived from them (the
  // coupling's cell-centred velocity) reuses it while the version it was made at holds.
  [[nodiscard]] std::uint64_t velocity_version() const { return velocity_version_; }
  // p' at cell centres [Pa]; the full gradient is grad p' + background_pressure_gradient().
  [[nodiscard]] GridField& pressure() { return p_; }
  [[nodiscard]] const GridField& pressure() const { return p_; }
  // eps_g at cell centres, set by the coupling before each step (d(eps)/dt is taken against the
  // value at the previous step).
  [[nodiscard]] GridField& volume_fraction() { return eps_; }
  [[nodiscard]] const GridField& volume_fraction() const { return eps_; }
  void reset_volume_fraction_history() { eps_old_ = eps_; }
  // Deposited drag: beta_cell = sum_i beta_i W / V_cell [N s/m^4] and (beta v)_cell [N/m^3].
  [[nodiscard]] GridField& drag_coefficient() { return beta_; }
  [[nodiscard]] GridField& drag_velocity_sum(int axis) { return beta_v_[axis]; }

  // MFIX-Exa's gp0: -delp/L along an axis with an imposed periodic drop, rho_g g along
  // non-periodic axes (hydrostatic), 0 on other periodic axes (docs/theory.md §4).
  [[nodiscard]] std::array<double, 3> background_pressure_gradient() const;

  // C = dt (advective_rate + 2 nu sum_a 1/dx_a^2), the viscous part only while the viscosity is
  // explicit (implicit_viscosity_now()).
  [[nodiscard]] double courant_number(double dt) const;
  // Whether the next step() takes the Laplacian implicit: the setting, or under
  // implicit_viscosity_auto the choice advance() made for its interval.
  [[nodiscard]] bool implicit_viscosity_now() const { return implicit_now_; }
  // Largest dt whose Courant number is `courant` (inf for a still inviscid gas).
  [[nodiscard]] double dt_for_courant(double courant) const;
  // The rates the adaptive coupling step is priced on (fluid/fluid_step_rule.hpp): advection as
  // the sub-steps' Courant number counts it, the viscous rate only where the Laplacian would be
  // explicit (not with implicit or "auto" viscosity: advance() takes it implicit where that
  // saves sub-steps), and the forcing of the body force (gravity less the background gradient).
  // Collective on R ranks.
  [[nodiscard]] FluidStepRates step_rates() const;

  // One step with the fixed or adaptive dt.
  GasStepReport step();
  // One step with a given dt; throws std::runtime_error if its Courant number exceeds
  // max_stable_courant (message gives the largest stable dt).
  GasStepReport step(double dt);
  // Advances by `interval` (e.g. the coupling step dt_f) in as many equal-CFL sub-steps as
  // stability needs (small cells make the explicit viscous limit shorter than dt_f); eps_g is
  // interpolated linearly in time from its previous value to the current one over the sub-steps.
  // The continuity source d(eps)/dt is the change of eps_g over `eps_interval`, the time the
  // particles took to make it (the coupling's previous fluid step; 0: `interval`): in a loop
  // whose dt_f varies, the change deposited at the start of a step happened over the step
  // before, and dividing it by this step's length would drive a spurious flow (a short last step
  // of the riser gave 5.8 m/s). The report sums iterations and gives the last dt and the count.
  // `observe`, when set, is called after every sub-step with the sub-steps taken, the time
  // reached within `interval`, the sub-step's length and `interval` (a progress line for an
  // interval that takes many sub-steps); it changes nothing.
  using SubstepObserver = std::function<void(int count, double t, double dt, double interval)>;
  GasStepReport advance(double interval, int* substeps = nullptr, double eps_interval = 0.0,
                        const SubstepObserver& observe = {});

  // Velocity component averaged to cell centres (for interpolation to particles).
  void cell_centred_velocity(int axis, GridField& out) const;
  // Full pressure gradient at cell centres, d p'/dx_a (central) + gp0_a, for the particles'
  // pressure force -V_p grad p (docs/theory.md §4).
  void cell_pressure_gradient(int axis, GridField& out) const;

  // The wall time of the steps so far, by part (advance() and step() alike).
  [[nodiscard]] const GasStepSeconds& seconds() const { return seconds_; }

  // Checkpoint/restart: everything a later step reads that it did not compute itself -- face
  // velocities (the predictor's u^n and the CG first guesses), p' (the projection's first guess;
  // its ghosts feed cell_pressure_gradient), eps_g and its previous value (the continuity source
  // d(eps)/dt). Whole padded arrays, ghosts included, so nothing depends on when they were last
  // filled. Drag fields, mobilities and right-hand sides are rebuilt by every step before use;
  // the hypre set-up is a function of the matrix alone, so a fresh one solves identically.
  struct State {
    std::array<std::vector<double>, 3> velocity;
    std::vector<double> pressure, volume_fraction, volume_fraction_old;
  };
  [[nodiscard]] State save_state() const;
  // Throws std::invalid_argument if the arrays do not fit this grid.
  void restore_state(const State& s);

private:
  // The Courant rate C/dt [1/s] with the viscous term explicit and without it: {advective_rate +
  // 2 nu sum_a 1 / dx_a^2, advective_rate} (u's ghosts filled).
  [[nodiscard]] std::array<double, 2> courant_rates() const;
  // The same from the faces' largest speeds umax (max_face_speeds).
  [[nodiscard]] std::array<double, 2> courant_rates(const std::array<double, 3>& umax) const;
  // C at dt from those rates: the viscous part only while the viscosity is explicit.
  [[nodiscard]] double courant_at(double dt, const std::array<double, 2>& rates) const {
    return dt * (implicit_now_ ? rates[1] : rates[0]);
  }
  // max |u_a| over the faces of each axis (over the ranks: a max is exact).
  [[nodiscard]] std::array<double, 3> max_face_speeds() const;
  // The sub-step advance() takes at time t of `interval` at a Courant rate `rate` [1/s]: at
  // most cfl / rate, and the rest of the interval where less than a thousandth of a step would
  // be left.
  [[nodiscard]] double next_substep(double interval, double t, double rate) const;
  // How many sub-steps advance() takes over `interval` at a Courant rate `rate`: counted up to
  // kMaxSubstepsPerInterval, beyond it interval * rate / cfl.
  [[nodiscard]] double substeps_for(double interval, double rate) const;
  // Throws std::runtime_error when `count` sub-steps taken plus those the Courant rate `rate`
  // asks for the rest of `interval` (from t) exceed kMaxSubstepsPerInterval, naming fluid.cfl,
  // the rate's parts and the fastest face (collective over the ranks, as the rate is).
  void check_substep_count(double interval, double t, int count, double rate) const;
  // The update of one stage from u^n (u_start_; the Godunov step's one stage from u_ itself) with
  // the rate of its kind, the drag point-implicit,
  // the Laplacian implicit where it is, and the projection (none for a lagged predictor).
  enum class Stage { predictor, corrector, godunov };
  // Whether a step computes L(u^n) (with the Laplacian implicit): for the trapezoidal stages
  // (the corrector, Godunov) and the predictor's first guess (time order 2).
  [[nodiscard]] bool keeps_lap_start() const {
    return settings_.time_order == 2 || settings_.advection == Advection::godunov;
  }
  void stage(double dt, Stage kind, GasStepReport& report);
  // u's ghosts from the boundary conditions, then zero on every closed face (a column's wall).
  void fill_ghosts_and_close();
  // A column's faces for this step: no mobility through closed faces, the wall's shear added
  // to the drag gain, no continuity source in solid cells.
  void close_solid_faces(double dt);
  // step(dt) once u's ghosts are filled (advance() fills them for its Courant number). The
  // continuity source is (eps - eps_old)/dt times source_scale (advance(): interval /
  // eps_interval, from the sub-step's rate to the particles').
  // keep_eps_old false: eps_old_ is left as it was (the caller overwrites it), not set to eps_.
  // `rates` are courant_rates() of u as it stands (advance() has them; each is three passes over
  // u and a reduction over the ranks).
  GasStepReport step_with_ghosts(double dt, const std::array<double, 2>& rates,
                                 double source_scale = 1.0, bool keep_eps_old = true);

  MacGrid grid_;
  GasSolverSettings settings_;
  std::shared_ptr<const GridHalo> halo_;
  SolidMask solid_; // a column's solid cells (empty for a box)
  std::array<double, 3> body_{};
  std::array<GridField, 3> u_;
  std::uint64_t velocity_version_ = 0; // velocity_version()
  std::array<GridField, 3> u_start_;
  std::array<GridField, 3> rhs_;
  std::array<GridField, 3> rhs_stage_;
  MomentumWorkspace work_;
  std::unique_ptr<ImplicitViscosity> viscosity_; // implicit or auto viscosity only
  bool implicit_now_ = false;
  std::array<GridField, 3> lap_start_; // L(u^n) for the trapezoidal corrector
  GridField diag_, vrhs_;
  std::array<GridField, 3> mobility_;
  // Per face, for both stages of a step: 1 + k beta_f, k (beta v)_f (k = dt/(rho eps_f)) and,
  // with implicit viscosity, eps_f rho.
  std::array<GridField, 3> drag_gain_, drag_push_, face_mass_;
  std::array<GridField, 3> beta_v_;
  GridField p_, eps_, eps_old_, beta_, source_;
  GridField eps_target_, eps_start_; // advance()'s end and start eps_g
  std::unique_ptr<PressureProjection> projection_;
  GasStepSeconds seconds_;
  SimdLevel level_ = simd_level();
};

} // namespace cfddem::fluid
