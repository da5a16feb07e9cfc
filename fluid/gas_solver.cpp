#include "fluid/gas_solver.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include "core/simd_level.hpp"
#include "core/stopwatch.hpp"
#include "fluid/box_loops.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/multigrid_poisson.hpp"

namespace cfddem::fluid {

namespace {

// A row of a-faces: its first face's index, its length, the stride to the face below (the
// cell below), and the step's dt and gas density.
struct FaceRow {
  std::ptrdiff_t f0, n, s;
  double dt, rho;
};

// The drag's face factors on a row (docs/theory.md §5): the projection's mobility
// dt/(rho + dt beta_f/eps_f), the gain 1 + k beta_f and the push k (beta v)_f with
// k = dt/(rho eps_f), from the face means of eps_g, beta and beta v; with implicit viscosity
// (mass not null) also the face mass eps_f rho, from the same eps_f.
[[gnu::always_inline]] inline void face_drag_body(const double* eps, const double* beta,
                                                  const double* beta_v, double* mobility,
                                                  double* gain, double* push, double* mass,
                                                  const FaceRow& r) {
  const double dt = r.dt, rho = r.rho;
  for (std::ptrdiff_t f = r.f0; f < r.f0 + r.n; ++f) {
    const std::ptrdiff_t below = f - r.s;
    const double eps_f = 0.5 * (eps[f] + eps[below]);
    const double beta_f = 0.5 * (beta[f] + beta[below]);
    const double beta_v_f = 0.5 * (beta_v[f] + beta_v[below]);
    const double k_drag = dt / (rho * eps_f);
    mobility[f] = dt / (rho + dt * beta_f / eps_f);
    gain[f] = 1.0 + k_drag * beta_f;
    push[f] = k_drag * beta_v_f;
    if (mass != nullptr) { // loop-invariant: GCC versions the loop on it
      mass[f] = eps_f * rho;
    }
  }
}

// The implicit viscous system of one stage on a row of a-faces (GasSolver::stage): the diagonal
// eps_f rho (1 + k beta_f) and the right-hand side eps_f rho (u* + k (beta v)_f) [- eps_f dt grad
// p, lagged], u* = u^n + dt rate, rate = R (the corrector: the stages' mean) [+ L(u^n) / 2,
// trapezoidal]. Restrict parameters: the loop vectorizes (the cell-by-cell lambda it replaced,
// through the fields' operator[], did not); the same operations per face.
struct ImplicitRowInputs {
  const double *rhs, *rhs_stage, *lap_start, *pressure, *mass, *gain, *push, *start;
  bool corrector, half_lap, lagged;
  double dt, inv_dx, dt_over_rho;
};

// The stage's rate at face f: R (the corrector: the stages' mean) [+ L(u^n) / 2, trapezoidal].
[[gnu::always_inline]] inline double stage_rate(bool corrector, bool half_lap, const double* rhs,
                                                const double* rhs_stage, const double* lap,
                                                std::ptrdiff_t f) {
  double rate = corrector ? 0.5 * (rhs[f] + rhs_stage[f]) : rhs[f];
  if (half_lap) {
    rate += 0.5 * lap[f]; // trapezoidal: half of L(u^n) explicit
  }
  return rate;
}
// With FromResidual, the same system's residual at u^n instead of its right-hand side (the
// factored step's, which starts from u^n): rhs - A u^n = eps_f rho (u^n + dt (R + L(u^n)) +
// k (beta v)_f) [- eps_f dt grad p] - diag u^n, since A = diag - theta dt mu div(eps grad) and
// eps_f rho dt L = dt mu div(eps grad u^n) (L = lap_start: mu div(eps grad u^n) / (rho eps_f),
// the face's eps_f as the mass's): the implicit part theta dt L and the explicit part the
// trapezoidal rule keeps, (1 - theta) dt L, add up to dt L whatever theta. The stencil is then
// applied once, for L(u^n), not again for A u^n.
template <bool FromResidual>
[[gnu::noinline]] void implicit_system_row(const ImplicitRowInputs& in, const FaceRow& r,
                                           double* __restrict diag, double* __restrict vrhs) {
  const double* __restrict rhs = in.rhs;
  const double* __restrict rhs_stage = in.rhs_stage;
  const double* __restrict lap = in.lap_start;
  const double* __restrict pp = in.pressure;
  const double* __restrict mass = in.mass;
  const double* __restrict gain = in.gain;
  const double* __restrict push = in.push;
  const double* __restrict start = in.start;
  const double dt = in.dt;
  for (std::ptrdiff_t f = r.f0; f < r.f0 + r.n; ++f) {
    const double rate = FromResidual
                            ? stage_rate(in.corrector, false, rhs, rhs_stage, lap, f) + lap[f]
                            : stage_rate(in.corrector, in.half_lap, rhs, rhs_stage, lap, f);
    const double grad_p = in.lagged ? (pp[f] - pp[f - r.s]) * in.inv_dx : 0.0;
    const double d = mass[f] * gain[f];
    const double b = mass[f] * (start[f] + dt * rate + push[f] - in.dt_over_rho * grad_p);
    diag[f] = d;
    vrhs[f] = FromResidual ? b - d * start[f] : b;
  }
}

// The row's copies, one type per instruction set (core/simd_level.hpp: the loop vectorizes only
// from restrict parameters; every copy gives the same bits). Two divisions per face: the copies
// take four (AVX2) or eight at a time.
#define CFDDEM_FACE_DRAG_ROWS(NAME, ...)                                                           \
  struct NAME {                                                                                    \
    [[gnu::noinline __VA_ARGS__]] static void                                                      \
    row(const double* __restrict eps, const double* __restrict beta,                               \
        const double* __restrict beta_v, double* __restrict mobility, double* __restrict gain,     \
        double* __restrict push, double* __restrict mass, const FaceRow& r) {                      \
      face_drag_body(eps, beta, beta_v, mobility, gain, push, mass, r);                            \
    }                                                                                              \
  };
CFDDEM_SIMD_COPY_TYPES(CFDDEM_FACE_DRAG_ROWS, FaceDrag)
#undef CFDDEM_FACE_DRAG_ROWS

} // namespace

GasSolver::GasSolver(const MacGrid& grid, const GasSolverSettings& settings,
                     std::shared_ptr<const GridHalo> halo)
    : grid_(grid), settings_(settings), halo_(std::move(halo)), solid_(grid) {
  if (grid.distributed() != (halo_ != nullptr)) {
    throw std::invalid_argument("gas solver: a distributed grid needs its halo (and only it)");
  }
  const GasProperties& gas = settings.gas;
  if (!(gas.density > 0.0) || gas.viscosity < 0.0) {
    throw std::invalid_argument(
        fmt::format("gas density must be > 0 and viscosity >= 0 (got {} kg/m^3, {} Pa s)",
                    gas.density, gas.viscosity));
  }
  const double max_courant = max_stable_courant(settings.advection);
  if (!(settings.cfl > 0.0 && settings.cfl <= max_courant)) {
    throw std::invalid_argument(
        fmt::format("fluid cfl = {} is outside (0, {}]: the gas step is unstable above {}",
                    settings.cfl, max_courant, max_courant));
  }
  if (settings.fixed_dt < 0.0) {
    throw std::invalid_argument("fluid fixed_dt must be >= 0 (0: adaptive)");
  }
  if (settings.time_order != 1 && settings.time_order != 2) {
    throw std::invalid_argument(
        fmt::format("fluid time_order = {} (choose 1 or 2)", settings.time_order));
  }
  if (settings.projections != 1 && settings.projections != 2) {
    throw std::invalid_argument(
        fmt::format("fluid projections = {} (choose 1 or 2)", settings.projections));
  }
  const std::array<double, 3> gp0 = background_pressure_gradient();
  for (int a = 0; a < 3; ++a) {
    body_[a] = gas.gravity[a] - gp0[a] / gas.density;
    u_[a] = grid.make_field();
    u_start_[a] = grid.make_field();
    rhs_[a] = grid.make_field();
    rhs_stage_[a] = grid.make_field();
    mobility_[a] = grid.make_field();
    drag_gain_[a] = grid.make_field();
    drag_push_[a] = grid.make_field();
    beta_v_[a] = grid.make_field();
  }
  p_ = grid.make_field();
  eps_ = grid.make_field(1.0);
  eps_old_ = grid.make_field(1.0);
  eps_target_ = grid.make_field(1.0); // advance() swaps eps_ into it: no copy at the first step
  beta_ = grid.make_field();
  source_ = grid.make_field();
  size_workspace(work_, grid.layout(), settings.advection == Advection::godunov);
  projection_ = std::make_unique<PressureProjection>(grid, settings.projection, halo_.get());
  if ((settings.implicit_viscosity || settings.implicit_viscosity_auto) && gas.viscosity > 0.0) {
    implicit_now_ = !settings.implicit_viscosity_auto;
    viscosity_ = std::make_unique<ImplicitViscosity>(grid, halo_.get(),
                                                     solid_.empty() ? nullptr : &solid_);
    viscosity_->use_multigrid(settings.viscous_multigrid);
    if (settings.factored_viscosity) {
      viscosity_->prepare_factored();
    }
    for (GridField& l : lap_start_) {
      l = grid.make_field();
    }
    for (GridField& m : face_mass_) {
      m = grid.make_field();
    }
    diag_ = grid.make_field();
    vrhs_ = grid.make_field();
  }
}

std::array<double, 3> background_pressure_gradient(const std::array<bool, 3>& periodic,
                                                   const std::array<double, 3>& pressure_drop,
                                                   const std::array<double, 3>& length,
                                                   double density,
                                                   const std::array<double, 3>& gravity) {
  std::array<double, 3> gp0{};
  for (std::size_t a = 0; a < 3; ++a) {
    gp0[a] = periodic[a] ? -pressure_drop[a] / length[a] : density * gravity[a];
  }
  return gp0;
}

std::array<double, 3> GasSolver::background_pressure_gradient() const {
  std::array<bool, 3> periodic{};
  std::array<double, 3> drop{}, length{};
  for (int a = 0; a < 3; ++a) {
    const auto k = static_cast<std::size_t>(a);
    periodic[k] = grid_.periodic(a);
    drop[k] = grid_.pressure_drop(a);
    length[k] = grid_.length(a);
  }
  return fluid::background_pressure_gradient(periodic, drop, length, settings_.gas.density,
                                             settings_.gas.gravity);
}

std::array<double, 3> GasSolver::max_face_speeds() const {
  const auto& n = grid_.cells();
  std::array<double, 3> umax{};
  for (int a = 0; a < 3; ++a) {
    std::array<int, 3> hi = n;
    hi[a] = n[a] + 1;
    // A max is exact in any order: the planes are TBB tasks.
    umax[a] = tbb::parallel_reduce(
        tbb::blocked_range<int>(0, hi[2]), 0.0,
        [&](const tbb::blocked_range<int>& r, double m) {
          for (int k = r.begin(); k != r.end(); ++k) {
            for (int j = 0; j < hi[1]; ++j) {
              for (int i = 0; i < hi[0]; ++i) {
                m = std::max(m, std::abs(u_[a](i, j, k)));
              }
            }
          }
          return m;
        },
        [](double x, double y) { return std::max(x, y); });
  }
  if (halo_) {
    halo_->comm().max(umax); // a max is exact: every rank takes the same dt
  }
  return umax;
}

std::array<double, 2> GasSolver::courant_rates() const {
  return courant_rates(max_face_speeds());
}

std::array<double, 2> GasSolver::courant_rates(const std::array<double, 3>& umax) const {
  const double nu = settings_.gas.viscosity / settings_.gas.density;
  // {explicit viscosity, implicit}: the axes' terms added in the same order as ever.
  std::array<double, 2> rates{};
  if (settings_.advection == Advection::godunov) {
    // The adaptive step's rates without forcing (fluid_step_rule.hpp). The method of lines keeps
    // its interleaved sum below, bitwise as ever.
    const FluidStepRates r =
        fluid_step_rates(umax, {grid_.spacing(0), grid_.spacing(1), grid_.spacing(2)}, nu, true, {},
                         Advection::godunov);
    return {r.advection + r.viscous, r.advection};
  }
  for (int a = 0; a < 3; ++a) {
    const double dx = grid_.spacing(a);
    rates[0] += umax[a] / dx + 2.0 * nu / (dx * dx);
    rates[1] += umax[a] / dx;
  }
  return rates;
}

double GasSolver::courant_number(double dt) const {
  return courant_at(dt, courant_rates());
}

void GasSolver::use_simd_level(SimdLevel level) {
  level_ = level;
  if (viscosity_) {
    viscosity_->use_simd_level(level);
  }
  if (MultigridPoisson* mg = projection_->multigrid()) {
    mg->use_simd_level(level);
  }
}

double GasSolver::next_substep(double interval, double t, double rate) const {
  const double step = rate > 0.0 ? settings_.cfl / rate : std::numeric_limits<double>::infinity();
  double dt = std::min(interval - t, step);
  // Do not leave a sliver of a step at the end.
  if (interval - t - dt < 1e-3 * dt) {
    dt = interval - t;
  }
  return dt;
}

double GasSolver::substeps_for(double interval, double rate) const {
  if (rate > 0.0 && interval * rate / settings_.cfl > kMaxSubstepsPerInterval) {
    return interval * rate / settings_.cfl; // not counted one by one
  }
  double t = 0.0;
  int count = 0;
  while (interval - t > 1e-12 * interval) {
    t += next_substep(interval, t, rate);
    ++count;
  }
  return count;
}

void GasSolver::check_substep_count(double interval, double t, int count, double rate) const {
  const double left = rate > 0.0 ? (interval - t) * rate / settings_.cfl : 0.0;
  if (!(count + left > kMaxSubstepsPerInterval)) {
    return;
  }
  // The fastest face of the axis whose speed adds most to the rate; every rank looks at its own
  // faces and all name the first over the global grid.
  const std::array<double, 3> umax = max_face_speeds();
  int axis = 0;
  for (int a = 1; a < 3; ++a) {
    if (umax[a] / grid_.spacing(a) > umax[axis] / grid_.spacing(axis)) {
      axis = a;
    }
  }
  const auto& n = grid_.cells();
  const auto& global = grid_.global_cells();
  const CellBox& box = grid_.box();
  std::int64_t key = std::numeric_limits<std::int64_t>::max();
  std::string where;
  std::array<int, 3> hi = n;
  hi[axis] = n[axis] + 1;
  for (int k = 0; k < hi[2] && where.empty(); ++k) {
    for (int j = 0; j < hi[1] && where.empty(); ++j) {
      for (int i = 0; i < hi[0] && where.empty(); ++i) {
        if (umax[axis] > 0.0 && std::abs(u_[axis](i, j, k)) == umax[axis]) {
          const std::array<int, 3> c = {i, j, k};
          std::array<double, 3> x{};
          for (int a = 0; a < 3; ++a) {
            x[a] = a == axis ? grid_.face_position(a, c[a]) : grid_.cell_centre(a, c[a]);
          }
          key = (static_cast<std::int64_t>(box.lo[2] + k) * (global[1] + 1) + box.lo[1] + j) *
                    (global[0] + 1) +
                box.lo[0] + i;
          where = fmt::format("{:.3g} m/s along {} at the face at ({:.4g}, {:.4g}, {:.4g}) m",
                              u_[axis](i, j, k), "xyz"[axis], x[0], x[1], x[2]);
        }
      }
    }
  }
  if (halo_) {
    where = halo_->comm().agree_on_error(key, where);
  }
  const double advective = courant_rates(umax)[1];
  throw std::runtime_error(fmt::format(
      "the gas would take {:.3g} sub-steps in this fluid step of {:.3g} s at fluid.cfl = {:g} "
      "(a Courant rate of {:.3g} 1/s; {}), beyond the {:g} a fluid step may take: {}",
      count + left, interval, settings_.cfl, rate,
      where.empty()
          ? std::string("the gas is at rest: the explicit viscous term sets it")
          : fmt::format("the gas speeds' part {:.3g} 1/s, the fastest {}", advective, where),
      kMaxSubstepsPerInterval,
      settings_.cfl < 0.1 * max_stable_courant(settings_.advection)
          ? fmt::format("raise fluid.cfl (the gas step is stable up to {:g})",
                        max_stable_courant(settings_.advection))
          : std::string("the gas has run away (look at its boundary speeds, fluid.dt and the "
                        "drag)")));
}

double GasSolver::dt_for_courant(double courant) const {
  const double rate = courant_number(1.0);
  return rate > 0.0 ? courant / rate : std::numeric_limits<double>::infinity();
}

FluidStepRates GasSolver::step_rates() const {
  return fluid_step_rates(max_face_speeds(), {grid_.spacing(0), grid_.spacing(1), grid_.spacing(2)},
                          settings_.gas.viscosity / settings_.gas.density, !viscosity_, body_,
                          settings_.advection);
}

GasStepReport GasSolver::step() {
  return step(settings_.fixed_dt > 0.0 ? settings_.fixed_dt : dt_for_courant(settings_.cfl));
}

void GasSolver::stage(double dt, Stage kind, GasStepReport& report) {
  const GridLayout& layout = grid_.layout();
  const auto& n = grid_.cells();
  // One projection per step: the predictor of time order 2 takes the pressure gradient of the
  // last step, -dt/rho grad p per unit of the drag gain (the projection's mobility), and is not
  // projected. It reads p's ghosts as every step leaves them (filled at its end; a restore
  // brings them, a rebox fills them: fluid/grid_move.cpp).
  const bool lagged =
      kind == Stage::predictor && settings_.time_order == 2 && settings_.projections == 1;
  // The Laplacian's implicit weight: backward Euler in the predictor, trapezoidal (Crank-
  // Nicolson) in the corrector and the Godunov step, where L(u^n) is at hand.
  const bool trapezoidal = kind != Stage::predictor;
  const bool have_lap_start = keeps_lap_start();
  const double theta = trapezoidal ? 0.5 : 1.0;
  // The implicit Laplacian by one factored step from u^n, or by a solve from a first guess,
  // which takes theta dt L(u^n) where guess_lap (both read by the implicit branch below only).
  const bool factored = settings_.factored_viscosity;
  const bool guess_lap =
      !factored && have_lap_start &&
      explicit_guess_pays(theta * dt * settings_.gas.viscosity / settings_.gas.density,
                          {grid_.spacing(0), grid_.spacing(1), grid_.spacing(2)},
                          settings_.viscous_guess_limit);
  // Point-implicit drag (docs/theory.md §5) on u* = u^n + dt R (Euler) or u^n + dt (R^n + R^1)/2:
  // u <- (u* + dt (beta v)_f/(rho eps_f)) / (1 + dt beta_f/(rho eps_f)), with the face factors
  // step() computed once for both stages.
  // The stage's start u^n: u_ itself in the Godunov step (its one stage reads u^n at a face only
  // to write that face, so u_ needs no copy), u_start_ in the method of lines' stages.
  std::array<GridField, 3>& start = kind == Stage::godunov ? u_ : u_start_;
  for (int a = 0; a < 3; ++a) {
    std::array<int, 3> hi = {n[0] - 1, n[1] - 1, n[2] - 1};
    hi[a] = n[a]; // faces 0..n along a
    const double* gain = drag_gain_[a].values().data();
    const double* push = drag_push_[a].values().data();
    const auto below = static_cast<std::size_t>(layout.stride(a));
    const double inv_dx = 1.0 / grid_.spacing(a);
    const double dt_over_rho = dt / settings_.gas.density;
    if (!implicit_now_) {
      // Explicit viscosity: the update row by row through local pointers (GCC vectorizes these
      // loops, not the cell-by-cell lambda below through the fields' operator[]); the same
      // operations per face.
      const double* r0 = rhs_[a].values().data();
      const double* r1 = rhs_stage_[a].values().data(); // read by the corrector only
      const double* us = start[a].values().data();
      const double* pp = p_.values().data();
      const double* mobility = mobility_[a].values().data();
      double* u = u_[a].values().data();
      const auto s = static_cast<std::ptrdiff_t>(below);
      const bool corrector = kind == Stage::corrector;
      for_box_rows(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t row, int, int) {
        const std::ptrdiff_t end = row + hi[0] + 1;
        if (us == u) { // in place (written so: GCC would test u against us and not vectorize)
          for (std::ptrdiff_t f = row; f < end; ++f) {
            u[f] = (u[f] + dt * r0[f] + push[f]) / gain[f];
          }
        } else if (corrector) {
          for (std::ptrdiff_t f = row; f < end; ++f) {
            u[f] = (us[f] + dt * (0.5 * (r0[f] + r1[f])) + push[f]) / gain[f];
          }
        } else {
          for (std::ptrdiff_t f = row; f < end; ++f) {
            u[f] = (us[f] + dt * r0[f] + push[f]) / gain[f];
          }
        }
        if (lagged) {
          for (std::ptrdiff_t f = row; f < end; ++f) {
            u[f] -= mobility[f] * ((pp[f] - pp[f - s]) * inv_dx);
          }
        }
      });
      continue;
    }
    // The implicit system's rows, first guess and solve are the viscous phase's time.
    const Stopwatch timed(seconds_.viscous);
    // eps_f rho (1 + k beta_f) u - theta dt div(eps mu grad u) = eps_f rho (u* + k (beta v)_f)
    // [- eps_f dt grad p, lagged], row by row (implicit_system_row).
    const ImplicitRowInputs inputs{rhs_[a].values().data(),
                                   rhs_stage_[a].values().data(),
                                   lap_start_[a].values().data(),
                                   p_.values().data(),
                                   face_mass_[a].values().data(),
                                   gain,
                                   push,
                                   start[a].values().data(),
                                   kind == Stage::corrector,
                                   trapezoidal,
                                   lagged,
                                   dt,
                                   inv_dx,
                                   dt_over_rho};
    // The factored step starts from u^n: where the step keeps L(u^n), its right-hand side is
    // the residual made from it (implicit_system_row<true>), and the guess needs no ghosts.
    const bool from_residual = factored && have_lap_start;
    for_box_rows(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t row, int, int) {
      const FaceRow face_row{row, hi[0] + 1, static_cast<std::ptrdiff_t>(below), dt, 0.0};
      if (from_residual) {
        implicit_system_row<true>(inputs, face_row, diag_.values().data(), vrhs_.values().data());
      } else {
        implicit_system_row<false>(inputs, face_row, diag_.values().data(), vrhs_.values().data());
      }
    });
    // First guess: with guess_lap, the implicit part taken at u^n, theta dt L(u^n) (see
    // explicit_guess_pays). The factored step starts from u^n itself: from a guess that holds
    // the trapezoidal rule's explicit half it would keep that half's amplification, up to
    // |1 - theta dt nu lambda| (lambda an eigenvalue of -L; 4.8 on the bed's cells), on the
    // modes stiff along two or three axes (docs/gas_step.md, "The factored viscous step"). In
    // the Godunov step u^n is u_ itself: nothing to copy.
    if (!factored) {
      for_box(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t p) {
        const auto f = static_cast<std::size_t>(p);
        const double rate =
            stage_rate(inputs.corrector, inputs.half_lap, inputs.rhs, inputs.rhs_stage,
                       inputs.lap_start, static_cast<std::ptrdiff_t>(f));
        const double lap = guess_lap ? theta * lap_start_[a][f] : 0.0;
        u_[a][f] = (start[a][f] + dt * (rate + lap) + push[f]) / gain[f];
      });
    } else if (&start[a] != &u_[a]) {
      for_box(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t p) {
        const auto f = static_cast<std::size_t>(p);
        u_[a][f] = start[a][f];
      });
    }
    if (!from_residual)
      fill_velocity_ghosts(grid_, halo_.get(), a, u_[a]); // the guess's boundary values
    const double c = theta * dt * settings_.gas.viscosity;
    const ViscousSolveReport vr =
        factored
            ? viscosity_->step_factored(a, c, eps_, diag_, vrhs_, u_[a], from_residual)
            : viscosity_->solve(a, c, eps_, diag_, vrhs_, u_[a], settings_.viscous_tolerance, 1000);
    report.viscous_iterations += vr.iterations;
  }
  fill_ghosts_and_close();
  if (lagged) {
    return;
  }
  ProjectionReport pr;
  {
    const Stopwatch timed(seconds_.projection);
    pr = projection_->project(u_, eps_, mobility_, source_, p_);
  }
  fill_ghosts_and_close();
  report.projection_iterations += pr.iterations;
  report.relative_residual = std::max(report.relative_residual, pr.relative_residual);
  report.used_fallback = report.used_fallback || pr.used_fallback;
}

void GasSolver::fill_ghosts_and_close() {
  fill_velocity_ghosts(grid_, halo_.get(), u_);
  solid_.close(u_); // a solid cell's faces (an inflow face under it too) carry no gas
}

GasStepReport GasSolver::step(double dt) {
  ++velocity_version_;
  fill_ghosts_and_close();
  return step_with_ghosts(dt, courant_rates());
}

GasStepReport GasSolver::step_with_ghosts(double dt, const std::array<double, 2>& rates,
                                          double source_scale, bool keep_eps_old) {
  GasStepReport report;
  report.dt = dt;
  if (!(dt > 0.0) || !std::isfinite(dt)) {
    throw std::runtime_error(fmt::format(
        "fluid step: dt = {} is not a positive finite number (an inviscid gas at rest has no "
        "CFL time step: set fixed_dt)",
        dt));
  }
  report.courant = courant_at(dt, rates);
  const double max_courant = max_stable_courant(settings_.advection);
  if (report.courant > max_courant * (1.0 + 1e-12)) {
    throw std::runtime_error(fmt::format(
        "fluid step: dt = {:g} s gives Courant number {:.3g} > {} (stable dt <= {:g} s)", dt,
        report.courant, max_courant, dt_for_courant(max_courant)));
  }
  const GridLayout& layout = grid_.layout();
  const auto& n = grid_.cells();
  const double rho = settings_.gas.density;
  fill_cell_ghosts(grid_, halo_.get(), eps_, CellGhosts::zero_gradient);
  if (viscosity_ && settings_.declare_eps) {
    // eps_ (ghosts included) stays as it is until this step's end: the viscous coefficients are
    // made from it once a step, not checked against a copy at every call.
    viscosity_->declare_eps(eps_);
  }
  fill_cell_ghosts(grid_, halo_.get(), eps_old_, CellGhosts::zero_gradient);
  fill_cell_ghosts(grid_, halo_.get(), beta_, CellGhosts::zero_gradient);
  for (int a = 0; a < 3; ++a) {
    fill_cell_ghosts(grid_, halo_.get(), beta_v_[a], CellGhosts::zero_gradient);
  }
  // Projection mobility dt/(rho + dt beta_f/eps_f): the pressure correction sees the same
  // implicit drag factor as the predictor, so the corrected velocity is exactly constrained.
  // On wall and inflow faces the velocity is prescribed: their eps_f, mobility and drag are
  // computed here and in stage() but never read (the inflow's eps_g = 1 enters through
  // flux_divergence and the viscous stresses in the inflow plane).
  // The same face averages give the stages' drag factors, 1 + k beta_f and k (beta v)_f with
  // k = dt/(rho eps_f), and with implicit viscosity the face mass eps_f rho: computed here once
  // for both stages (one pass over eps, beta and beta v per axis).
  const bool implicit = implicit_now_;
  report.implicit_viscosity = implicit;
  for (int a = 0; a < 3; ++a) {
    const std::ptrdiff_t s = layout.stride(a);
    std::array<int, 3> hi = {n[0] - 1, n[1] - 1, n[2] - 1};
    hi[a] = n[a]; // faces 0..n along a
    const double* eps = eps_.values().data();
    const double* beta = beta_.values().data();
    const double* beta_v = beta_v_[a].values().data();
    double* mobility = mobility_[a].values().data();
    double* gain = drag_gain_[a].values().data();
    double* push = drag_push_[a].values().data();
    double* mass = implicit ? face_mass_[a].values().data() : nullptr;
    with_copy_at<FaceDragX86_64, FaceDragV3, FaceDragV4>(level_, [&](auto rows) {
      for_box_rows(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t row, int, int) {
        rows.row(eps, beta, beta_v, mobility, gain, push, mass,
                 FaceRow{row, hi[0] + 1, s, dt, rho});
      });
    });
  }
  {
    // Through local pointers: GCC vectorizes the row with them (checking that source_ overlaps
    // neither input), not through the fields' operator[].
    const double* eps = eps_.values().data();
    const double* eps_old = eps_old_.values().data();
    double* source = source_.values().data();
    for_box_rows(layout, {0, 0, 0}, {n[0] - 1, n[1] - 1, n[2] - 1},
                 [&](std::ptrdiff_t row, int, int) {
                   for (std::ptrdiff_t c = row; c < row + n[0]; ++c) {
                     source[c] = (eps[c] - eps_old[c]) / dt * source_scale;
                   }
                 });
  }
  if (!solid_.empty()) {
    close_solid_faces(dt);
  }
  // Predictor: u1 = P(u^n + dt R(u^n)). Corrector (time_order 2, MFIX-Exa's predictor-
  // corrector, i.e. Heun): u^{n+1} = P(u^n + dt (R(u^n) + R(u1))/2). Each stage is projected,
  // so the returned field satisfies the constraint whatever u^n did.
  // With implicit viscosity the predictor is backward Euler and the corrector trapezoidal in
  // the Laplacian part div(eps mu grad u).
  const bool godunov = settings_.advection == Advection::godunov;
  if (!godunov) { // the stages' start (stage(): the Godunov step starts from u_ itself)
    for (int a = 0; a < 3; ++a) {
      copy_field(u_[a], u_start_[a]);
    }
  }
  if (implicit && keeps_lap_start()) {
    const Stopwatch timed(seconds_.viscous);
    for (int a = 0; a < 3; ++a) { // u_ is still u^n here
      viscosity_->laplacian(a, settings_.gas.viscosity, rho, eps_, u_[a], lap_start_[a]);
    }
  }
  if (godunov) {
    // One stage: the advective fluxes from edge states centred at t^n + dt/2, the explicit
    // viscous terms of the half-step velocities (the Laplacian's trapezoidal where implicit),
    // one projection.
    EdgePrediction prediction;
    prediction.dt = dt;
    prediction.halo = halo_.get();
    prediction.pressure = &p_;
    prediction.laplacian = implicit ? &lap_start_ : nullptr;
    prediction.drag_gain = &drag_gain_;
    prediction.drag_push = &drag_push_;
    {
      const Stopwatch timed(seconds_.momentum);
      godunov_momentum_rhs(grid_, settings_.gas, settings_.limiter, u_, eps_, body_, prediction,
                           rhs_, work_, implicit, level_);
    }
    stage(dt, Stage::godunov, report);
  } else {
    {
      const Stopwatch timed(seconds_.momentum);
      momentum_rhs(grid_, settings_.gas, settings_.limiter, u_, eps_, body_, rhs_, work_, implicit,
                   level_);
    }
    stage(dt, Stage::predictor, report);
    if (settings_.time_order == 2) {
      {
        const Stopwatch timed(seconds_.momentum);
        momentum_rhs(grid_, settings_.gas, settings_.limiter, u_, eps_, body_, rhs_stage_, work_,
                     implicit, level_);
      }
      stage(dt, Stage::corrector, report);
    }
  }
  fill_cell_ghosts(grid_, halo_.get(), p_, CellGhosts::pressure);
  if (keep_eps_old) {
    copy_field(eps_, eps_old_);
  }
  return report;
}

GasStepReport GasSolver::advance(double interval, int* substeps, double eps_interval,
                                 const SubstepObserver& observe) {
  ++velocity_version_;
  if (!(interval > 0.0)) {
    throw std::runtime_error(fmt::format("fluid advance: interval {} is not positive", interval));
  }
  if (eps_interval < 0.0 || !std::isfinite(eps_interval)) {
    throw std::runtime_error(
        fmt::format("fluid advance: eps_g interval {} is not a positive time", eps_interval));
  }
  // Each sub-step's eps_g rises by its share of the change, so (eps - eps_old)/dt is the change
  // over `interval`; the scale makes it the change over the time the particles took (exactly 1
  // for a fixed fluid step).
  const double source_scale = eps_interval > 0.0 ? interval / eps_interval : 1.0;
  // eps_g of the fluid step's end and start (members: no allocation per fluid step). The end,
  // eps_ as the caller left it, is swapped into eps_target_ (made with the solver, on its grid),
  // and swapped back after the last sub-step. The start
  // is eps_old_ itself until a sub-step that is not the last would overwrite it: only then is it
  // copied (most intervals take one sub-step).
  std::swap(eps_, eps_target_);
  const GridField& target = eps_target_;
  bool start_copied = false;
  GasStepReport total;
  double t = 0.0;
  int count = 0;
  while (interval - t > 1e-12 * interval) {
    fill_ghosts_and_close();
    const std::array<double, 2> rates = courant_rates();
    if (count == 0 && settings_.implicit_viscosity_auto && viscosity_) {
      // The viscous treatment for this interval, from the Courant rates at its start.
      implicit_now_ = kImplicitSubstepCost * substeps_for(interval, rates[1]) <
                      substeps_for(interval, rates[0]);
    }
    const double rate = implicit_now_ ? rates[1] : rates[0];
    check_substep_count(interval, t, count, rate);
    const double dt = next_substep(interval, t, rate);
    const bool last = dt == interval - t;
    const double fraction = last ? 1.0 : (t + dt) / interval;
    std::span<double> e = eps_.values();
    std::span<const double> e0 = (start_copied ? eps_start_ : eps_old_).values();
    std::span<const double> e1 = target.values();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, e.size(), 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t m = r.begin(); m != r.end(); ++m) {
                          e[m] = e0[m] + fraction * (e1[m] - e0[m]);
                        }
                      });
    if (!last && !start_copied) { // this sub-step's end sets eps_old_
      copy_field(eps_old_, eps_start_);
      start_copied = true;
    }
    // u's ghosts filled above; after the last sub-step eps_old_ becomes the target (below).
    const GasStepReport r = step_with_ghosts(dt, rates, source_scale, !last);
    total.dt = r.dt;
    total.courant = std::max(total.courant, r.courant);
    total.projection_iterations += r.projection_iterations;
    total.viscous_iterations += r.viscous_iterations;
    total.relative_residual = std::max(total.relative_residual, r.relative_residual);
    total.used_fallback = total.used_fallback || r.used_fallback;
    t += dt;
    ++count;
    if (observe)
      observe(count, t, dt, interval);
  }
  total.implicit_viscosity = implicit_now_;
  std::swap(eps_, eps_target_); // eps_ is the end again, bit for bit
  copy_field(eps_, eps_old_);
  if (substeps != nullptr) {
    *substeps = count;
  }
  return total;
}

void GasSolver::close_solid_faces(double dt) {
  const GridLayout& layout = grid_.layout();
  const auto& n = grid_.cells();
  const double nu = settings_.gas.viscosity / settings_.gas.density;
  for (int a = 0; a < 3; ++a) {
    std::array<int, 3> hi = {n[0] - 1, n[1] - 1, n[2] - 1};
    hi[a] = n[a];
    const GridField& open = solid_.open_faces(a);
    const GridField& wall = solid_.wall_rate(a);
    const GridField& normal = solid_.normal_rate(a);
    // The explicit Laplacian reads a closed neighbour as zero, so only the mirror's extra shear
    // is added; the implicit one cuts the links to closed faces (fluid/implicit_viscosity.hpp),
    // so the wall's whole shear, and the normal neighbour's zero, come back here.
    const bool implicit = implicit_now_;
    for_box(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t p) {
      const auto f = static_cast<std::size_t>(p);
      // No pressure coupling through a closed face; the wall's shear beside it point-implicit
      // with the drag: (1 + k beta_f + dt nu wall_rate) u = ... (fluid/solid_mask.hpp).
      mobility_[a][f] *= open[f];
      drag_gain_[a][f] += dt * nu * (implicit ? 2.0 * wall[f] + normal[f] : wall[f]);
    });
  }
  solid_.clear_solid(source_); // the particles' volume beside the wall changes no solid cell
}

void GasSolver::cell_pressure_gradient(int axis, GridField& out) const {
  const std::ptrdiff_t s = grid_.layout().stride(axis);
  const double gp0 = background_pressure_gradient()[static_cast<std::size_t>(axis)];
  const double inv_2dx = 0.5 / grid_.spacing(axis);
  const auto& n = grid_.cells();
  if (!solid_.empty()) {
    // Beside the wall the difference is one-sided, across the open face only (a solid cell's
    // p' is no gas pressure); inside the solid, the background gradient alone.
    const GridField& open = solid_.open_faces(axis);
    const double inv_dx = 1.0 / grid_.spacing(axis);
    for_box(grid_.layout(), {0, 0, 0}, {n[0] - 1, n[1] - 1, n[2] - 1}, [&](std::ptrdiff_t p) {
      const auto c = static_cast<std::size_t>(p);
      const auto up = c + static_cast<std::size_t>(s);
      const auto down = c - static_cast<std::size_t>(s);
      const double faces = open[c] + open[up];
      const double sum = open[up] * (p_[up] - p_[c]) + open[c] * (p_[c] - p_[down]);
      out[c] = (faces > 0.0 ? sum / faces * inv_dx : 0.0) + gp0;
    });
    return;
  }
  for_box(grid_.layout(), {0, 0, 0}, {n[0] - 1, n[1] - 1, n[2] - 1}, [&](std::ptrdiff_t p) {
    const auto c = static_cast<std::size_t>(p);
    out[c] =
        (p_[c + static_cast<std::size_t>(s)] - p_[c - static_cast<std::size_t>(s)]) * inv_2dx + gp0;
  });
}

void GasSolver::cell_centred_velocity(int axis, GridField& out) const {
  const std::ptrdiff_t s = grid_.layout().stride(axis);
  const auto& n = grid_.cells();
  const double* u = u_[axis].values().data();
  double* o = out.values().data(); // local pointers: the row vectorizes (as in the source's)
  for_box_rows(grid_.layout(), {0, 0, 0}, {n[0] - 1, n[1] - 1, n[2] - 1},
               [&](std::ptrdiff_t row, int, int) {
                 for (std::ptrdiff_t c = row; c < row + n[0]; ++c) {
                   o[c] = 0.5 * (u[c] + u[c + s]);
                 }
               });
}

GasSolver::State GasSolver::save_state() const {
  const auto copy = [](const GridField& f) {
    return std::vector<double>(f.values().begin(), f.values().end());
  };
  State s;
  for (int a = 0; a < 3; ++a) {
    s.velocity[a] = copy(u_[a]);
  }
  s.pressure = copy(p_);
  s.volume_fraction = copy(eps_);
  s.volume_fraction_old = copy(eps_old_);
  return s;
}

void GasSolver::restore_state(const State& s) {
  ++velocity_version_;
  const auto load = [](const std::vector<double>& from, GridField& to, const char* name) {
    if (from.size() != to.values().size()) {
      throw std::invalid_argument(fmt::format("gas state '{}' has {} values, the grid {}", name,
                                              from.size(), to.values().size()));
    }
    std::copy(from.begin(), from.end(), to.values().begin());
  };
  for (int a = 0; a < 3; ++a) {
    load(s.velocity[a], u_[a], "velocity");
  }
  load(s.pressure, p_, "pressure");
  load(s.volume_fraction, eps_, "volume_fraction");
  load(s.volume_fraction_old, eps_old_, "volume_fraction_old");
}

} // namespace cfddem::fluid
