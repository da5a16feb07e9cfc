// Explicit right-hand side of the model-A gas momentum equation on the faces (docs/theory.md §5,
// divided by eps rho_g): -u.grad u (limited MUSCL) + div(eps tau)/(eps rho_g) + body force.
// Pressure is left to the projection and drag to the point-implicit update.
#pragma once

#include <array>

#include "core/simd_level.hpp"
#include "fluid/grid_field.hpp"
#include "fluid/mac_grid.hpp"
#include "fluid/muscl_kernels.hpp"

namespace cfddem::fluid {

struct GasProperties {
  double density = 1.0;   // rho_g [kg/m^3]
  double viscosity = 0.0; // mu_g [Pa s]
  std::array<double, 3> gravity{};
};

// rhs[comp] on faces 0..n (comp axis) x interior cells (other axes). Preconditions: ghosts of u
// and eps filled. body[comp] is the uniform body acceleration (g - gp0/rho_g).
// Advection in convective form, u.grad q = div(a q) - q div(a), with a the face-averaged
// advecting velocity on the control-volume faces and q the MUSCL upwind edge state.
// Viscous stress tau = mu (grad u + grad u^T) - (2/3) mu (div u) I, eps averaged to edges.
// exclude_laplacian leaves out div(eps mu grad u_a), the part ImplicitViscosity treats
// implicitly; the transpose and dilatation parts stay explicit.
// Each control-volume face quantity (upwind flux, advecting velocity, stress) is computed
// once, into the workspace, and differenced: per component, one pass writes the quantities of
// all three directions, a second sums their differences (both TBB-parallel over k-planes, each
// point written once: bitwise independent of the thread count).
struct MomentumWorkspace {
  std::array<GridField, 3> flux, speed, stress; // on the low control-volume face along b
  GridField divergence;
  // godunov_momentum_rhs, on component a's faces, ghosts filled as its velocity: base[a][b], the
  // base state along b (the edge state without its normal slope term), and half[a], u_a
  // advanced half a step (the advecting velocities are means of it).
  std::array<std::array<GridField, 3>, 3> base;
  std::array<GridField, 3> half;
};

// Sizes the workspace's fields to the layout (those of godunov_momentum_rhs too with `godunov`),
// so that their first touch falls in the solver's set-up, not in its first step (22 fields of
// 4.4 MB on the 1e5 bed's grid). The passes size what is missing anyway.
void size_workspace(MomentumWorkspace& work, const GridLayout& layout, bool godunov);

// `level`: the instruction set of the row loops' copy (core/simd_level.hpp); every level gives
// bitwise the same fields, so only tests and measurements name one.
void momentum_rhs(const MacGrid& grid, const GasProperties& gas, Limiter limiter,
                  const std::array<GridField, 3>& u, const GridField& eps,
                  const std::array<double, 3>& body, std::array<GridField, 3>& rhs,
                  MomentumWorkspace& work, bool exclude_laplacian = false,
                  SimdLevel level = simd_level());
// Same, with a workspace of its own (allocates).
void momentum_rhs(const MacGrid& grid, const GasProperties& gas, Limiter limiter,
                  const std::array<GridField, 3>& u, const GridField& eps,
                  const std::array<double, 3>& body, std::array<GridField, 3>& rhs);

class GridHalo;

// What the time-centred edge states of godunov_momentum_rhs are extrapolated with.
struct EdgePrediction {
  double dt = 0.0;                     // the step the edge states are centred in (at dt / 2)
  const GridHalo* halo = nullptr;      // the grid's halo on R ranks (ghost fills are collective)
  const GridField* pressure = nullptr; // p' of the last step, ghosts filled (its gradient)
  // L(u^n) per unit mass, the Laplacian part of the viscous term where it is implicit (and
  // left out of the right-hand side); nullptr where it is explicit.
  const std::array<GridField, 3>* laplacian = nullptr;
  // The point-implicit drag over dt on the faces (GasSolver): 1 + k beta_f and k (beta v)_f.
  const std::array<GridField, 3>* drag_gain = nullptr;
  const std::array<GridField, 3>* drag_push = nullptr;
};

// momentum_rhs with the advective fluxes taken from time-centred upwind edge states, the
// single-stage Godunov step of Bell, Colella & Glaz (1989, J. Comput. Phys. 85, 257) as
// MFIX-Exa takes it (docs/gas_step.md "The Godunov step"): the edge state on a control-volume
// face along b is extrapolated from the upwind point m by half a cell and half a step,
//   q_e = q_m + (1/2)(1 - a dt / dx_b) s_b(m) - (dt/2) sum_{c != b} T_c(m) + (dt/2) F_m,
// with s_b the limited slope, T_c(m) = ubar_c dq/dx_c the transverse advection (the difference
// of the upwinded MUSCL states on m's faces along c; corner transport upwind, Colella 1990,
// J. Comput. Phys. 87, 171), a the advecting velocity, the mean of the two half-step values
// u^n + (dt/2)(-u.grad u + F) of u_b around the face, by which the state is upwinded, and F
// the rest of the momentum rate at t^n (viscous terms, body force, the last step's pressure
// gradient); the drag is taken point-implicitly over dt/2, so a stiff drag cannot overshoot.
// Linear stability (von Neumann, docs/gas_step.md): max(max_a c_a, sum_a c_a / 1.25) <= 0.95
// for the Courant numbers c_a = |u_a| dt / dx_a (fluid_step_rule.hpp). The explicit viscous
// terms in rhs are those of the half-step velocities u^n + (dt/2)(-u.grad u + F) (the midpoint
// rule, second order; exclude_laplacian leaves the Laplacian to a Crank-Nicolson solve).
// Collective on R ranks (the base states' ghost fills).
void godunov_momentum_rhs(const MacGrid& grid, const GasProperties& gas, Limiter limiter,
                          const std::array<GridField, 3>& u, const GridField& eps,
                          const std::array<double, 3>& body, const EdgePrediction& prediction,
                          std::array<GridField, 3>& rhs, MomentumWorkspace& work,
                          bool exclude_laplacian, SimdLevel level = simd_level());

} // namespace cfddem::fluid
