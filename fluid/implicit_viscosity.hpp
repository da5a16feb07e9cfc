// Implicit treatment of the Laplacian part of the viscous stress, div(eps mu grad u_a), for one
// face-velocity component (with the point-implicit drag on the diagonal):
//   eps_f rho (1 + k beta_f) u - theta dt div(eps mu grad u) = eps_f rho b,
// solved by Chebyshev iteration where the mass term dominates (below), else by conjugate gradients
// (the operator is SPD: it is weighted by eps_f rho), preconditioned by the projection's geometric
// multigrid on one grid (fluid/multigrid_poisson.hpp: the same face-coefficient form with a mass
// term), by Jacobi on a distributed grid.
// Removes the explicit viscous limit 2 nu dt sum 1/dx^2 <= 1/2 (cells smaller than particles).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "core/cell_box.hpp"
#include "core/halo_exchange.hpp"
#include "core/simd_level.hpp"
#include "fluid/grid_field.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/mac_grid.hpp"
#include "fluid/multigrid_poisson.hpp"

namespace cfddem::fluid {

class SolidMask;

struct ViscousSolveReport {
  int iterations = 0; // Chebyshev, multigrid and CG iterations together
  double relative_residual = 0.0;
  bool converged = true;
  // The largest off-diagonal sum over the diagonal of the operator's rows (< 1: the mass term
  // makes every row strictly diagonally dominant); 0 when the solve did not compute it.
  double dominance = 0.0;
  bool chebyshev = false; // solved by the Chebyshev iteration
  // Rows of unknowns whose face coefficients the Chebyshev iteration computed from eps rather
  // than read (solve_chebyshev).
  int rows_from_eps = 0;
  bool factored = false; // one factored step (step_factored), not a solve: iterations = 1
};

// Chebyshev iteration is used while the dominance ratio rho is at most this. Its contraction per
// iteration is (sqrt(k) - 1) / (sqrt(k) + 1) with k = (1 + rho) / (1 - rho): 0.13 at the riser's
// rho = 0.25, 0.41 at 0.7, where it still takes fewer passes over the grid than two multigrid-CG
// iterations with their set-up (docs/gas_step.md, "Implicit viscosity by Chebyshev iteration").
inline constexpr double kChebyshevMaxDominance = 0.7;

// Fewest z-planes per task of the Chebyshev iteration's paired sweeps: a task's first and last
// planes take their second iteration after the sweep, from memory again.
inline constexpr int kPairedChunkPlanes = 8;

// What a Chebyshev row reads (solve_chebyshev). Every choice gives the same bits; they differ in
// how many arrays a pass streams against how many operations it takes per unknown.
enum class CoefficientSource {
  automatic,      // by chebyshev_row_source below
  stored,         // the three stored face-coefficient arrays; the inverse diagonal computed
  stored_inverse, // the stored arrays and the inverse diagonal stored by the dominance pass
  from_eps,       // a regular row's coefficients computed from eps, at every level that has the
                  // copies (not x86-64); the rows beside an inflow plane or a column: stored
};

// A component's fields (values and ghosts) below this many bytes stay in the caches between the
// passes, where an iteration is bound by its instructions (about 15 per unknown at x86-64-v3)
// rather than by bytes: there the rows read a stored inverse diagonal (one array more, a
// division and seven additions less). From this size up the passes wait on memory and the rows
// stream fewer arrays: the stored ones with the inverse computed, or at x86-64-v4 (32 registers
// for the extra operations) the coefficients computed from eps. Measured (docs/performance.md,
// "The implicit viscosity's Chebyshev rows"): on the Zen 3 VM (x86-64-v3) the stored inverse
// took 0.85-0.9x the time on the small bed's 0.6 MB fields, 0.93x on 1.2 MB, 0.98-1.03x on
// 2.09 MB, 1.12x on 3.2 MB and 0.99-1.1x on the 1e5 bed's 4.9 MB ones, and the eps rows were
// slower than the stored ones on both beds; on a Zen 5 (x86-64-v4) the
// stored rows took 0.87x the eps rows' time on the small bed's fields, the eps rows 0.85x the
// stored rows' on the 1e5 bed's.
inline constexpr std::size_t kChebyshevCachedFieldBytes = std::size_t{2} << 20;

// The source the rows of a component whose fields hold field_bytes use (never automatic).
[[nodiscard]] constexpr CoefficientSource
chebyshev_row_source(CoefficientSource source, SimdLevel level, std::size_t field_bytes) {
  switch (source) {
  case CoefficientSource::stored:
  case CoefficientSource::stored_inverse:
    return source;
  case CoefficientSource::from_eps:
    return level != SimdLevel::x86_64 ? source : CoefficientSource::stored;
  case CoefficientSource::automatic:
    break;
  }
  if (field_bytes < kChebyshevCachedFieldBytes) {
    return CoefficientSource::stored_inverse;
  }
  return level == SimdLevel::x86_64_v4 ? CoefficientSource::from_eps : CoefficientSource::stored;
}

// The unknown faces of component comp in `box` of grid's global grid, in global indices: the
// box's faces of comp but a wall or inflow face of the domain on the low side (known), and the
// face beyond its last cell where that is an outflow face of the domain (an unknown); a box side
// inside the domain or on a periodic axis owns its face 0, not its face n (the neighbour's 0).
struct UnknownFaces {
  std::array<int, 3> lo, hi;
  [[nodiscard]] bool empty() const { return hi[0] < lo[0] || hi[1] < lo[1] || hi[2] < lo[2]; }
};
[[nodiscard]] UnknownFaces unknown_faces(const MacGrid& grid, const CellBox& box, int comp);

// A distributed factored sweep's segment ends (implicit_viscosity_factored.cpp), per component
// and axis: the array holds this box's six values per line first, then, per rank whose box
// shares lines along the axis with this one, its six per shared line, brought by `exchange`
// (point to point, with those ranks only); per line of this box, where its segments' values
// lie, in order along the axis, and the place of this box's own among them.
// Made once: the halo's boxes do not change under an ImplicitViscosity.
struct FactoredSweepLinks {
  bool made = false;
  bool cut = false; // some box is cut along the axis, or it is periodic
  std::size_t size = 0;
  HaloExchange exchange;
  std::vector<std::size_t> line_first; // lines + 1: line l's segments are [first[l], first[l+1])
  std::vector<std::size_t> segment_at;
  std::vector<int> line_mine;
};

class ImplicitViscosity {
public:
  // halo: the grid's halo when it is one box of a distributed grid (the CG's search directions
  // are exchanged, its dot products summed over the ranks).
  // solid: the grid's solid mask where it has a round column (fluid/solid_mask.hpp; kept by
  // the caller): the links to closed faces are cut, so a closed face's row is its mass term
  // alone and an open face beside one loses that link (the caller puts the wall's shear on
  // the diagonal). Throws std::invalid_argument when the mask is missing or not wanted.
  explicit ImplicitViscosity(const MacGrid& grid, const GridHalo* halo = nullptr,
                             const SolidMask* solid = nullptr);
  ~ImplicitViscosity();
  ImplicitViscosity(const ImplicitViscosity&) = delete;
  ImplicitViscosity& operator=(const ImplicitViscosity&) = delete;

  // One grid: false solves with Jacobi CG as a distributed grid does (tests, benchmarks).
  void use_multigrid(bool on) { multigrid_ = on; }

  // The caller's word that `eps` keeps its values (ghosts included) until its next
  // declare_eps: the face coefficients are then made once per component and declaration from
  // it, with no copy of it kept to compare each call against (GasSolver declares its eps_g once
  // a gas step, after filling its ghosts: three copies and three compares of the field a step
  // saved). Calls with another field compare against the copy, as without a declaration.
  void declare_eps(const GridField& eps) {
    declared_eps_ = &eps;
    ++declaration_;
  }

  // lap = div(eps mu grad u_comp) / (rho eps_f) on the unknown faces (solve's), 0 on the others
  // (prescribed or periodic copies: the boundary fill replaces whatever the predictor writes
  // there); ghosts of u[comp] and eps filled.
  void laplacian(int comp, double mu, double rho, const GridField& eps, const GridField& u,
                 GridField& lap);

  // Solves (diag - c div(eps grad)) u = rhs for u[comp] on its unknown faces (not the wall and
  // inflow faces, nor the periodic copy of face 0, nor face n of an exchanged side: the
  // neighbour's face 0), c = theta dt mu. diag = eps_f rho (1 + k
  // beta_f), rhs = eps_f rho b. u: in, first guess with ghosts filled; out, the solution (the
  // caller refills ghosts). Throws std::runtime_error if CG does not reach the tolerance.
  ViscousSolveReport solve(int comp, double c, const GridField& eps, const GridField& diag,
                           const GridField& rhs, GridField& u, double tolerance,
                           int max_iterations);

  // Instead of solving the same system, one step of its approximate factorization in delta
  // form from the first guess u (ghosts filled),
  //   (diag + c N_x) diag^-1 (diag + c N_y) diag^-1 (diag + c N_z) (u_new - u) = rhs - A u,
  // N_b = -d_b(eps d_b) along axis b: three sweeps of tridiagonal line solves (cyclic on a
  // periodic axis) rather than iterations to a tolerance. Second order in time like the
  // trapezoidal solve it replaces (docs/gas_step.md, "The factored viscous step"). On a
  // distributed grid the lines cross the boxes: each box solves its segments and sends their
  // ends to the boxes that share its lines (FactoredSweepLinks; the one grid's result up to
  // round-off). With `rhs_is_residual`, rhs already holds rhs - A u (the gas solver makes it
  // from the L(u^n) its step keeps, so the stencil is not applied to u^n twice): the step
  // solves for it directly and does not read u's ghosts.
  ViscousSolveReport step_factored(int comp, double c, const GridField& eps, const GridField& diag,
                                   const GridField& rhs, GridField& u,
                                   bool rhs_is_residual = false);
  // The factored step's scratch fields and end closures made now (the gas solver's set-up),
  // not at the first step_factored (each new field of the 1e5 bed's grid took about 11 ms to
  // fault in there).
  void prepare_factored();

  // Off: every solve goes to CG (tests of the CG paths).
  void use_chebyshev(bool on) { chebyshev_ = on; }

  // The instruction set of the Chebyshev rows (default simd_level(); tests and benchmarks
  // compare the levels, which give the same bits).
  void use_simd_level(SimdLevel level) { level_ = level; }

  // Off: the Chebyshev iteration takes one iteration per sweep over the grid, as a distributed
  // grid does (tests: both give the same bits).
  void use_paired_iterations(bool on) { pairs_ = on; }

  // Where the Chebyshev rows take their face coefficients from (default automatic; tests and
  // benchmarks force either: both give the same bits).
  void use_coefficient_source(CoefficientSource source) { source_ = source; }

private:
  // Chebyshev iteration with the Jacobi preconditioner, when the rows' dominance ratio is at
  // most kChebyshevMaxDominance (report.chebyshev false otherwise, u untouched). Pointwise
  // passes and one ghost fill per iteration; no inner products but the residual norm.
  ViscousSolveReport solve_chebyshev(int comp, double c, const GridField& eps,
                                     const GridField& diag, const GridField& rhs, GridField& u,
                                     double tolerance, int max_iterations);
  // cv_k_[comp][b] = eps on the low control-volume face along b / dx_b^2 of each unknown face
  // of comp and of the one beyond the box's high end along b; recomputed only when eps (ghosts
  // included) differs from the last one seen for comp (both stages of a gas step share it), or,
  // for the declared field (declare_eps), once per declaration.
  void face_coefficients(int comp, const GridField& eps);
  // Per row of comp's unknowns (j fastest, then k), 1 where its face coefficients are
  // face_coefficients' plain eps formulas (no face on an inflow plane, no solid mask), so the
  // Chebyshev rows compute them from eps instead of reading the three stored arrays; 0 where
  // they read them. Depends on the grid alone: made once per component.
  const std::vector<char>& regular_rows(int comp);
  // CG: preconditioned by the multigrid on one grid (with Jacobi CG to finish if it stalls), by
  // Jacobi on a distributed grid.
  ViscousSolveReport solve_cg(int comp, double c, const GridField& eps, const GridField& diag,
                              const GridField& rhs, GridField& u, double tolerance,
                              int max_iterations);
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
  // 1 where the link between a face at p and the one below it along an axis of stride sb is
  // open (both faces open: `open`, a component's open faces), 0 where it is cut; 1 without a
  // column (open == nullptr).
  [[nodiscard]] static double link(const double* open, std::ptrdiff_t p, std::ptrdiff_t sb) {
    return open == nullptr ? 1.0 : open[p] * open[p - sb];
  }

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
  bool chebyshev_ = true;
  // Chebyshev: face coefficients, regular rows and the two search directions.
  std::array<std::array<GridField, 3>, 3> cv_k_;
  std::array<std::vector<char>, 3> regular_;
  // A column's open faces per component (the caller's SolidMask; null without a column).
  std::array<const double*, 3> open_{};
  std::array<GridField, 3> eps_seen_; // made at the first compared call (declare_eps: never)
  std::array<bool, 3> cv_k_valid_{};
  // declare_eps: the field and its declaration's number; per component, the declaration its
  // coefficients were made under (0: made from a compared copy, eps_seen_).
  const GridField* declared_eps_ = nullptr;
  std::uint64_t declaration_ = 0;
  std::array<std::uint64_t, 3> cv_k_declaration_{};
  GridField dir_, dir_next_;
  GridField inverse_diagonal_; // CoefficientSource::stored_inverse
  // The factored step: per component, what the homogeneous ghost fill puts beyond each end of
  // a non-periodic line, end[b][side] times the end unknown (found once: it depends on the grid
  // alone); the line solves' scratch.
  struct FactoredEnds {
    std::array<std::array<double, 2>, 3> end{};
    bool known = false;
  };
  const FactoredEnds& factored_ends(int comp);
  void make_factored_scratch();
  std::array<FactoredEnds, 3> factored_ends_{};
  GridField factored_cp_, factored_zp_, factored_wp_;
  const FactoredSweepLinks& sweep_links(int comp, int axis);
  std::array<std::array<FactoredSweepLinks, 3>, 3> sweep_links_{};
  std::vector<double> sweep_ends_;
  bool pairs_ = true;
  SimdLevel level_ = simd_level();
  CoefficientSource source_ = CoefficientSource::automatic;
};

} // namespace cfddem::fluid
