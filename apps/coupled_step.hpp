// The gas <-> particle coupling of one fluid step (the paper's Algorithm 1;
// docs/theory.md §4, §5, §7):
//   1. deposit the solid fraction eps_s, the drag coefficients beta_i (drag law at each particle
//      with eps_g and the slip |u_g - v_i| interpolated there) and beta_i v_i to the cells,
//   2. advance the gas by dt_f (point-implicit drag, hypre projection),
//   3. interpolate u_g and grad p to the particles with the same weights and set the force
//      F_i = beta_i (u_g - v_i) - V_p grad p, held fixed over the particle sub-cycle (MFIX-Exa).
// With the same kernel for deposition and interpolation, v_i frozen over the sub-cycle and the
// face averages of the solver, the momentum the gas loses to drag and pressure is exactly what
// the particles gain (tests/apps/coupling_test.cpp checks it on a periodic riser).
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "core/cell_box.hpp"
#include "core/communicator.hpp"
#include "core/particle_snapshot.hpp"
#include "core/particle_store.hpp"
#include "core/scene.hpp"
#include "fluid/deposition.hpp"
#include "fluid/drag_law.hpp"
#include "fluid/gas_solver.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::apps {

// The fluid grid of a scene; throws ConfigError naming the key (cells that do not tile, a
// boundary condition that cannot be satisfied, a CFL above the stable limit, ...).
fluid::MacGridSpec fluid_grid_spec(const Scene& scene);
// The gas grid's count cut into one box per rank (fluid/gas_boxes.hpp; the whole grid on one
// rank). Throws ConfigError naming fluid.cells when the grid is too small for the ranks.
std::vector<CellBox> gas_boxes(const Scene& scene, const Communicator* comm);
// All fluid checks of a scene (a no-op without [fluid]); throws ConfigError naming the key.
void validate_fluid(const Scene& scene);

struct FluidDiagnostics {
  double pressure_drop = 0.0; // mean p, bottom minus top boundary face along the axis [Pa]
  std::array<double, 3> gas_momentum{}; // sum rho_g eps_g u_g V_cell [kg m/s]
  double mass_residual = 0.0; // max |div(eps u) + d(eps)/dt| dt_f over cells (dimensionless)
};

// The gas of `gas` at its cells' centres (this rank's box on R ranks, placed by block_lo):
// eps_g, the full pressure p' + gp0 . (x - origin) and the face velocities averaged to the
// centres. Snapshots and column profiles read the gas through it.
CellFields cell_fields(const fluid::GasSolver& gas);

// Distributed (a communicator of more than one rank): the gas grid is cut into one box per rank
// (fluid::orb_cell_boxes), each rank holds its box's cells and passes the particles it owns
// (the first `owned` of the store: those of its box, as the scheme's decomposition_of the
// boxes makes them); deposits in ghost cells go to their owners, interpolation reads exchanged
// ghosts, and the diagnostics are reduced over the ranks (the same values on every rank).
// Every call is then collective.
// Wall seconds of the fluid steps by part, summed (this rank's): what run.json's
// fluid_phase_seconds reports.
struct FluidPhaseSeconds {
  double deposition = 0.0;    // eps_s, beta and beta v to the cells
  double momentum = 0.0;      // momentum right-hand sides (Godunov: with the edge prediction)
  double viscous = 0.0;       // implicit viscous Laplacians, systems and solves
  double projection = 0.0;    // pressure projections
  double gas_other = 0.0;     // the rest of the gas step: ghost fills, drag factors, updates
  double interpolation = 0.0; // gas velocity and pressure gradient to the particles, forces
};

class GasCoupling {
public:
  GasCoupling(const Scene& scene, const ParticleStore& particles,
              const Communicator* comm = nullptr, std::size_t owned = kAllParticles);
  static constexpr std::size_t kAllParticles = static_cast<std::size_t>(-1);
  // In two parts, so that the run's set-up pays for the grid, the solver and their fields (the
  // first touch of every page: most of a large gas's start) and the loop only for the first
  // deposit: the coupling for particles of radius at most r_max (the same on every rank), on
  // `boxes` (R ranks: one per rank, as a restart finds them; empty: the count cut), ...
  GasCoupling(const Scene& scene, double r_max, const Communicator* comm = nullptr,
              const std::vector<CellBox>& boxes = {});
  // ... then eps_g of the initial particles (the first `owned` of the store), so the first step
  // sees no d(eps)/dt. The one-call constructor above is the two in a row.
  void attach(const ParticleStore& particles, std::size_t owned = kAllParticles);
  // The r_max of the constructor above: the largest radius of the first `owned` particles, over
  // the ranks when comm has more than one (collective then).
  static double largest_radius(const ParticleStore& particles, const Communicator* comm,
                               std::size_t owned = kAllParticles);
  ~GasCoupling();
  GasCoupling(const GasCoupling&) = delete;
  GasCoupling& operator=(const GasCoupling&) = delete;

  // Steps 1-3 above with the particles' current positions and velocities (v_i: whatever the
  // scheme holds, the same value in the deposit and in the force). Afterwards force(a) holds
  // F_i, one entry per particle in the store's current order.
  fluid::GasStepReport step(const ParticleStore& particles, double dt_f,
                            std::size_t owned = kAllParticles);
  // The ranks' boxes of gas cells (distributed; one box, the grid, otherwise).
  [[nodiscard]] const std::vector<CellBox>& boxes() const { return boxes_; }
  // Distributed, between fluid steps: the gas moves to a new cutting of the grid into boxes (a
  // load-balancing regrid; every rank passes the same list, rank r's box boxes[r]). Each owned
  // cell and face value goes to its new owner unchanged (fluid/grid_move); the new boxes get
  // their own halo and hypre set-up. Returns the values this rank sent to other ranks. The
  // caller moves the particles (step() deposits only particles within its box's reach).
  // Collective; throws ConfigError if a box is too narrow.
  std::size_t rebox(const std::vector<CellBox>& boxes);
  // The next adaptive dt_f (fluid.dt = 0) with `time_left` to the end of the run: the gas's
  // Courant step with its forcing at fluid.cfl, capped by fluid.max_dt, a fraction of the
  // smallest particle relaxation time of the last deposit and 1.1x the last fluid step; no
  // sliver at the end (fluid/fluid_step_rule.hpp). Collective on R ranks.
  [[nodiscard]] double adaptive_dt(double time_left) const;
  [[nodiscard]] std::span<const double> force(int axis) const { return force_[axis]; }
  // The ids of the particles force(a) is for (the owned ones at the last step()).
  [[nodiscard]] std::span<const std::int64_t> force_ids() const { return force_ids_; }
  // F_i of the last step() in the order of `ids` (the store's order now: the schemes permute the
  // store, and the force they hold, after step()); empty before the first step.
  [[nodiscard]] std::array<std::vector<double>, 3>
  force_in_order(std::span<const std::int64_t> ids) const;
  [[nodiscard]] FluidDiagnostics diagnostics() const;
  [[nodiscard]] const fluid::GasSolver& solver() const { return *solver_; }
  [[nodiscard]] fluid::GasSolver& solver() { return *solver_; }
  // The scene's axis for the pressure drop: gravity's, else a pressure drop's, else an inflow's,
  // else y.
  [[nodiscard]] int axis() const { return axis_; }
  [[nodiscard]] long long gas_substeps() const { return gas_substeps_; }
  [[nodiscard]] long long implicit_viscosity_steps() const { return implicit_viscosity_steps_; }
  [[nodiscard]] long long projection_iterations() const { return projection_iterations_; }
  // Iterations of the implicit viscous solves (all components and stages).
  [[nodiscard]] long long viscous_iterations() const { return viscous_iterations_; }
  // Fluid steps whose projection fell back from PFMG to SMG preconditioning.
  [[nodiscard]] long long projection_fallbacks() const { return projection_fallbacks_; }
  [[nodiscard]] const FluidPhaseSeconds& phase_seconds() const { return seconds_; }
  // Called after each gas sub-step of step() (fluid::GasSolver::advance): the time loop's
  // progress line inside a fluid step that takes many sub-steps.
  void observe_substeps(fluid::GasSolver::SubstepObserver f) { observe_ = std::move(f); }

  // The gas at cell centres for a snapshot (eps_g, full pressure, gas velocity).
  [[nodiscard]] CellFields cell_fields() const { return apps::cell_fields(*solver_); }

  // Checkpoint/restart at a fluid-step boundary: the solver's state, what the diagnostics read
  // and the counters. Not in it: the deposited eps_s and drag coefficients (step() deposits them
  // afresh before any use) and the particle force (the scheme holds it: force_in_order()).
  struct State {
    fluid::GasSolver::State solver;
    std::vector<double> eps_prev; // eps_g before the last step (mass residual); empty: no step
    double last_dt = 0.0;
    // min m_i / beta_i of the last deposit (adaptive fluid step only; else inf); NaN: not in the
    // checkpoint (older ones), keep the constructor's
    double drag_time = std::numeric_limits<double>::quiet_NaN();
    std::int64_t gas_substeps = 0, projection_iterations = 0, projection_fallbacks = 0;
    std::int64_t implicit_viscosity_steps = 0; // fluid steps with the Laplacian implicit
    std::int64_t viscous_iterations = 0;
  };
  [[nodiscard]] State save_state() const;
  // Throws RunError if the state does not fit this grid.
  void restore_state(const State& s);

private:
  // The coupling's own fields on grid_ (at construction and after a rebox).
  void make_work_fields();
  void deposit(const ParticleStore& p, std::size_t n);
  // Each particle's force from the new gas: drag with the gas velocity at it and frozen v_i,
  // and -V_p grad p (the first n particles of p).
  void interpolate_forces(const ParticleStore& p, std::size_t n);
  // The drag rates of the last deposit: the adaptive dt_f's cap (drag_time_), and with dt_f > 0
  // a RunError when a particle's drag, held over the fluid step dt_f, is unstable or not finite
  // (the .cpp). Collective.
  void check_drag(const ParticleStore& p, std::size_t n, double dt_f);
  const Scene& scene_;
  const Communicator* comm_ = nullptr; // distributed only
  std::vector<CellBox> boxes_;
  fluid::MacGrid grid_;
  std::shared_ptr<const fluid::GridHalo> halo_;
  std::unique_ptr<fluid::GasSolver> solver_;
  fluid::GasSolver::SubstepObserver observe_;
  std::unique_ptr<fluid::Deposition> deposition_;
  fluid::TransferPlan plan_; // the kernels of the particles deposit() saw (deposition_'s grid)
  fluid::DragLaw law_;
  int axis_ = 1;
  double last_dt_ = 0.0, r_max_ = 0.0;
  // The eps_g change of the last step() was made over this time (the fluid step before it). Not
  // checkpointed: only diagnostics() reads it, and only after a step() of the same process.
  double source_dt_ = 0.0;
  double drag_time_ = std::numeric_limits<double>::infinity();
  long long gas_substeps_ = 0, projection_iterations_ = 0, projection_fallbacks_ = 0;
  long long implicit_viscosity_steps_ = 0, viscous_iterations_ = 0;
  FluidPhaseSeconds seconds_;
  // eps_s_: the deposited solid fraction (scratch); eps_prev_: eps_g at the last step's start,
  // meaningful once a step was taken (last_dt_ > 0: the mass residual and the checkpoint read it
  // only then), made at set-up (a new field of the 1e5 bed's grid took about 11 ms to fault in
  // inside the loop's first step).
  fluid::GridField eps_s_, eps_prev_;
  std::array<fluid::GridField, 3> cell_u_, cell_gp_; // cell-centred gas velocity, grad p
  // The solver's velocity_version() cell_u_ (ghosts filled) was made at; none until made on
  // these fields: interpolate_forces makes it after the gas step, and the next step's deposit,
  // before which the gas does not move, reads it again (on R ranks: three halo fills a step).
  std::optional<std::uint64_t> cell_u_version_;
  // cell_u_ of the solver's velocity now, made unless it is already.
  void make_cell_velocity();
  // diagnostics()'s scratch: eps_g with its ghosts, div(eps u), and per z-plane partial sums.
  mutable fluid::GridField diag_eps_, diag_div_;
  mutable std::vector<double> diag_sums_;
  std::vector<double> eps_p_, beta_, ug_[3], bv_[3], gp_[3], force_[3];
  std::vector<std::int64_t> force_ids_; // particle ids in force_'s order
};

} // namespace cfddem::apps
