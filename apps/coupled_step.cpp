#include "apps/coupled_step.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <unordered_map>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include "core/error.hpp"
#include "core/stopwatch.hpp"
#include "fluid/box_loops.hpp"
#include "fluid/gas_boxes.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/grid_move.hpp"
#include "fluid/pressure_projection.hpp"

namespace cfddem::apps {

namespace {

// refuse_unstable_drag's key for agree_on_error: a particle whose drag is not finite is named
// before any other (ids are non-negative and below 2^62), then by the smallest id.
constexpr std::int64_t kNotFiniteFirst = std::int64_t{1} << 62;

// Floor on eps_g seen by the solver and the drag laws: a cell packed beyond random close packing
// (eps_g ~ 0.36) by deposition noise would make 1/eps^3 terms blow up. Only dense beds reach it.
constexpr double kMinGasFraction = 0.3;

fluid::BoundaryKind boundary_kind(const std::string& name) {
  if (name == "periodic")
    return fluid::BoundaryKind::periodic;
  if (name == "inflow")
    return fluid::BoundaryKind::inflow;
  if (name == "outflow")
    return fluid::BoundaryKind::outflow;
  return fluid::BoundaryKind::wall;
}

fluid::DepositionKernel kernel(const std::string& name) {
  if (name == "trilinear")
    return fluid::DepositionKernel::trilinear;
  if (name == "dpvm_sphere")
    return fluid::DepositionKernel::dpvm_sphere;
  return fluid::DepositionKernel::dpvm_cube; // "dpvm" = MFIX-Exa's cube kernel
}

fluid::GasSolverSettings solver_settings(const Scene& s) {
  fluid::GasSolverSettings g;
  g.gas.density = s.fluid.density;
  g.gas.viscosity = s.fluid.viscosity;
  g.gas.gravity = s.gravity;
  g.cfl = s.fluid.cfl;
  g.advection = fluid::advection_named(s.fluid.advection);
  g.implicit_viscosity = s.fluid.implicit_viscosity;
  g.implicit_viscosity_auto = s.fluid.implicit_viscosity_auto;
  g.factored_viscosity = s.fluid.viscous_step == "factored";
  g.time_order = s.fluid.time_order;
  g.projections = s.fluid.projections;
  g.projection.tolerance = s.fluid.tolerance;
  g.projection.preconditioner = s.fluid.preconditioner == "smg"
                                    ? fluid::PoissonPreconditioner::smg
                                    : fluid::PoissonPreconditioner::pfmg;
  g.projection.solver = s.fluid.solver == "multigrid" ? fluid::PoissonSolver::multigrid
                        : s.fluid.solver == "hypre"   ? fluid::PoissonSolver::hypre
                                                      : fluid::PoissonSolver::automatic;
  return g;
}

} // namespace

fluid::MacGridSpec fluid_grid_spec(const Scene& s) {
  const FluidSpec& f = s.fluid;
  fluid::MacGridSpec spec;
  for (int a = 0; a < 3; ++a) {
    spec.cells[a] = static_cast<int>(f.cells[a]);
    spec.origin[a] = s.domain.lo[a];
    spec.extent[a] = s.domain.length(a);
    spec.spacing[a] = f.cell_size[a];
    spec.pressure_drop[a] = f.pressure_drop[a];
  }
  if (s.domain.cylinder()) {
    spec.cylinder_axis = s.domain.cylinder_axis;
    spec.cylinder_radius = s.domain.cylinder_radius;
  }
  for (int k = 0; k < fluid::kFaces; ++k) {
    auto& bc = spec.bc[static_cast<std::size_t>(k)];
    bc.kind = boundary_kind(f.bc[static_cast<std::size_t>(k)]);
    if (bc.kind == fluid::BoundaryKind::inflow)
      bc.velocity = f.inflow_velocity;
    if (bc.kind == fluid::BoundaryKind::outflow)
      bc.pressure = f.outflow_pressure;
  }
  const std::vector<std::string> problems = fluid::check_mac_grid(spec);
  if (!problems.empty()) {
    // Name the key each problem comes from (the fluid library words them per axis or face).
    const std::string& p = problems.front();
    std::string key = "fluid.bc";
    if (p.find("cylinder") != std::string::npos)
      key = "domain.cylinder_radius";
    else if (p.find("tile") != std::string::npos || p.find("cell size") != std::string::npos)
      key = "fluid.cell_size";
    else if (p.find(" cells") != std::string::npos)
      key = "fluid.cells";
    else if (p.find("pressure drop") != std::string::npos)
      key = "fluid.pressure_drop";
    else if (p.find("inflow velocity") != std::string::npos)
      key = "fluid.inflow_velocity";
    std::string all;
    for (const auto& q : problems)
      all += (all.empty() ? "" : "; ") + q;
    throw ConfigError(fmt::format("scene key '{}'", key), all);
  }
  return spec;
}

void validate_fluid(const Scene& s) {
  if (!s.fluid.enabled)
    return;
  (void)fluid_grid_spec(s);
  // The column's solid cells (fluid/solid_mask.hpp) are the multigrid's empty rows.
  if (s.domain.cylinder() && s.fluid.solver == "hypre")
    throw ConfigError("scene key 'fluid.solver'",
                      "\"hypre\" does not take the solid cells of domain.shape = "
                      "\"cylinder\"; use \"multigrid\" or \"auto\"");
  const fluid::Advection advection = fluid::advection_named(s.fluid.advection);
  const bool mol = advection == fluid::Advection::mol;
  const double max_courant = fluid::max_stable_courant(advection);
  if (!(s.fluid.cfl <= max_courant))
    throw ConfigError(
        "scene key 'fluid.cfl'",
        fmt::format("{} is above the stable limit {} of the gas step with "
                    "fluid.advection = \"{}\" ({})",
                    s.fluid.cfl, max_courant, s.fluid.advection,
                    mol ? "limited MUSCL advection with SSP Euler stages"
                        : "Godunov edge states, von Neumann analysis in gas_step.md"));
}

namespace {

// f(i) for particles 0..n-1, blocks of them as TBB tasks.
template <class F> void for_particles(std::size_t n, F&& f) {
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t i = r.begin(); i != r.end(); ++i)
                        f(i);
                    });
}

fluid::MacGrid gas_grid(const Scene& scene, const Communicator* comm,
                        const std::vector<CellBox>& boxes) {
  if (comm == nullptr || comm->size() == 1)
    return fluid::MacGrid(fluid_grid_spec(scene));
  return fluid::MacGrid(fluid_grid_spec(scene), boxes[static_cast<std::size_t>(comm->rank())]);
}

fluid::DepositionSettings deposition_settings(const Scene& scene) {
  fluid::DepositionSettings ds;
  ds.kernel = kernel(scene.fluid.deposition);
  ds.width = scene.fluid.deposition_width;
  return ds;
}

} // namespace

std::vector<CellBox> gas_boxes(const Scene& scene, const Communicator* comm) {
  const fluid::MacGridSpec spec = fluid_grid_spec(scene);
  if (comm == nullptr || comm->size() == 1)
    return {CellBox{{0, 0, 0}, spec.cells}};
  try {
    return fluid::gas_cell_boxes(spec, comm->size());
  } catch (const std::invalid_argument& e) {
    throw ConfigError("scene key 'fluid.cells'", e.what());
  }
}

double GasCoupling::largest_radius(const ParticleStore& p, const Communicator* comm,
                                   std::size_t owned) {
  const std::size_t n = std::min(owned, p.size());
  double r_max = 0.0;
  for (std::size_t i = 0; i < n; ++i)
    r_max = std::max(r_max, p.radius[i]);
  return comm != nullptr && comm->size() > 1 ? comm->max(r_max) : r_max;
}

GasCoupling::GasCoupling(const Scene& scene, const ParticleStore& p, const Communicator* comm,
                         std::size_t owned)
    : GasCoupling(scene, largest_radius(p, comm, owned), comm) {
  attach(p, owned);
}

GasCoupling::GasCoupling(const Scene& scene, double r_max, const Communicator* comm,
                         const std::vector<CellBox>& boxes)
    : scene_(scene), comm_(comm != nullptr && comm->size() > 1 ? comm : nullptr),
      boxes_(comm_ != nullptr && !boxes.empty() ? boxes : gas_boxes(scene, comm_)),
      grid_(gas_grid(scene, comm_, boxes_)) {
  if (comm_ != nullptr)
    halo_ = std::make_shared<fluid::GridHalo>(grid_, boxes_, *comm_);
  solver_ = std::make_unique<fluid::GasSolver>(grid_, solver_settings(scene), halo_);
  r_max_ = std::max(r_max, 1e-300);
  deposition_ =
      std::make_unique<fluid::Deposition>(grid_, deposition_settings(scene), r_max_, halo_.get());
  law_ = fluid::parse_drag_law(scene.fluid.drag);
  make_work_fields();
  eps_prev_ = grid_.make_field(); // made here, not at the first step (a rebox moves it)
  // Axis of the pressure drop diagnostic.
  int axis = -1;
  double gmax = 0.0;
  for (int a = 0; a < 3; ++a)
    if (std::abs(scene.gravity[a]) > gmax)
      gmax = std::abs(scene.gravity[a]), axis = a;
  for (int a = 0; a < 3 && axis < 0; ++a)
    if (scene.fluid.pressure_drop[a] != 0.0)
      axis = a;
  for (int k = 0; k < fluid::kFaces && axis < 0; ++k)
    if (scene.fluid.bc[static_cast<std::size_t>(k)] == "inflow")
      axis = k / 2;
  axis_ = axis < 0 ? 1 : axis;
  // Initial gas velocity: uniform on faces (the first projection makes it admissible).
  for (int a = 0; a < 3; ++a)
    solver_->velocity()[a].fill(scene.fluid.velocity[a]);
}

void GasCoupling::attach(const ParticleStore& p, std::size_t owned) {
  const std::size_t n = std::min(owned, p.size());
  deposit(p, n);
  check_drag(p, n, 0.0); // the adaptive dt_f's first cap
  solver_->reset_volume_fraction_history();
}

GasCoupling::~GasCoupling() = default;

void GasCoupling::make_work_fields() {
  eps_s_ = grid_.make_field();
  diag_eps_ = grid_.make_field(), diag_div_ = grid_.make_field();
  for (int a = 0; a < 3; ++a)
    cell_u_[a] = grid_.make_field(), cell_gp_[a] = grid_.make_field();
  cell_u_version_.reset(); // new fields (a rebox: of a new solver)
}

std::size_t GasCoupling::rebox(const std::vector<CellBox>& boxes) {
  if (comm_ == nullptr)
    throw std::logic_error("GasCoupling::rebox: the gas is not distributed");
  if (boxes == boxes_)
    return 0;
  fluid::MacGrid grid = [&] {
    try {
      return gas_grid(scene_, comm_, boxes);
    } catch (const std::invalid_argument& e) {
      throw ConfigError("scene key 'fluid.cells'", e.what());
    }
  }();
  auto halo = std::make_shared<const fluid::GridHalo>(grid, boxes, *comm_);
  auto solver = std::make_unique<fluid::GasSolver>(grid, solver_settings(scene_), halo);
  const fluid::GridMove move(grid_, grid, boxes_, boxes, *comm_);
  fluid::move_solver_state(*solver_, *solver, move);
  {
    // eps_g before the last step: the mass residual reads its owned cells only.
    fluid::GridField e = grid.make_field();
    move.move(eps_prev_, e, fluid::kCellCentred);
    eps_prev_ = std::move(e);
  }
  const std::size_t sent = move.points_sent();
  // The rest is rebuilt from the particles at the next step().
  boxes_ = boxes;
  grid_ = std::move(grid);
  halo_ = std::move(halo);
  solver_ = std::move(solver);
  deposition_ =
      std::make_unique<fluid::Deposition>(grid_, deposition_settings(scene_), r_max_, halo_.get());
  plan_ = {}; // its cells were the old box's
  make_work_fields();
  return sent;
}

void GasCoupling::deposit(const ParticleStore& p, std::size_t n) {
  const fluid::ParticlePositions pos{
      {p.x.data(), n}, {p.y.data(), n}, {p.z.data(), n}, {p.radius.data(), n}};
  if (comm_ != nullptr) {
    // A stencil beyond the ghost layers on any rank stops every rank before the collective
    // deposits (the first particle by rank).
    const std::string problem = deposition_->reach_problem(pos);
    const std::string agreed =
        comm_->agree_on_error(problem.empty() ? comm_->size() : comm_->rank(), problem);
    if (!agreed.empty())
      throw RunError(agreed);
  }
  // Solid fraction -> eps_g (docs/theory.md §7), floored (kMinGasFraction). One-way coupled,
  // eps_g is for the particles' drag law alone: it replaces the solid fraction in eps_s_ (a
  // scratch field, each value read before it is written), and the gas keeps the fraction 1 it
  // started with.
  // The particles' kernels once for the three transfers here and interpolate_forces' (the
  // particles stand still until then).
  deposition_->plan(pos, plan_);
  fluid::fill_field(eps_s_, 0.0);
  deposition_->deposit_solid_fraction(plan_, eps_s_);
  fluid::GridField& eps = scene_.fluid.one_way ? eps_s_ : solver_->volume_fraction();
  const auto& nc = grid_.cells();
  tbb::parallel_for(0, nc[2], [&](int k) { // planes as tasks (pointwise)
    for (int j = 0; j < nc[1]; ++j)
      for (int i = 0; i < nc[0]; ++i)
        eps(i, j, k) = std::max(kMinGasFraction, 1.0 - eps_s_(i, j, k));
  });
  // eps_g and the gas velocity (of the last step) at the particles, in one pass (over ranks,
  // from the fields with their exchanged ghosts).
  eps_p_.resize(n), beta_.resize(n);
  if (halo_)
    halo_->fill(eps, fluid::kCellCentred);
  for (int a = 0; a < 3; ++a)
    ug_[a].resize(n), bv_[a].resize(n);
  make_cell_velocity();
  {
    const fluid::GridField* in[] = {&eps, &cell_u_[0], &cell_u_[1], &cell_u_[2]};
    const std::span<double> out[] = {eps_p_, ug_[0], ug_[1], ug_[2]};
    deposition_->interpolate(plan_, in, out);
  }
  // beta_i from the drag law (docs/theory.md §4) with the slip |u_g - v_i|.
  // Particle blocks as TBB tasks (each particle's values written once: thread-count free).
  const double rho = scene_.fluid.density, mu = scene_.fluid.viscosity;
  const std::vector<double>* v[3] = {&p.vx, &p.vy, &p.vz};
  for_particles(n, [&](std::size_t i) {
    const double sx = ug_[0][i] - p.vx[i], sy = ug_[1][i] - p.vy[i], sz = ug_[2][i] - p.vz[i];
    const double slip = std::sqrt(sx * sx + sy * sy + sz * sz);
    const double e = std::clamp(eps_p_[i], kMinGasFraction, 1.0);
    beta_[i] = fluid::drag_beta(law_, e, 2.0 * p.radius[i], slip, rho, mu);
    for (int a = 0; a < 3; ++a)
      bv_[a][i] = beta_[i] * (*v[a])[i];
  });
  if (scene_.fluid.one_way)
    return; // no reaction on the gas: its drag fields stay the zeros it started with
  // beta_i and beta_i v_i to the cells, in one pass.
  fluid::GridField* cells[] = {&solver_->drag_coefficient(), &solver_->drag_velocity_sum(0),
                               &solver_->drag_velocity_sum(1), &solver_->drag_velocity_sum(2)};
  for (fluid::GridField* f : cells)
    fluid::fill_field(*f, 0.0);
  const std::span<const double> values[] = {beta_, bv_[0], bv_[1], bv_[2]};
  deposition_->deposit(plan_, values, cells);
}

double GasCoupling::adaptive_dt(double time_left) const {
  fluid::FluidStepCaps caps;
  caps.max_dt = scene_.fluid.max_dt;
  caps.drag_time = drag_time_;
  caps.previous = last_dt_;
  return fluid::next_fluid_step(solver_->step_rates(), scene_.fluid.cfl, caps, time_left);
}

fluid::GasStepReport GasCoupling::step(const ParticleStore& p, double dt_f, std::size_t owned) {
  const std::size_t n = std::min(owned, p.size());
  {
    const Stopwatch timed(seconds_.deposition);
    fluid::copy_field(solver_->volume_fraction(), eps_prev_);
    deposit(p, n);
  }
  // beta_ is the drag held over this step (interpolate_forces): checked before the gas sees it.
  check_drag(p, n, dt_f);
  const fluid::GasStepSeconds before = solver_->seconds();
  double gas_seconds = 0.0;
  int substeps = 0;
  fluid::GasStepReport report;
  // The eps_g change deposited now is the particles' move over the previous fluid step (none
  // before the first: the constructor's deposit is the history).
  const double moved = last_dt_ > 0.0 ? last_dt_ : dt_f;
  try {
    const Stopwatch timed(gas_seconds);
    report = solver_->advance(dt_f, &substeps, moved, observe_);
  } catch (const std::runtime_error& e) {
    throw RunError(fmt::format("gas step: {}", e.what()));
  }
  {
    const fluid::GasStepSeconds& after = solver_->seconds();
    const double momentum = after.momentum - before.momentum;
    const double viscous = after.viscous - before.viscous;
    const double projection = after.projection - before.projection;
    seconds_.momentum += momentum, seconds_.viscous += viscous;
    seconds_.projection += projection;
    seconds_.gas_other += gas_seconds - (momentum + viscous + projection);
  }
  gas_substeps_ += substeps;
  implicit_viscosity_steps_ += report.implicit_viscosity ? 1 : 0;
  projection_iterations_ += report.projection_iterations;
  viscous_iterations_ += report.viscous_iterations;
  projection_fallbacks_ += report.used_fallback ? 1 : 0;
  source_dt_ = moved;
  last_dt_ = dt_f;
  interpolate_forces(p, n);
  return report;
}

// One pass over the drag rates beta_i / m_i of the last deposit, and one reduction over the
// ranks (a max: exact in any order):
// - the largest finite rate is the adaptive dt_f's cap, drag_time_ = 1 / rate (a fixed fluid.dt
//   never reads it);
// - with dt_f > 0, the drag on particle i is held over the fluid step with v_i frozen: forward
//   Euler on the relaxation dv/dt = (u_g - v) / tau_i, tau_i = m_i / beta_i, which scales the
//   slip by 1 - dt_f / tau_i each step. Beyond dt_f = 2 tau_i the slip grows geometrically, and
//   the run went on until a contact or a wall stopped it with words about the spring (a gas 5e4
//   times as viscous in the bed: the overlap stop 26 particle steps in). At the set-up the
//   still-gas drag time refuses such a fixed fluid.dt (apps/derived_numbers.cpp); a dense bed's
//   drag, or a particle an inlet adds, can still shorten tau_i below it. Such a step, or a drag
//   that is not finite (named first: a speed of 1e300 m/s made the gas's solve fail with "the
//   coarsest operator is not positive definite"), stops the run, naming the particle with the
//   smallest id over the ranks.
void GasCoupling::check_drag(const ParticleStore& p, std::size_t n, double dt_f) {
  const bool adaptive = !(scene_.fluid.dt > 0.0);
  if (!adaptive && !(dt_f > 0.0))
    return; // nothing asked: a fixed fluid.dt at the set-up
  std::size_t at = n;
  bool finite = true;
  double fastest = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const double rate = beta_[i] * p.inv_mass[i];
    const bool bad = !std::isfinite(rate) || !std::isfinite(bv_[0][i]) ||
                     !std::isfinite(bv_[1][i]) || !std::isfinite(bv_[2][i]);
    if (!bad)
      fastest = std::max(fastest, rate);
    if (!(dt_f > 0.0))
      continue; // the set-up's cap alone
    if (bad && (finite || p.id[i] < p.id[at]))
      at = i, finite = false;
    else if (finite && rate * dt_f >= 2.0 && (at == n || p.id[i] < p.id[at]))
      at = i;
  }
  std::array<double, 2> reduced = {fastest, at < n ? 1.0 : 0.0};
  if (comm_ != nullptr)
    comm_->max(reduced);
  if (adaptive)
    drag_time_ = reduced[0] > 0.0 ? 1.0 / reduced[0] : std::numeric_limits<double>::infinity();
  if (reduced[1] == 0.0)
    return; // no rank holds a fault
  std::string message;
  if (at < n && !finite) {
    const double sx = ug_[0][at] - p.vx[at], sy = ug_[1][at] - p.vy[at], sz = ug_[2][at] - p.vz[at];
    message = fmt::format(
        "particle {} at ({:g}, {:g}, {:g}) m: its drag is not finite (beta = {:g} kg/s at a slip "
        "of {:.4g} m/s; velocity ({:.4g}, {:.4g}, {:.4g}) m/s): no step can follow such a speed",
        p.id[at], p.x[at], p.y[at], p.z[at], beta_[at], std::sqrt(sx * sx + sy * sy + sz * sz),
        p.vx[at], p.vy[at], p.vz[at]);
  } else if (at < n) {
    const double tau = p.mass[at] / beta_[at];
    message = fmt::format(
        "particle {} at ({:g}, {:g}, {:g}) m: its drag time m / beta = {:.3g} s (drag law \"{}\", "
        "eps_g {:.3g}) is less than half the fluid step of {:.3g} s: the drag, held over a fluid "
        "step with the particle's velocity frozen, reverses and grows its slip every step beyond "
        "twice the drag time; {}",
        p.id[at], p.x[at], p.y[at], p.z[at], tau, scene_.fluid.drag, eps_p_[at], dt_f,
        adaptive ? std::string("lower fluid.max_dt")
                 : fmt::format("lower fluid.dt below {:.3g} s (a tenth of the drag time keeps it "
                               "accurate), or set fluid.dt = 0 (adaptive: it follows the drag "
                               "time)",
                               2.0 * tau));
  }
  // Over the ranks a non-finite drag comes first (its key below every id), then the smallest id.
  const std::int64_t key = at == n ? 0 : finite ? p.id[at] : p.id[at] - kNotFiniteFirst;
  throw RunError(comm_ != nullptr ? comm_->agree_on_error(key, message) : message);
}

void GasCoupling::interpolate_forces(const ParticleStore& p, std::size_t n) {
  const Stopwatch timed(seconds_.interpolation);
  // Force on each particle: drag with the new gas velocity and the frozen v_i, and -V_p grad p.
  force_ids_.assign(p.id.begin(), p.id.begin() + static_cast<std::ptrdiff_t>(n));
  const fluid::ParticlePositions pos{
      {p.x.data(), n}, {p.y.data(), n}, {p.z.data(), n}, {p.radius.data(), n}};
  const std::vector<double>* v[3] = {&p.vx, &p.vy, &p.vz};
  // The new gas velocity and the pressure gradient at the particles, in one pass.
  make_cell_velocity();
  for (int a = 0; a < 3; ++a) {
    force_[a].resize(n), gp_[a].resize(n);
    solver_->cell_pressure_gradient(a, cell_gp_[a]);
    if (halo_)
      halo_->fill(cell_gp_[a], fluid::kCellCentred);
  }
  {
    const fluid::GridField* in[] = {&cell_u_[0],  &cell_u_[1],  &cell_u_[2],
                                    &cell_gp_[0], &cell_gp_[1], &cell_gp_[2]};
    const std::span<double> out[] = {ug_[0], ug_[1], ug_[2], gp_[0], gp_[1], gp_[2]};
    // deposit()'s plan where it is of these particles (step() makes it just before the gas step).
    if (plan_.count != n || plan_.positions.x.data() != p.x.data())
      deposition_->plan(pos, plan_);
    deposition_->interpolate(plan_, in, out);
  }
  for_particles(n, [&](std::size_t i) {
    const double r = p.radius[i];
    const double vp = (4.0 / 3.0) * std::numbers::pi * r * r * r;
    for (int a = 0; a < 3; ++a)
      force_[a][i] = beta_[i] * (ug_[a][i] - (*v[a])[i]) - vp * gp_[a][i];
  });
}

void GasCoupling::make_cell_velocity() {
  const fluid::GasSolver& gas = *solver_;
  if (cell_u_version_ == gas.velocity_version())
    return;
  for (int a = 0; a < 3; ++a) {
    gas.cell_centred_velocity(a, cell_u_[a]);
    if (halo_)
      halo_->fill(cell_u_[a], fluid::kCellCentred);
  }
  cell_u_version_ = gas.velocity_version();
}

FluidDiagnostics GasCoupling::diagnostics() const {
  // One pass over the cells for the sums, one for the continuity residual, both as TBB tasks
  // over z-planes into per-plane partials summed in plane order: the values do not depend on
  // the thread count. The scratch fields are kept (make_work_fields): a row at every fluid step
  // of the 1e5 riser took 22 ms when it allocated four 3 MB fields and faulted them in.
  FluidDiagnostics d;
  const auto& nc = grid_.cells();
  const fluid::GridLayout& layout = grid_.layout();
  const double rho = scene_.fluid.density, vol = grid_.cell_volume();
  const fluid::GridField& eps = solver_->volume_fraction();
  const auto& u = solver_->velocity();
  const fluid::GridField& pp = solver_->pressure();
  // Pressure drop along the axis between the boundary faces: plane means of the full pressure
  // p = p' + gp0 . x, extrapolated linearly from the two cell planes next to each face (so the
  // particles in the first and last half cells count, and a uniform gradient is exact).
  const int ax = axis_;
  const auto& global = grid_.global_cells();
  const int m = global[ax];
  const int lo = grid_.box().lo[ax];
  // In a column the means are over the gas cells (a solid cell's p' is no gas pressure).
  const bool column = grid_.has_solid();
  // Per z-plane: the momentum sums of the three components, then each pressure plane's sum (and
  // gas cells) over the plane's cells.
  const auto planes = static_cast<std::size_t>(nc[2]);
  const auto width = static_cast<std::size_t>(3 + 2 * m);
  diag_sums_.assign(planes * width, 0.0);
  const std::array<std::ptrdiff_t, 3> stride = {layout.stride(0), layout.stride(1),
                                                layout.stride(2)};
  tbb::parallel_for(tbb::blocked_range<int>(0, nc[2]), [&](const tbb::blocked_range<int>& r) {
    for (int k = r.begin(); k != r.end(); ++k) {
      double* out = diag_sums_.data() + static_cast<std::size_t>(k) * width;
      double* plane = out + 3;
      double* gas = plane + m;
      for (int j = 0; j < nc[1]; ++j) {
        const auto row = static_cast<std::size_t>(layout.index(0, j, k));
        for (int a = 0; a < 3; ++a) {
          const double* ua = u[a].values().data();
          const auto s = static_cast<std::size_t>(stride[a]);
          double sum = 0.0;
          for (std::size_t c = row; c < row + static_cast<std::size_t>(nc[0]); ++c)
            sum += eps[c] * (0.5 * (ua[c] + ua[c + s])); // the cell-centred velocity
          out[a] += sum;
        }
        for (int i = 0; i < nc[0]; ++i) {
          const int at[3] = {i, j, k};
          const auto q = static_cast<std::size_t>(lo + at[ax]);
          if (column) {
            if (grid_.solid_cell(i, j, k))
              continue;
            gas[q] += 1.0;
          }
          plane[q] += pp[row + static_cast<std::size_t>(i)];
        }
      }
    }
  });
  std::vector<double> plane(static_cast<std::size_t>(m), 0.0);
  std::vector<double> gas_cells(column ? static_cast<std::size_t>(m) : 0, 0.0);
  std::array<double, 3> momentum{};
  for (std::size_t k = 0; k < planes; ++k) {
    const double* in = diag_sums_.data() + k * width;
    for (int a = 0; a < 3; ++a)
      momentum[static_cast<std::size_t>(a)] += in[a];
    for (std::size_t c = 0; c < plane.size(); ++c)
      plane[c] += in[3 + c];
    for (std::size_t c = 0; c < gas_cells.size(); ++c)
      gas_cells[c] += in[3 + plane.size() + c];
  }
  for (int a = 0; a < 3; ++a)
    d.gas_momentum[a] = rho * vol * momentum[static_cast<std::size_t>(a)];
  if (comm_ != nullptr) {
    // Reductions over the ranks: O(cells along the axis) for the planes.
    comm_->sum(plane);
    if (column)
      comm_->sum(gas_cells);
    comm_->sum(d.gas_momentum);
  }
  const double per_plane = static_cast<double>(global[0]) * global[1] * global[2] / m;
  const double gp0 = solver_->background_pressure_gradient()[static_cast<std::size_t>(ax)];
  const double dx = grid_.spacing(ax);
  for (int c = 0; c < m; ++c)
    plane[static_cast<std::size_t>(c)] =
        plane[static_cast<std::size_t>(c)] /
            (column ? gas_cells[static_cast<std::size_t>(c)] : per_plane) +
        gp0 * (c + 0.5) * dx;
  const double p_lo = m > 1 ? 1.5 * plane[0] - 0.5 * plane[1] : plane[0] - 0.5 * gp0 * dx;
  const double p_hi = m > 1 ? 1.5 * plane[static_cast<std::size_t>(m - 1)] -
                                  0.5 * plane[static_cast<std::size_t>(m - 2)]
                            : plane[0] + 0.5 * gp0 * dx;
  // Across a periodic axis p' repeats: the drop over the period is the imposed one.
  d.pressure_drop = grid_.periodic(ax) ? -gp0 * grid_.length(ax) : p_lo - p_hi;
  // Continuity residual of the last step.
  if (last_dt_ > 0.0) {
    fluid::copy_field(eps, diag_eps_);
    fluid::fill_cell_ghosts(grid_, halo_.get(), diag_eps_, fluid::CellGhosts::zero_gradient);
    fluid::flux_divergence(grid_, solver_->velocity(), diag_eps_, diag_div_);
    // div(eps u) + (eps^{n+1} - eps^n)/dt_s, dt_s the time the particles took for the change
    // (the previous fluid step; every gas sub-step satisfied the same rate). A maximum: the
    // same in any order.
    const double source_dt = source_dt_ > 0.0 ? source_dt_ : last_dt_;
    double worst = tbb::parallel_reduce(
        tbb::blocked_range<int>(0, nc[2]), 0.0,
        [&](const tbb::blocked_range<int>& r, double w) {
          for (int k = r.begin(); k != r.end(); ++k)
            for (int j = 0; j < nc[1]; ++j) {
              const auto row = static_cast<std::size_t>(layout.index(0, j, k));
              for (int i = 0; i < nc[0]; ++i) {
                if (column && grid_.solid_cell(i, j, k))
                  continue; // a solid cell's eps_g is not the gas's
                const std::size_t c = row + static_cast<std::size_t>(i);
                w = std::max(w, std::abs(diag_div_[c] + (eps[c] - eps_prev_[c]) / source_dt));
              }
            }
          return w;
        },
        [](double a, double b) { return std::max(a, b); });
    if (comm_ != nullptr)
      worst = comm_->max(worst);
    d.mass_residual = worst * last_dt_;
  }
  return d;
}

std::array<std::vector<double>, 3>
GasCoupling::force_in_order(std::span<const std::int64_t> ids) const {
  std::array<std::vector<double>, 3> f;
  if (force_ids_.empty())
    return f;
  if (ids.size() != force_ids_.size())
    throw RunError(
        fmt::format("{} particles, the gas force has {}", ids.size(), force_ids_.size()));
  std::unordered_map<std::int64_t, std::size_t> at;
  at.reserve(force_ids_.size());
  for (std::size_t i = 0; i < force_ids_.size(); ++i)
    at.emplace(force_ids_[i], i);
  for (int a = 0; a < 3; ++a)
    f[a].resize(ids.size());
  for (std::size_t i = 0; i < ids.size(); ++i) {
    const auto it = at.find(ids[i]);
    if (it == at.end())
      throw RunError(fmt::format("particle id {} has no gas force", ids[i]));
    for (int a = 0; a < 3; ++a)
      f[a][i] = force_[a][it->second];
  }
  return f;
}

CellFields cell_fields(const fluid::GasSolver& gas) {
  const fluid::MacGrid& grid = gas.grid();
  // On several ranks: this rank's box (its arrays), placed in the whole grid by block_lo.
  const auto& nc = grid.cells();
  const auto& global = grid.global_cells();
  std::array<int, 3> lo{};
  if (grid.distributed())
    lo = grid.box().lo;
  CellFields c;
  std::vector<double>* nodes[3] = {&c.x_nodes, &c.y_nodes, &c.z_nodes};
  for (int a = 0; a < 3; ++a) {
    c.cells[a] = global[a];
    c.block_lo[a] = lo[a];
    c.block_cells[a] = nc[a];
    for (int i = 0; i <= global[a]; ++i)
      nodes[a]->push_back(grid.origin(a) + i * grid.spacing(a));
  }
  const fluid::GridField& eps = gas.volume_fraction();
  const fluid::GridField& pp = gas.pressure();
  const auto gp0 = gas.background_pressure_gradient();
  std::array<fluid::GridField, 3> u;
  for (int a = 0; a < 3; ++a) {
    u[a] = grid.make_field();
    gas.cell_centred_velocity(a, u[a]);
  }
  for (int k = 0; k < nc[2]; ++k)
    for (int j = 0; j < nc[1]; ++j)
      for (int i = 0; i < nc[0]; ++i) {
        c.eps_g.push_back(eps(i, j, k));
        // As the pressure-drop diagnostic: p' plus the background gradient from the low corner.
        c.pressure.push_back(pp(i, j, k) + gp0[0] * (i + lo[0] + 0.5) * grid.spacing(0) +
                             gp0[1] * (j + lo[1] + 0.5) * grid.spacing(1) +
                             gp0[2] * (k + lo[2] + 0.5) * grid.spacing(2));
        for (int a = 0; a < 3; ++a)
          c.gas_velocity.push_back(u[a](i, j, k));
      }
  return c;
}

GasCoupling::State GasCoupling::save_state() const {
  State s;
  s.solver = solver_->save_state();
  if (last_dt_ > 0.0) // eps_prev_ holds a step's start only once a step was taken
    s.eps_prev.assign(eps_prev_.values().begin(), eps_prev_.values().end());
  s.last_dt = last_dt_;
  s.drag_time = drag_time_;
  s.gas_substeps = gas_substeps_;
  s.projection_iterations = projection_iterations_;
  s.projection_fallbacks = projection_fallbacks_;
  s.implicit_viscosity_steps = implicit_viscosity_steps_;
  s.viscous_iterations = viscous_iterations_;
  return s;
}

void GasCoupling::restore_state(const State& s) {
  try {
    solver_->restore_state(s.solver);
  } catch (const std::invalid_argument& e) {
    throw RunError(e.what());
  }
  if (!s.eps_prev.empty()) {
    if (s.eps_prev.size() != grid_.layout().size())
      throw RunError(fmt::format("gas state 'eps_prev' has {} values, the grid {}",
                                 s.eps_prev.size(), grid_.layout().size()));
    std::copy(s.eps_prev.begin(), s.eps_prev.end(), eps_prev_.values().begin());
  }
  last_dt_ = s.last_dt;
  if (!std::isnan(s.drag_time))
    drag_time_ = s.drag_time;
  gas_substeps_ = s.gas_substeps;
  projection_iterations_ = s.projection_iterations;
  projection_fallbacks_ = s.projection_fallbacks;
  implicit_viscosity_steps_ = s.implicit_viscosity_steps;
  viscous_iterations_ = s.viscous_iterations;
}

} // namespace cfddem::apps
