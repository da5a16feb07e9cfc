// The implicit viscosity's factored step: instead of solving the trapezoidal Helmholtz system
// A u = rhs, A = D + c (N_x + N_y + N_z) (D the mass and drag diagonal, N_b = -d_b(eps d_b) along
// one axis), one step of its approximate factorization in delta form,
//   (D + c N_x) D^-1 (D + c N_y) D^-1 (D + c N_z) delta = rhs - A u_guess,  u = u_guess + delta,
// three sweeps of tridiagonal line solves (Beam & Warming, J. Comput. Phys. 22 (1976) 87; the
// Douglas-Gunn splitting, Numer. Math. 6 (1964) 428). The factors differ from A by
// c^2 (N_x D^-1 N_y + N_x D^-1 N_z + N_y D^-1 N_z) + c^3 N_x D^-1 N_y D^-1 N_z, applied to delta,
// which is itself O(dt): a local error O(dt^3), so the step keeps the trapezoidal rule's second
// order, and with D in every factor the drag stays coupled to the viscous terms (the error
// shrinks where the drag dominates D). For a constant-coefficient operator every Fourier mode's
// amplification lies in [-1, 1] whatever c (docs/gas_step.md, "The factored viscous step").
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <span>
#include <stdexcept>
#include <utility>
#include <vector>

#include <Eigen/Dense>
#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/simd_level.hpp"
#include "fluid/box_loops.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/implicit_viscosity.hpp"
#include "fluid/viscous_stencil.hpp"

namespace cfddem::fluid {

namespace {

// f(idx) over the box [lo, hi], x fastest, serially.
template <class F>
void for_each_index(const std::array<int, 3>& lo, const std::array<int, 3>& hi, F&& f) {
  for (int k = lo[2]; k <= hi[2]; ++k) {
    for (int j = lo[1]; j <= hi[1]; ++j) {
      for (int i = lo[0]; i <= hi[0]; ++i) {
        f(std::array<int, 3>{i, j, k});
      }
    }
  }
}

// One sweep's lines: the unknowns' face coefficients along the axis (k[p]: the low face of
// unknown p, k[p + s]: its high one), the diagonal D, the end closures and the scratch arrays.
struct Sweep {
  const double* k;
  const double* dg;
  double c;
  std::ptrdiff_t s; // stride along the lines
  int n;            // unknowns per line
  bool periodic;    // the lines close on themselves
  bool cyclic;      // periodic with at least three unknowns (shorter ones fold onto themselves)
  double end_lo, end_hi; // a non-periodic line's ghost = end * its end unknown
  double* cp;            // elimination: the super-diagonal over the pivot
  double* zp;            // cyclic: the Sherman-Morrison vector's elimination, then the vector
};

// Row m of a line: sub (coupling to m - 1), dia, sup (coupling to m + 1), with the ends closed:
// a non-periodic end's ghost folded into the diagonal; a periodic line of one or two unknowns
// folded onto itself; a cyclic line's corner couplings left in sub (m = 0) and sup (m = n - 1)
// for the caller.
struct Row {
  double sub, dia, sup;
};
[[gnu::always_inline]] inline Row row_at(const Sweep& w, std::ptrdiff_t p, int m) {
  const double klo = w.k[p];
  const double khi = w.k[p + w.s];
  Row r{-w.c * klo, w.dg[p] + w.c * (klo + khi), -w.c * khi};
  if (w.periodic) {
    if (w.n == 1) { // both ghosts are the unknown itself
      r.dia += r.sub + r.sup;
      r.sub = r.sup = 0.0;
    } else if (w.n == 2) { // the other unknown on both sides
      if (m == 0) {
        r.sup += r.sub, r.sub = 0.0;
      } else {
        r.sub += r.sup, r.sup = 0.0;
      }
    }
    return r;
  }
  if (m == 0) {
    r.dia += r.sub * w.end_lo;
    r.sub = 0.0;
  }
  if (m == w.n - 1) {
    r.dia += r.sup * w.end_hi;
    r.sup = 0.0;
  }
  return r;
}

// A cyclic line's Sherman-Morrison scalars, from its row 0 at `first`: gamma = -D_0 (row 0's
// diagonal) and beta, row 0's coupling to unknown n - 1.
struct Corner {
  double gamma, beta;
};
[[gnu::always_inline]] inline Corner corner_at(const Sweep& w, std::ptrdiff_t first) {
  return {-w.dg[first] - w.c * (w.k[first] + w.k[first + w.s]), -w.c * w.k[first]};
}

// Solves the lines through `lanes` side-by-side points of a plane normal to the sweep's axis
// (lane q of line point m at p0 + m s + q stride; stride 1: the lanes are a row, and the lane
// loops vectorize): out = (D + c N)^-1 rhs, rhs_at(p) the right-hand side at p, by the Thomas
// algorithm (out holds the eliminated right-hand side until the back substitution overwrites
// it), and on a cyclic line by Sherman-Morrison around it (Numerical Recipes, 2nd ed., section
// 2.7: gamma = -D_0, the corners alpha = row n-1's coupling to unknown 0 and beta = row 0's to
// unknown n-1). add_to (or null): the solution is also added into it, point by point, as it is
// made. Each point's operations are the same whatever the lanes: the same bits for any grouping.
template <bool Unit, class Rhs>
[[gnu::always_inline]] inline void solve_lines(const Sweep& w, std::ptrdiff_t p0, int lanes,
                                               std::ptrdiff_t stride, const Rhs& rhs_at,
                                               double* out, double* add_to) {
  const std::ptrdiff_t st = Unit ? 1 : stride;
  const std::ptrdiff_t s = w.s;
  const int n = w.n;
  // Forward elimination.
  for (int m = 0; m < n; ++m) {
    const std::ptrdiff_t row = p0 + m * s;
    for (int q = 0; q < lanes; ++q) {
      const std::ptrdiff_t p = row + q * st;
      Row r = row_at(w, p, m);
      double u = 0.0; // the Sherman-Morrison vector's entry
      if (w.cyclic) {
        if (m == 0) {
          u = -r.dia; // gamma
          r.dia -= u;
          r.sub = 0.0;
        } else if (m == n - 1) {
          const Corner corner = corner_at(w, p0 + q * st);
          u = r.sup; // alpha
          r.dia -= r.sup * corner.beta / corner.gamma;
          r.sup = 0.0;
        }
      }
      const double rhs = rhs_at(p);
      if (m == 0) {
        const double inv = 1.0 / r.dia;
        w.cp[p] = r.sup * inv;
        out[p] = rhs * inv;
        if (w.cyclic) {
          w.zp[p] = u * inv;
        }
      } else {
        const std::ptrdiff_t b = p - s;
        const double inv = 1.0 / (r.dia - r.sub * w.cp[b]);
        w.cp[p] = r.sup * inv;
        out[p] = (rhs - r.sub * out[b]) * inv;
        if (w.cyclic) {
          w.zp[p] = (u - r.sub * w.zp[b]) * inv;
        }
      }
    }
  }
  // Back substitution.
  const bool add_now = add_to != nullptr && !w.cyclic;
  for (int m = n - 1; m >= 0; --m) {
    const std::ptrdiff_t row = p0 + m * s;
    for (int q = 0; q < lanes; ++q) {
      const std::ptrdiff_t p = row + q * st;
      if (m != n - 1) {
        out[p] -= w.cp[p] * out[p + s];
        if (w.cyclic) {
          w.zp[p] -= w.cp[p] * w.zp[p + s];
        }
      }
      if (add_now) {
        add_to[p] += out[p];
      }
    }
  }
  if (!w.cyclic) {
    return;
  }
  // x = y - z (y_0 + beta y_{n-1} / gamma) / (1 + z_0 + beta z_{n-1} / gamma).
  const std::ptrdiff_t last = (n - 1) * s;
  for (int q = 0; q < lanes; ++q) {
    const std::ptrdiff_t first = p0 + q * st;
    const auto [gamma, beta] = corner_at(w, first);
    const double f = (out[first] + beta * out[first + last] / gamma) /
                     (1.0 + w.zp[first] + beta * w.zp[first + last] / gamma);
    for (int m = 0; m < n; ++m) {
      const std::ptrdiff_t p = first + m * s;
      out[p] -= f * w.zp[p];
      if (add_to != nullptr) {
        add_to[p] += out[p];
      }
    }
  }
}

// r = rhs - A u on the points p0 .. p0 + n - 1 of a row (u's ghosts filled by the caller), the
// Chebyshev rows' stencil (viscous_stencil.hpp): a pass of its own over a plane's rows ahead of
// the x lines that read it (made as the strided lines reached each point, it kept the x sweep
// scalar). Inlined into the copies' residual (below), whose restrict parameters let GCC
// vectorize the loop.
[[gnu::always_inline]] inline void residual_row(const double* k0, const double* k1,
                                                const double* k2, const double* dg, const double* b,
                                                const double* x, double* out, std::ptrdiff_t p0,
                                                std::ptrdiff_t n, std::ptrdiff_t sy,
                                                std::ptrdiff_t sz, double c) {
  for (std::ptrdiff_t p = p0; p < p0 + n; ++p) {
    double k[6];
    viscous_stencil::faces_at<-1>(k0, k1, k2, nullptr, 0.0, 0.0, 0.0, p, sy, sz, k);
    out[p] = b[p] - viscous_stencil::apply_at(k, dg[p], x, p, sy, sz, c);
  }
}

// solve_lines for four non-cyclic lines at p0 + q stride (q < 4), the same operations, with each
// line's last pivot ratio and eliminated value carried in registers from point to point rather
// than reloaded from the arrays just written (the x sweep's lines are strided: its recurrences'
// latency, not their arithmetic, sets their speed).
template <class Rhs>
[[gnu::always_inline]] inline void solve_four_lines(const Sweep& w, std::ptrdiff_t p0,
                                                    std::ptrdiff_t stride, const Rhs& rhs_at,
                                                    double* out) {
  constexpr int kFour = 4;
  const std::ptrdiff_t s = w.s;
  const int n = w.n;
  double cp_last[kFour];
  double out_last[kFour];
  for (int m = 0; m < n; ++m) {
    const std::ptrdiff_t row = p0 + m * s;
    for (int q = 0; q < kFour; ++q) {
      const std::ptrdiff_t p = row + q * stride;
      const Row r = row_at(w, p, m);
      const double rhs = rhs_at(p);
      const double inv = m == 0 ? 1.0 / r.dia : 1.0 / (r.dia - r.sub * cp_last[q]);
      cp_last[q] = r.sup * inv;
      out_last[q] = m == 0 ? rhs * inv : (rhs - r.sub * out_last[q]) * inv;
      w.cp[p] = cp_last[q];
      out[p] = out_last[q];
    }
  }
  for (int m = n - 2; m >= 0; --m) {
    const std::ptrdiff_t row = p0 + m * s;
    for (int q = 0; q < kFour; ++q) {
      const std::ptrdiff_t p = row + q * stride;
      out_last[q] = out[p] - w.cp[p] * out_last[q];
      out[p] = out_last[q];
    }
  }
}

// solve_lines' copies, one type per instruction set (core/simd_level.hpp; the same operations in
// the same order at every level): the lane loops of the y and z sweeps take 32-byte vectors at
// x86-64-v3, whose divisions are the recurrences' costliest step.
#define CFDDEM_FACTORED_LINES(NAME, ...)                                                           \
  struct NAME {                                                                                    \
    template <bool Unit, class Rhs>                                                                \
    [[gnu::noinline __VA_ARGS__]] static void lines(const Sweep& w, std::ptrdiff_t p0, int lanes,  \
                                                    std::ptrdiff_t stride, const Rhs& rhs_at,      \
                                                    double* out, double* add_to) {                 \
      if (!Unit && lanes == 4 && !w.cyclic && add_to == nullptr) {                                 \
        solve_four_lines(w, p0, stride, rhs_at, out);                                              \
        return;                                                                                    \
      }                                                                                            \
      solve_lines<Unit>(w, p0, lanes, stride, rhs_at, out, add_to);                                \
    }                                                                                              \
    [[gnu::noinline __VA_ARGS__]] static void                                                      \
    residual(const double* __restrict k0, const double* __restrict k1,                             \
             const double* __restrict k2, const double* __restrict dg, const double* __restrict b, \
             const double* __restrict x, double* __restrict out, std::ptrdiff_t p0,                \
             std::ptrdiff_t n, std::ptrdiff_t sy, std::ptrdiff_t sz, double c) {                   \
      residual_row(k0, k1, k2, dg, b, x, out, p0, n, sy, sz, c);                                   \
    }                                                                                              \
  };
CFDDEM_SIMD_COPY_TYPES(CFDDEM_FACTORED_LINES, FactoredLines)
#undef CFDDEM_FACTORED_LINES

// One sweep over a distributed grid's lines along axis b, which the boxes cut into segments
// (the partition method: Wang, ACM Trans. Math. Softw. 7 (1981) 170). Each box solves its
// segment with the couplings to its neighbours' end unknowns L (below) and R (above) taken out,
// x = y - v L - w R, with T y = rhs, T v = sub_0 e_0, T w = sup_{n-1} e_{n-1}; each box sends
// the end values of its segments (y, v, w at both ends) to the boxes that share the lines
// (FactoredSweepLinks: point to point, those ranks only), and every box that holds a
// piece of a line solves the same small system for the line's end unknowns (two per segment, in
// the segments' order along b, closed into a ring on a periodic axis), then its own unknowns
// from them. The one-grid sweep's direct solve up to round-off.
struct DistributedSweep {
  const MacGrid& grid;
  const GridLayout& layout;
  int b;
  std::array<int, 3> lo, hi; // this box's unknowns (local indices)
  const double* k;
  const double* dg;
  double c;
  double end_lo, end_hi; // closures of the domain's ends (unused on exchanged sides)
  double* cp;
  double* v;
  double* w;
  const FactoredSweepLinks& links;
  std::vector<double>& ends;

  // out = the sweep's solution for the right-hand side rhs_at(p).
  template <class Rhs> void operator()(const Rhs& rhs_at, double* out) const {
    const int a1 = b == 0 ? 1 : 0;
    const int a2 = b == 2 ? 1 : 2;
    const std::ptrdiff_t s = layout.stride(b);
    const int n = hi[b] - lo[b] + 1;
    const int n1 = hi[a1] - lo[a1] + 1;
    const int n2 = hi[a2] - lo[a2] + 1;
    const bool low_open = grid.exchanged(b, 0);
    const bool high_open = grid.exchanged(b, 1);
    // A segment's rows as solve_lines takes them, its open ends' couplings left out (an
    // exchanged side's closure is 0: factored_ends).
    const Sweep rows{k, dg, c, s, n, false, false, end_lo, end_hi, cp, nullptr};
    ends.resize(links.size);
    double* mine = ends.data(); // this box's lines' values come first
    // The segments: y into out, v and w beside it, their end values into `ends`. Lanes of
    // lines advance together as in solve_lines: a row of them along x for the y and z sweeps
    // (the lane loops vectorize), four rows for the x sweep.
    const auto solve_segments = [&](std::ptrdiff_t p0, int lanes, std::ptrdiff_t st) {
      for (int m = 0; m < n; ++m) {
        const std::ptrdiff_t row = p0 + m * s;
        const bool first = m == 0, last = m == n - 1;
        for (int q = 0; q < lanes; ++q) {
          const std::ptrdiff_t p = row + q * st;
          const Row r = row_at(rows, p, m);
          const double ev = first && low_open ? -c * k[p] : 0.0;
          const double ew = last && high_open ? -c * k[p + s] : 0.0;
          const double rhs = rhs_at(p);
          if (first) {
            const double inv = 1.0 / r.dia;
            cp[p] = r.sup * inv, out[p] = rhs * inv, v[p] = ev * inv, w[p] = ew * inv;
          } else {
            const std::ptrdiff_t pb = p - s;
            const double inv = 1.0 / (r.dia - r.sub * cp[pb]);
            cp[p] = r.sup * inv;
            out[p] = (rhs - r.sub * out[pb]) * inv;
            v[p] = (ev - r.sub * v[pb]) * inv;
            w[p] = (ew - r.sub * w[pb]) * inv;
          }
        }
      }
      for (int m = n - 2; m >= 0; --m) {
        const std::ptrdiff_t row = p0 + m * s;
        for (int q = 0; q < lanes; ++q) {
          const std::ptrdiff_t p = row + q * st;
          out[p] -= cp[p] * out[p + s];
          v[p] -= cp[p] * v[p + s];
          w[p] -= cp[p] * w[p + s];
        }
      }
    };
    const auto pack = [&](int t1, int t2) {
      std::array<int, 3> idx{};
      idx[a1] = lo[a1] + t1, idx[a2] = lo[a2] + t2, idx[b] = lo[b];
      const auto p0 = static_cast<std::ptrdiff_t>(layout.index(idx));
      const std::ptrdiff_t last = p0 + (n - 1) * s;
      double* e = mine + 6 * (static_cast<std::size_t>(t1) +
                              static_cast<std::size_t>(n1) * static_cast<std::size_t>(t2));
      e[0] = out[p0], e[1] = v[p0], e[2] = w[p0];
      e[3] = out[last], e[4] = v[last], e[5] = w[last];
    };
    tbb::parallel_for(0, n2, [&](int t2) {
      if (b == 0) { // lines along x: rows j (a1 = y) side by side
        for (int t1 = 0; t1 < n1; t1 += 4) {
          const auto p0 = static_cast<std::ptrdiff_t>(layout.index(lo[0], lo[1] + t1, lo[2] + t2));
          solve_segments(p0, std::min(4, n1 - t1), layout.stride(1));
        }
      } else { // a1 = x: the row of lines along x side by side
        std::array<int, 3> idx{};
        idx[a1] = lo[a1], idx[a2] = lo[a2] + t2, idx[b] = lo[b];
        solve_segments(static_cast<std::ptrdiff_t>(layout.index(idx)), n1, 1);
      }
      for (int t1 = 0; t1 < n1; ++t1) {
        pack(t1, t2);
      }
    });
    // Every box cut along b needs the others' ends; a box alone along b (not periodic) has none.
    if (!links.cut) {
      return;
    }
    links.exchange.forward(std::span<double>(ends));
    const bool periodic = grid.periodic(b);
    tbb::parallel_for(tbb::blocked_range<int>(0, n2), [&](const tbb::blocked_range<int>& planes) {
      // A line's interface system (two unknowns per segment): LU with partial pivoting (Eigen),
      // its arrays made once per task.
      Eigen::MatrixXd a;
      Eigen::VectorXd z, sol;
      Eigen::PartialPivLU<Eigen::MatrixXd> lu;
      for (int t2 = planes.begin(); t2 != planes.end(); ++t2) {
        for (int t1 = 0; t1 < n1; ++t1) {
          const std::size_t line = static_cast<std::size_t>(t1) +
                                   static_cast<std::size_t>(n1) * static_cast<std::size_t>(t2);
          const std::size_t first = links.line_first[line];
          const int S = static_cast<int>(links.line_first[line + 1] - first);
          const int N = 2 * S;
          a.setZero(N, N);
          z.setZero(N);
          for (int q = 0; q < S; ++q) {
            const double* e = ends.data() + links.segment_at[first + static_cast<std::size_t>(q)];
            // first_q + v0 L_q + w0 R_q = y0; last_q + vN L_q + wN R_q = yN.
            const int left = q > 0 ? 2 * (q - 1) + 1 : (periodic ? 2 * (S - 1) + 1 : -1);
            const int right = q < S - 1 ? 2 * (q + 1) : (periodic ? 0 : -1);
            for (int row = 0; row < 2; ++row) {
              const int i = 2 * q + row;
              a(i, i) += 1.0;
              if (left >= 0) {
                a(i, left) += e[3 * row + 1];
              }
              if (right >= 0) {
                a(i, right) += e[3 * row + 2];
              }
              z(i) = e[3 * row];
            }
          }
          lu.compute(a);
          sol = lu.solve(z);
          const int q = links.line_mine[line];
          const double L = q > 0 ? sol(2 * (q - 1) + 1) : (periodic ? sol(2 * (S - 1) + 1) : 0.0);
          const double R = q < S - 1 ? sol(2 * (q + 1)) : (periodic ? sol(0) : 0.0);
          std::array<int, 3> idx{};
          idx[a1] = lo[a1] + t1, idx[a2] = lo[a2] + t2, idx[b] = lo[b];
          const auto p0 = static_cast<std::ptrdiff_t>(layout.index(idx));
          for (int m = 0; m < n; ++m) {
            const std::ptrdiff_t p = p0 + m * s;
            out[p] = (out[p] - v[p] * L) - w[p] * R;
          }
        }
      }
    });
  }
};
} // namespace

const FactoredSweepLinks& ImplicitViscosity::sweep_links(int comp, int axis) {
  FactoredSweepLinks& links =
      sweep_links_[static_cast<std::size_t>(comp)][static_cast<std::size_t>(axis)];
  if (links.made) { // the halo's boxes are this object's for its life (a rebox makes a new one)
    return links;
  }
  links.made = true;
  const std::vector<CellBox>& boxes = halo_->boxes();
  const int a1 = axis == 0 ? 1 : 0;
  const int a2 = axis == 2 ? 1 : 2;
  const int me = halo_->comm().rank();
  std::vector<UnknownFaces> ranges;
  for (const CellBox& box : boxes) {
    ranges.push_back(unknown_faces(grid_, box, comp));
  }
  const UnknownFaces& own = ranges[static_cast<std::size_t>(me)];
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  for (int a = 0; a < 3; ++a) {
    if (!own.empty() && own.hi[a] - own.lo[a] != hi[a] - lo[a]) {
      throw std::logic_error("ImplicitViscosity::sweep_links: the box's unknowns do not match");
    }
  }
  links.cut = grid_.periodic(axis);
  for (const CellBox& box : boxes) {
    links.cut = links.cut || box.lo[axis] > 0 || box.hi[axis] < grid_.global_cells()[axis];
  }
  const int n1 = own.empty() ? 0 : own.hi[a1] - own.lo[a1] + 1;
  const int n2 = own.empty() ? 0 : own.hi[a2] - own.lo[a2] + 1;
  const auto lines = static_cast<std::size_t>(n1) * static_cast<std::size_t>(n2);
  const auto line_of = [&](int g1, int g2) {
    return static_cast<std::size_t>(g1 - own.lo[a1]) +
           static_cast<std::size_t>(n1) * static_cast<std::size_t>(g2 - own.lo[a2]);
  };
  // Each line's segments: this box's, then every other box's that crosses the line.
  std::vector<std::vector<std::pair<int, std::size_t>>> segments(lines);
  for (std::size_t l = 0; l < lines; ++l) {
    segments[l].emplace_back(own.lo[axis], 6 * l);
  }
  links.size = 6 * lines;
  std::vector<HaloExchange::Link> peers;
  for (int r = 0; r < static_cast<int>(boxes.size()) && links.cut; ++r) {
    const UnknownFaces& u = ranges[static_cast<std::size_t>(r)];
    if (r == me || u.empty() || own.empty()) {
      continue;
    }
    const int lo1 = std::max(own.lo[a1], u.lo[a1]), hi1 = std::min(own.hi[a1], u.hi[a1]);
    const int lo2 = std::max(own.lo[a2], u.lo[a2]), hi2 = std::min(own.hi[a2], u.hi[a2]);
    if (lo1 > hi1 || lo2 > hi2) {
      continue; // no line in common
    }
    // The shared lines in one order on both sides (a2 slowest, then a1): this box's six values
    // of each go to r, r's six arrive after everything before them.
    HaloExchange::Link link;
    link.rank = r;
    for (int g2 = lo2; g2 <= hi2; ++g2) {
      for (int g1 = lo1; g1 <= hi1; ++g1) {
        const std::size_t l = line_of(g1, g2);
        segments[l].emplace_back(u.lo[axis], links.size);
        for (std::size_t e = 0; e < 6; ++e) {
          link.send.push_back(6 * l + e);
          link.recv.push_back(links.size + e);
        }
        links.size += 6;
      }
    }
    peers.push_back(std::move(link));
  }
  links.exchange = HaloExchange(halo_->comm(), std::move(peers));
  links.line_first.assign(lines + 1, 0);
  links.line_mine.assign(lines, 0);
  for (std::size_t l = 0; l < lines; ++l) {
    std::vector<std::pair<int, std::size_t>>& line = segments[l];
    std::sort(line.begin(), line.end()); // in order along the axis (starts differ)
    links.line_first[l + 1] = links.line_first[l] + line.size();
    for (std::size_t q = 0; q < line.size(); ++q) {
      links.segment_at.push_back(line[q].second);
      if (line[q].first == own.lo[axis]) {
        links.line_mine[l] = static_cast<int>(q);
      }
    }
  }
  return links;
}

void ImplicitViscosity::make_factored_scratch() {
  const GridLayout& layout = grid_.layout();
  for (GridField* f : {&factored_cp_, &factored_zp_}) {
    if (f->values().size() != layout.size()) {
      *f = GridField(layout);
    }
  }
  if (halo_ != nullptr && factored_wp_.values().size() != layout.size()) {
    factored_wp_ = GridField(layout);
  }
}

void ImplicitViscosity::prepare_factored() {
  for (int comp = 0; comp < 3; ++comp) {
    (void)factored_ends(comp); // makes the scratch first
  }
}

const ImplicitViscosity::FactoredEnds& ImplicitViscosity::factored_ends(int comp) {
  const auto c = static_cast<std::size_t>(comp);
  FactoredEnds& ends = factored_ends_[c];
  if (ends.known) {
    return ends;
  }
  // What the homogeneous ghost fill puts beyond each end of comp's lines, found by filling a
  // field that is 1 on one end plane of unknowns: ghost = end * the end unknown, the same at
  // every point of the plane and independent of the unknowns further in (as the boundary
  // conditions of fluid/ghost_fill.hpp are). A periodic axis's lines close on themselves.
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  // One probe field for all of them, the line solves' scratch (zero until their first sweep):
  // between probes only its points outside the unknowns (what the fill wrote) and the probed
  // plane are set back to 0, so it is zero again at the end, and the loops visit that plane only
  // (a whole new field per probe, allocated and walked, took 28 ms of the 1e5 bed's first step).
  make_factored_scratch();
  GridField& f = factored_cp_;
  const auto plane_box = [&](int b, int at) {
    std::array<int, 3> plo = lo, phi = hi;
    plo[b] = phi[b] = at;
    return std::array<std::array<int, 3>, 2>{plo, phi};
  };
  const auto clear = [&](int b, int at) {
    const auto [plo, phi] = plane_box(b, at);
    for_each_index(plo, phi, [&](std::array<int, 3> idx) { f(idx[0], idx[1], idx[2]) = 0.0; });
    zero_outside(f, lo, hi);
  };
  for (int b = 0; b < 3; ++b) {
    for (int side = 0; side < 2; ++side) {
      double& end = ends.end[static_cast<std::size_t>(b)][static_cast<std::size_t>(side)];
      if (grid_.bc(b, side).kind == BoundaryKind::periodic || grid_.exchanged(b, side)) {
        end = 0.0; // the line goes on (periodic or into the next box): no closure
        continue;
      }
      const int plane = side == 0 ? lo[b] : hi[b];
      const int ghost = side == 0 ? lo[b] - 1 : hi[b] + 1;
      const int inner = side == 0 ? lo[b] + 1 : hi[b] - 1;
      std::array<double, 2> seen{};
      for (int probe = 0; probe < (lo[b] < hi[b] ? 2 : 1); ++probe) {
        const int set = probe == 0 ? plane : inner;
        const auto [slo, shi] = plane_box(b, set);
        for_each_index(slo, shi, [&](std::array<int, 3> idx) { f(idx[0], idx[1], idx[2]) = 1.0; });
        fill_velocity_ghosts(homogeneous_, nullptr, comp, f);
        bool first = true;
        bool uniform = true;
        const auto [elo, ehi] = plane_box(b, plane);
        for_each_index(elo, ehi, [&](std::array<int, 3> idx) {
          idx[b] = ghost;
          const double g = f(idx[0], idx[1], idx[2]);
          if (first) {
            seen[static_cast<std::size_t>(probe)] = g;
            first = false;
          } else if (g != seen[static_cast<std::size_t>(probe)]) {
            uniform = false;
          }
        });
        if (!uniform) {
          throw std::logic_error(fmt::format(
              "factored viscous step: the ghosts beyond the {} end of component {}'s lines "
              "along axis {} are not one multiple of the end unknown",
              side == 0 ? "low" : "high", comp, b));
        }
        clear(b, set);
      }
      if (seen[1] != 0.0) {
        throw std::logic_error(fmt::format(
            "factored viscous step: the ghosts beyond the {} end of component {}'s lines along "
            "axis {} depend on more than the end unknown",
            side == 0 ? "low" : "high", comp, b));
      }
      end = seen[0];
    }
  }
  ends.known = true;
  return ends;
}

ViscousSolveReport ImplicitViscosity::step_factored(int comp, double c, const GridField& eps,
                                                    const GridField& diag, const GridField& rhs,
                                                    GridField& u, bool rhs_is_residual) {
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  if (hi[0] < lo[0] || hi[1] < lo[1] || hi[2] < lo[2]) {
    return {};
  }
  face_coefficients(comp, eps);
  const FactoredEnds& ends = factored_ends(comp); // made the scratch fields with them
  const GridLayout& layout = grid_.layout();
  const auto cs = static_cast<std::size_t>(comp);
  const double* k0 = cv_k_[cs][0].values().data();
  const double* k1 = cv_k_[cs][1].values().data();
  const double* k2 = cv_k_[cs][2].values().data();
  const double* dg = diag.values().data();
  const double* b = rhs.values().data();
  double* x = u.values().data();
  const std::ptrdiff_t sy = layout.stride(1);
  const std::ptrdiff_t sz = layout.stride(2);
  const std::ptrdiff_t len = hi[0] - lo[0] + 1;
  double* y = dir_.values().data();
  double* z = dir_next_.values().data();
  // The x sweep's right-hand side, the residual r = rhs - A u_guess: rhs itself where it is the
  // residual, else what a row pass (residual_row) leaves in y, which the sweep solves in place;
  // the y and z sweeps', D y and D z.
  const double* r = rhs_is_residual ? b : y;
  const auto r_at = [=](std::ptrdiff_t p) { return r[p]; };
  const auto scaled_y = [=](std::ptrdiff_t p) { return dg[p] * y[p]; };
  const auto scaled_z = [=](std::ptrdiff_t p) { return dg[p] * z[p]; };
  if (halo_ != nullptr) {
    // The residual over the box first (u's ghosts filled by the caller).
    if (!rhs_is_residual) {
      with_copy_at<FactoredLinesX86_64, FactoredLinesV3, FactoredLinesV4>(level_, [&](auto copy) {
        for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int) {
          decltype(copy)::residual(k0, k1, k2, dg, b, x, y, row, len, sy, sz, c);
        });
      });
    }
    for (int axis = 0; axis < 3; ++axis) {
      const auto a = static_cast<std::size_t>(axis);
      const DistributedSweep sweep{grid_,
                                   layout,
                                   axis,
                                   lo,
                                   hi,
                                   cv_k_[cs][a].values().data(),
                                   dg,
                                   c,
                                   ends.end[a][0],
                                   ends.end[a][1],
                                   factored_cp_.values().data(),
                                   factored_zp_.values().data(),
                                   factored_wp_.values().data(),
                                   sweep_links(comp, axis),
                                   sweep_ends_};
      // x: the residual in y -> y; y: D y -> z; z: D z -> delta (in y).
      if (axis == 0) {
        sweep(r_at, y);
      } else if (axis == 1) {
        sweep(scaled_y, z);
      } else {
        sweep(scaled_z, y);
      }
    }
    for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int) {
      for (std::ptrdiff_t p = row; p < row + len; ++p) {
        x[p] += y[p];
      }
    });
  } else {
    const auto sweep_for = [&](int axis, const double* k) {
      const auto a = static_cast<std::size_t>(axis);
      const int n = hi[axis] - lo[axis] + 1;
      const bool periodic = grid_.bc(axis, 0).kind == BoundaryKind::periodic;
      return Sweep{k,
                   dg,
                   c,
                   layout.stride(axis),
                   n,
                   periodic,
                   periodic && n >= 3,
                   ends.end[a][0],
                   ends.end[a][1],
                   factored_cp_.values().data(),
                   factored_zp_.values().data()};
    };
    // Per z-plane (a task each), both sweeps whose lines lie in it, while the plane's arrays
    // are in the caches: the residual r into y row by row (residual_row; x is read here and
    // only added to by the last sweep), (D + c N_x) y = r in place (four rows side by side:
    // independent recurrences the core overlaps, solve_four_lines), then (D + c N_y) z = D y
    // (a row of lines side by side).
    with_copy_at<FactoredLinesX86_64, FactoredLinesV3, FactoredLinesV4>(level_, [&](auto copy) {
      const Sweep wx = sweep_for(0, k0);
      const Sweep wy = sweep_for(1, k1);
      tbb::parallel_for(lo[2], hi[2] + 1, [&](int k) {
        if (!rhs_is_residual) {
          for (int j = lo[1]; j <= hi[1]; ++j) {
            decltype(copy)::residual(k0, k1, k2, dg, b, x, y,
                                     static_cast<std::ptrdiff_t>(layout.index(lo[0], j, k)), len,
                                     sy, sz, c);
          }
        }
        for (int j = lo[1]; j <= hi[1]; j += 4) {
          const auto p0 = static_cast<std::ptrdiff_t>(layout.index(lo[0], j, k));
          decltype(copy)::template lines<false>(wx, p0, std::min(4, hi[1] - j + 1), sy, r_at, y,
                                                nullptr);
        }
        const auto p0 = static_cast<std::ptrdiff_t>(layout.index(lo[0], lo[1], k));
        decltype(copy)::template lines<true>(wy, p0, static_cast<int>(len), 1, scaled_y, z,
                                             nullptr);
      });
      // (D + c N_z) delta = D z, delta added into x: lines along z, a row of them side by side; a
      // y-row per task.
      const Sweep wz = sweep_for(2, k2);
      tbb::parallel_for(lo[1], hi[1] + 1, [&](int j) {
        const auto p0 = static_cast<std::ptrdiff_t>(layout.index(lo[0], j, lo[2]));
        decltype(copy)::template lines<true>(wz, p0, static_cast<int>(len), 1, scaled_z, y, x);
      });
    });
  }
  ViscousSolveReport report;
  report.iterations = 1;
  report.factored = true;
  return report;
}

} // namespace cfddem::fluid
