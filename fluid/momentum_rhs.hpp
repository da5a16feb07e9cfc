// Explicit right-hand side of the model-A gas momentum equation on the faces (docs/theory.md §5,
// divided by eps rho_g): -u.grad u (limited MUSCL) + div(eps tau)/(eps rho_g) + body force.
// Pressure is left to the projection and drag to the point-implicit update.
#pragma once

#include <array>

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
// once, into the workspace, and differenced.
struct MomentumWorkspace {
  GridField flux, speed, stress, viscous, divergence;
};

void momentum_rhs(const MacGrid& grid, const GasProperties& gas, Limiter limiter,
                  const std::array<GridField, 3>& u, const GridField& eps,
                  const std::array<double, 3>& body, std::array<GridField, 3>& rhs,
                  MomentumWorkspace& work, bool exclude_laplacian = false);
// Same, with a workspace of its own (allocates).
void momentum_rhs(const MacGrid& grid, const GasProperties& gas, Limiter limiter,
                  const std::array<GridField, 3>& u, const GridField& eps,
                  const std::array<double, 3>& body, std::array<GridField, 3>& rhs);

} // namespace cfddem::fluid
