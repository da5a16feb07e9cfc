#include "fluid/multigrid_poisson.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <stdexcept>
#include <utility>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/usable_threads.hpp"
#include "fluid/multigrid_exchange.hpp"
#include "fluid/multigrid_rows.hpp"

namespace cfddem::fluid {

// One level: n cells per axis padded by one ghost layer (periodic images; zero elsewhere). K[a] at
// a cell's index is the coefficient of its low a-face (face n_a sits in the high ghost slot); it
// is zero on non-periodic boundary faces, whose Dirichlet coefficients are kept in dface and
// folded into diag (ghost -phi: 2 K on the diagonal).
struct MultigridPoisson::Level {
  std::array<int, 3> n{};
  std::array<double, 3> h{};
  std::array<bool, 3> periodic{};
  std::array<std::array<bool, 2>, 3> dirichlet{};
  // Distance from the last unknown's centre to a Dirichlet boundary, in spacings (1/2 for a face,
  // 1 for a node; coarsening moves it).
  std::array<std::array<double, 2>, 3> bdist{};
  std::array<std::ptrdiff_t, 3> s{};
  std::size_t size = 0;
  std::array<int, 3> ratio{1, 1, 1}; // coarsening factor to the next level
  int line = -1;
  // Level arrays on huge pages where large (core/huge_page_allocator.hpp).
  std::array<HugePageVector<double>, 3> K;
  // Dirichlet face coefficients per axis and side, on the transverse plane (lower axis fastest).
  std::array<std::array<std::vector<double>, 2>, 3> dface;
  HugePageVector<double> diag, inv_diag;
  HugePageVector<double> mass; // empty without a mass term
  // A line-relaxed level's tridiagonal factors, per line (index ip + n_p iq) and position along
  // it: the sub-diagonal, the Thomas pivots and multipliers, and for a periodic line the
  // Sherman-Morrison vector; sm: per line 2 values (lo[0] / g and the denominator; for a period
  // of 2, the determinant). They depend on the coefficients only (factor_lines).
  std::vector<double> line_lo, line_pivot, line_mult, line_z, line_sm;
  HugePageVector<double> x, b; // a coarse level's correction and right-hand side
  // Distributed: the level's exchange (nullptr on one grid, where periodic images are copied
  // locally), which sides of the box are exchanged rather than boundary faces, the parity of
  // the box's first cell (red-black colours follow the global indices) and the global cells.
  const MultigridExchange* exchange = nullptr;
  std::array<std::array<bool, 2>, 3> exchanged{};
  int parity = 0;
  double total = 0.0;
  // Cells whose row is not empty (diag > 0; every rank's), and whether some row is: a solid
  // cell of a column has no open face, so its row and column are zero. Such cells keep x = 0:
  // relaxation leaves them (inv_diag 0), the means and shifts of a singular problem skip them,
  // line and direct solves give them an identity row.
  double active = 0.0;
  bool has_inactive = false;
  bool empty_rows = false; // MultigridSettings::empty_rows
  double omega = 1.0;      // MultigridSettings::relaxation_weight (point relaxation)
  SimdLevel simd = simd_level(); // the row kernels' copy (fluid/multigrid_rows.hpp)

  Level(std::array<int, 3> cells, std::array<double, 3> spacing,
        const std::array<std::array<PoissonSide, 2>, 3>& sides)
      : n(cells), h(spacing) {
    s[0] = 1;
    s[1] = n[0] + 2;
    s[2] = static_cast<std::ptrdiff_t>(n[0] + 2) * (n[1] + 2);
    size = static_cast<std::size_t>(s[2]) * static_cast<std::size_t>(n[2] + 2);
    for (int a = 0; a < 3; ++a) {
      periodic[a] = sides[a][0] == PoissonSide::periodic;
      for (int side = 0; side < 2; ++side) {
        dirichlet[a][side] = sides[a][side] == PoissonSide::dirichlet ||
                             sides[a][side] == PoissonSide::dirichlet_node;
        bdist[a][side] = sides[a][side] == PoissonSide::dirichlet_node ? 1.0 : 0.5;
        if (dirichlet[a][side]) {
          dface[a][side].assign(plane_cells(a), 0.0);
        }
      }
      K[a].assign(size, 0.0);
    }
    diag.assign(size, 0.0);
    inv_diag.assign(size, 0.0);
    x.assign(size, 0.0);
    b.assign(size, 0.0);
    total = static_cast<double>(n[0]) * n[1] * n[2];
  }
  [[nodiscard]] std::size_t at(int i, int j, int k) const {
    return static_cast<std::size_t>((i + 1) * s[0] + (j + 1) * s[1] + (k + 1) * s[2]);
  }
  [[nodiscard]] std::size_t cells() const {
    return static_cast<std::size_t>(n[0]) * static_cast<std::size_t>(n[1]) *
           static_cast<std::size_t>(n[2]);
  }
  [[nodiscard]] std::size_t plane_cells(int a) const {
    return cells() / static_cast<std::size_t>(n[a]);
  }
  // Index of cell c's position on the plane transverse to axis a.
  [[nodiscard]] std::size_t plane_index(int a, const std::array<int, 3>& c) const {
    const int p = a == 0 ? 1 : 0;
    const int q = a == 2 ? 1 : 2;
    return static_cast<std::size_t>(c[p]) +
           static_cast<std::size_t>(n[p]) * static_cast<std::size_t>(c[q]);
  }
};

namespace {

using Level = MultigridPoisson::Level;

// Row j of plane k of level L.
multigrid_rows::Row row_of(const Level& L, int j, int k) {
  return multigrid_rows::Row{static_cast<std::ptrdiff_t>(L.at(0, j, k)), L.n[0], L.s[1], L.s[2]};
}

// Loops over fewer cells than this run on the calling thread: on the coarse levels a task
// launch costs more than the work.
constexpr std::size_t kParallelCells = 4096;

// f(k) for every plane k; work: the cells the loop touches (decides serial or TBB).
template <class F> void for_planes(int planes, std::size_t work, F&& f) {
  if (work < kParallelCells) {
    for (int k = 0; k < planes; ++k) {
      f(k);
    }
    return;
  }
  tbb::parallel_for(tbb::blocked_range<int>(0, planes), [&](const tbb::blocked_range<int>& r) {
    for (int k = r.begin(); k < r.end(); ++k) {
      f(k);
    }
  });
}

// Sum over z-planes of f(k): per-plane partial sums added in plane order, so the result does not
// depend on how the planes were shared among threads.
template <class F> double sum_planes(int planes, std::size_t work, F&& f) {
  std::vector<double> partial(static_cast<std::size_t>(planes), 0.0);
  for_planes(planes, work, [&](int k) { partial[static_cast<std::size_t>(k)] = f(k); });
  double total = 0.0;
  for (const double v : partial) {
    total += v;
  }
  return total;
}

template <std::size_t N, class F>
std::array<double, N> sum_planes_n(int planes, std::size_t work, F&& f) {
  std::vector<std::array<double, N>> partial(static_cast<std::size_t>(planes));
  for_planes(planes, work, [&](int k) { partial[static_cast<std::size_t>(k)] = f(k); });
  std::array<double, N> total{};
  for (const auto& v : partial) {
    for (std::size_t m = 0; m < N; ++m) {
      total[m] += v[m];
    }
  }
  return total;
}

// f(c) on every interior cell of a level, plane-parallel.
template <class F> void for_cells(const Level& L, F&& f) {
  for_planes(L.n[2], L.cells(), [&](int k) {
    for (int j = 0; j < L.n[1]; ++j) {
      std::size_t c = L.at(0, j, k);
      for (int i = 0; i < L.n[0]; ++i, ++c) {
        f(c);
      }
    }
  });
}

// f(c, s) adds cell c's terms into the sum s; summed as sum_planes does (thread-count free).
template <class F> double sum_cells(const Level& L, F&& f) {
  return sum_planes(L.n[2], L.cells(), [&](int k) {
    double s = 0.0;
    for (int j = 0; j < L.n[1]; ++j) {
      std::size_t c = L.at(0, j, k);
      for (int i = 0; i < L.n[0]; ++i, ++c) {
        f(c, s);
      }
    }
    return s;
  });
}

// Periodic images along x and y into the ghost layer of plane k.
void fill_plane_ghosts(const Level& L, double* v, int k) {
  const auto& n = L.n;
  if (L.periodic[0] && n[0] > 1) {
    for (int j = 0; j < n[1]; ++j) {
      v[L.at(-1, j, k)] = v[L.at(n[0] - 1, j, k)];
      v[L.at(n[0], j, k)] = v[L.at(0, j, k)];
    }
  }
  if (L.periodic[1] && n[1] > 1) {
    for (int i = 0; i < n[0]; ++i) {
      v[L.at(i, -1, k)] = v[L.at(i, n[1] - 1, k)];
      v[L.at(i, n[1], k)] = v[L.at(i, 0, k)];
    }
  }
}

// Periodic images along z: the ghost planes -1 and n_z.
void fill_z_ghosts(const Level& L, double* v) {
  const auto& n = L.n;
  if (L.periodic[2] && n[2] > 1) {
    for (int j = 0; j < n[1]; ++j) {
      std::copy_n(v + L.at(0, j, n[2] - 1), n[0], v + L.at(0, j, -1));
      std::copy_n(v + L.at(0, j, 0), n[0], v + L.at(0, j, n[2]));
    }
  }
}

// Periodic images into the ghost layer (faces only: no kernel reads edges or corners).
void fill_ghosts(const Level& L, double* v) {
  if (L.exchange != nullptr) {
    L.exchange->fill(std::span<double>(v, L.size)); // periodic images included
    return;
  }
  const auto& n = L.n;
  if ((L.periodic[0] && n[0] > 1) || (L.periodic[1] && n[1] > 1)) {
    for_planes(n[2], 2 * static_cast<std::size_t>((n[0] + n[1]) * n[2]),
               [&](int k) { fill_plane_ghosts(L, v, k); });
  }
  fill_z_ghosts(L, v);
}

// (A x)_c = diag_c x_c - sum over faces K_f x_neighbour (ghosts of x filled).
inline double apply_at(const Level& L, const double* x, std::size_t c) {
  const auto p = static_cast<std::ptrdiff_t>(c);
  return L.diag[c] * x[c] - multigrid_rows::neighbours(L.K[0].data(), L.K[1].data(),
                                                       L.K[2].data(), x, p, L.s[1], L.s[2]);
}

// r = b - A x on the interior; returns |r|^2.
double residual(const Level& L, const double* b, const double* x, double* r) {
  return sum_cells(L, [&](std::size_t c, double& rr) {
    r[c] = b[c] - apply_at(L, x, c);
    rr += r[c] * r[c];
  });
}

// The same, returning {|r|^2, sum of r} (the sum as mean_interior adds it: plane by plane).
std::array<double, 2> residual_and_sum(const Level& L, const double* b, const double* x,
                                       double* r) {
  return sum_planes_n<2>(L.n[2], L.cells(), [&](int k) {
    std::array<double, 2> s{};
    for (int j = 0; j < L.n[1]; ++j) {
      std::size_t c = L.at(0, j, k);
      for (int i = 0; i < L.n[0]; ++i, ++c) {
        r[c] = b[c] - apply_at(L, x, c);
        s[0] += r[c] * r[c];
        s[1] += r[c];
      }
    }
    return s;
  });
}

// Gauss-Seidel on the cells of one colour ((i + j + k) even or odd): they depend only on the
// other colour, except across the seam of an odd periodic axis, where the neighbour is read from
// the ghost (its value before this pass: a Jacobi step there, still symmetric and convergent).
// The cells of one colour on plane k.
inline void relax_plane(const Level& L, const double* b, double* x, int colour, int k) {
  const std::size_t sy = static_cast<std::size_t>(L.s[1]);
  const std::size_t sz = static_cast<std::size_t>(L.s[2]);
  const double* kx = L.K[0].data();
  const double* ky = L.K[1].data();
  const double* kz = L.K[2].data();
  const double* id = L.inv_diag.data();
  const double omega = L.omega;
  // The cell's Gauss-Seidel value from its neighbours.
  const auto gauss_seidel = [&](std::size_t c) {
    return (b[c] + kx[c] * x[c - 1] + kx[c + 1] * x[c + 1] + ky[c] * x[c - sy] +
            ky[c + sy] * x[c + sy] + kz[c] * x[c - sz] + kz[c + sz] * x[c + sz]) *
           id[c];
  };
  for (int j = 0; j < L.n[1]; ++j) {
    const int i0 = (colour + j + k + L.parity) & 1;
    std::size_t c = L.at(i0, j, k);
    // Weight 1 takes the value itself (x + (gs - x) would round differently).
    if (omega == 1.0) {
      for (int i = i0; i < L.n[0]; i += 2, c += 2) {
        x[c] = gauss_seidel(c);
      }
      continue;
    }
    for (int i = i0; i < L.n[0]; i += 2, c += 2) {
      x[c] += omega * (gauss_seidel(c) - x[c]);
    }
  }
}

void relax_points(const Level& L, const double* b, double* x, int colour) {
  for_planes(L.n[2], L.cells(), [&](int k) { relax_plane(L, b, x, colour, k); });
  fill_ghosts(L, x);
}

// Tridiagonal solve (Thomas): lo[m] couples m to m-1, up[m] m to m+1; diagonally dominant
// rows, no pivoting. w: n scratch values. rhs is overwritten by the solution.
void thomas(int n, const double* lo, const double* d, const double* up, double* rhs, double* w) {
  double beta = d[0];
  rhs[0] /= beta;
  for (int m = 1; m < n; ++m) {
    w[m] = up[m - 1] / beta;
    beta = d[m] - lo[m] * w[m];
    rhs[m] = (rhs[m] - lo[m] * rhs[m - 1]) / beta;
  }
  for (int m = n - 2; m >= 0; --m) {
    rhs[m] -= w[m + 1] * rhs[m + 1];
  }
}

// thomas() with its pivots and multipliers already computed (by thomas's own expressions, so the
// solution is bitwise thomas's): rhs is overwritten by the solution.
void thomas_factored(int n, const double* lo, const double* pivot, const double* mult,
                     double* rhs) {
  rhs[0] /= pivot[0];
  for (int m = 1; m < n; ++m) {
    rhs[m] = (rhs[m] - lo[m] * rhs[m - 1]) / pivot[m];
  }
  for (int m = n - 2; m >= 0; --m) {
    rhs[m] -= mult[m + 1] * rhs[m + 1];
  }
}

// Thomas's pivots and multipliers of the tridiagonal (lo, d, up), as thomas() computes them.
void thomas_factors(int n, const double* lo, const double* d, const double* up, double* pivot,
                    double* mult) {
  double beta = d[0];
  pivot[0] = beta;
  mult[0] = 0.0;
  for (int m = 1; m < n; ++m) {
    mult[m] = up[m - 1] / beta;
    beta = d[m] - lo[m] * mult[m];
    pivot[m] = beta;
  }
}

// The line relaxation's matrices change only with the coefficients: factor every line once per
// set_coefficients, so a relaxation pass only substitutes.
// A periodic (cyclic) line, n >= 3: lo[0] couples 0 to n-1 and up[n-1] couples n-1 to 0.
// A = T + u v^T with u = (g, 0, .., up[n-1]), v = (1, 0, .., lo[0] / g), g = -d[0], and the
// Sherman-Morrison formula x = y - (v.y) / (1 + v.z) z with T y = rhs, T z = u (Golub & Van Loan,
// "Matrix Computations", 4th ed., §2.1.4): T's factors, z and 1 + v.z are stored per line.
void factor_lines(Level& L) {
  if (L.line < 0) {
    return;
  }
  const int a = L.line;
  const int p = a == 0 ? 1 : 0;
  const int q = a == 2 ? 1 : 2;
  const int na = L.n[a];
  const auto len = static_cast<std::size_t>(na);
  const std::size_t lines = L.plane_cells(a);
  const std::size_t sa = static_cast<std::size_t>(L.s[a]);
  const bool cyclic = L.periodic[a] && na > 2;
  L.line_lo.assign(lines * len, 0.0);
  L.line_pivot.assign(lines * len, 0.0);
  L.line_mult.assign(lines * len, 0.0);
  L.line_z.assign(cyclic ? lines * len : 0, 0.0);
  L.line_sm.assign(2 * lines, 0.0);
  std::vector<double> buf(5 * len);
  double* d = buf.data();
  double* up = d + na;
  double* td = up + na;
  double* w = td + na;
  for (int iq = 0; iq < L.n[q]; ++iq) {
    for (int ip = 0; ip < L.n[p]; ++ip) {
      std::array<int, 3> first{};
      first[p] = ip;
      first[q] = iq;
      const std::size_t base = L.at(first[0], first[1], first[2]);
      const std::size_t line = static_cast<std::size_t>(ip) +
                               static_cast<std::size_t>(L.n[p]) * static_cast<std::size_t>(iq);
      double* lo = L.line_lo.data() + line * len;
      double* pivot = L.line_pivot.data() + line * len;
      double* mult = L.line_mult.data() + line * len;
      for (int m = 0; m < na; ++m) {
        const std::size_t c = base + static_cast<std::size_t>(m) * sa;
        d[m] = L.diag[c] > 0.0 ? L.diag[c] : 1.0; // an empty row: x = its right-hand side
        lo[m] = -L.K[a][c];
        up[m] = -L.K[a][c + sa];
      }
      if (L.periodic[a] && na == 2) {
        // Both faces of the period join cells 0 and 1: a 2 x 2 solve (relax_lines).
        const double off0 = lo[0] + up[0];
        const double off1 = lo[1] + up[1];
        pivot[0] = d[0];
        pivot[1] = d[1];
        mult[0] = off0;
        mult[1] = off1;
        L.line_sm[2 * line] = d[0] * d[1] - off0 * off1;
      } else if (!cyclic) {
        thomas_factors(na, lo, d, up, pivot, mult); // lo[0], up[na-1] unused (boundary faces)
      } else {
        // T = tridiag(lo, td, up), u = (g, 0, .., up[n-1]), z = T^-1 u.
        const double g = -d[0];
        std::copy_n(d, na, td);
        td[0] = d[0] - g;
        td[na - 1] = d[na - 1] - lo[0] * up[na - 1] / g;
        thomas_factors(na, lo, td, up, pivot, mult);
        double* z = L.line_z.data() + line * len;
        std::fill_n(z, na, 0.0);
        z[0] = g;
        z[na - 1] = up[na - 1];
        thomas(na, lo, td, up, z, w);
        const double ratio = lo[0] / g;
        L.line_sm[2 * line] = ratio;
        L.line_sm[2 * line + 1] = 1.0 + z[0] + ratio * z[na - 1];
      }
    }
  }
}

// Block Gauss-Seidel on the lines along L.line of one colour (by the parity of the two transverse
// indices): each line solved exactly with its transverse neighbours fixed.
void relax_lines(const Level& L, const double* b, double* x, int colour) {
  const int a = L.line;
  const int p = a == 0 ? 1 : 0;
  const int q = a == 2 ? 1 : 2;
  const int na = L.n[a];
  const std::size_t sa = static_cast<std::size_t>(L.s[a]);
  const std::size_t sp = static_cast<std::size_t>(L.s[p]);
  const std::size_t sq = static_cast<std::size_t>(L.s[q]);
  const double* kp = L.K[p].data();
  const double* kq = L.K[q].data();
  const auto len = static_cast<std::size_t>(na);
  const bool cyclic = L.periodic[a] && na > 2;
  const bool pair = L.periodic[a] && na == 2;
  for_planes(L.n[q], 4 * L.cells(), [&](int iq) {
    std::vector<double> rhs(len);
    for (int ip = (colour + iq) & 1; ip < L.n[p]; ip += 2) {
      std::array<int, 3> first{};
      first[p] = ip;
      first[q] = iq;
      const std::size_t base = L.at(first[0], first[1], first[2]);
      const std::size_t line = static_cast<std::size_t>(ip) +
                               static_cast<std::size_t>(L.n[p]) * static_cast<std::size_t>(iq);
      const double* lo = L.line_lo.data() + line * len;
      const double* pivot = L.line_pivot.data() + line * len;
      const double* mult = L.line_mult.data() + line * len;
      for (int m = 0; m < na; ++m) {
        const std::size_t c = base + static_cast<std::size_t>(m) * sa;
        rhs[static_cast<std::size_t>(m)] = b[c] + kp[c] * x[c - sp] + kp[c + sp] * x[c + sp] +
                                           kq[c] * x[c - sq] + kq[c + sq] * x[c + sq];
      }
      if (pair) {
        // Both faces of the period join cells 0 and 1 (factor_lines: diagonal in pivot, the two
        // couplings in mult, the determinant in line_sm).
        const double det = L.line_sm[2 * line];
        const double r0 = rhs[0];
        rhs[0] = (pivot[1] * r0 - mult[0] * rhs[1]) / det;
        rhs[1] = (pivot[0] * rhs[1] - mult[1] * r0) / det;
      } else {
        thomas_factored(na, lo, pivot, mult, rhs.data());
        if (cyclic) {
          // Sherman-Morrison (factor_lines): x = y - (v.y) / (1 + v.z) z.
          const double* z = L.line_z.data() + line * len;
          const double ratio = L.line_sm[2 * line];
          const double factor = (rhs[0] + ratio * rhs[len - 1]) / L.line_sm[2 * line + 1];
          for (std::size_t m = 0; m < len; ++m) {
            rhs[m] -= factor * z[m];
          }
        }
      }
      for (int m = 0; m < na; ++m) {
        x[base + static_cast<std::size_t>(m) * sa] = rhs[static_cast<std::size_t>(m)];
      }
    }
  });
  fill_ghosts(L, x);
}

void relax(const Level& L, const double* b, double* x, int colour) {
  if (L.line >= 0) {
    relax_lines(L, b, x, colour);
  } else {
    relax_points(L, b, x, colour);
  }
}

// Coarse right-hand side: the mean of the fine residual b - A x over each coarse cell's children
// (the transpose of piecewise-constant prolongation, scaled by 1 / children), the residual
// computed on the fly (ghosts of x filled).
// On an odd axis (uneven coarsening) the last coarse cell has one child: its missing child adds
// nothing, and the sum is still scaled by 1 / (full children), so the coarse equation stays the
// fine equations' sum over the children scaled alike on every cell (R = P^T / children).
// Coarse plane k of the restriction; row, acc: F.n[0] + 1 and C.n[0] values of scratch (row's
// last value stays zero: the missing child along x).
void restrict_plane(const Level& F, const Level& C, const double* b, const double* x, double* bc,
                    int k, double* row, double* acc) {
  const auto& q = F.ratio;
  const double inv = 1.0 / (q[0] * q[1] * q[2]);
  const auto nc = static_cast<std::size_t>(C.n[0]);
  // Row by row: the fine residual of a whole row (fluid/multigrid_rows.hpp), then its pairs (or
  // cells) added into the coarse row.
  for (int j = 0; j < C.n[1]; ++j) {
    std::fill_n(acc, nc, 0.0);
    for (int dk = 0; dk < q[2]; ++dk) {
      for (int dj = 0; dj < q[1]; ++dj) {
        if (q[1] * j + dj >= F.n[1] || q[2] * k + dk >= F.n[2]) {
          continue; // the missing child of a last coarse cell on an odd axis
        }
        multigrid_rows::with_rows_at(F.simd, [&](auto rows) {
          rows.residual_values(b, F.diag.data(), F.K[0].data(), F.K[1].data(), F.K[2].data(), x,
                               row, row_of(F, q[1] * j + dj, q[2] * k + dk));
        });
        if (q[0] == 2) {
          for (std::size_t i = 0; i < nc; ++i) {
            acc[i] += row[2 * i] + row[2 * i + 1];
          }
        } else if (q[0] == 3) {
          for (std::size_t i = 0; i < nc; ++i) {
            acc[i] += row[3 * i] + row[3 * i + 1] + row[3 * i + 2];
          }
        } else {
          for (std::size_t i = 0; i < nc; ++i) {
            acc[i] += row[i];
          }
        }
      }
    }
    double* out = bc + C.at(0, j, k);
    for (std::size_t i = 0; i < nc; ++i) {
      out[i] = acc[i] * inv;
    }
  }
}

void restrict_residual(const Level& F, const Level& C, const double* b, const double* x,
                       double* bc) {
  for_planes(C.n[2], F.cells(), [&](int k) {
    std::vector<double> row(static_cast<std::size_t>(F.n[0]) + 1); // + the missing child: 0
    std::vector<double> acc(static_cast<std::size_t>(C.n[0]));
    restrict_plane(F, C, b, x, bc, k, row.data(), acc.data());
  });
}

// The weight of a point-relaxed level of n (global) cells: the settings' where red and black
// are a true two-colouring. Across the seam of an odd periodic axis two cells of one colour are
// neighbours and each colour step is a Jacobi step on those pairs, whose over-relaxation
// converges only while omega < 2 / (1 + K / sqrt(diag_1 diag_2)) with K their link: a link that
// carries most of both diagonals (a strong coefficient jump at the seam) would leave no room
// above 1, so such a level keeps Gauss-Seidel.
double relaxation_weight(const MultigridSettings& settings, const std::array<bool, 3>& periodic,
                         const std::array<int, 3>& n) {
  for (int a = 0; a < 3; ++a) {
    if (periodic[a] && n[a] > 1 && n[a] % 2 == 1) {
      return 1.0;
    }
  }
  return settings.relaxation_weight;
}

// The first red pass from x = 0: red cells omega b / diag (the weighted correction from 0; at
// weight 1 the product is exact), black cells 0 (their neighbours are zero).
void relax_points_from_zero(const Level& L, const double* b, double* x) {
  const double* id = L.inv_diag.data();
  for_planes(L.n[2], L.cells(), [&](int k) {
    for (int j = 0; j < L.n[1]; ++j) {
      std::size_t c = L.at(0, j, k);
      const int red = (j + k + L.parity) & 1; // i parity of the red cells in this row
      for (int i = 0; i < L.n[0]; ++i, ++c) {
        x[c] = (i & 1) == red ? L.omega * (b[c] * id[c]) : 0.0;
      }
    }
  });
  fill_ghosts(L, x);
}

// Plane k of the first red pass from x = 0 (relax_points_from_zero), after b -= *shift on the
// plane when shift is given.
void relax_plane_from_zero(const Level& L, double* b, double* x, int k, const double* shift) {
  const double* id = L.inv_diag.data();
  for (int j = 0; j < L.n[1]; ++j) {
    std::size_t c = L.at(0, j, k);
    const int red = (j + k + L.parity) & 1;
    if (shift != nullptr) {
      for (int i = 0; i < L.n[0]; ++i) {
        b[c + static_cast<std::size_t>(i)] -= *shift;
      }
    }
    for (int i = 0; i < L.n[0]; ++i, ++c) {
      x[c] = (i & 1) == red ? L.omega * (b[c] * id[c]) : 0.0;
    }
  }
}

// Fewest planes per task of a fused sweep (relax_pair, update_and_apply).
constexpr int kMinPairPlanes = 4;

// {tasks, planes per task} of a fused sweep over nz planes: one block per thread.
std::array<int, 2> plane_blocks(int nz) {
  const int threads = usable_threads();
  const int tasks = std::max(1, std::min(threads, nz / kMinPairPlanes));
  return {tasks, (nz + tasks - 1) / tasks};
}

// relax_pair needs a z-neighbour of the other colour on both sides: an odd period along z puts
// cells of one colour next to each other across the seam.
// A distributed level exchanges whole passes (its ghosts come from other ranks).
bool pair_fusable(const Level& L) {
  return L.line < 0 && L.exchange == nullptr && !(L.periodic[2] && L.n[2] > 1 && L.n[2] % 2 == 1);
}

// Two colour passes, `first` then 1 - first, in one sweep over the planes: the second colour's
// plane k - 1 is relaxed right after the first colour's plane k, while those planes are still in
// cache (the second pass reads the first colour on planes k - 2 .. k only). Every value is computed
// from the same inputs as by relax_points(first) followed by relax_points(1 - first), so the
// result is bitwise theirs:
// - a task owns a block of planes; it relaxes the first colour on all of them and the second
//   colour on its inner planes, each after the first colour of the plane above (whose first pass
//   read the second colour's old values);
// - then the periodic z ghosts get the new first colour, and the second colour is relaxed on the
//   tasks' edge planes (their neighbours in other tasks are done by then);
// - x and y ghosts of a plane are refreshed right after its first pass, as fill_ghosts after the
//   whole pass would (the second pass reads the first colour's new images; at an odd x or y
//   period the same colour's old one, as relax_points does).
// Since no value depends on where the blocks end, their number may follow the thread count:
// one block per thread (at least kMinPairPlanes planes each) leaves the fewest edge planes, which
// are relaxed from memory rather than from cache (on one thread only the first and the last).
// from_zero: the first pass is relax_points_from_zero's (first = 0), after b -= *shift if given.
// coarse (optional): also restrict the residual to coarse->b (restrict_residual, bitwise) in the
// same sweep, for each coarse plane whose fine planes and their neighbours are final inside the
// block (a plane's x and y ghosts refreshed after its second pass); the others after the pair.
void relax_pair(const Level& L, double* b, double* x, int first, bool from_zero,
                const double* shift, Level* coarse = nullptr) {
  const int nz = L.n[2];
  const auto [tasks, block] = plane_blocks(nz);
  const int second = 1 - first;
  const int qz = L.ratio[2];
  std::vector<char> restricted(coarse != nullptr ? static_cast<std::size_t>(coarse->n[2]) : 0, 0);
  const auto first_pass = [&](int k) {
    if (from_zero) {
      relax_plane_from_zero(L, b, x, k, shift);
    } else {
      relax_plane(L, b, x, first, k);
    }
    fill_plane_ghosts(L, x, k);
  };
  for_planes(tasks, L.cells(), [&](int t) {
    const int k0 = std::min(nz, t * block);
    const int k1 = std::min(nz, k0 + block);
    std::vector<double> row(coarse != nullptr ? static_cast<std::size_t>(L.n[0]) + 1 : 0);
    std::vector<double> acc(coarse != nullptr ? static_cast<std::size_t>(coarse->n[0]) : 0);
    for (int k = k0; k < k1; ++k) {
      first_pass(k);
      if (k - 1 > k0 && k - 1 < k1 - 1) {
        relax_plane(L, b, x, second, k - 1);
        if (coarse == nullptr) {
          continue;
        }
        fill_plane_ghosts(L, x, k - 1);
        // Fine planes up to k - 1 are final: the coarse plane ending at fine plane k - 2, if
        // its first fine plane's lower neighbour is final too (an inner plane of this block).
        const int m = k - 2;
        const int kc = m / qz;
        if ((m + 1) % qz == 0 && kc * qz >= k0 + 2) {
          restrict_plane(L, *coarse, b, x, coarse->b.data(), kc, row.data(), acc.data());
          restricted[static_cast<std::size_t>(kc)] = 1;
        }
      }
    }
  });
  fill_z_ghosts(L, x);
  for_planes(tasks, 2 * L.cells() / static_cast<std::size_t>(block), [&](int t) {
    const int k0 = std::min(nz, t * block);
    const int k1 = std::min(nz, k0 + block);
    if (k0 == k1) {
      return;
    }
    relax_plane(L, b, x, second, k0);
    if (k1 - 1 != k0) {
      relax_plane(L, b, x, second, k1 - 1);
    }
  });
  fill_ghosts(L, x);
  if (coarse != nullptr) {
    for_planes(coarse->n[2], L.cells(), [&](int kc) {
      if (restricted[static_cast<std::size_t>(kc)] == 0) {
        std::vector<double> row(static_cast<std::size_t>(L.n[0]) + 1);
        std::vector<double> acc(static_cast<std::size_t>(coarse->n[0]));
        restrict_plane(L, *coarse, b, x, coarse->b.data(), kc, row.data(), acc.data());
      }
    });
  }
}

// CG's new direction p = z + beta p (p = z when `first`) and q = A p with p.q, in one sweep over
// the planes: q on plane k - 1 right after p on plane k, while p's planes k - 2 .. k are in cache.
// Blocks of planes as relax_pair's: a block's inner planes in the sweep; after every block's p
// (and the z ghosts), its edge planes. Each value, and each plane's partial sum of p.q, is
// computed as by the two separate loops (summed in plane order): bitwise theirs.
double update_and_apply(const Level& L, const double* z, double beta, bool first, double* p,
                        double* q) {
  if (L.exchange != nullptr) {
    // Distributed: p's ghosts come from the other ranks between the two loops (the same values
    // as the fused sweep's). The sum is this box's, plane by plane.
    for_cells(L, [&](std::size_t c) { p[c] = first ? z[c] : z[c] + beta * p[c]; });
    fill_ghosts(L, p);
    return sum_cells(L, [&](std::size_t c, double& s) {
      q[c] = apply_at(L, p, c);
      s += p[c] * q[c];
    });
  }
  const int nz = L.n[2];
  const auto [tasks, block] = plane_blocks(nz);
  std::vector<double> partial(static_cast<std::size_t>(nz), 0.0);
  const auto update = [&](int k) {
    for (int j = 0; j < L.n[1]; ++j) {
      const std::size_t c0 = L.at(0, j, k);
      if (first) {
        std::copy_n(z + c0, L.n[0], p + c0);
      } else {
        for (std::size_t c = c0; c < c0 + static_cast<std::size_t>(L.n[0]); ++c) {
          p[c] = z[c] + beta * p[c];
        }
      }
    }
    fill_plane_ghosts(L, p, k);
  };
  // q's row by the row kernel (vectorized), then p.q in the cells' order.
  const auto apply = [&](int k) {
    double sum = 0.0;
    multigrid_rows::with_rows_at(L.simd, [&](auto rows) {
      for (int j = 0; j < L.n[1]; ++j) {
        const multigrid_rows::Row row = row_of(L, j, k);
        rows.apply_values(L.diag.data(), L.K[0].data(), L.K[1].data(), L.K[2].data(), p, q + row.c0,
                          row);
        for (std::ptrdiff_t c = row.c0; c < row.c0 + row.n; ++c) {
          sum += p[c] * q[c];
        }
      }
    });
    partial[static_cast<std::size_t>(k)] = sum;
  };
  for_planes(tasks, L.cells(), [&](int t) {
    const int k0 = std::min(nz, t * block);
    const int k1 = std::min(nz, k0 + block);
    for (int k = k0; k < k1; ++k) {
      update(k);
      if (k - 1 > k0 && k - 1 < k1 - 1) {
        apply(k - 1);
      }
    }
  });
  fill_z_ghosts(L, p);
  for_planes(tasks, 2 * L.cells() / static_cast<std::size_t>(block), [&](int t) {
    const int k0 = std::min(nz, t * block);
    const int k1 = std::min(nz, k0 + block);
    if (k0 == k1) {
      return;
    }
    apply(k0);
    if (k1 - 1 != k0) {
      apply(k1 - 1);
    }
  });
  double total = 0.0;
  for (const double v : partial) {
    total += v;
  }
  return total;
}

// x_fine += x_coarse of the parent cell (piecewise constant).
void prolong_add(const Level& F, const Level& C, const double* xc, double* xf) {
  const auto& q = F.ratio;
  for_planes(F.n[2], F.cells(), [&](int k) {
    for (int j = 0; j < F.n[1]; ++j) {
      std::size_t f = F.at(0, j, k);
      const std::size_t crow = C.at(0, j / q[1], k / q[2]);
      if (q[0] == 2) {
        for (int i = 0; i < F.n[0]; ++i, ++f) {
          xf[f] += xc[crow + static_cast<std::size_t>(i >> 1)];
        }
      } else if (q[0] == 3) {
        for (int i = 0; i < F.n[0]; ++i, ++f) {
          xf[f] += xc[crow + static_cast<std::size_t>(i / 3)];
        }
      } else {
        for (int i = 0; i < F.n[0]; ++i, ++f) {
          xf[f] += xc[crow + static_cast<std::size_t>(i)];
        }
      }
    }
  });
  fill_ghosts(F, xf);
}

// The mean over the level's cells (every rank's on a distributed level: collective).
double mean_interior(const Level& L, const double* v) {
  double sum = sum_cells(L, [&](std::size_t c, double& s) { s += v[c]; });
  if (L.exchange != nullptr) {
    sum = L.exchange->sum(sum);
  }
  return sum / L.active;
}

void shift_interior(const Level& L, double* v, double shift) {
  if (L.has_inactive) {
    for_cells(L, [&](std::size_t c) { v[c] -= L.diag[c] > 0.0 ? shift : 0.0; });
    return;
  }
  for_cells(L, [&](std::size_t c) { v[c] -= shift; });
}

// v = 0 on the cells with an empty row.
void clear_inactive(const Level& L, double* v) {
  if (L.has_inactive) {
    for_cells(L, [&](std::size_t c) { v[c] = L.diag[c] > 0.0 ? v[c] : 0.0; });
  }
}

// L.active and L.has_inactive from the diagonal (collective on a distributed level); without
// empty rows (settings: empty_rows false) every cell is active and nothing is counted.
void count_active(Level& L) {
  if (!L.empty_rows) {
    L.active = L.total;
    L.has_inactive = false;
    return;
  }
  double count = sum_cells(L, [&](std::size_t c, double& s) { s += L.diag[c] > 0.0 ? 1.0 : 0.0; });
  if (L.exchange != nullptr) {
    count = L.exchange->sum(count);
  }
  // A grid of one isolated cell has no non-empty row: its means stay over the cells.
  L.active = count > 0.0 ? count : L.total;
  L.has_inactive = L.active < L.total;
}

// The diagonal from the face coefficients and the Dirichlet faces. Row by row (the inner loops
// run along x and vectorize); each cell's terms are added in the order mass, then per axis the
// two faces and that axis's Dirichlet faces, as a cell-by-cell loop would.
void build_diagonal(Level& L) {
  const int n0 = L.n[0];
  for_planes(L.n[2], L.cells(), [&](int k) {
    for (int j = 0; j < L.n[1]; ++j) {
      const std::size_t c = L.at(0, j, k);
      double* __restrict d = L.diag.data() + c;
      if (L.mass.empty()) {
        std::fill_n(d, n0, 0.0);
      } else {
        std::copy_n(L.mass.data() + c, n0, d);
      }
      const std::array<int, 3> row = {0, j, k};
      for (int a = 0; a < 3; ++a) {
        const double* __restrict lo = L.K[a].data() + c;
        const double* __restrict hi = lo + L.s[a];
        for (int i = 0; i < n0; ++i) {
          d[i] += lo[i] + hi[i];
        }
        for (int side = 0; side < 2; ++side) {
          if (!L.dirichlet[a][side]) {
            continue;
          }
          const int edge = side == 0 ? 0 : L.n[a] - 1;
          const double* face = L.dface[a][side].data();
          const double dist = L.bdist[a][side];
          if (a == 0) {
            d[edge] += face[L.plane_index(0, {edge, j, k})] / dist;
          } else if (row[a] == edge) {
            // The x-fastest plane index of the row's first cell; the row runs along it.
            const std::size_t first = L.plane_index(a, row);
            for (int i = 0; i < n0; ++i) {
              d[i] += face[first + static_cast<std::size_t>(i)] / dist;
            }
          }
        }
      }
      double* __restrict inv = L.inv_diag.data() + c;
      for (int i = 0; i < n0; ++i) {
        inv[i] = d[i] > 0.0 ? 1.0 / d[i] : 0.0;
      }
    }
  });
  count_active(L);
  factor_lines(L);
}

// Coarse face coefficients: the arithmetic mean of the fine faces that make up the coarse face
// (fluxes through side-by-side faces add: conductances in parallel), divided by ratio^2 along the
// face normal because the coefficient carries 1 / h^2 (re-discretisation, as in cell-centred
// geometric multigrid, e.g. Trottenberg et al. 2001 §5.7 / AMReX's MLMG).
void coarsen_coefficients(const Level& F, Level& C) {
  const auto& q = F.ratio;
  for (int a = 0; a < 3; ++a) {
    const double scale = 1.0 / (q[a] * q[a]);
    // Transverse children of a coarse face.
    std::array<int, 3> kids = q;
    kids[a] = 1;
    const double inv = scale / (kids[0] * kids[1] * kids[2]);
    std::array<int, 3> hi = C.n;
    hi[a] = C.n[a] + 1;
    const bool wrap_to_self = C.periodic[a] && C.n[a] == 1;
    // Row by row: each coarse face accumulates its children in the order (dk, dj, di), as a
    // face-by-face sum would, in the coarse row itself, then scales it.
    for_planes(hi[2], 2 * C.cells(), [&](int k) {
      for (int j = 0; j < hi[1]; ++j) {
        double* __restrict out = C.K[a].data() + C.at(0, j, k);
        std::fill_n(out, hi[0], 0.0);
        if (wrap_to_self) {
          continue; // a one-cell period couples a cell only to itself: no flux
        }
        for (int dk = 0; dk < kids[2]; ++dk) {
          for (int dj = 0; dj < kids[1]; ++dj) {
            // A fine face index past the fine grid: the missing child of an odd axis's last
            // coarse cell (transverse), or the high face of such an axis (normal; a Neumann
            // side, so no flux).
            const int fj = q[1] * j + dj;
            const int fk = q[2] * k + dk;
            if (fj > F.n[1] || fk > F.n[2] || (a != 1 && fj == F.n[1]) ||
                (a != 2 && fk == F.n[2])) {
              continue;
            }
            const double* __restrict in = F.K[a].data() + F.at(0, fj, fk);
            if (kids[0] == 2) {
              const int pairs = F.n[0] / 2;
              for (int i = 0; i < pairs; ++i) {
                out[i] += in[2 * i];
                out[i] += in[2 * i + 1];
              }
              if (pairs < hi[0]) {
                out[pairs] += in[2 * pairs]; // an odd x axis: the last coarse cell's one child
              }
            } else if (kids[0] == 3) {
              // A third along x (an axis divisible by 3: every coarse cell has its 3 children).
              for (int i = 0; i < hi[0]; ++i) {
                out[i] += in[3 * i];
                out[i] += in[3 * i + 1];
                out[i] += in[3 * i + 2];
              }
            } else {
              const int stride = q[0];
              const int faces = std::min(hi[0], F.n[0] / stride + 1);
              for (int i = 0; i < faces; ++i) {
                out[i] += in[stride * i];
              }
            }
          }
        }
        for (int i = 0; i < hi[0]; ++i) {
          out[i] = out[i] * inv;
        }
      }
    });
    for (int side = 0; side < 2; ++side) {
      if (!C.dirichlet[a][side]) {
        continue;
      }
      const int p = a == 0 ? 1 : 0;
      const int pq = a == 2 ? 1 : 2;
      for (int iq = 0; iq < C.n[pq]; ++iq) {
        for (int ip = 0; ip < C.n[p]; ++ip) {
          double sum = 0.0;
          for (int dq = 0; dq < q[pq]; ++dq) {
            for (int dp = 0; dp < q[p]; ++dp) {
              if (q[p] * ip + dp >= F.n[p] || q[pq] * iq + dq >= F.n[pq]) {
                continue; // the missing child of an odd axis
              }
              sum += F.dface[a][side][static_cast<std::size_t>(q[p] * ip + dp) +
                                      static_cast<std::size_t>(F.n[p]) *
                                          static_cast<std::size_t>(q[pq] * iq + dq)];
            }
          }
          C.dface[a][side][static_cast<std::size_t>(ip) +
                           static_cast<std::size_t>(C.n[p]) * static_cast<std::size_t>(iq)] =
              sum * scale / (q[p] * q[pq]);
        }
      }
    }
  }
  for (int a = 0; a < 3; ++a) {
    for (int side = 0; side < 2; ++side) {
      // The coarse centre sits (r - 1) / 2 fine spacings further in than the first child's.
      C.bdist[a][side] = (F.bdist[a][side] + 0.5 * (q[a] - 1)) / q[a];
    }
  }
  if (!F.mass.empty()) {
    // The mass term's restriction R M P: the mean over the children.
    C.mass.assign(C.size, 0.0);
    const double inv = 1.0 / (q[0] * q[1] * q[2]);
    for_planes(C.n[2], F.cells(), [&](int k) {
      for (int j = 0; j < C.n[1]; ++j) {
        double* __restrict out = C.mass.data() + C.at(0, j, k);
        std::fill_n(out, C.n[0], 0.0);
        for (int dk = 0; dk < q[2]; ++dk) {
          for (int dj = 0; dj < q[1]; ++dj) {
            if (q[1] * j + dj >= F.n[1] || q[2] * k + dk >= F.n[2]) {
              continue; // the missing child of an odd axis
            }
            const double* __restrict in = F.mass.data() + F.at(0, q[1] * j + dj, q[2] * k + dk);
            for (int i = 0; i < C.n[0]; ++i) {
              for (int di = 0; di < q[0]; ++di) {
                if (q[0] * i + di < F.n[0]) {
                  out[i] += in[q[0] * i + di];
                }
              }
            }
          }
        }
        for (int i = 0; i < C.n[0]; ++i) {
          out[i] = out[i] * inv;
        }
      }
    });
  } else {
    C.mass.clear();
  }
  build_diagonal(C);
}

// The factor an axis of n cells may coarsen by, 1 if none: 2 when n is even or `uneven` (an odd
// axis whose last coarse cell keeps one child), else 3 when 3 divides n (an odd periodic or
// Dirichlet-ended axis such as 135 = 3^3 x 5, which would otherwise keep its cells on every
// coarser level; coarsening by 3 is cell-centred multigrid's other aligned ratio, the coarse
// faces falling on fine faces); at least 2 coarse cells either way.
int axis_ratio(int n, bool uneven) {
  if ((n % 2 == 0 || uneven) && n >= 4) {
    return 2;
  }
  if (n % 3 == 0 && n >= 6) {
    return 3;
  }
  return 1;
}

// Which axes the next level coarsens (axis_ratio), among the finest of those that can
// (semi-coarsening keeps the coarse level's couplings near isotropic). An axis that cannot
// coarsen is left to line relaxation when it is the only one; with two or more such axes, the
// others stop once they are as coarse as those (point relaxation would stall on the rest).
std::array<int, 3> coarsening(const std::array<int, 3>& n, const std::array<double, 3>& h,
                              const std::array<bool, 3>& uneven) {
  std::array<bool, 3> can{};
  double hmin = 0.0;
  double hstuck = 0.0;
  int stuck = 0;
  for (int a = 0; a < 3; ++a) {
    can[a] = axis_ratio(n[a], uneven[a]) > 1;
    if (can[a] && (hmin == 0.0 || h[a] < hmin)) {
      hmin = h[a];
    }
    if (!can[a] && n[a] > 1) {
      hstuck = stuck == 0 ? h[a] : std::min(hstuck, h[a]);
      ++stuck;
    }
  }
  std::array<int, 3> ratio{1, 1, 1};
  for (int a = 0; a < 3; ++a) {
    if (can[a] && h[a] <= 1.5 * hmin && (stuck < 2 || h[a] <= 1.01 * hstuck)) {
      ratio[a] = axis_ratio(n[a], uneven[a]);
    }
  }
  return ratio;
}

// The ratio by which a one-grid hierarchy coarsens a level of n cells at spacing h: {1, 1, 1}
// when the level is the coarsest (small enough for the direct solve, or no axis coarsens).
std::array<int, 3> level_ratio(const std::array<int, 3>& n, const std::array<double, 3>& h,
                               const std::array<bool, 3>& uneven, int max_direct_cells) {
  if (static_cast<double>(n[0]) * n[1] * n[2] <= max_direct_cells) {
    return {1, 1, 1};
  }
  return coarsening(n, h, uneven);
}

// Line relaxation along the finest axis when it is markedly finer than every other.
int choose_line_axis(const std::array<int, 3>& n, const std::array<double, 3>& h) {
  int best = -1;
  for (int a = 0; a < 3; ++a) {
    if (n[a] > 1 && (best < 0 || h[a] < h[best])) {
      best = a;
    }
  }
  if (best < 0) {
    return -1;
  }
  for (int a = 0; a < 3; ++a) {
    if (a != best && n[a] > 1 && !(1.5 * h[best] < h[a])) {
      return -1;
    }
  }
  return best;
}

// Cell c's entry in a vector of a box of n cells, i fastest.
std::size_t packed_index(const std::array<int, 3>& n, const std::array<int, 3>& c) {
  return static_cast<std::size_t>(c[0]) +
         static_cast<std::size_t>(n[0]) *
             (static_cast<std::size_t>(c[1]) +
              static_cast<std::size_t>(n[1]) * static_cast<std::size_t>(c[2]));
}

// A level's interior values to a vector of its cells (i fastest), and back.
void pack(const Level& L, const double* v, double* out) {
  for (int k = 0; k < L.n[2]; ++k) {
    for (int j = 0; j < L.n[1]; ++j) {
      std::copy_n(v + L.at(0, j, k), L.n[0], out + packed_index(L.n, {0, j, k}));
    }
  }
}

void unpack(const Level& L, const double* in, double* v) {
  for (int k = 0; k < L.n[2]; ++k) {
    for (int j = 0; j < L.n[1]; ++j) {
      std::copy_n(in + packed_index(L.n, {0, j, k}), L.n[0], v + L.at(0, j, k));
    }
  }
}

// The constructors' argument checks; returns whether a side is Dirichlet.
bool check_arguments(const std::array<int, 3>& cells, const std::array<double, 3>& spacing,
                     const std::array<std::array<PoissonSide, 2>, 3>& sides,
                     const MultigridSettings& settings) {
  bool dirichlet = false;
  for (int a = 0; a < 3; ++a) {
    if (cells[a] < 1 || !(spacing[a] > 0.0)) {
      throw std::invalid_argument(
          fmt::format("multigrid: axis {} has {} cells of spacing {:g}", a, cells[a], spacing[a]));
    }
    if ((sides[a][0] == PoissonSide::periodic) != (sides[a][1] == PoissonSide::periodic)) {
      throw std::invalid_argument(
          fmt::format("multigrid: axis {} is periodic on one side only", a));
    }
    for (int side = 0; side < 2; ++side) {
      if (sides[a][side] == PoissonSide::dirichlet ||
          sides[a][side] == PoissonSide::dirichlet_node) {
        dirichlet = true;
      }
    }
  }
  if (settings.pre_sweeps < 1 || settings.post_sweeps != settings.pre_sweeps) {
    throw std::invalid_argument("multigrid: pre_sweeps must be >= 1 and equal post_sweeps (a "
                                "symmetric preconditioner for CG)");
  }
  if (!(settings.relaxation_weight > 0.0 && settings.relaxation_weight < 2.0)) {
    throw std::invalid_argument(
        fmt::format("multigrid: relaxation_weight {:g} is not in (0, 2) (the smoother diverges)",
                    settings.relaxation_weight));
  }
  return dirichlet;
}

} // namespace

// A Neumann high side: the missing child of the last coarse cell leaves a coarse boundary face
// that carries no flux either. A periodic or Dirichlet high side needs its last cell's face
// aligned.
std::array<bool, 3>
MultigridPoisson::halves_unevenly(std::array<std::array<PoissonSide, 2>, 3> sides) {
  std::array<bool, 3> uneven{};
  for (int a = 0; a < 3; ++a) {
    uneven[a] = sides[a][1] == PoissonSide::neumann;
  }
  return uneven;
}

std::size_t MultigridPoisson::coarsest_cells(std::array<int, 3> cells,
                                             std::array<double, 3> spacing,
                                             std::array<std::array<PoissonSide, 2>, 3> sides,
                                             MultigridSettings settings) {
  const std::array<bool, 3> uneven = halves_unevenly(sides);
  for (;;) {
    const std::array<int, 3> ratio = level_ratio(cells, spacing, uneven, settings.max_direct_cells);
    if (ratio == std::array<int, 3>{1, 1, 1}) {
      return static_cast<std::size_t>(cells[0]) * cells[1] * cells[2];
    }
    for (int a = 0; a < 3; ++a) {
      cells[a] = (cells[a] + ratio[a] - 1) / ratio[a];
      spacing[a] *= ratio[a];
    }
  }
}

MultigridPoisson::MultigridPoisson(std::array<int, 3> cells, std::array<double, 3> spacing,
                                   std::array<std::array<PoissonSide, 2>, 3> sides,
                                   MultigridSettings settings)
    : settings_(settings), sides_(sides),
      has_dirichlet_(check_arguments(cells, spacing, sides, settings)) {
  singular_ = !has_dirichlet_;
  levels_.emplace_back(cells, spacing, sides);
  const std::array<bool, 3> uneven = halves_unevenly(sides);
  for (;;) {
    Level& fine = levels_.back();
    const std::array<int, 3> ratio =
        level_ratio(fine.n, fine.h, uneven, settings_.max_direct_cells);
    if (ratio == std::array<int, 3>{1, 1, 1}) {
      break;
    }
    fine.ratio = ratio;
    std::array<int, 3> n{};
    std::array<double, 3> h{};
    for (int a = 0; a < 3; ++a) {
      n[a] = (fine.n[a] + ratio[a] - 1) / ratio[a]; // an odd axis: the last cell has one child
      h[a] = fine.h[a] * ratio[a];
    }
    levels_.emplace_back(n, h, sides);
  }
  for (std::size_t l = 0; l + 1 < levels_.size(); ++l) {
    levels_[l].line = choose_line_axis(levels_[l].n, levels_[l].h);
  }
  for (Level& L : levels_) {
    L.empty_rows = settings_.empty_rows;
    L.omega = relaxation_weight(settings_, L.periodic, L.n);
  }
  const std::size_t size = levels_.front().size;
  for (HugePageVector<double>* v : {&x_, &b_, &r_, &r_old_, &z_, &p_, &q_}) {
    v->assign(size, 0.0);
  }
}

MultigridPoisson::MultigridPoisson(std::array<int, 3> cells, std::array<double, 3> spacing,
                                   std::array<std::array<PoissonSide, 2>, 3> sides,
                                   std::vector<CellBox> boxes, const Communicator& comm,
                                   MultigridSettings settings)
    : settings_(settings), sides_(sides),
      has_dirichlet_(check_arguments(cells, spacing, sides, settings)) {
  singular_ = !has_dirichlet_;
  if (boxes.size() != static_cast<std::size_t>(comm.size())) {
    throw std::invalid_argument(
        fmt::format("multigrid: {} boxes for {} ranks", boxes.size(), comm.size()));
  }
  const auto me = static_cast<std::size_t>(comm.rank());
  std::array<bool, 3> periodic{};
  std::array<std::array<double, 2>, 3> bdist{};
  for (int a = 0; a < 3; ++a) {
    periodic[a] = sides[a][0] == PoissonSide::periodic;
    for (int side = 0; side < 2; ++side) {
      bdist[a][side] = sides[a][side] == PoissonSide::dirichlet_node ? 1.0 : 0.5;
    }
  }
  std::array<int, 3> n = cells;
  std::array<double, 3> h = spacing;
  const std::array<bool, 3> uneven = halves_unevenly(sides);
  for (;;) {
    const CellBox& box = boxes[me];
    // A side of the box is exchanged when a box (or its periodic image) lies beyond it; else it
    // is the domain's boundary condition. A one-cell period couples a cell to itself: no flux.
    std::array<std::array<PoissonSide, 2>, 3> local{};
    std::array<std::array<bool, 2>, 3> open{};
    for (int a = 0; a < 3; ++a) {
      for (int side = 0; side < 2; ++side) {
        const bool touches = side == 0 ? box.lo[a] == 0 : box.hi[a] == n[a];
        open[a][side] = n[a] > 1 && (periodic[a] || !touches);
        local[a][side] = touches && !periodic[a] ? sides[a][side] : PoissonSide::neumann;
      }
    }
    exchanges_.push_back(std::make_unique<MultigridExchange>(n, periodic, boxes, comm));
    Level& L = levels_.emplace_back(box.cells(), h, local);
    L.empty_rows = settings_.empty_rows;
    L.omega = relaxation_weight(settings_, periodic, n);
    L.exchange = exchanges_.back().get();
    L.exchanged = open;
    L.parity = (box.lo[0] + box.lo[1] + box.lo[2]) & 1;
    L.total = static_cast<double>(n[0]) * n[1] * n[2];
    L.bdist = bdist;
    // Coarsen as one grid would, along the axes every box divides; gather a level that would
    // need line relaxation (its lines would cross the ranks) or is small.
    bool gather = choose_line_axis(n, h) >= 0 || L.total <= settings.gather_cells;
    std::array<int, 3> ratio{1, 1, 1};
    if (!gather) {
      // Ends that the ratio divides: each coarse cell's children in one box. An odd axis with a
      // Neumann high side halves unevenly as on one grid: every box's ends even but the grid's
      // odd high end, whose box keeps the last coarse cell with its one child.
      ratio = coarsening(n, h, uneven);
      for (int a = 0; a < 3; ++a) {
        for (const CellBox& b : boxes) {
          const bool lo_ok = b.lo[a] % ratio[a] == 0;
          const bool hi_ok = b.hi[a] % ratio[a] == 0 || (uneven[a] && b.hi[a] == n[a]);
          if (!lo_ok || !hi_ok) {
            ratio[a] = 1;
          }
        }
      }
      gather = ratio == std::array<int, 3>{1, 1, 1};
    }
    if (gather) {
      break;
    }
    L.ratio = ratio;
    for (int a = 0; a < 3; ++a) {
      const int coarse = (n[a] + ratio[a] - 1) / ratio[a]; // an odd uneven axis: (n + 1) / 2
      h[a] *= ratio[a];
      for (int side = 0; side < 2; ++side) {
        bdist[a][side] = (bdist[a][side] + 0.5 * (ratio[a] - 1)) / ratio[a];
      }
      for (CellBox& b : boxes) {
        b.lo[a] /= ratio[a];
        b.hi[a] = b.hi[a] == n[a] ? coarse : b.hi[a] / ratio[a];
      }
      n[a] = coarse;
    }
  }
  gathered_cells_ = n;
  if (me == 0) {
    gathered_ = std::make_unique<MultigridPoisson>(n, h, sides, settings);
    gathered_->levels_.front().bdist = bdist;
  }
  const std::size_t size = levels_.front().size;
  for (HugePageVector<double>* v : {&x_, &b_, &r_, &r_old_, &z_, &p_, &q_}) {
    v->assign(size, 0.0);
  }
}

MultigridPoisson::~MultigridPoisson() = default;

int MultigridPoisson::gathered_levels() const {
  return gathered_ ? gathered_->levels() : 0;
}

void MultigridPoisson::all_sum(std::span<double> v) const {
  if (!exchanges_.empty()) {
    exchanges_.front()->sum(v);
  }
}

double MultigridPoisson::all_sum(double v) const {
  return exchanges_.empty() ? v : exchanges_.front()->sum(v);
}

// The gathered level's face coefficients, mass and Dirichlet faces into rank 0's one-grid
// hierarchy, laid out as its set_coefficients would (a periodic axis's face n is face 0), then
// its set-up.
void MultigridPoisson::gather_coefficients() {
  const Level& G = levels_.back();
  const MultigridExchange& ex = *G.exchange;
  const bool root = gathered_ != nullptr;
  Level* R = root ? &gathered_->levels_.front() : nullptr;
  mine_.assign(G.cells(), 0.0);
  all_.assign(root ? R->cells() : 0, 0.0);
  const auto gather_field = [&](const HugePageVector<double>& local,
                                HugePageVector<double>* global) {
    pack(G, local.data(), mine_.data());
    ex.gather(mine_, all_);
    if (root) {
      unpack(*R, all_.data(), global->data());
    }
  };
  for (int a = 0; a < 3; ++a) {
    gather_field(G.K[a], root ? &R->K[a] : nullptr);
    if (!root) {
      continue;
    }
    // Face n (the high ghost slot): face 0 on a periodic axis of two or more cells, else none.
    const bool wraps = R->periodic[a] && R->n[a] > 1;
    std::array<int, 3> hi = R->n;
    hi[a] = 1;
    for (int k = 0; k < hi[2]; ++k) {
      for (int j = 0; j < hi[1]; ++j) {
        for (int i = 0; i < hi[0]; ++i) {
          std::array<int, 3> c = {i, j, k};
          const std::size_t first = R->at(c[0], c[1], c[2]);
          c[a] = R->n[a];
          R->K[a][R->at(c[0], c[1], c[2])] = wraps ? R->K[a][first] : 0.0;
        }
      }
    }
  }
  if (!G.mass.empty()) {
    if (root) {
      R->mass.assign(R->size, 0.0);
    }
    gather_field(G.mass, root ? &R->mass : nullptr);
  } else if (root) {
    R->mass.clear();
  }
  for (int a = 0; a < 3; ++a) {
    const int p = a == 0 ? 1 : 0;
    const int q = a == 2 ? 1 : 2;
    for (int side = 0; side < 2; ++side) {
      if (sides_[a][side] != PoissonSide::dirichlet &&
          sides_[a][side] != PoissonSide::dirichlet_node) {
        continue;
      }
      // Each face's coefficient at its cell's position in a gathered cell vector.
      std::fill(mine_.begin(), mine_.end(), 0.0);
      if (G.dirichlet[a][side]) {
        for (int iq = 0; iq < G.n[q]; ++iq) {
          for (int ip = 0; ip < G.n[p]; ++ip) {
            std::array<int, 3> c{};
            c[a] = side == 0 ? 0 : G.n[a] - 1;
            c[p] = ip;
            c[q] = iq;
            mine_[packed_index(G.n, c)] = G.dface[a][side][G.plane_index(a, c)];
          }
        }
      }
      ex.gather(mine_, all_);
      if (!root) {
        continue;
      }
      for (int iq = 0; iq < R->n[q]; ++iq) {
        for (int ip = 0; ip < R->n[p]; ++ip) {
          std::array<int, 3> c{};
          c[a] = side == 0 ? 0 : R->n[a] - 1;
          c[p] = ip;
          c[q] = iq;
          R->dface[a][side][R->plane_index(a, c)] = all_[packed_index(R->n, c)];
        }
      }
    }
  }
  if (root) {
    gathered_->singular_ = singular_;
    gathered_->finish_coefficients();
  }
}

// The last level's right-hand side onto rank 0, one V-cycle of the one-grid hierarchy there
// (a fixed symmetric operator: the V-cycle over the ranks stays an SPD preconditioner), the
// correction back to every box, its ghosts exchanged.
void MultigridPoisson::gathered_solve(const double* b, double* x) {
  const Level& G = levels_.back();
  const MultigridExchange& ex = *G.exchange;
  const bool root = gathered_ != nullptr;
  mine_.resize(G.cells());
  all_.resize(root ? gathered_->levels_.front().cells() : 0);
  pack(G, b, mine_.data());
  ex.gather(mine_, all_);
  if (root) {
    MultigridPoisson& g = *gathered_;
    const Level& R = g.levels_.front();
    unpack(R, all_.data(), g.b_.data());
    g.vcycle(0, g.b_.data(), g.x_.data(), nullptr);
    pack(R, g.x_.data(), all_.data());
  }
  ex.scatter(all_, mine_);
  unpack(G, mine_.data(), x);
  fill_ghosts(G, x);
}

int MultigridPoisson::levels() const {
  return static_cast<int>(levels_.size());
}

std::array<int, 3> MultigridPoisson::level_cells(int level) const {
  return levels_.at(static_cast<std::size_t>(level)).n;
}

int MultigridPoisson::line_axis(int level) const {
  return levels_.at(static_cast<std::size_t>(level)).line;
}

void MultigridPoisson::set_coefficients(const std::array<GridField, 3>& coef,
                                        const GridField* mass) {
  Level& L = levels_.front();
  singular_ = !has_dirichlet_ && mass == nullptr;
  if (mass != nullptr) {
    if (mass->layout().cells() != L.n) {
      throw std::invalid_argument("multigrid: mass field of another grid");
    }
    L.mass.assign(L.size, 0.0);
    for_planes(L.n[2], L.cells(), [&](int k) {
      for (int j = 0; j < L.n[1]; ++j) {
        for (int i = 0; i < L.n[0]; ++i) {
          L.mass[L.at(i, j, k)] = (*mass)(i, j, k);
        }
      }
    });
  } else {
    L.mass.clear();
  }
  for (int a = 0; a < 3; ++a) {
    const GridField& in = coef[a];
    const GridLayout& layout = in.layout();
    if (layout.cells() != L.n) {
      throw std::invalid_argument("multigrid: coefficient field of another grid");
    }
    std::array<int, 3> hi = L.n;
    hi[a] = L.n[a] + 1;
    const bool self = L.periodic[a] && L.n[a] == 1;
    // Row by row: interior faces copied; a boundary face takes face 0's value on a periodic axis
    // (face n is face 0) and 0 otherwise (Neumann; Dirichlet faces go to dface below). On a
    // distributed level a face on an exchanged side of the box is copied like an interior one
    // (face n is then replaced by its owner's face 0 through the exchange below).
    const bool wraps = L.periodic[a] && !self;
    const std::array<bool, 2> open = L.exchanged[a];
    for_planes(hi[2], L.cells(), [&](int k) {
      for (int j = 0; j < hi[1]; ++j) {
        std::array<int, 3> face = {0, j, k};
        double* __restrict out = L.K[a].data() + L.at(0, j, k);
        if (a != 0 && (face[a] == 0 || face[a] == L.n[a]) && open[face[a] == 0 ? 0 : 1]) {
          std::copy_n(in.values().data() + layout.index(face), hi[0], out);
          continue;
        }
        if (a != 0 && (face[a] == 0 || face[a] == L.n[a])) {
          face[a] = 0;
          if (wraps) {
            std::copy_n(in.values().data() + layout.index(face), hi[0], out);
          } else {
            std::fill_n(out, hi[0], 0.0);
          }
          continue;
        }
        const double* row = in.values().data() + layout.index(face);
        std::copy_n(row, hi[0], out);
        if (a == 0) {
          out[0] = open[0] || wraps ? row[0] : 0.0;
          out[L.n[0]] = open[1] ? row[L.n[0]] : wraps ? row[0] : 0.0;
        }
      }
    });
    for (int side = 0; side < 2; ++side) {
      if (!L.dirichlet[a][side]) {
        continue;
      }
      const int p = a == 0 ? 1 : 0;
      const int q = a == 2 ? 1 : 2;
      for (int iq = 0; iq < L.n[q]; ++iq) {
        for (int ip = 0; ip < L.n[p]; ++ip) {
          std::array<int, 3> face{};
          face[a] = side == 0 ? 0 : L.n[a];
          face[p] = ip;
          face[q] = iq;
          L.dface[a][side][static_cast<std::size_t>(ip) +
                           static_cast<std::size_t>(L.n[p]) * static_cast<std::size_t>(iq)] =
              in[layout.index(face)];
        }
      }
    }
    if (L.exchange != nullptr) {
      // Face n of an exchanged side is the neighbour's face 0: one value per face, bitwise.
      L.exchange->fill(L.K[a]);
    }
  }
  finish_coefficients();
}

void MultigridPoisson::finish_coefficients() {
  build_diagonal(levels_.front());
  for (std::size_t l = 1; l < levels_.size(); ++l) {
    coarsen_coefficients(levels_[l - 1], levels_[l]);
  }
  if (exchanges_.empty()) {
    factor_coarsest();
  } else {
    gather_coefficients();
  }
}

// Dense Cholesky of the coarsest operator (a singular one with its first non-empty diagonal
// doubled: with a right-hand side of zero sum, the pinned system's solution solves the singular
// one).
void MultigridPoisson::factor_coarsest() {
  const Level& L = levels_.back();
  const std::size_t m = L.cells();
  if (m > static_cast<std::size_t>(settings_.max_direct_cells)) {
    cholesky_.clear();
    return;
  }
  cholesky_.assign(m * m, 0.0);
  dense_rhs_.assign(m, 0.0);
  const auto id = [&](int i, int j, int k) {
    return static_cast<std::size_t>(i) +
           static_cast<std::size_t>(L.n[0]) *
               (static_cast<std::size_t>(j) + static_cast<std::size_t>(L.n[1]) * k);
  };
  double* A = cholesky_.data();
  std::size_t pin = m; // the pinned row of a singular operator
  for (int k = 0; k < L.n[2]; ++k) {
    for (int j = 0; j < L.n[1]; ++j) {
      for (int i = 0; i < L.n[0]; ++i) {
        const std::array<int, 3> cell = {i, j, k};
        const std::size_t row = id(i, j, k);
        const std::size_t c = L.at(i, j, k);
        A[row * m + row] += L.diag[c] > 0.0 ? L.diag[c] : 1.0; // an empty row: identity
        if (L.diag[c] > 0.0 && pin == m) {
          pin = row;
        }
        for (int a = 0; a < 3; ++a) {
          for (int side = 0; side < 2; ++side) {
            const double coef = L.K[a][side == 0 ? c : c + static_cast<std::size_t>(L.s[a])];
            std::array<int, 3> nb = cell;
            nb[a] += side == 0 ? -1 : 1;
            if (nb[a] < 0 || nb[a] >= L.n[a]) {
              if (!L.periodic[a]) {
                continue;
              }
              nb[a] = (nb[a] + L.n[a]) % L.n[a];
            }
            A[row * m + id(nb[0], nb[1], nb[2])] -= coef;
          }
        }
      }
    }
  }
  if (singular_ && pin < m) {
    // The first cell with a non-empty row (cell 0 may be solid in a column).
    A[pin * m + pin] *= 2.0;
  }
  for (std::size_t col = 0; col < m; ++col) {
    double d = A[col * m + col];
    for (std::size_t t = 0; t < col; ++t) {
      d -= A[col * m + t] * A[col * m + t];
    }
    if (!(d > 0.0)) {
      throw std::runtime_error("multigrid: the coarsest operator is not positive definite");
    }
    d = std::sqrt(d);
    A[col * m + col] = d;
    for (std::size_t row = col + 1; row < m; ++row) {
      double v = A[row * m + col];
      for (std::size_t t = 0; t < col; ++t) {
        v -= A[row * m + t] * A[col * m + t];
      }
      A[row * m + col] = v / d;
    }
  }
}

void MultigridPoisson::coarsest_solve(const double* b, double* x) {
  Level& L = levels_.back();
  // Round-off leaves a singular system's right-hand side slightly off zero sum: remove its mean.
  const double mean = singular_ ? mean_interior(L, b) : 0.0;
  if (!cholesky_.empty()) {
    const std::size_t m = L.cells();
    double* y = dense_rhs_.data();
    std::size_t row = 0;
    for (int k = 0; k < L.n[2]; ++k) {
      for (int j = 0; j < L.n[1]; ++j) {
        for (int i = 0; i < L.n[0]; ++i) {
          const std::size_t c = L.at(i, j, k);
          y[row++] = L.diag[c] > 0.0 ? b[c] - mean : 0.0;
        }
      }
    }
    const double* A = cholesky_.data();
    for (std::size_t r = 0; r < m; ++r) {
      double v = y[r];
      for (std::size_t t = 0; t < r; ++t) {
        v -= A[r * m + t] * y[t];
      }
      y[r] = v / A[r * m + r];
    }
    for (std::size_t r = m; r-- > 0;) {
      double v = y[r];
      for (std::size_t t = r + 1; t < m; ++t) {
        v -= A[t * m + r] * y[t];
      }
      y[r] = v / A[r * m + r];
    }
    row = 0;
    for (int k = 0; k < L.n[2]; ++k) {
      for (int j = 0; j < L.n[1]; ++j) {
        for (int i = 0; i < L.n[0]; ++i) {
          x[L.at(i, j, k)] = y[row++];
        }
      }
    }
  } else {
    // A large coarsest level (no axis coarsens further): Jacobi-preconditioned CG to a fixed
    // relative residual; the outer flexible CG tolerates the inexact solve.
    cg_r_.assign(L.size, 0.0);
    cg_p_.assign(L.size, 0.0);
    cg_q_.assign(L.size, 0.0);
    cg_z_.assign(L.size, 0.0);
    std::fill(x, x + L.size, 0.0);
    std::copy(b, b + L.size, cg_r_.begin());
    shift_interior(L, cg_r_.data(), mean);
    const auto precond = [&] {
      return sum_cells(L, [&](std::size_t c, double& rz) {
        cg_z_[c] = cg_r_[c] * L.inv_diag[c];
        rz += cg_r_[c] * cg_z_[c];
      });
    };
    const double bb = sum_cells(L, [&](std::size_t c, double& s) { s += cg_r_[c] * cg_r_[c]; });
    double rz = precond();
    cg_p_ = cg_z_;
    for (int it = 0; it < 1000 && bb > 0.0; ++it) {
      fill_ghosts(L, cg_p_.data());
      const double pq = sum_cells(L, [&](std::size_t c, double& s) {
        cg_q_[c] = apply_at(L, cg_p_.data(), c);
        s += cg_p_[c] * cg_q_[c];
      });
      if (!(pq > 0.0)) {
        break;
      }
      const double alpha = rz / pq;
      const double rr = sum_cells(L, [&](std::size_t c, double& s) {
        x[c] += alpha * cg_p_[c];
        cg_r_[c] -= alpha * cg_q_[c];
        s += cg_r_[c] * cg_r_[c];
      });
      if (rr <= 1e-12 * bb) {
        break;
      }
      const double rz_new = precond();
      const double beta = rz_new / rz;
      rz = rz_new;
      for_cells(L, [&](std::size_t c) { cg_p_[c] = cg_z_[c] + beta * cg_p_[c]; });
    }
  }
  if (singular_) {
    shift_interior(L, x, mean_interior(L, x));
  }
  fill_ghosts(L, x);
}

// One V-cycle for A x = b from x = 0: symmetric (red-black before, black-red after, the
// restriction the scaled transpose of the prolongation), so it is an SPD preconditioner.
// shift (level 0 only): b -= *shift on the interior first, in the first smoothing pass.
void MultigridPoisson::vcycle(int level, double* b, double* x, const double* shift) {
  Level& L = levels_[static_cast<std::size_t>(level)];
  if (static_cast<std::size_t>(level) + 1 == levels_.size()) {
    if (shift != nullptr) {
      shift_interior(L, b, *shift);
    }
    if (exchanges_.empty()) {
      coarsest_solve(b, x);
    } else {
      gathered_solve(b, x);
    }
    return;
  }
  Level& C = levels_[static_cast<std::size_t>(level) + 1];
  const bool fused = settings_.fuse_colour_pairs && pair_fusable(L);
  if (fused) {
    // The last pre-smoothing pair restricts the residual as it goes.
    const int pairs = settings_.pre_sweeps;
    relax_pair(L, b, x, 0, true, shift, pairs == 1 ? &C : nullptr);
    for (int s = 1; s < pairs; ++s) {
      relax_pair(L, b, x, 0, false, nullptr, s + 1 == pairs ? &C : nullptr);
    }
  } else {
    if (shift != nullptr) {
      shift_interior(L, b, *shift);
    }
    if (L.line < 0) {
      relax_points_from_zero(L, b, x);
    } else {
      std::fill(x, x + L.size, 0.0);
      relax(L, b, x, 0);
    }
    relax(L, b, x, 1);
    for (int s = 1; s < settings_.pre_sweeps; ++s) {
      relax(L, b, x, 0);
      relax(L, b, x, 1);
    }
  }
  if (!fused) {
    restrict_residual(L, C, b, x, C.b.data());
  }
  vcycle(level + 1, C.b.data(), C.x.data(), nullptr);
  prolong_add(L, C, C.x.data(), x);
  for (int s = 0; s < settings_.post_sweeps; ++s) {
    if (fused) {
      relax_pair(L, b, x, 1, false, nullptr);
    } else {
      relax(L, b, x, 1);
      relax(L, b, x, 0);
    }
  }
}

double MultigridPoisson::precondition(double* r, double* z, double r_sum) {
  const Level& L = levels_.front();
  if (!singular_) {
    vcycle(0, r, z, nullptr);
    return 0.0;
  }
  // The V-cycle is definite on mean-zero vectors only: a residual whose constant part (round-off
  // of a tiny right-hand side) is not removed can give r.z <= 0 and break CG down. The constant
  // part is unreachable anyway (A's null space).
  const double r_mean =
      (std::isnan(r_sum) ? all_sum(sum_cells(L, [&](std::size_t c, double& s) { s += r[c]; }))
                         : r_sum) /
      L.active;
  vcycle(0, r, z, &r_mean); // the shift rides on the first smoothing pass where it can
  // z's mean: the caller removes it in its next pass over z (z's ghosts are not read before).
  // One grid of one level: the coarsest solve left it zero; gathered onto rank 0, the one-grid
  // V-cycle there does not.
  return levels_.size() > 1 || !exchanges_.empty() ? mean_interior(L, z) : 0.0;
}

// Flexible preconditioned CG (Notay, SIAM J. Sci. Comput. 22 (2000) 1444: beta from
// z_{k+1}.(r_{k+1} - r_k)), robust when the coarsest solve is an inexact CG; with a direct
// coarsest solve it equals standard PCG in exact arithmetic.
MultigridReport MultigridPoisson::solve(std::span<const double> b, std::span<double> x,
                                        double tolerance, int max_iterations) {
  Level& L = levels_.front();
  if (b.size() != L.cells() || x.size() != L.cells()) {
    throw std::invalid_argument("multigrid: vector of another grid");
  }
  const int planes = L.n[2];
  // Entry m = i + n0 (j + n1 k) of b and x is cell (i, j, k).
  const auto entry = [&](int j, int k) {
    return static_cast<std::size_t>(L.n[0]) *
           (static_cast<std::size_t>(j) +
            static_cast<std::size_t>(L.n[1]) * static_cast<std::size_t>(k));
  };
  for_planes(planes, L.cells(), [&](int k) {
    for (int j = 0; j < L.n[1]; ++j) {
      const std::size_t m = entry(j, k);
      const std::size_t c = L.at(0, j, k);
      for (int i = 0; i < L.n[0]; ++i) {
        b_[c + static_cast<std::size_t>(i)] = b[m + static_cast<std::size_t>(i)];
        x_[c + static_cast<std::size_t>(i)] = x[m + static_cast<std::size_t>(i)];
      }
    }
  });
  if (singular_) {
    shift_interior(L, b_.data(), mean_interior(L, b_.data()));
  }
  const auto dot = [&](const HugePageVector<double>& u, const HugePageVector<double>& v) {
    return sum_cells(L, [&](std::size_t c, double& s) { s += u[c] * v[c]; });
  };
  MultigridReport report;
  const double bb = all_sum(dot(b_, b_));
  // |b|^2 below the smallest normal double (a right-hand side of round-off from a field that is
  // already divergence-free): b is zero to working precision and so is x; relative residuals of
  // such a b are noise (a V-cycle of it underflows to zero).
  if (!(bb >= std::numeric_limits<double>::min())) {
    std::fill(x.begin(), x.end(), 0.0);
    report.converged = true;
    return report;
  }
  fill_ghosts(L, x_.data());
  std::array<double, 2> rr_sum = residual_and_sum(L, b_.data(), x_.data(), r_.data());
  all_sum(rr_sum);
  double rel = std::sqrt(rr_sum[0] / bb);
  int it = 0;
  while (rel > tolerance && it < max_iterations) {
    const double z_mean = precondition(r_.data(), z_.data(), rr_sum[1]);
    // z -= its mean (singular; a shift by 0 otherwise), fused with r.z.
    double rz = all_sum(sum_cells(L, [&](std::size_t c, double& s) {
      z_[c] -= z_mean;
      s += r_[c] * z_[c];
    }));
    bool restart = true; // p = z
    double beta = 0.0;
    while (it < max_iterations) {
      const double pq =
          all_sum(update_and_apply(L, z_.data(), beta, restart, p_.data(), q_.data()));
      restart = false;
      if (!(pq > 0.0) || !(rz > 0.0)) {
        break;
      }
      const double alpha = rz / pq;
      // |r|^2 and the sum of r (the preconditioner's mean removal) in the update's pass. The new
      // residual goes into r_old_'s storage and the two swap: r_ is then the new residual and
      // r_old_ the old one without a copy of r (CG reads only their interiors).
      auto rr = sum_planes_n<2>(planes, L.cells(), [&](int k) {
        std::array<double, 2> s{};
        for (int j = 0; j < L.n[1]; ++j) {
          std::size_t c = L.at(0, j, k);
          for (int i = 0; i < L.n[0]; ++i, ++c) {
            x_[c] += alpha * p_[c];
            const double r_new = r_[c] - alpha * q_[c];
            r_old_[c] = r_new;
            s[0] += r_new * r_new;
            s[1] += r_new;
          }
        }
        return s;
      });
      std::swap(r_, r_old_);
      all_sum(rr);
      ++it;
      if (std::sqrt(rr[0] / bb) <= tolerance) {
        break;
      }
      const double z_shift = precondition(r_.data(), z_.data(), rr[1]);
      auto sums = sum_planes_n<2>(planes, L.cells(), [&](int k) {
        std::array<double, 2> s{};
        for (int j = 0; j < L.n[1]; ++j) {
          std::size_t c = L.at(0, j, k);
          for (int i = 0; i < L.n[0]; ++i, ++c) {
            z_[c] -= z_shift;
            s[0] += r_[c] * z_[c];
            s[1] += r_old_[c] * z_[c];
          }
        }
        return s;
      });
      all_sum(sums);
      beta = (sums[0] - sums[1]) / rz;
      rz = sums[0];
    }
    // The recursive residual drifts from b - A x: judge (and restart from) the true one.
    fill_ghosts(L, x_.data());
    rr_sum = residual_and_sum(L, b_.data(), x_.data(), r_.data());
    all_sum(rr_sum);
    const double rel_new = std::sqrt(rr_sum[0] / bb);
    if (!(rel_new < rel) && rel_new > tolerance) {
      rel = rel_new;
      report.stalled = true;
      break; // no progress (breakdown): report what was reached
    }
    rel = rel_new;
  }
  clear_inactive(L, x_.data()); // junk a fused shift left on empty rows (their x is free)
  if (singular_) {
    shift_interior(L, x_.data(), mean_interior(L, x_.data()));
  }
  for_planes(planes, L.cells(), [&](int k) {
    for (int j = 0; j < L.n[1]; ++j) {
      const std::size_t m = entry(j, k);
      const std::size_t c = L.at(0, j, k);
      for (int i = 0; i < L.n[0]; ++i) {
        x[m + static_cast<std::size_t>(i)] = x_[c + static_cast<std::size_t>(i)];
      }
    }
  });
  report.iterations = it;
  report.relative_residual = rel;
  report.converged = rel <= tolerance;
  return report;
}

void MultigridPoisson::use_simd_level(SimdLevel level) {
  for (Level& L : levels_) {
    L.simd = level;
  }
  if (gathered_) {
    gathered_->use_simd_level(level);
  }
}

void MultigridPoisson::benchmark_vcycle() {
  const double z_mean = precondition(r_.data(), z_.data());
  shift_interior(levels_.front(), z_.data(), z_mean);
}

void MultigridPoisson::benchmark_sweep() {
  const Level& L = levels_.front();
  relax(L, b_.data(), x_.data(), 0);
  relax(L, b_.data(), x_.data(), 1);
}

double MultigridPoisson::benchmark_residual() {
  const Level& L = levels_.front();
  return residual(L, b_.data(), x_.data(), r_.data());
}

} // namespace cfddem::fluid
