// The implicit viscosity's Chebyshev solve: for the Helmholtz operators of gas steps whose cells
// are not much smaller than the viscous length sqrt(nu dt), the mass term eps_f rho (1 + k beta_f)
// dominates every row, and a Jacobi-preconditioned Chebyshev iteration converges in a handful of
// pointwise passes, without the multigrid's set-up, restriction and coarse levels or CG's inner
// products.
#include <algorithm>
#include <cmath>
#include <vector>

#include <tbb/parallel_for.h>

#include "fluid/box_loops.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/implicit_viscosity.hpp"

namespace cfddem::fluid {

namespace {

// The operator's arrays: k[b][p] is the low control-volume face's eps / dx_b^2 along b of the
// unknown p, k[b][p + s_b] its high one's; A x = diag x - c div(eps grad x).
struct Operator {
  const double* k0;
  const double* k1;
  const double* k2;
  const double* diag;
  const double* inv; // 1 / A's diagonal
  std::ptrdiff_t sy, sz;
  double c;
};

// (A x)_p with x's ghosts filled. Restrict parameters: GCC takes no-alias from parameters only,
// and the row loops below vectorize only with it.
[[gnu::always_inline]] inline double
apply_at(const double* __restrict k0, const double* __restrict k1, const double* __restrict k2,
         const double* __restrict dg, const double* __restrict x, std::ptrdiff_t p,
         std::ptrdiff_t sy, std::ptrdiff_t sz, double c) {
  const double xp = x[p];
  const double lap = (k0[p + 1] * (x[p + 1] - xp) - k0[p] * (xp - x[p - 1])) +
                     (k1[p + sy] * (x[p + sy] - xp) - k1[p] * (xp - x[p - sy])) +
                     (k2[p + sz] * (x[p + sz] - xp) - k2[p] * (xp - x[p - sz]));
  return dg[p] * xp - c * lap;
}

// r = b - A x and d = r / A's diagonal on the points p0 .. p0 + n - 1 of a row.
[[gnu::noinline]] void residual_row(std::ptrdiff_t p0, std::ptrdiff_t n,
                                    const double* __restrict k0, const double* __restrict k1,
                                    const double* __restrict k2, const double* __restrict dg,
                                    const double* __restrict inv, const double* __restrict x,
                                    const double* __restrict b, double* __restrict r,
                                    double* __restrict d, std::ptrdiff_t sy, std::ptrdiff_t sz,
                                    double c) {
  for (std::ptrdiff_t p = p0; p < p0 + n; ++p) {
    r[p] = b[p] - apply_at(k0, k1, k2, dg, x, p, sy, sz, c);
    d[p] = inv[p] * r[p];
  }
}

// (Not inlined: GCC keeps the restrict parameters of a function it calls, not of one it inlines.)
// One Chebyshev iteration on a row: x += d, r -= A d, d_next = keep d + push r / A's diagonal.
[[gnu::noinline]] void chebyshev_row(std::ptrdiff_t p0, std::ptrdiff_t n,
                                     const double* __restrict k0, const double* __restrict k1,
                                     const double* __restrict k2, const double* __restrict dg,
                                     const double* __restrict inv, const double* __restrict d,
                                     double* __restrict x, double* __restrict r,
                                     double* __restrict dn, std::ptrdiff_t sy, std::ptrdiff_t sz,
                                     double c, double keep, double push) {
  for (std::ptrdiff_t p = p0; p < p0 + n; ++p) {
    const double q = apply_at(k0, k1, k2, dg, d, p, sy, sz, c);
    x[p] += d[p];
    r[p] -= q;
    dn[p] = keep * d[p] + push * inv[p] * r[p];
  }
}

// sum v^2 over a row in four fixed lanes (vectorizes; the same sum whatever the thread count).
[[gnu::noinline]] double row_squares(const double* __restrict v, std::ptrdiff_t p0,
                                     std::ptrdiff_t n) {
  double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
  std::ptrdiff_t i = 0;
  for (; i + 4 <= n; i += 4) {
    const double* q = v + p0 + i;
    s0 += q[0] * q[0], s1 += q[1] * q[1], s2 += q[2] * q[2], s3 += q[3] * q[3];
  }
  for (; i < n; ++i) {
    s0 += v[p0 + i] * v[p0 + i];
  }
  return (s0 + s1) + (s2 + s3);
}

} // namespace

// Chebyshev iteration for A u = rhs preconditioned by D = diag(A) (Saad, "Iterative Methods for
// Sparse Linear Systems", 2nd ed., SIAM 2003, Algorithm 12.1). Every eigenvalue of D^-1 A lies in
// [1 - rho, 1 + rho], rho the largest off-diagonal sum over the diagonal of a row (Gershgorin; a
// wall's reflected ghost only moves a row's interval inward), so the interval's centre is 1 and
// its half-width rho. The error falls by at least 2 s^k / (1 + s^2k) after k iterations in the
// A-norm, s = (sqrt(kappa) - 1) / (sqrt(kappa) + 1), kappa = (1 + rho) / (1 - rho). The stopping
// test is the CG path's: |rhs - A u| <= tolerance |rhs| over the unknowns, on the recursive
// residual r_{k+1} = r_k - A d_k (a few passes of a well-conditioned operator: its drift stays
// near round-off).
ViscousSolveReport ImplicitViscosity::solve_chebyshev(int comp, double c, const GridField& diag,
                                                      const GridField& rhs, GridField& u,
                                                      double tolerance, int max_iterations) {
  const GridLayout& layout = grid_.layout();
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  const std::ptrdiff_t len = hi[0] - lo[0];
  const std::size_t cs = static_cast<std::size_t>(comp);
  const Operator op{cv_k_[cs][0].values().data(),
                    cv_k_[cs][1].values().data(),
                    cv_k_[cs][2].values().data(),
                    diag.values().data(),
                    inv_diag_.values().data(),
                    layout.stride(1),
                    layout.stride(2),
                    c};
  double* inv = inv_diag_.values().data();
  ViscousSolveReport report;
  // Inverse diagonals and the dominance ratio (a max is exact in any order).
  std::vector<double> plane_max(static_cast<std::size_t>(hi[2] - lo[2] + 1), 0.0);
  for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int k) {
    double m = 0.0;
    for (std::ptrdiff_t p = row; p <= row + len; ++p) {
      const double off = c * ((op.k0[p] + op.k0[p + 1]) + (op.k1[p] + op.k1[p + op.sy]) +
                              (op.k2[p] + op.k2[p + op.sz]));
      const double d = op.diag[p] + off;
      inv[p] = 1.0 / d;
      m = std::max(m, off / d);
    }
    double& pm = plane_max[static_cast<std::size_t>(k - lo[2])];
    pm = std::max(pm, m);
  });
  double rho = *std::max_element(plane_max.begin(), plane_max.end());
  if (halo_ != nullptr) {
    rho = halo_->max(rho);
  }
  report.dominance = rho;
  if (!(rho <= kChebyshevMaxDominance)) {
    return report; // not chosen: u untouched
  }
  report.chebyshev = true;
  // Sums over the unknowns: per z-plane, rows in order, then the planes in order (the same
  // whatever the thread count).
  std::vector<std::array<double, 2>> partial(plane_max.size());
  const auto ordered = [&]() {
    std::array<double, 2> s{};
    for (const auto& v : partial) {
      s[0] += v[0], s[1] += v[1];
    }
    if (halo_ != nullptr) {
      halo_->sum(s);
    }
    return s;
  };
  // r = rhs - A u with u's true boundary values; the first direction d = D^-1 r.
  const double* x = u.values().data();
  const double* b = rhs.values().data();
  double* r = r_.values().data();
  double* d = dir_.values().data();
  std::fill(partial.begin(), partial.end(), std::array<double, 2>{});
  for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int k) {
    residual_row(row, len + 1, op.k0, op.k1, op.k2, op.diag, op.inv, x, b, r, d, op.sy, op.sz,
                 op.c);
    auto& s = partial[static_cast<std::size_t>(k - lo[2])];
    s[0] += row_squares(b, row, len + 1);
    s[1] += row_squares(r, row, len + 1);
  });
  const std::array<double, 2> first = ordered();
  const double target = tolerance * tolerance * first[0];
  double rr = first[1];
  // delta >= 0.01 keeps the recurrence finite for a vanishing viscous term (rho -> 0: one
  // iteration is then exact); a wider interval than the spectrum only slows it slightly.
  const double delta = std::max(rho, 0.01);
  const double sigma = 1.0 / delta;
  double omega = 1.0 / sigma;
  double* xu = u.values().data();
  while (rr > target && report.iterations < max_iterations) {
    fill_velocity_ghosts(homogeneous_, halo_, comp, dir_);
    const double omega_next = 1.0 / (2.0 * sigma - omega);
    const double keep = omega_next * omega;
    const double push = 2.0 * omega_next / delta;
    d = dir_.values().data();
    double* dn = dir_next_.values().data();
    std::fill(partial.begin(), partial.end(), std::array<double, 2>{});
    for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int k) {
      chebyshev_row(row, len + 1, op.k0, op.k1, op.k2, op.diag, op.inv, d, xu, r, dn, op.sy, op.sz,
                    op.c, keep, push);
      partial[static_cast<std::size_t>(k - lo[2])][0] += row_squares(r, row, len + 1);
    });
    rr = ordered()[0];
    std::swap(dir_, dir_next_);
    omega = omega_next;
    ++report.iterations;
  }
  report.relative_residual = first[0] > 0.0 ? std::sqrt(rr / first[0]) : 0.0;
  report.converged = rr <= target;
  if (!report.converged) {
    fill_velocity_ghosts(grid_, halo_, comp, u); // the CG path goes on from u
  }
  return report;
}

} // namespace cfddem::fluid
