// The implicit viscosity's Chebyshev solve: for the Helmholtz operators of gas steps whose cells
// are not much smaller than the viscous length sqrt(nu dt), the mass term eps_f rho (1 + k beta_f)
// dominates every row, and a Jacobi-preconditioned Chebyshev iteration converges in a handful of
// pointwise passes, without the multigrid's set-up, restriction and coarse levels or CG's inner
// products.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <type_traits>
#include <utility>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "core/simd_level.hpp"
#include "fluid/box_loops.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/implicit_viscosity.hpp"
#include "fluid/viscous_stencil.hpp"

namespace cfddem::fluid {

namespace {

using viscous_stencil::apply_at;
using viscous_stencil::faces_at;

// The operator's arrays: k[b][p] is the low control-volume face's eps / dx_b^2 along b of the
// unknown p, k[b][p + s_b] its high one's; A x = diag x - c div(eps grad x). ep: the eps they
// were made from.
struct Operator {
  const double* k0;
  const double* k1;
  const double* k2;
  const double* ep;
  const double* diag;
  std::ptrdiff_t sy, sz;
  double c;
};

// The off-diagonal part of the unknown's row, c times the sum of its face coefficients.
[[gnu::always_inline]] inline double off_diagonal(const double (&k)[6], double c) {
  return c * ((k[0] + k[1]) + (k[2] + k[3]) + (k[4] + k[5]));
}

[[gnu::always_inline]] inline double inverse_diagonal(const double (&k)[6], double dg, double c) {
  return 1.0 / (dg + off_diagonal(k, c));
}

// A row's inverse diagonal at p: read from iv (A = -2: the dominance pass wrote
// inverse_diagonal's value there) or computed.
template <int A>
[[gnu::always_inline]] inline double inverse_diagonal_at(const double (&k)[6], const double* dg,
                                                         const double* iv, std::ptrdiff_t p,
                                                         double c) {
  if constexpr (A == -2) {
    return iv[p];
  } else {
    return inverse_diagonal(k, dg[p], c);
  }
}

// A row's scalars: its first point and length, the strides, the operator's c and the
// iteration's coefficients (keep, push; unused by the residual).
struct RowScalars {
  std::ptrdiff_t p0, n, sy, sz;
  double c, keep, push;
  double ix, iy, iz; // 1 / dx_b^2
};

// r = b - A x and d = r / A's diagonal on the points of a row.
template <int A>
[[gnu::always_inline]] inline void
residual_body(const double* k0, const double* k1, const double* k2, const double* ep,
              const double* iv, const double* dg, const double* x, const double* b, double* r,
              double* d, const RowScalars& s) {
  const std::ptrdiff_t sy = s.sy, sz = s.sz;
  const double c = s.c, ix = s.ix, iy = s.iy, iz = s.iz;
  for (std::ptrdiff_t p = s.p0; p < s.p0 + s.n; ++p) {
    double k[6];
    faces_at<A>(k0, k1, k2, ep, ix, iy, iz, p, sy, sz, k);
    r[p] = b[p] - apply_at(k, dg[p], x, p, sy, sz, c);
    d[p] = inverse_diagonal_at<A>(k, dg, iv, p, c) * r[p];
  }
}

// How a Chebyshev row pass treats x (solve_chebyshev): `plain`, x += d; `pending`, the first
// iteration of a pair after an earlier pair, x = (x + dn) + d, where dn still holds the direction
// the earlier pair's second iteration did not add (the unfused iterations' two sums in their
// order); `lagged`, the second iteration of a pair, x untouched (its direction joins x in the
// next pair's first iteration or in the pass that ends the solve).
enum class XUpdate { plain, pending, lagged };

// One Chebyshev iteration on a row: x += d, r -= A d, d_next = keep d + push r / A's diagonal.
// The inverse diagonal is read where the fields stay in the caches, and computed again where they
// do not: there a division costs less than streaming one more array (kChebyshevCachedFieldBytes).
template <int A, XUpdate X>
[[gnu::always_inline]] inline void
chebyshev_body(const double* k0, const double* k1, const double* k2, const double* ep,
               const double* iv, const double* dg, const double* d, double* x, double* r,
               double* dn, const RowScalars& s) {
  const std::ptrdiff_t sy = s.sy, sz = s.sz;
  const double c = s.c, keep = s.keep, push = s.push, ix = s.ix, iy = s.iy, iz = s.iz;
  for (std::ptrdiff_t p = s.p0; p < s.p0 + s.n; ++p) {
    double k[6];
    faces_at<A>(k0, k1, k2, ep, ix, iy, iz, p, sy, sz, k);
    const double q = apply_at(k, dg[p], d, p, sy, sz, c);
    if constexpr (X == XUpdate::plain) {
      x[p] += d[p];
    } else if constexpr (X == XUpdate::pending) {
      x[p] = (x[p] + dn[p]) + d[p];
    }
    r[p] -= q;
    dn[p] = keep * d[p] + push * inverse_diagonal_at<A>(k, dg, iv, p, c) * r[p];
  }
}

// The row kernels' copies, one type per instruction set (core/simd_level.hpp; the same operations
// in the same order at every level). Not inlined, with restrict parameters: GCC keeps the restrict
// of the parameters of a function it calls, not of one it inlines or of a local pointer, and the
// loops vectorize only with it.
#define CFDDEM_CHEBYSHEV_ROWS(NAME, ...)                                                           \
  struct NAME {                                                                                    \
    template <int A>                                                                               \
    [[gnu::noinline __VA_ARGS__]] static void                                                      \
    residual(const double* __restrict k0, const double* __restrict k1,                             \
             const double* __restrict k2, const double* __restrict ep,                             \
             const double* __restrict iv, const double* __restrict dg, const double* __restrict x, \
             const double* __restrict b, double* __restrict r, double* __restrict d,               \
             const RowScalars& s) {                                                                \
      residual_body<A>(k0, k1, k2, ep, iv, dg, x, b, r, d, s);                                     \
    }                                                                                              \
    template <int A, XUpdate X>                                                                    \
    [[gnu::noinline __VA_ARGS__]] static void                                                      \
    iterate(const double* __restrict k0, const double* __restrict k1, const double* __restrict k2, \
            const double* __restrict ep, const double* __restrict iv, const double* __restrict dg, \
            const double* __restrict d, double* __restrict x, double* __restrict r,                \
            double* __restrict dn, const RowScalars& s) {                                          \
      chebyshev_body<A, X>(k0, k1, k2, ep, iv, dg, d, x, r, dn, s);                                \
    }                                                                                              \
  };
CFDDEM_SIMD_COPY_TYPES(CFDDEM_CHEBYSHEV_ROWS, ChebyshevRows)
#undef CFDDEM_CHEBYSHEV_ROWS

// Calls f with the row kernels' copy for `level` (a type with static residual and iterate).
template <class F> void with_chebyshev_rows_at(SimdLevel level, F&& f) {
  with_copy_at<ChebyshevRowsX86_64, ChebyshevRowsV3, ChebyshevRowsV4>(level, f);
}

// Calls f(axis) with the row's coefficient source as a compile-time integer (faces_at's A): the
// component's axis on a regular row computed from eps, -2 with the stored inverse diagonal, -1
// otherwise.
template <class F> [[gnu::always_inline]] inline void with_row_faces(int comp, int source, F&& f) {
  if (source == -1) {
    f(std::integral_constant<int, -1>{});
  } else if (source == -2) {
    f(std::integral_constant<int, -2>{});
  } else if (comp == 0) {
    f(std::integral_constant<int, 0>{});
  } else if (comp == 1) {
    f(std::integral_constant<int, 1>{});
  } else {
    f(std::integral_constant<int, 2>{});
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

// A Chebyshev solve's rows: the operator, the box of unknowns, what each row reads and the
// instruction set of the row kernels.
struct SolveRows {
  const GridLayout* layout;
  Operator op;
  std::array<int, 3> lo, hi;
  std::ptrdiff_t len; // a row's points less one
  int comp;
  const std::vector<char>* regular; // ImplicitViscosity::regular_rows
  bool eps_rows;                    // regular rows compute their coefficients from eps
  const double* inv; // the stored inverse diagonal (every row then reads it), or null
  double ix, iy, iz; // 1 / dx_b^2
  SimdLevel level;

  [[nodiscard]] int planes() const { return hi[2] - lo[2] + 1; }

  // Row (j, k)'s source as with_row_faces takes it.
  [[nodiscard]] int source(int j, int k) const {
    if (inv != nullptr) {
      return -2;
    }
    const bool regular_row = (*regular)[static_cast<std::size_t>(j - lo[1]) +
                                        static_cast<std::size_t>(hi[1] - lo[1] + 1) *
                                            static_cast<std::size_t>(k - lo[2])] != 0;
    return eps_rows && regular_row ? comp : -1;
  }

  // r = b - A x and d = r / A's diagonal on row (j, k), whose first point is `row`.
  void residual(std::ptrdiff_t row, int j, int k, const double* x, const double* b, double* r,
                double* d) const {
    const RowScalars rs{row, len + 1, op.sy, op.sz, op.c, 0.0, 0.0, ix, iy, iz};
    with_row_faces(comp, source(j, k), [&](auto axis) {
      with_chebyshev_rows_at(level, [&](auto rows) {
        decltype(rows)::template residual<decltype(axis)::value>(op.k0, op.k1, op.k2, op.ep, inv,
                                                                 op.diag, x, b, r, d, rs);
      });
    });
  }

  // One iteration on row (j, k): X says what it does to x, dir is the direction it reads,
  // dir_next the one it writes; the row's |r|^2 goes into sum.
  template <XUpdate X>
  void iterate(int j, int k, double keep, double push, const double* dir, double* x, double* r,
               double* dir_next, double& sum) const {
    const auto row = static_cast<std::ptrdiff_t>(layout->index(lo[0], j, k));
    const RowScalars rs{row, len + 1, op.sy, op.sz, op.c, keep, push, ix, iy, iz};
    with_row_faces(comp, source(j, k), [&](auto axis) {
      with_chebyshev_rows_at(level, [&](auto rows) {
        decltype(rows)::template iterate<decltype(axis)::value, X>(
            op.k0, op.k1, op.k2, op.ep, inv, op.diag, dir, x, r, dir_next, rs);
      });
    });
    sum += row_squares(r, row, len + 1);
  }
};

// The Chebyshev recurrence's coefficients for the interval [1 - delta, 1 + delta] (Saad,
// Algorithm 12.1): each iteration's d_next = keep d + push D^-1 r.
struct Recurrence {
  double delta, sigma, omega;
  // delta >= 0.01 keeps the recurrence finite for a vanishing viscous term (rho -> 0: one
  // iteration is then exact); a wider interval than the spectrum only slows it slightly.
  explicit Recurrence(double rho)
      : delta(std::max(rho, 0.01)), sigma(1.0 / delta), omega(1.0 / sigma) {}
  struct Step {
    double keep, push;
  };
  // The next iteration's coefficients.
  Step next() {
    const double omega_next = 1.0 / (2.0 * sigma - omega);
    const Step step{omega_next * omega, 2.0 * omega_next / delta};
    omega = omega_next;
    return step;
  }
};

// Sums over the unknowns: per z-plane, rows in order, then the planes in order (the same
// whatever the thread count).
struct PlaneSums {
  std::vector<std::array<double, 2>> partial;
  explicit PlaneSums(int planes) : partial(static_cast<std::size_t>(planes)) {}
  void clear() { std::fill(partial.begin(), partial.end(), std::array<double, 2>{}); }
  [[nodiscard]] double& at(int plane, std::size_t which) {
    return partial[static_cast<std::size_t>(plane)][which];
  }
  // Both sums, over the ranks' boxes too where halo is given.
  [[nodiscard]] std::array<double, 2> both(const GridHalo* halo) const {
    std::array<double, 2> s{};
    for (const auto& v : partial) {
      s[0] += v[0], s[1] += v[1];
    }
    if (halo != nullptr) {
      halo->sum(s);
    }
    return s;
  }
};

using Plain = std::integral_constant<XUpdate, XUpdate::plain>;
using Pending = std::integral_constant<XUpdate, XUpdate::pending>;
using Lagged = std::integral_constant<XUpdate, XUpdate::lagged>;

// Chebyshev iterations on one grid, two per sweep over the planes, from x, r and the first
// direction in dir (ghosts not yet filled) while |r|^2 = rr > target and fewer than
// max_iterations are done; returns the last |r|^2 and counts the iterations in `iterations`.
// Iteration k reads d_k in dir (ghosts filled) and writes x_{k+1}, r_{k+1} and d_{k+1} into
// dir_next; iteration k + 1 follows one plane behind, as soon as d_{k+1} is there on the planes
// around it, and writes d_{k+2} into dir over d_k, which iteration k no longer reads below its
// plane. So the pair reads the arrays once from memory, the second iteration finding them in the
// caches. Iteration k + 1 leaves x alone: x takes d_{k+1} in the next pair's first iteration, or
// after the loop. A chunk of planes per task; a chunk's first and last planes, whose neighbours
// another task makes, and the grid's end planes, whose ghosts come along z, wait for the whole of
// iteration k and the ghost fill of d_{k+1}. Every point takes the unfused iterations' operations
// in their order, and every residual sum the same terms in the same order: the same bits on any
// thread count.
double iterate_in_pairs(const SolveRows& rows, const MacGrid& homogeneous, GridField& dir,
                        GridField& dir_next, double* x, double* r, Recurrence& recurrence,
                        PlaneSums& sums, double rr, double target, int max_iterations,
                        int& iterations) {
  const GridLayout& layout = *rows.layout;
  const std::array<int, 3>& lo = rows.lo;
  const std::array<int, 3>& hi = rows.hi;
  const PlaneGhostFill fill(homogeneous, rows.comp);
  double* d0 = dir.values().data();
  double* d1 = dir_next.values().data();
  const int planes = rows.planes();
  const int chunks =
      std::clamp(planes / kPairedChunkPlanes, 1, tbb::this_task_arena::max_concurrency());
  const auto chunk_first = [&](int t) { return lo[2] + planes * t / chunks; };
  const auto chunk_last = [&](int t) { return lo[2] + planes * (t + 1) / chunks - 1; };
  // The rest of a direction's ghost fill once its planes of unknowns have their x and y ghosts:
  // the planes beyond the unknowns along x and y, then every plane along z.
  const auto fill_rest = [&](GridField& f) {
    for (int k = -kGhostLayers; k < lo[2]; ++k) {
      fill.fill_plane(f, k);
    }
    for (int k = hi[2] + 1; k <= layout.cells()[2] + kGhostLayers; ++k) {
      fill.fill_plane(f, k);
    }
    fill.fill_z(f);
  };
  // After a whole pair: d_{k-1} in dir_next is not yet added to x, and d_k in dir has the x and
  // y ghosts of its planes of unknowns.
  bool pending = false;
  while (rr > target && iterations < max_iterations) {
    if (pending) {
      fill_rest(dir); // its planes' x and y ghosts were filled as the last pair made them
    } else {
      fill_velocity_ghosts(homogeneous, nullptr, rows.comp, dir);
    }
    const Recurrence::Step step1 = recurrence.next();
    const Recurrence::Step step2 = recurrence.next();
    const bool second = iterations + 1 < max_iterations;
    sums.clear();
    const auto first_plane = [&](int k) {
      double& sum = sums.at(k - lo[2], 0);
      for (int j = lo[1]; j <= hi[1]; ++j) {
        if (pending) {
          rows.iterate<Pending::value>(j, k, step1.keep, step1.push, d0, x, r, d1, sum);
        } else {
          rows.iterate<Plain::value>(j, k, step1.keep, step1.push, d0, x, r, d1, sum);
        }
      }
      fill.fill_plane(dir_next, k);
    };
    const auto second_plane = [&](int k) {
      double& sum = sums.at(k - lo[2], 1);
      for (int j = lo[1]; j <= hi[1]; ++j) {
        rows.iterate<Lagged::value>(j, k, step2.keep, step2.push, d1, nullptr, r, d0, sum);
      }
      fill.fill_plane(dir, k);
    };
    tbb::parallel_for(tbb::blocked_range<int>(0, chunks, 1),
                      [&](const tbb::blocked_range<int>& range) {
                        for (int t = range.begin(); t != range.end(); ++t) {
                          const int c0 = chunk_first(t);
                          for (int k = c0; k <= chunk_last(t); ++k) {
                            first_plane(k);
                            if (second && k - 1 > c0) {
                              second_plane(k - 1);
                            }
                          }
                        }
                      });
    ++iterations;
    rr = sums.both(nullptr)[0];
    pending = false;
    if (rr <= target || !second) {
      break; // x is x_{k+1}; the second iteration's partial work is dropped
    }
    fill_rest(dir_next);
    tbb::parallel_for(tbb::blocked_range<int>(0, chunks, 1),
                      [&](const tbb::blocked_range<int>& range) {
                        for (int t = range.begin(); t != range.end(); ++t) {
                          second_plane(chunk_first(t));
                          if (chunk_last(t) != chunk_first(t)) {
                            second_plane(chunk_last(t));
                          }
                        }
                      });
    ++iterations;
    rr = sums.both(nullptr)[1];
    pending = true;
  }
  if (pending) {
    for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int) {
      for (std::ptrdiff_t p = row; p <= row + rows.len; ++p) {
        x[p] += d1[p];
      }
    });
  }
  return rr;
}

// The same iterations one per sweep, the direction's ghosts filled (and exchanged with the other
// boxes where halo is given) between them, as a distributed grid takes them.
double iterate_one_at_a_time(const SolveRows& rows, const MacGrid& homogeneous,
                             const GridHalo* halo, GridField& dir, GridField& dir_next, double* x,
                             double* r, Recurrence& recurrence, PlaneSums& sums, double rr,
                             double target, int max_iterations, int& iterations) {
  while (rr > target && iterations < max_iterations) {
    fill_velocity_ghosts(homogeneous, halo, rows.comp, dir);
    const Recurrence::Step step = recurrence.next();
    const double* d = dir.values().data();
    double* dn = dir_next.values().data();
    sums.clear();
    for_box_rows(*rows.layout, rows.lo, rows.hi, [&](std::ptrdiff_t, int j, int k) {
      rows.iterate<Plain::value>(j, k, step.keep, step.push, d, x, r, dn,
                                 sums.at(k - rows.lo[2], 0));
    });
    rr = sums.both(halo)[0];
    std::swap(dir, dir_next);
    ++iterations;
  }
  return rr;
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
ViscousSolveReport ImplicitViscosity::solve_chebyshev(int comp, double c, const GridField& eps,
                                                      const GridField& diag, const GridField& rhs,
                                                      GridField& u, double tolerance,
                                                      int max_iterations) {
  const GridLayout& layout = grid_.layout();
  const std::size_t cs = static_cast<std::size_t>(comp);
  // Fewer operations or fewer streamed arrays per unknown, by the fields' size
  // (chebyshev_row_source).
  const CoefficientSource source =
      chebyshev_row_source(source_, level_, eps.values().size() * sizeof(double));
  // The stored inverse diagonal, which the dominance pass below writes (null: computed by rows).
  double* inv = nullptr;
  if (source == CoefficientSource::stored_inverse) {
    if (inverse_diagonal_.values().size() != layout.size()) {
      inverse_diagonal_ = GridField(layout);
    }
    inv = inverse_diagonal_.values().data();
  }
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  const SolveRows rows{&layout,
                       Operator{cv_k_[cs][0].values().data(), cv_k_[cs][1].values().data(),
                                cv_k_[cs][2].values().data(),
                                eps.values().data(), // what face_coefficients made them from
                                diag.values().data(), layout.stride(1), layout.stride(2), c},
                       lo,
                       hi,
                       hi[0] - lo[0],
                       comp,
                       &regular_rows(comp),
                       source == CoefficientSource::from_eps,
                       inv,
                       1.0 / (grid_.spacing(0) * grid_.spacing(0)),
                       1.0 / (grid_.spacing(1) * grid_.spacing(1)),
                       1.0 / (grid_.spacing(2) * grid_.spacing(2)),
                       level_};
  const Operator& op = rows.op;
  const std::ptrdiff_t len = rows.len;
  ViscousSolveReport report;
  // The dominance ratio (a max is exact in any order); the stored inverse diagonal with it.
  std::vector<double> plane_max(static_cast<std::size_t>(rows.planes()), 0.0);
  for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int k) {
    double m = 0.0;
    for (std::ptrdiff_t p = row; p <= row + len; ++p) {
      double kf[6];
      faces_at<-1>(op.k0, op.k1, op.k2, op.ep, rows.ix, rows.iy, rows.iz, p, op.sy, op.sz, kf);
      const double off = off_diagonal(kf, c);
      const double dg = op.diag[p] + off;
      m = std::max(m, off / dg);
      if (inv != nullptr) {
        inv[p] = 1.0 / dg; // inverse_diagonal's value
      }
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
  if (rows.eps_rows) {
    report.rows_from_eps = static_cast<int>(
        std::count(rows.regular->begin(), rows.regular->end(), static_cast<char>(1)));
  }
  // r = rhs - A u with u's true boundary values; the first direction d = D^-1 r.
  PlaneSums sums(rows.planes());
  double* x = u.values().data();
  const double* b = rhs.values().data();
  double* r = r_.values().data();
  double* d = dir_.values().data();
  for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int j, int k) {
    rows.residual(row, j, k, x, b, r, d);
    sums.at(k - lo[2], 0) += row_squares(b, row, len + 1);
    sums.at(k - lo[2], 1) += row_squares(r, row, len + 1);
  });
  const std::array<double, 2> first = sums.both(halo_);
  const double target = tolerance * tolerance * first[0];
  Recurrence recurrence(rho);
  const double rr =
      halo_ == nullptr && pairs_
          ? iterate_in_pairs(rows, homogeneous_, dir_, dir_next_, x, r, recurrence, sums, first[1],
                             target, max_iterations, report.iterations)
          : iterate_one_at_a_time(rows, homogeneous_, halo_, dir_, dir_next_, x, r, recurrence,
                                  sums, first[1], target, max_iterations, report.iterations);
  report.relative_residual = first[0] > 0.0 ? std::sqrt(rr / first[0]) : 0.0;
  report.converged = rr <= target;
  if (!report.converged) {
    fill_velocity_ghosts(grid_, halo_, comp, u); // the CG path goes on from u
  }
  return report;
}

} // namespace cfddem::fluid
