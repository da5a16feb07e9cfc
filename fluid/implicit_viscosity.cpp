#include "fluid/implicit_viscosity.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include "fluid/box_loops.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/solid_mask.hpp"
#include "fluid/viscous_stencil.hpp"

namespace cfddem::fluid {

namespace {

MacGridSpec homogeneous_spec(const MacGridSpec& spec) {
  MacGridSpec h = spec;
  for (BoundaryCondition& bc : h.bc) {
    bc.velocity = {0.0, 0.0, 0.0};
    bc.pressure = 0.0;
  }
  return h;
}

// Pointwise loops run their z-planes as TBB tasks (fluid/box_loops.hpp: each point written once,
// bitwise independent of the thread count); sums run over the points in one fixed serial order.
template <class F>
void for_box_serial(const GridLayout& layout, const std::array<int, 3>& lo,
                    const std::array<int, 3>& hi, F&& f) {
  for (int k = lo[2]; k <= hi[2]; ++k) {
    for (int j = lo[1]; j <= hi[1]; ++j) {
      const auto row = static_cast<std::ptrdiff_t>(layout.index(lo[0], j, k));
      for (std::ptrdiff_t p = row; p <= row + (hi[0] - lo[0]); ++p) {
        f(p);
      }
    }
  }
}

// The pointwise loop f(p, idx) with the point's indices, planes as TBB tasks.
template <class F>
void for_box_indexed(const GridLayout& layout, const std::array<int, 3>& lo,
                     const std::array<int, 3>& hi, F&& f) {
  for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int j, int k) {
    for (int i = lo[0]; i <= hi[0]; ++i) {
      f(row + (i - lo[0]), std::array<int, 3>{i, j, k});
    }
  });
}

// eps on the low control-volume face of face p along b (cell p - 1 when b == a, else the
// (a, b) edge average, or the incoming gas's on the plane of an inflow face: mac_grid.hpp).
double cv_face_eps(const double* ep, std::ptrdiff_t p, std::ptrdiff_t sa, std::ptrdiff_t sb,
                   bool same, bool inflow_plane = false) {
  if (same) {
    return ep[p - sa];
  }
  return inflow_plane ? kInflowVolumeFraction
                      : 0.25 * (ep[p] + ep[p - sa] + ep[p - sb] + ep[p - sa - sb]);
}

} // namespace

ImplicitViscosity::ImplicitViscosity(const MacGrid& grid, const GridHalo* halo,
                                     const SolidMask* solid)
    : grid_(grid),
      homogeneous_(grid.distributed() ? MacGrid(homogeneous_spec(grid.spec()), grid.box())
                                      : MacGrid(homogeneous_spec(grid.spec()))),
      halo_(halo), r_(grid.layout()), p_(grid.layout()), ap_(grid.layout()), z_(grid.layout()),
      dir_(grid.layout()), dir_next_(grid.layout()) {
  for (int b = 0; b < 3; ++b) {
    inflow_[b] = {grid.inflow_face(b, 0), grid.inflow_face(b, 1)};
    for (GridField& k : cv_k_[static_cast<std::size_t>(b)]) {
      k = GridField(grid.layout());
    }
  }
  if (grid.has_solid() != (solid != nullptr && !solid->empty())) {
    throw std::invalid_argument("implicit viscosity: a grid with solid cells needs its mask (and "
                                "only it)");
  }
  if (solid != nullptr && !solid->empty()) {
    for (int comp = 0; comp < 3; ++comp) {
      open_[static_cast<std::size_t>(comp)] = solid->open_faces(comp).values().data();
    }
  }
}

void ImplicitViscosity::face_coefficients(int comp, const GridField& eps) {
  const GridLayout& layout = grid_.layout();
  const auto c = static_cast<std::size_t>(comp);
  if (&eps == declared_eps_) { // declare_eps: made once per declaration, nothing compared
    if (cv_k_valid_[c] && cv_k_declaration_[c] == declaration_) {
      return;
    }
    cv_k_declaration_[c] = declaration_;
  } else {
    if (cv_k_valid_[c] && cv_k_declaration_[c] == 0 &&
        equal_values(eps.values(), eps_seen_[c].values())) {
      return;
    }
    if (eps_seen_[c].values().size() != layout.size()) {
      eps_seen_[c] = GridField(layout); // only a caller that does not declare its eps needs it
    }
    copy_field(eps, eps_seen_[c]);
    cv_k_declaration_[c] = 0;
  }
  cv_k_valid_[c] = true;
  const double* ep = eps.values().data();
  const std::ptrdiff_t sa = layout.stride(comp);
  const std::array<int, 3> lo = unknown_lo(comp);
  for (int b = 0; b < 3; ++b) {
    const std::ptrdiff_t sb = layout.stride(b);
    const double inv_dx2 = 1.0 / (grid_.spacing(b) * grid_.spacing(b));
    std::array<int, 3> top = unknown_hi(comp);
    ++top[b]; // the high face of the last unknown along b
    double* k = cv_k_[c][static_cast<std::size_t>(b)].values().data();
    // The face is the low face of the unknown at idx and the high face of the one below it,
    // either of which may lie on an inflow plane (as in solve_multigrid). Row by row: the
    // inflow test varies along a row only for b = x, at the row's two ends.
    const auto on_inflow = [&](const std::array<int, 3>& idx) {
      std::array<int, 3> below = idx;
      below[b] -= 1;
      return inflow_plane(b, 0, idx) || inflow_plane(b, 1, below);
    };
    for_box_rows(layout, lo, top, [&](std::ptrdiff_t row, int j, int kk) {
      const std::ptrdiff_t end = row + (top[0] - lo[0]);
      if (b == comp) {
        for (std::ptrdiff_t p = row; p <= end; ++p) {
          k[p] = inv_dx2 * ep[p - sa];
        }
        return;
      }
      if (b != 0 && on_inflow({lo[0], j, kk})) {
        for (std::ptrdiff_t p = row; p <= end; ++p) {
          k[p] = inv_dx2 * kInflowVolumeFraction;
        }
        return;
      }
      for (std::ptrdiff_t p = row; p <= end; ++p) {
        k[p] = inv_dx2 * (0.25 * (ep[p] + ep[p - sa] + ep[p - sb] + ep[p - sa - sb]));
      }
      if (b == 0) {
        for (const int i : {lo[0], top[0]}) {
          if (on_inflow({i, j, kk})) {
            k[row + (i - lo[0])] = inv_dx2 * kInflowVolumeFraction;
          }
        }
      }
      if (const double* open = open_[c]; open != nullptr) {
        for (std::ptrdiff_t p = row; p <= end; ++p) {
          k[p] *= link(open, p, sb);
        }
      }
    });
  }
}

const std::vector<char>& ImplicitViscosity::regular_rows(int comp) {
  const auto c = static_cast<std::size_t>(comp);
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  const std::size_t rows = hi[1] < lo[1] || hi[2] < lo[2]
                               ? 0
                               : static_cast<std::size_t>(hi[1] - lo[1] + 1) *
                                     static_cast<std::size_t>(hi[2] - lo[2] + 1);
  std::vector<char>& regular = regular_[c];
  if (regular.size() == rows) {
    return regular;
  }
  regular.assign(rows, 0);
  if (open_[c] != nullptr) {
    return regular; // a closed face's cut links live in the stored coefficients only
  }
  // As face_coefficients: a face along b is the low face of the unknown at idx and the high face
  // of the one below it, and either may lie on an inflow plane. A row's faces along x (b = 0)
  // can do so only at its two ends, its faces along y or z all or none.
  const auto on_inflow = [&](int b, std::array<int, 3> idx) {
    std::array<int, 3> below = idx;
    below[b] -= 1;
    return inflow_plane(b, 0, idx) || inflow_plane(b, 1, below);
  };
  std::size_t n = 0;
  for (int k = lo[2]; k <= hi[2]; ++k) {
    for (int j = lo[1]; j <= hi[1]; ++j, ++n) {
      bool plain = true;
      for (int b = 0; b < 3 && plain; ++b) {
        if (b == comp) {
          continue; // eps of the cell below: never an inflow plane's
        }
        std::array<int, 3> low{lo[0], j, k};
        std::array<int, 3> high = low;
        if (b == 0) {
          high[0] = hi[0] + 1;
        } else {
          high[b] += 1;
        }
        plain = !on_inflow(b, low) && !on_inflow(b, high);
      }
      regular[n] = plain ? 1 : 0;
    }
  }
  return regular;
}

ImplicitViscosity::~ImplicitViscosity() = default;

UnknownFaces unknown_faces(const MacGrid& grid, const CellBox& box, int comp) {
  UnknownFaces u{box.lo, {box.hi[0] - 1, box.hi[1] - 1, box.hi[2] - 1}};
  // A wall, inflow or outflow side is never periodic, so "on the domain's face" is all it needs.
  const BoundaryKind low = grid.bc(comp, 0).kind;
  if (box.lo[comp] == 0 && (low == BoundaryKind::wall || low == BoundaryKind::inflow)) {
    u.lo[comp] += 1;
  }
  if (box.hi[comp] == grid.global_cells()[comp] && grid.bc(comp, 1).kind == BoundaryKind::outflow) {
    u.hi[comp] += 1;
  }
  return u;
}

std::array<int, 3> ImplicitViscosity::unknown_lo(int comp) const {
  const CellBox& box = grid_.box();
  const std::array<int, 3> g = unknown_faces(grid_, box, comp).lo;
  return {g[0] - box.lo[0], g[1] - box.lo[1], g[2] - box.lo[2]};
}

std::array<int, 3> ImplicitViscosity::unknown_hi(int comp) const {
  const CellBox& box = grid_.box();
  const std::array<int, 3> g = unknown_faces(grid_, box, comp).hi;
  return {g[0] - box.lo[0], g[1] - box.lo[1], g[2] - box.lo[2]};
}

bool ImplicitViscosity::inflow_plane(int b, int side, const std::array<int, 3>& idx) const {
  return inflow_[b][side] && idx[b] == (side == 0 ? 0 : grid_.cells(b) - 1);
}

namespace {

// lap = mu div(eps grad q) / (rho eps_f) on the points p0 .. p0 + n - 1 of a row (k[b]: the low
// control-volume face's eps / dx_b^2; sa: the component's stride). Not inlined: GCC keeps the
// restrict parameters of a function it calls, and the loop vectorizes with them.
[[gnu::noinline]] void laplacian_row(std::ptrdiff_t p0, std::ptrdiff_t n,
                                     const double* __restrict k0, const double* __restrict k1,
                                     const double* __restrict k2, const double* __restrict q,
                                     const double* __restrict ep, double* __restrict lap,
                                     std::ptrdiff_t sa, std::ptrdiff_t sy, std::ptrdiff_t sz,
                                     double mu_over_rho) {
  for (std::ptrdiff_t p = p0; p < p0 + n; ++p) {
    double k[6];
    viscous_stencil::faces_at<-1>(k0, k1, k2, nullptr, 0.0, 0.0, 0.0, p, sy, sz, k);
    const double sum = viscous_stencil::laplacian_sum(k, q, p, sy, sz);
    lap[p] = mu_over_rho * sum / (0.5 * (ep[p] + ep[p - sa]));
  }
}

} // namespace

void ImplicitViscosity::laplacian(int comp, double mu, double rho, const GridField& eps,
                                  const GridField& u, GridField& lap) {
  face_coefficients(comp, eps);
  const GridLayout& layout = grid_.layout();
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  const auto& k = cv_k_[static_cast<std::size_t>(comp)];
  zero_outside(lap, lo, hi); // the rows below write every unknown
  for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int) {
    laplacian_row(row, hi[0] - lo[0] + 1, k[0].values().data(), k[1].values().data(),
                  k[2].values().data(), u.values().data(), eps.values().data(), lap.values().data(),
                  layout.stride(comp), layout.stride(1), layout.stride(2), mu / rho);
  });
}

void ImplicitViscosity::apply(int comp, double c, const GridField& eps, const GridField& diag,
                              const GridField& x, GridField& y) const {
  const GridLayout& layout = grid_.layout();
  const double* ep = eps.values().data();
  const double* q = x.values().data();
  const std::ptrdiff_t sa = layout.stride(comp);
  const double* open = open_[static_cast<std::size_t>(comp)];
  for_box_indexed(
      layout, unknown_lo(comp), unknown_hi(comp),
      [&](std::ptrdiff_t p, const std::array<int, 3>& idx) {
        double sum = 0.0;
        for (int b = 0; b < 3; ++b) {
          const std::ptrdiff_t sb = layout.stride(b);
          const double inv_dx2 = 1.0 / (grid_.spacing(b) * grid_.spacing(b));
          const double e_lo =
              cv_face_eps(ep, p, sa, sb, b == comp, inflow_plane(b, 0, idx)) * link(open, p, sb);
          const double e_hi = cv_face_eps(ep, p + sb, sa, sb, b == comp, inflow_plane(b, 1, idx)) *
                              link(open, p + sb, sb);
          sum += (e_hi * (q[p + sb] - q[p]) - e_lo * (q[p] - q[p - sb])) * inv_dx2;
        }
        y[static_cast<std::size_t>(p)] = diag[static_cast<std::size_t>(p)] * q[p] - c * sum;
      });
}

double ImplicitViscosity::dot(const GridField& a, const GridField& b, int comp) const {
  double s = 0.0;
  for_box_serial(grid_.layout(), unknown_lo(comp), unknown_hi(comp), [&](std::ptrdiff_t p) {
    s += a[static_cast<std::size_t>(p)] * b[static_cast<std::size_t>(p)];
  });
  return s;
}

// The unknown faces of component comp form a box of cells for the multigrid: along comp the faces
// lo..hi (a known wall or inflow face one spacing beyond: dirichlet_node; an outflow face's
// zero-gradient ghost: Neumann), across it the cells (wall and inflow ghosts -u: Dirichlet on the
// face; outflow: Neumann). Its face coefficients are c eps_cv / h^2, its mass term diag.
ViscousSolveReport ImplicitViscosity::solve_multigrid(int comp, double c, const GridField& eps,
                                                      const GridField& diag, const GridField& rhs,
                                                      GridField& u, double tolerance,
                                                      int max_iterations) {
  const GridLayout& layout = grid_.layout();
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  std::array<int, 3> m{};
  for (int b = 0; b < 3; ++b) {
    m[b] = hi[b] - lo[b] + 1;
  }
  Multigrid& s = mg_[static_cast<std::size_t>(comp)];
  if (!s.mg) {
    std::array<std::array<PoissonSide, 2>, 3> sides{};
    std::array<double, 3> spacing{};
    for (int b = 0; b < 3; ++b) {
      spacing[b] = grid_.spacing(b);
      for (int side = 0; side < 2; ++side) {
        const BoundaryKind kind = grid_.bc(b, side).kind;
        sides[b][side] = kind == BoundaryKind::periodic  ? PoissonSide::periodic
                         : kind == BoundaryKind::outflow ? PoissonSide::neumann
                         : b == comp                     ? PoissonSide::dirichlet_node
                                                         : PoissonSide::dirichlet;
      }
    }
    s.mg = std::make_unique<MultigridPoisson>(m, spacing, sides);
    const GridLayout box(m);
    s.coef = {GridField(box), GridField(box), GridField(box)};
    s.mass = GridField(box);
    const std::size_t cells = static_cast<std::size_t>(m[0]) * m[1] * m[2];
    s.r.assign(cells, 0.0);
    s.e.assign(cells, 0.0);
  }
  const GridLayout& box = s.mass.layout();
  const double* ep = eps.values().data();
  const std::ptrdiff_t sa = layout.stride(comp);
  for (int b = 0; b < 3; ++b) {
    const std::ptrdiff_t sb = layout.stride(b);
    const double k = c / (grid_.spacing(b) * grid_.spacing(b));
    std::array<int, 3> top = m;
    top[b] = m[b] + 1; // faces 0..m_b along b
    // Planes of faces as TBB tasks (each coefficient written once).
    tbb::parallel_for(0, top[2], [&](int kk) {
      for (int jj = 0; jj < top[1]; ++jj) {
        for (int ii = 0; ii < top[0]; ++ii) {
          const auto p =
              static_cast<std::ptrdiff_t>(layout.index(lo[0] + ii, lo[1] + jj, lo[2] + kk));
          // The same face volume fraction as apply(): the face is the lo face of the unknown
          // at `up` and the hi face of the one below it, either of which may lie on an inflow
          // plane (the incoming gas's eps there, mac_grid.hpp).
          const std::array<int, 3> up{lo[0] + ii, lo[1] + jj, lo[2] + kk};
          std::array<int, 3> dn = up;
          dn[b] -= 1;
          s.coef[static_cast<std::size_t>(b)][box.index(ii, jj, kk)] =
              k *
              cv_face_eps(ep, p, sa, sb, b == comp,
                          inflow_plane(b, 0, up) || inflow_plane(b, 1, dn)) *
              link(open_[static_cast<std::size_t>(comp)], p, sb);
        }
      }
    });
  }
  // r = rhs - A u with the true boundary values in u's ghosts.
  apply(comp, c, eps, diag, u, ap_);
  // The unknowns into the multigrid's vectors (entry n = ii + m0 (jj + m1 kk)), planes as TBB
  // tasks; the norms after, summed in that order on one thread.
  const auto entry = [&](int jj, int kk) {
    return static_cast<std::size_t>(m[0]) *
           (static_cast<std::size_t>(jj) + static_cast<std::size_t>(m[1]) * kk);
  };
  tbb::parallel_for(0, m[2], [&](int kk) {
    for (int jj = 0; jj < m[1]; ++jj) {
      std::size_t n = entry(jj, kk);
      for (int ii = 0; ii < m[0]; ++ii, ++n) {
        const std::size_t p = layout.index(lo[0] + ii, lo[1] + jj, lo[2] + kk);
        s.mass(ii, jj, kk) = diag[p];
        s.r[n] = rhs[p] - ap_[p];
        s.e[n] = 0.0;
      }
    }
  });
  double b_norm2 = 0.0;
  double r_norm2 = 0.0;
  std::size_t n = 0;
  for (int kk = 0; kk < m[2]; ++kk) {
    for (int jj = 0; jj < m[1]; ++jj) {
      for (int ii = 0; ii < m[0]; ++ii, ++n) {
        const std::size_t p = layout.index(lo[0] + ii, lo[1] + jj, lo[2] + kk);
        b_norm2 += rhs[p] * rhs[p];
        r_norm2 += s.r[n] * s.r[n];
      }
    }
  }
  ViscousSolveReport report;
  if (!(r_norm2 > tolerance * tolerance * b_norm2)) {
    report.relative_residual = b_norm2 > 0.0 ? std::sqrt(r_norm2 / b_norm2) : 0.0;
    return report;
  }
  s.mg->set_coefficients(s.coef, &s.mass);
  const double scale = std::sqrt(r_norm2 / b_norm2); // |r0| / |rhs|
  const MultigridReport mr = s.mg->solve(s.r, s.e, tolerance / scale, max_iterations);
  report.iterations = mr.iterations;
  report.relative_residual = mr.relative_residual * scale;
  report.converged = mr.converged;
  // Not converged (a tolerance near round-off, judged on the true residual): the correction is
  // kept all the same; solve() goes on from it with Jacobi CG.
  tbb::parallel_for(0, m[2], [&](int kk) {
    for (int jj = 0; jj < m[1]; ++jj) {
      std::size_t e = entry(jj, kk);
      for (int ii = 0; ii < m[0]; ++ii, ++e) {
        u[layout.index(lo[0] + ii, lo[1] + jj, lo[2] + kk)] += s.e[e];
      }
    }
  });
  return report;
}

ViscousSolveReport ImplicitViscosity::solve(int comp, double c, const GridField& eps,
                                            const GridField& diag, const GridField& rhs,
                                            GridField& u, double tolerance, int max_iterations) {
  // One grid whose component has no unknown face (a single cell between walls): nothing to
  // solve (the solvers' sums and plane tables assume at least one row).
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  if (halo_ == nullptr && (hi[0] < lo[0] || hi[1] < lo[1] || hi[2] < lo[2])) {
    return {};
  }
  ViscousSolveReport chebyshev;
  if (chebyshev_) {
    face_coefficients(comp, eps);
    chebyshev = solve_chebyshev(comp, c, eps, diag, rhs, u, tolerance, max_iterations);
    if (chebyshev.chebyshev && chebyshev.converged) {
      return chebyshev;
    }
    // Not dominant enough (u untouched), or not converged (u's ghosts refilled): CG goes on.
  }
  ViscousSolveReport report = solve_cg(comp, c, eps, diag, rhs, u, tolerance, max_iterations);
  report.iterations += chebyshev.iterations;
  report.dominance = chebyshev.dominance;
  return report;
}

ViscousSolveReport ImplicitViscosity::solve_cg(int comp, double c, const GridField& eps,
                                               const GridField& diag, const GridField& rhs,
                                               GridField& u, double tolerance, int max_iterations) {
  int multigrid_iterations = 0;
  if (halo_ == nullptr && multigrid_) {
    const ViscousSolveReport mg =
        solve_multigrid(comp, c, eps, diag, rhs, u, tolerance, max_iterations);
    if (mg.converged) {
      return mg;
    }
    // The multigrid stalled above the tolerance (its true residual sits at round-off): Jacobi
    // CG, whose recursive residual keeps falling, finishes from the multigrid's solution, as
    // the projection falls back from PFMG to SMG.
    multigrid_iterations = mg.iterations;
  }
  const GridLayout& layout = grid_.layout();
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  // r = rhs - A u with the true (inhomogeneous) boundary values in u's ghosts.
  apply(comp, c, eps, diag, u, ap_);
  double b_norm2 = 0.0;
  for_box_serial(layout, lo, hi, [&](std::ptrdiff_t p) {
    const auto m = static_cast<std::size_t>(p);
    r_[m] = rhs[m] - ap_[m];
    b_norm2 += rhs[m] * rhs[m];
  });
  // Corrections satisfy homogeneous boundary conditions; Jacobi-preconditioned CG.
  const auto precondition = [&](const GridField& in, GridField& out) {
    for_box_indexed(layout, lo, hi, [&](std::ptrdiff_t p, const std::array<int, 3>& idx) {
      double centre = diag[static_cast<std::size_t>(p)];
      for (int b = 0; b < 3; ++b) {
        const std::ptrdiff_t sb = layout.stride(b);
        const double inv_dx2 = 1.0 / (grid_.spacing(b) * grid_.spacing(b));
        centre += c * inv_dx2 *
                  (cv_face_eps(eps.values().data(), p, layout.stride(comp), sb, b == comp,
                               inflow_plane(b, 0, idx)) *
                       link(open_[static_cast<std::size_t>(comp)], p, sb) +
                   cv_face_eps(eps.values().data(), p + sb, layout.stride(comp), sb, b == comp,
                               inflow_plane(b, 1, idx)) *
                       link(open_[static_cast<std::size_t>(comp)], p + sb, sb));
      }
      out[static_cast<std::size_t>(p)] = in[static_cast<std::size_t>(p)] / centre;
    });
  };
  fill_field(z_, 0.0);
  fill_field(p_, 0.0);
  precondition(r_, z_);
  for_box(layout, lo, hi, [&](std::ptrdiff_t p) {
    p_[static_cast<std::size_t>(p)] = z_[static_cast<std::size_t>(p)];
  });
  std::array<double, 3> sums = {dot(r_, z_, comp), dot(r_, r_, comp), b_norm2};
  if (halo_ != nullptr) {
    halo_->sum(sums);
  }
  double rz = sums[0];
  double rr = sums[1];
  b_norm2 = sums[2];
  const double target = tolerance * tolerance * b_norm2;
  ViscousSolveReport report;
  report.iterations = multigrid_iterations;
  while (rr > target && report.iterations < max_iterations) {
    fill_velocity_ghosts(homogeneous_, halo_, comp, p_);
    apply(comp, c, eps, diag, p_, ap_);
    double pap = dot(p_, ap_, comp);
    if (halo_ != nullptr) {
      pap = halo_->sum(pap);
    }
    const double alpha = rz / pap;
    for_box(layout, lo, hi, [&](std::ptrdiff_t p) {
      const auto m = static_cast<std::size_t>(p);
      u[m] += alpha * p_[m];
      r_[m] -= alpha * ap_[m];
    });
    precondition(r_, z_);
    std::array<double, 2> next = {dot(r_, z_, comp), dot(r_, r_, comp)};
    if (halo_ != nullptr) {
      halo_->sum(next); // one reduction for both
    }
    const double rz_new = next[0];
    for_box(layout, lo, hi, [&](std::ptrdiff_t p) {
      const auto m = static_cast<std::size_t>(p);
      p_[m] = z_[m] + rz_new / rz * p_[m];
    });
    rz = rz_new;
    rr = next[1];
    ++report.iterations;
  }
  report.relative_residual = b_norm2 > 0.0 ? std::sqrt(rr / b_norm2) : 0.0;
  report.converged = rr <= target;
  if (rr > target) {
    throw std::runtime_error(fmt::format("implicit viscosity: CG reached relative residual {:g} "
                                         "after {} iterations (tolerance {:g})",
                                         report.relative_residual, report.iterations, tolerance));
  }
  return report;
}

} // namespace cfddem::fluid
