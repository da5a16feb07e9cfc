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
#include <cstddef>
#include <stdexcept>
#include <vector>

#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include "fluid/box_loops.hpp"
#include "fluid/ghost_fill.hpp"
#include "fluid/implicit_viscosity.hpp"

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
  double* dp;            // elimination: the right-hand side over the pivot
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

// Solves the lines through `lanes` side-by-side points of a plane normal to the sweep's axis
// (lane q of line point m at p0 + m s + q stride; stride 1: the lanes are a row, and the lane
// loops vectorize): out = (D + c N) ^-1 (scale ? D in : in), by the Thomas algorithm, and on a
// cyclic line by Sherman-Morrison around it (Numerical Recipes, 2nd ed., section 2.7: gamma =
// -D_0, the corners alpha = row n-1's coupling to unknown 0 and beta = row 0's to unknown n-1).
// Each point's operations are the same whatever the lanes: the same bits for any grouping.
template <bool Unit>
void solve_lines(const Sweep& w, std::ptrdiff_t p0, int lanes, std::ptrdiff_t stride,
                 const double* in, bool scale, double* out) {
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
          const double gamma =
              -w.dg[p0 + q * st] - w.c * (w.k[p0 + q * st] + w.k[p0 + q * st + s]); // -D_0
          const double beta = -w.c * w.k[p0 + q * st]; // row 0's corner
          u = r.sup;                                   // alpha
          r.dia -= r.sup * beta / gamma;
          r.sup = 0.0;
        }
      }
      const double rhs = scale ? w.dg[p] * in[p] : in[p];
      if (m == 0) {
        const double inv = 1.0 / r.dia;
        w.cp[p] = r.sup * inv;
        w.dp[p] = rhs * inv;
        if (w.cyclic) {
          w.zp[p] = u * inv;
        }
      } else {
        const std::ptrdiff_t b = p - s;
        const double inv = 1.0 / (r.dia - r.sub * w.cp[b]);
        w.cp[p] = r.sup * inv;
        w.dp[p] = (rhs - r.sub * w.dp[b]) * inv;
        if (w.cyclic) {
          w.zp[p] = (u - r.sub * w.zp[b]) * inv;
        }
      }
    }
  }
  // Back substitution.
  for (int m = n - 1; m >= 0; --m) {
    const std::ptrdiff_t row = p0 + m * s;
    for (int q = 0; q < lanes; ++q) {
      const std::ptrdiff_t p = row + q * st;
      if (m == n - 1) {
        out[p] = w.dp[p];
      } else {
        out[p] = w.dp[p] - w.cp[p] * out[p + s];
        if (w.cyclic) {
          w.zp[p] -= w.cp[p] * w.zp[p + s];
        }
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
    const double gamma = -w.dg[first] - w.c * (w.k[first] + w.k[first + s]);
    const double beta = -w.c * w.k[first];
    const double f = (out[first] + beta * out[first + last] / gamma) /
                     (1.0 + w.zp[first] + beta * w.zp[first + last] / gamma);
    for (int m = 0; m < n; ++m) {
      const std::ptrdiff_t p = first + m * s;
      out[p] -= f * w.zp[p];
    }
  }
}

} // namespace

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
  const GridLayout& layout = grid_.layout();
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  for (int b = 0; b < 3; ++b) {
    for (int side = 0; side < 2; ++side) {
      double& end = ends.end[static_cast<std::size_t>(b)][static_cast<std::size_t>(side)];
      if (grid_.bc(b, side).kind == BoundaryKind::periodic) {
        end = 0.0;
        continue;
      }
      const int plane = side == 0 ? lo[b] : hi[b];
      const int ghost = side == 0 ? lo[b] - 1 : hi[b] + 1;
      const int inner = side == 0 ? lo[b] + 1 : hi[b] - 1;
      std::array<double, 2> seen{};
      for (int probe = 0; probe < (lo[b] < hi[b] ? 2 : 1); ++probe) {
        GridField f(layout);
        const int set = probe == 0 ? plane : inner;
        for_each_index(lo, hi, [&](std::array<int, 3> idx) {
          if (idx[b] == set) {
            f(idx[0], idx[1], idx[2]) = 1.0;
          }
        });
        fill_velocity_ghosts(homogeneous_, nullptr, comp, f);
        bool first = true;
        bool uniform = true;
        for_each_index(lo, hi, [&](std::array<int, 3> idx) {
          if (idx[b] != plane) {
            return;
          }
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
                                                    GridField& u) {
  if (halo_ != nullptr) {
    throw std::logic_error("factored viscous step: the lines of a distributed grid cross boxes "
                           "(one grid only)");
  }
  const std::array<int, 3> lo = unknown_lo(comp);
  const std::array<int, 3> hi = unknown_hi(comp);
  if (hi[0] < lo[0] || hi[1] < lo[1] || hi[2] < lo[2]) {
    return {};
  }
  face_coefficients(comp, eps);
  const FactoredEnds& ends = factored_ends(comp);
  const GridLayout& layout = grid_.layout();
  const auto cs = static_cast<std::size_t>(comp);
  for (GridField* f : {&factored_cp_, &factored_dp_, &factored_zp_}) {
    if (f->values().size() != layout.size()) {
      *f = GridField(layout);
    }
  }
  const double* k0 = cv_k_[cs][0].values().data();
  const double* k1 = cv_k_[cs][1].values().data();
  const double* k2 = cv_k_[cs][2].values().data();
  const double* dg = diag.values().data();
  const double* b = rhs.values().data();
  double* x = u.values().data();
  double* r = r_.values().data();
  const std::ptrdiff_t sy = layout.stride(1);
  const std::ptrdiff_t sz = layout.stride(2);
  const std::ptrdiff_t len = hi[0] - lo[0] + 1;
  // r = rhs - A u_guess (u's ghosts filled by the caller), as the Chebyshev rows take it.
  for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int) {
    for (std::ptrdiff_t p = row; p < row + len; ++p) {
      const double xp = x[p];
      const double lap = (k0[p + 1] * (x[p + 1] - xp) - k0[p] * (xp - x[p - 1])) +
                         (k1[p + sy] * (x[p + sy] - xp) - k1[p] * (xp - x[p - sy])) +
                         (k2[p + sz] * (x[p + sz] - xp) - k2[p] * (xp - x[p - sz]));
      r[p] = b[p] - (dg[p] * xp - c * lap);
    }
  });
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
                 factored_dp_.values().data(),
                 factored_zp_.values().data()};
  };
  double* y = dir_.values().data();
  double* z = dir_next_.values().data();
  // (D + c N_x) y = r: lines along x, four rows side by side (independent recurrences the core
  // overlaps); a z-plane per task.
  const Sweep wx = sweep_for(0, k0);
  tbb::parallel_for(lo[2], hi[2] + 1, [&](int k) {
    for (int j = lo[1]; j <= hi[1]; j += 4) {
      const auto p0 = static_cast<std::ptrdiff_t>(layout.index(lo[0], j, k));
      solve_lines<false>(wx, p0, std::min(4, hi[1] - j + 1), sy, r, false, y);
    }
  });
  // (D + c N_y) z = D y: lines along y, a row of them side by side; a z-plane per task.
  const Sweep wy = sweep_for(1, k1);
  tbb::parallel_for(lo[2], hi[2] + 1, [&](int k) {
    const auto p0 = static_cast<std::ptrdiff_t>(layout.index(lo[0], lo[1], k));
    solve_lines<true>(wy, p0, static_cast<int>(len), 1, y, true, z);
  });
  // (D + c N_z) delta = D z: lines along z, a row of them side by side; a y-row per task.
  const Sweep wz = sweep_for(2, k2);
  tbb::parallel_for(lo[1], hi[1] + 1, [&](int j) {
    const auto p0 = static_cast<std::ptrdiff_t>(layout.index(lo[0], j, lo[2]));
    solve_lines<true>(wz, p0, static_cast<int>(len), 1, z, true, y);
  });
  for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int) {
    for (std::ptrdiff_t p = row; p < row + len; ++p) {
      x[p] += y[p];
    }
  });
  ViscousSolveReport report;
  report.iterations = 1;
  report.factored = true;
  return report;
}

} // namespace cfddem::fluid
