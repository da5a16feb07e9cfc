#include "fluid/momentum_rhs.hpp"

#include <type_traits>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/simd_level.hpp"
#include "fluid/box_loops.hpp"
#include "fluid/grid_halo.hpp"

namespace cfddem::fluid {

namespace {

void ensure(GridField& f, const GridLayout& layout) {
  if (f.values().size() != layout.size()) {
    f = GridField(layout);
  }
}

} // namespace

void size_workspace(MomentumWorkspace& work, const GridLayout& layout, bool godunov) {
  for (int b = 0; b < 3; ++b) {
    ensure(work.flux[b], layout);
    ensure(work.speed[b], layout);
    ensure(work.stress[b], layout);
  }
  ensure(work.divergence, layout);
  if (!godunov) {
    return;
  }
  for (auto& row : work.base) {
    for (GridField& f : row) {
      ensure(f, layout);
    }
  }
  for (GridField& f : work.half) {
    ensure(f, layout);
  }
}

namespace {

// Everything one component's passes read, with the strides and spacings.
struct ComponentView {
  int a = 0;
  std::array<std::ptrdiff_t, 3> st{};
  std::array<double, 3> inv_dx{};
  std::array<const double*, 3> u{};
  const double* ep = nullptr;
  const double* div = nullptr;
  double mu = 0.0;
  double own = 1.0; // weight of the grad u_a (Laplacian) part of tau
  // The instruction set the row loops run with (at_simd_level, core/simd_level.hpp): every level
  // gives bitwise the same fields.
  SimdLevel level = SimdLevel::x86_64;
};

// The last point of component a's faces: faces 0..n along a, cells 0..n-1 across.
std::array<int, 3> faces_hi(const MacGrid& grid, int a) {
  const auto& n = grid.cells();
  std::array<int, 3> hi = {n[0] - 1, n[1] - 1, n[2] - 1};
  hi[a] = n[a];
  return hi;
}

// Calls f with the limiter as a compile-time constant (the row kernels are templates on it).
template <class F> void with_limiter(Limiter limiter, F&& f) {
  if (limiter == Limiter::minmod) {
    f(std::integral_constant<Limiter, Limiter::minmod>{});
  } else {
    f(std::integral_constant<Limiter, Limiter::van_leer>{});
  }
}

// Advecting velocity and upwind MUSCL flux on the low control-volume face along b of the points
// p0 .. p0 + len of a row (docs/theory.md §5: convective form, see the header).
template <Limiter L>
[[gnu::always_inline]] inline void advective_row(const ComponentView& v, int b, std::ptrdiff_t p0,
                                                 std::ptrdiff_t len, double* __restrict speed,
                                                 double* __restrict flux) {
  const double* __restrict q = v.u[v.a];
  // b == a: the mean of the two faces around the cell below; else the b-velocity on the edge.
  const double* __restrict w = b == v.a ? q : v.u[b];
  const std::ptrdiff_t sw = b == v.a ? v.st[b] : v.st[v.a];
  const std::ptrdiff_t sb = v.st[b];
  for (std::ptrdiff_t p = p0; p <= p0 + len; ++p) {
    const double adv = 0.5 * (w[p] + w[p - sw]);
    speed[p] = adv;
    flux[p] = adv * muscl_edge_state<L>(q[p - 2 * sb], q[p - sb], q[p], q[p + sb], adv);
  }
}

// eps tau_ab on the low control-volume face along b: the normal stress at the cell below p when
// b == a; else the shear stress on the (a, b) edge, eps averaged from the edge's four cells, or
// eps = kInflowVolumeFraction on the plane of an inflow face (inflow_row: the whole row lies in
// it; inflow_ends: its first and/or last point does, for b = x).
[[gnu::always_inline]] inline void stress_row(const ComponentView& v, int b, std::ptrdiff_t p0,
                                              std::ptrdiff_t len, bool inflow_row,
                                              std::array<bool, 2> inflow_ends,
                                              double* __restrict stress) {
  const int a = v.a;
  const double* __restrict q = v.u[a];
  const double* __restrict ep = v.ep;
  const std::ptrdiff_t sa = v.st[a];
  const double mu = v.mu;
  if (b == a) {
    const double* __restrict div = v.div;
    const double own = v.own;
    const double inv_dx = v.inv_dx[a];
    for (std::ptrdiff_t p = p0; p <= p0 + len; ++p) {
      const std::ptrdiff_t c = p - sa;
      stress[p] = ep[c] * mu * ((1.0 + own) * (q[c + sa] - q[c]) * inv_dx - 2.0 / 3.0 * div[c]);
    }
    return;
  }
  const double* __restrict ub = v.u[b];
  const std::ptrdiff_t sb = v.st[b];
  const double own = v.own;
  const double inv_dx_a = v.inv_dx[a];
  const double inv_dx_b = v.inv_dx[b];
  const auto shear_rate = [&](std::ptrdiff_t p) {
    return own * (q[p] - q[p - sb]) * inv_dx_b + (ub[p] - ub[p - sa]) * inv_dx_a;
  };
  if (inflow_row) {
    for (std::ptrdiff_t p = p0; p <= p0 + len; ++p) {
      stress[p] = kInflowVolumeFraction * mu * shear_rate(p);
    }
    return;
  }
  for (std::ptrdiff_t p = p0; p <= p0 + len; ++p) {
    const double eps_edge = 0.25 * (ep[p] + ep[p - sa] + ep[p - sb] + ep[p - sa - sb]);
    stress[p] = eps_edge * mu * shear_rate(p);
  }
  if (inflow_ends[0]) {
    stress[p0] = kInflowVolumeFraction * mu * shear_rate(p0);
  }
  if (inflow_ends[1]) {
    stress[p0 + len] = kInflowVolumeFraction * mu * shear_rate(p0 + len);
  }
}

// rhs_a = -(u.grad u_a) + div(eps tau_a)/(eps_f rho) + body_a on the points of a row, the three
// directions' differences summed in the order x, y, z.
template <bool Viscous>
[[gnu::always_inline]] inline void sum_row(const ComponentView& v, std::ptrdiff_t p0,
                                           std::ptrdiff_t len, const MomentumWorkspace& work,
                                           double inv_rho, double body, double* __restrict out) {
  const double* __restrict q = v.u[v.a];
  const double* __restrict ep = v.ep;
  const std::ptrdiff_t sa = v.st[v.a];
  const std::array<const double*, 3> flux = {
      work.flux[0].values().data(), work.flux[1].values().data(), work.flux[2].values().data()};
  const std::array<const double*, 3> speed = {
      work.speed[0].values().data(), work.speed[1].values().data(), work.speed[2].values().data()};
  const std::array<const double*, 3> stress = {work.stress[0].values().data(),
                                               work.stress[1].values().data(),
                                               work.stress[2].values().data()};
  const double* __restrict f0 = flux[0];
  const double* __restrict f1 = flux[1];
  const double* __restrict f2 = flux[2];
  const double* __restrict s0 = speed[0];
  const double* __restrict s1 = speed[1];
  const double* __restrict s2 = speed[2];
  const double* __restrict t0 = stress[0];
  const double* __restrict t1 = stress[1];
  const double* __restrict t2 = stress[2];
  const std::ptrdiff_t sy = v.st[1];
  const std::ptrdiff_t sz = v.st[2];
  const double ix = v.inv_dx[0];
  const double iy = v.inv_dx[1];
  const double iz = v.inv_dx[2];
  for (std::ptrdiff_t p = p0; p <= p0 + len; ++p) {
    double o = 0.0;
    o -= ((f0[p + 1] - f0[p]) - q[p] * (s0[p + 1] - s0[p])) * ix;
    o -= ((f1[p + sy] - f1[p]) - q[p] * (s1[p + sy] - s1[p])) * iy;
    o -= ((f2[p + sz] - f2[p]) - q[p] * (s2[p + sz] - s2[p])) * iz;
    double visc = 0.0;
    if constexpr (Viscous) {
      visc += (t0[p + 1] - t0[p]) * ix;
      visc += (t1[p + sy] - t1[p]) * iy;
      visc += (t2[p + sz] - t2[p]) * iz;
    }
    const double eps_face = 0.5 * (ep[p] + ep[p - sa]);
    out[p] = o + (visc * inv_rho / eps_face + body);
  }
}

// Calls row(b, p0, len) for every row of component a's control-volume faces along every
// direction b: the box 0..hi (hi: the component's faces) with one more point along b (the high
// face of the last control volume); p0 is the row's first point, len its last offset. Planes of
// constant k are TBB tasks, and each (b, row) is visited once.
template <class Row>
void for_control_volume_rows(const GridLayout& layout, const std::array<int, 3>& hi, Row&& row) {
  tbb::parallel_for(tbb::blocked_range<int>(0, hi[2] + 2), [&](const tbb::blocked_range<int>& r) {
    for (int k = r.begin(); k != r.end(); ++k) {
      for (int b = 0; b < 3; ++b) {
        std::array<int, 3> edge_hi = hi;
        ++edge_hi[b];
        if (k > edge_hi[2]) {
          continue;
        }
        for (int j = 0; j <= edge_hi[1]; ++j) {
          row(b, static_cast<std::ptrdiff_t>(layout.index(0, j, k)), j, k, edge_hi[0]);
        }
      }
    }
  });
}

// Where component a's shear stresses lie in the plane of an inflow face (stress_row's flags).
struct InflowPlanes {
  std::array<std::array<bool, 2>, 3> face{};
  std::array<int, 3> n{};
  InflowPlanes(const MacGrid& grid, int a) : n(grid.cells()) {
    for (int b = 0; b < 3; ++b) {
      face[b] = {b != a && grid.inflow_face(b, 0), b != a && grid.inflow_face(b, 1)};
    }
  }
  // The whole row (j, k) of direction b lies in an inflow plane (b = y or z).
  [[nodiscard]] bool row(int b, int j, int k) const {
    return (b == 2 && ((k == 0 && face[2][0]) || (k == n[2] && face[2][1]))) ||
           (b == 1 && ((j == 0 && face[1][0]) || (j == n[1] && face[1][1])));
  }
  // The row's first and last point do (b = x).
  [[nodiscard]] std::array<bool, 2> ends(int b) const {
    return {b == 0 && face[0][0], b == 0 && face[0][1]};
  }
};

template <Limiter L>
void component_rhs(const MacGrid& grid, const ComponentView& v, double inv_rho, double body,
                   MomentumWorkspace& work, GridField& rhs) {
  const GridLayout& layout = grid.layout();
  const int a = v.a;
  const std::array<int, 3> hi = faces_hi(grid, a);
  const InflowPlanes inflow(grid, a);
  const bool viscous = v.mu != 0.0;
  // Pass 1: the control-volume face quantities of every direction b on the box 0..hi, one more
  // point along b (the high face of the last control volume).
  for_control_volume_rows(layout, hi, [&](int b, std::ptrdiff_t p0, int j, int k, int len) {
    at_simd_level(v.level, [&]() CFDDEM_SIMD_BODY {
      advective_row<L>(v, b, p0, len, work.speed[b].values().data(), work.flux[b].values().data());
      if (viscous) {
        stress_row(v, b, p0, len, inflow.row(b, j, k), inflow.ends(b),
                   work.stress[b].values().data());
      }
    });
  });
  // Pass 2: differences, viscous term and body force on the component's faces.
  double* out = rhs.values().data();
  for_box_rows(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t p0, int, int) {
    at_simd_level(v.level, [&]() CFDDEM_SIMD_BODY {
      if (viscous) {
        sum_row<true>(v, p0, hi[0], work, inv_rho, body, out);
      } else {
        sum_row<false>(v, p0, hi[0], work, inv_rho, body, out);
      }
    });
  });
}

// div u of the view's velocities at cells -1..n, into the workspace.
void velocity_divergence(const MacGrid& grid, const ComponentView& v, MomentumWorkspace& work) {
  const auto& n = grid.cells();
  double* div = work.divergence.values().data();
  for_box_rows(grid.layout(), {-1, -1, -1}, {n[0], n[1], n[2]}, [&](std::ptrdiff_t p0, int, int) {
    at_simd_level(v.level, [&]() CFDDEM_SIMD_BODY {
      const double* __restrict ux = v.u[0];
      const double* __restrict uy = v.u[1];
      const double* __restrict uz = v.u[2];
      for (std::ptrdiff_t c = p0; c <= p0 + n[0] + 1; ++c) {
        double d = 0.0;
        d += (ux[c + 1] - ux[c]) * v.inv_dx[0];
        d += (uy[c + v.st[1]] - uy[c]) * v.inv_dx[1];
        d += (uz[c + v.st[2]] - uz[c]) * v.inv_dx[2];
        div[c] = d;
      }
    });
  });
}

// The workspace sized for the grid and the view of u and eps all components share; div u at
// cells -1..n when the gas is viscous (the normal stress of faces 0..n needs cells -1..n).
ComponentView prepare(const MacGrid& grid, const GasProperties& gas,
                      const std::array<GridField, 3>& u, const GridField& eps,
                      MomentumWorkspace& work, bool exclude_laplacian, SimdLevel level) {
  const GridLayout& layout = grid.layout();
  size_workspace(work, layout, false);
  ComponentView v;
  v.st = {layout.stride(0), layout.stride(1), layout.stride(2)};
  v.inv_dx = {1.0 / grid.spacing(0), 1.0 / grid.spacing(1), 1.0 / grid.spacing(2)};
  v.u = {u[0].values().data(), u[1].values().data(), u[2].values().data()};
  v.ep = eps.values().data();
  v.div = work.divergence.values().data();
  v.mu = gas.viscosity;
  v.own = exclude_laplacian ? 0.0 : 1.0;
  v.level = level;
  if (v.mu != 0.0) {
    velocity_divergence(grid, v, work);
  }
  return v;
}

// The viscous term and body force of u^n on a row of a component's faces: the rate the
// Godunov step's edge states are extrapolated with, and the non-advective part of its update.
template <bool Viscous>
[[gnu::always_inline]] inline void
viscous_row(const ComponentView& v, std::ptrdiff_t p0, std::ptrdiff_t len,
            const MomentumWorkspace& work, double inv_rho, double body, double* __restrict out) {
  const double* __restrict ep = v.ep;
  const std::ptrdiff_t sa = v.st[v.a];
  const double* __restrict t0 = work.stress[0].values().data();
  const double* __restrict t1 = work.stress[1].values().data();
  const double* __restrict t2 = work.stress[2].values().data();
  const std::ptrdiff_t sy = v.st[1];
  const std::ptrdiff_t sz = v.st[2];
  for (std::ptrdiff_t p = p0; p <= p0 + len; ++p) {
    double visc = 0.0;
    if constexpr (Viscous) {
      visc += (t0[p + 1] - t0[p]) * v.inv_dx[0];
      visc += (t1[p + sy] - t1[p]) * v.inv_dx[1];
      visc += (t2[p + sz] - t2[p]) * v.inv_dx[2];
    }
    const double eps_face = 0.5 * (ep[p] + ep[p - sa]);
    out[p] = visc * inv_rho / eps_face + body;
  }
}

// The half-step value and the three base states of a row's points (base_row's last loop; the
// transverse terms t_c at the row's points).
template <bool WithLaplacian>
[[gnu::always_inline]] inline void half_step_row(
    std::ptrdiff_t p0, std::ptrdiff_t len, std::ptrdiff_t sa, double half_dt, double grad_scale,
    const double* __restrict q, const double* __restrict rate, const double* __restrict pressure,
    const double* __restrict lap, const double* __restrict push, const double* __restrict gain,
    const double* __restrict t0, const double* __restrict t1, const double* __restrict t2,
    double* __restrict b0, double* __restrict b1, double* __restrict b2, double* __restrict half) {
  // GCC takes restrict from parameters, not from locals: every array is one.
  for (std::ptrdiff_t p = p0; p <= p0 + len; ++p) {
    double force = rate[p] - (pressure[p] - pressure[p - sa]) * grad_scale;
    if constexpr (WithLaplacian) {
      force += lap[p];
    }
    const double common = q[p] + half_dt * (force - (t0[p] + t1[p] + t2[p])) + 0.5 * push[p];
    const double inv_gain = 2.0 / (1.0 + gain[p]); // 1 / (1 + k beta / 2)
    half[p] = common * inv_gain;
    b0[p] = (common + half_dt * t0[p]) * inv_gain;
    b1[p] = (common + half_dt * t1[p]) * inv_gain;
    b2[p] = (common + half_dt * t2[p]) * inv_gain;
  }
}

// The base states of a row of component a's faces, one per direction b: the point's value
// advanced by half a step with the transverse advection (all directions but b), and `half`,
// with the advection along all three (u^{n+1/2} at the face, the advecting velocities' source);
// the rate
// `rate` (viscous and body, from viscous_row), the implicit Laplacian's L(u^n) and the last
// step's pressure gradient, the drag point-implicit over the half step. The advection along c
// is ubar_c times the difference of the limited MUSCL states on the point's two faces along c,
// both upwinded by ubar_c: second order in space, so the prediction adds no dt dx error.
template <Limiter L>
[[gnu::always_inline]] inline void base_row(const ComponentView& v, const EdgePrediction& pred,
                                            std::ptrdiff_t p0, std::ptrdiff_t len, double inv_rho,
                                            const double* __restrict rate,
                                            std::array<double*, 3> base, double* __restrict half) {
  const int a = v.a;
  const double* __restrict q = v.u[a];
  const std::ptrdiff_t sa = v.st[a];
  const double* __restrict pressure = pred.pressure->values().data();
  const double* __restrict lap =
      pred.laplacian != nullptr ? (*pred.laplacian)[a].values().data() : nullptr;
  const double* __restrict gain = (*pred.drag_gain)[a].values().data();
  const double* __restrict push = (*pred.drag_push)[a].values().data();
  const double half_dt = 0.5 * pred.dt;
  const double grad_scale = v.inv_dx[a] * inv_rho;
  // The transverse terms direction by direction into row buffers, each a loop without branches
  // (both upwind differences computed, one selected), so that the compiler vectorises them.
  const auto n = static_cast<std::size_t>(len + 1);
  thread_local std::vector<double> rows;
  if (rows.size() < 3 * n) {
    rows.resize(3 * n);
  }
  std::array<double*, 3> transverse = {rows.data(), rows.data() + n, rows.data() + 2 * n};
  for (int c = 0; c < 3; ++c) {
    const std::ptrdiff_t sc = v.st[c];
    const double* __restrict uc = v.u[c];
    const double inv_dx = v.inv_dx[c];
    double* __restrict t = transverse[static_cast<std::size_t>(c)] - p0;
    const auto fill = [&](auto along_a) CFDDEM_SIMD_BODY {
      for (std::ptrdiff_t p = p0; p <= p0 + len; ++p) {
        double ubar = q[p];
        if constexpr (!decltype(along_a)::value) {
          ubar = 0.25 * (uc[p] + uc[p + sc] + uc[p - sa] + uc[p - sa + sc]);
        }
        const double dm = q[p] - q[p - sc];
        const double dp = q[p + sc] - q[p];
        const double slope = limited_slope<L>(dm, dp);
        const double below = dm + 0.5 * (slope - limited_slope<L>(q[p - sc] - q[p - 2 * sc], dm));
        const double above = dp - 0.5 * (limited_slope<L>(dp, q[p + 2 * sc] - q[p + sc]) - slope);
        t[p] = ubar * (ubar > 0.0 ? below : above) * inv_dx;
      }
    };
    if (c == a) {
      fill(std::true_type{});
    } else {
      fill(std::false_type{});
    }
  }
  // The row buffers indexed by the points' own index.
  const std::array<const double*, 3> t = {transverse[0] - p0, transverse[1] - p0,
                                          transverse[2] - p0};
  if (lap != nullptr) {
    half_step_row<true>(p0, len, sa, half_dt, grad_scale, q, rate, pressure, lap, push, gain, t[0],
                        t[1], t[2], base[0], base[1], base[2], half);
  } else {
    half_step_row<false>(p0, len, sa, half_dt, grad_scale, q, rate, pressure, lap, push, gain, t[0],
                         t[1], t[2], base[0], base[1], base[2], half);
  }
}

// eps tau on component v.a's control-volume faces of every direction, into the workspace.
void stress_pass(const MacGrid& grid, const ComponentView& v, MomentumWorkspace& work) {
  const int a = v.a;
  const std::array<int, 3> hi = faces_hi(grid, a);
  const InflowPlanes inflow(grid, a);
  for_control_volume_rows(grid.layout(), hi, [&](int b, std::ptrdiff_t p0, int j, int k, int len) {
    at_simd_level(v.level, [&]() CFDDEM_SIMD_BODY {
      stress_row(v, b, p0, len, inflow.row(b, j, k), inflow.ends(b),
                 work.stress[b].values().data());
    });
  });
}

// One component's prediction: rhs = viscous term + body force of u^n, then its base states and
// half-step values (ghosts filled as the component's velocity: walls, inflow and periodic faces
// hold on the predicted values too).
template <Limiter L>
void predict_component(const MacGrid& grid, const ComponentView& v, double inv_rho, double body,
                       const EdgePrediction& pred, MomentumWorkspace& work, GridField& rhs) {
  const GridLayout& layout = grid.layout();
  const int a = v.a;
  const std::array<int, 3> hi = faces_hi(grid, a);
  const bool viscous = v.mu != 0.0;
  if (viscous) {
    stress_pass(grid, v, work);
  }
  double* out = rhs.values().data();
  auto& base_a = work.base[static_cast<std::size_t>(a)];
  const std::array<double*, 3> base = {base_a[0].values().data(), base_a[1].values().data(),
                                       base_a[2].values().data()};
  double* half = work.half[static_cast<std::size_t>(a)].values().data();
  for_box_rows(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t p0, int, int) {
    at_simd_level(v.level, [&]() CFDDEM_SIMD_BODY {
      if (viscous) {
        viscous_row<true>(v, p0, hi[0], work, inv_rho, body, out);
      } else {
        viscous_row<false>(v, p0, hi[0], work, inv_rho, body, out);
      }
      base_row<L>(v, pred, p0, hi[0], inv_rho, out, base, half);
    });
  });
  for (GridField& f : base_a) {
    fill_velocity_ghosts(grid, pred.halo, a, f);
  }
  fill_velocity_ghosts(grid, pred.halo, a, work.half[static_cast<std::size_t>(a)]);
}

// The advecting velocity and upwind flux on component a's low control-volume faces along b,
// p0 .. p0 + len of a row: the velocity is the mean of the two half-step values of u_b around
// the face (as the method of lines takes u^n's), and the edge state is the upwind point's base
// state plus its limited slope times (1 - A dt/dx_b)/2. Upwinding by the same velocity that
// multiplies the state keeps the flux continuous where the velocity changes sign.
template <Limiter L>
[[gnu::always_inline]] inline void
godunov_advective_row(const ComponentView& v, int b, double dt, std::ptrdiff_t p0,
                      std::ptrdiff_t len, const double* __restrict base,
                      const double* __restrict half_b, double* __restrict speed,
                      double* __restrict flux) {
  const double* __restrict q = v.u[v.a];
  const std::ptrdiff_t sw = b == v.a ? v.st[b] : v.st[v.a];
  const std::ptrdiff_t sb = v.st[b];
  const double courant_per_speed = dt * v.inv_dx[b];
  for (std::ptrdiff_t p = p0; p <= p0 + len; ++p) {
    const double adv = 0.5 * (half_b[p] + half_b[p - sw]);
    const double d0 = q[p] - q[p - sb];
    const double slope_m = limited_slope<L>(q[p - sb] - q[p - 2 * sb], d0);
    const double slope_p = limited_slope<L>(d0, q[p + sb] - q[p]);
    const double courant = adv * courant_per_speed;
    const double left = base[p - sb] + 0.5 * (1.0 - courant) * slope_m;
    const double right = base[p] - 0.5 * (1.0 + courant) * slope_p;
    speed[p] = adv;
    flux[p] = adv * (adv > 0.0 ? left : (adv < 0.0 ? right : 0.5 * (left + right)));
  }
}

// out -= div(A q_e) - q div(A) on the points of a row, the directions summed in the order x, y, z.
[[gnu::always_inline]] inline void
subtract_advection_row(const ComponentView& v, std::ptrdiff_t p0, std::ptrdiff_t len,
                       const double* __restrict q, std::array<const double*, 3> speed,
                       std::array<const double*, 3> flux, double* __restrict out) {
  const double* __restrict s0 = speed[0];
  const double* __restrict s1 = speed[1];
  const double* __restrict s2 = speed[2];
  const double* __restrict f0 = flux[0];
  const double* __restrict f1 = flux[1];
  const double* __restrict f2 = flux[2];
  const std::ptrdiff_t sy = v.st[1];
  const std::ptrdiff_t sz = v.st[2];
  const double ix = v.inv_dx[0];
  const double iy = v.inv_dx[1];
  const double iz = v.inv_dx[2];
  for (std::ptrdiff_t p = p0; p <= p0 + len; ++p) {
    double o = 0.0;
    o -= ((f0[p + 1] - f0[p]) - q[p] * (s0[p + 1] - s0[p])) * ix;
    o -= ((f1[p + sy] - f1[p]) - q[p] * (s1[p + sy] - s1[p])) * iy;
    o -= ((f2[p + sz] - f2[p]) - q[p] * (s2[p + sz] - s2[p])) * iz;
    out[p] += o;
  }
}

// rhs_a -= u.grad u_a in convective form, div(A q_e) - q div(A), with the time-centred
// advecting velocities and edge states (godunov_advective_row).
template <Limiter L>
void subtract_advection(const MacGrid& grid, const ComponentView& v, double dt,
                        MomentumWorkspace& work, GridField& rhs) {
  const GridLayout& layout = grid.layout();
  const int a = v.a;
  const std::array<int, 3> hi = faces_hi(grid, a);
  const auto& base_a = work.base[static_cast<std::size_t>(a)];
  for_control_volume_rows(layout, hi, [&](int b, std::ptrdiff_t p0, int, int, int len) {
    const auto k = static_cast<std::size_t>(b);
    at_simd_level(v.level, [&]() CFDDEM_SIMD_BODY {
      godunov_advective_row<L>(v, b, dt, p0, len, base_a[k].values().data(),
                               work.half[k].values().data(), work.speed[b].values().data(),
                               work.flux[b].values().data());
    });
  });
  const double* q = v.u[a];
  double* out = rhs.values().data();
  const std::array<const double*, 3> speed = {
      work.speed[0].values().data(), work.speed[1].values().data(), work.speed[2].values().data()};
  const std::array<const double*, 3> flux = {
      work.flux[0].values().data(), work.flux[1].values().data(), work.flux[2].values().data()};
  for_box_rows(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t p0, int, int) {
    at_simd_level(v.level, [&]() CFDDEM_SIMD_BODY {
      subtract_advection_row(v, p0, hi[0], q, speed, flux, out);
    });
  });
}

} // namespace

void momentum_rhs(const MacGrid& grid, const GasProperties& gas, Limiter limiter,
                  const std::array<GridField, 3>& u, const GridField& eps,
                  const std::array<double, 3>& body, std::array<GridField, 3>& rhs) {
  MomentumWorkspace work;
  momentum_rhs(grid, gas, limiter, u, eps, body, rhs, work);
}

void momentum_rhs(const MacGrid& grid, const GasProperties& gas, Limiter limiter,
                  const std::array<GridField, 3>& u, const GridField& eps,
                  const std::array<double, 3>& body, std::array<GridField, 3>& rhs,
                  MomentumWorkspace& work, bool exclude_laplacian, SimdLevel level) {
  ComponentView v = prepare(grid, gas, u, eps, work, exclude_laplacian, level);
  const double inv_rho = 1.0 / gas.density;
  for (int a = 0; a < 3; ++a) {
    v.a = a;
    with_limiter(limiter,
                 [&](auto L) { component_rhs<L()>(grid, v, inv_rho, body[a], work, rhs[a]); });
  }
}

void godunov_momentum_rhs(const MacGrid& grid, const GasProperties& gas, Limiter limiter,
                          const std::array<GridField, 3>& u, const GridField& eps,
                          const std::array<double, 3>& body, const EdgePrediction& prediction,
                          std::array<GridField, 3>& rhs, MomentumWorkspace& work,
                          bool exclude_laplacian, SimdLevel level) {
  size_workspace(work, grid.layout(), true);
  ComponentView v = prepare(grid, gas, u, eps, work, exclude_laplacian, level);
  const double inv_rho = 1.0 / gas.density;
  // Every component's half-step values first: they give the others' advecting velocities.
  for (int a = 0; a < 3; ++a) {
    v.a = a;
    with_limiter(limiter, [&](auto L) {
      predict_component<L()>(grid, v, inv_rho, body[a], prediction, work, rhs[a]);
    });
  }
  // The explicit viscous terms of the half-step velocities (the midpoint rule: second order; those
  // of u^n would be Euler's): rhs = viscous term + body force, at t^n + dt/2.
  if (v.mu != 0.0) {
    ComponentView h = v;
    h.u = {work.half[0].values().data(), work.half[1].values().data(),
           work.half[2].values().data()};
    velocity_divergence(grid, h, work);
    for (int a = 0; a < 3; ++a) {
      h.a = a;
      stress_pass(grid, h, work);
      const std::array<int, 3> hi = faces_hi(grid, a);
      double* out = rhs[a].values().data();
      for_box_rows(grid.layout(), {0, 0, 0}, hi, [&](std::ptrdiff_t p0, int, int) {
        at_simd_level(h.level, [&]() CFDDEM_SIMD_BODY {
          viscous_row<true>(h, p0, hi[0], work, inv_rho, body[a], out);
        });
      });
    }
  }
  for (int a = 0; a < 3; ++a) {
    v.a = a;
    with_limiter(limiter,
                 [&](auto L) { subtract_advection<L()>(grid, v, prediction.dt, work, rhs[a]); });
  }
}

} // namespace cfddem::fluid
