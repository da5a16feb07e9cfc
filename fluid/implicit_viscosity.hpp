// Implicit treatment of the Laplacian part of the viscous stress, div(eps mu grad u_a), for one
// face-velocity component (with the point-implicit drag on the diagonal):
//   eps_f rho (1 + k beta_f) u - theta dt div(eps mu grad u) = eps_f rho b,
// solved by conjugate gradients (the operator is SPD: it is weighted by eps_f rho), preconditioned
// by the projection's geometric multigrid on one grid (fluid/multigrid_poisson.hpp: the same
// face-coefficient form with a mass term), by Jacobi on a distributed grid.
// Removes the explicit viscous limit 2 nu dt sum 1/dx^2 <= 1/2 (cells smaller than particles).
#pragma once

#include <array>
#include <memory>
#include <vector>

#include "fluid/grid_field.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/mac_grid.hpp"
#include "fluid/multigrid_poisson.hpp"

namespace cfddem::fluid {

struct ViscousSolveReport {
  int iterations = 0; // multigrid and CG iterations together
  double relative_residual = 0.0;
  bool converged = true;
};

class ImplicitViscosity {
public:
  // halo: the grid's halo when it is one box of a distributed grid (the CG's search directions
  // are exchanged, its dot products summed over the ranks).
  explicit ImplicitViscosity(const MacGrid& grid, const GridHalo* halo = nullptr);
  ~ImplicitViscosity();
  ImplicitViscosity(const ImplicitViscosity&) = delete;
  ImplicitViscosity& operator=(const ImplicitViscosity&) = delete;

  // One grid: false solves with Jacobi CG as a distributed grid does (tests, benchmarks).
  void use_multigrid(bool on) { multigrid_ = on; }

  // lap = div(eps mu grad u_comp) / (rho eps_f) on the faces the predictor updates; ghosts of
  // u[comp] and eps filled.
  void laplacian(int comp, double mu, double rho, const GridField& eps, const GridField& u,
                 GridField& lap) const;

  // Solves (diag - c div(eps grad)) u = rhs for u[comp] on its unknown faces (not the wall and
  // inflow faces, nor the periodic copy of face 0, nor face n of an exchanged side: the
  // neighbour's face 0), c = theta dt mu. diag = eps_f rho (1 + k
  // beta_f), rhs = eps_f rho b. u: in, first guess with ghosts filled; out, the solution (the
  // caller refills ghosts). Throws std::runtime_error if CG does not reach the tolerance.
  ViscousSolveReport solve(int comp, double c, const GridField& eps, const GridField& diag,
                           const GridField& rhs, GridField& u, double tolerance,
                           int max_iterations);

private:
  // One grid: the correction of u from A e = rhs - A u by multigrid-preconditioned CG.
  ViscousSolveReport solve_multigrid(int comp, double c, const GridField& eps,
                                     const GridField& diag, const GridField& rhs, GridField& u,
                                     double tolerance, int max_iterations);
  // y = (diag - c div(eps grad)) x over the unknown faces; ghosts of x must be filled.
  void apply(int comp, double c, const GridField& eps, const GridField& diag, const GridField& x,
             GridField& y) const;
  [[nodiscard]] std::array<int, 3> unknown_lo(int comp) const;
  [[nodiscard]] std::array<int, 3> unknown_hi(int comp) const;

  [[nodiscard]] double dot(const GridField& a, const GridField& b, int comp) const;
  // The low (side 0) or high (side 1) control-volume face along b of the face at idx lies in
  // the plane of a velocity-inflow face (only meaningful for b != comp: cv_face_eps ignores it
  // otherwise).
  [[nodiscard]] bool inflow_plane(int b, int side, const std::array<int, 3>& idx) const;

  MacGrid grid_;
  MacGrid homogeneous_; // same faces with zero inflow velocity: BCs of a correction
  const GridHalo* halo_ = nullptr;
  std::array<std::array<bool, 2>, 3> inflow_{}; // grid_.inflow_face(axis, side)
  GridField r_, p_, ap_, z_;
  // Per component (one grid only): the multigrid on the box of unknown faces, its coefficient
  // and mass fields, and the residual and correction in the box's cell order.
  struct Multigrid {
    std::unique_ptr<MultigridPoisson> mg;
    std::array<GridField, 3> coef;
    GridField mass;
    std::vector<double> r, e;
  };
  std::array<Multigrid, 3> mg_;
  bool multigrid_ = true;
};

} // namespace cfddem::fluid
