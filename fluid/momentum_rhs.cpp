#include "fluid/momentum_rhs.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace cfddem::fluid {

namespace {

// Calls f(p) for the linear index p of every point of the box lo..hi (inclusive), planes of
// constant k as TBB tasks: every pass writes each point once from values no pass of the same
// sweep writes, so the result does not depend on the thread count.
template <class F>
void for_box(const GridLayout& layout, const std::array<int, 3>& lo, const std::array<int, 3>& hi,
             F&& f) {
  tbb::parallel_for(tbb::blocked_range<int>(lo[2], hi[2] + 1), [&](const tbb::blocked_range<int>& r) {
    for (int k = r.begin(); k != r.end(); ++k) {
      for (int j = lo[1]; j <= hi[1]; ++j) {
        const auto row = static_cast<std::ptrdiff_t>(layout.index(lo[0], j, k));
        for (std::ptrdiff_t p = row; p <= row + (hi[0] - lo[0]); ++p) {
          f(p);
        }
      }
    }
  });
}

void ensure(GridField& f, const GridLayout& layout) {
  if (f.values().size() != layout.size()) {
    f = GridField(layout);
  }
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
                  MomentumWorkspace& work, bool exclude_laplacian) {
  const GridLayout& layout = grid.layout();
  for (GridField* f : {&work.flux, &work.speed, &work.stress, &work.viscous, &work.divergence}) {
    ensure(*f, layout);
  }
  const std::array<std::ptrdiff_t, 3> st = {layout.stride(0), layout.stride(1), layout.stride(2)};
  const std::array<double, 3> inv_dx = {1.0 / grid.spacing(0), 1.0 / grid.spacing(1),
                                        1.0 / grid.spacing(2)};
  const double mu = gas.viscosity;
  // Weight of the grad u (Laplacian) part of tau: 0 when it is treated implicitly.
  const double own = exclude_laplacian ? 0.0 : 1.0;
  const double inv_rho = 1.0 / gas.density;
  const auto& n = grid.cells();
  const std::array<const double*, 3> uv = {u[0].values().data(), u[1].values().data(),
                                           u[2].values().data()};
  const double* ep = eps.values().data();
  double* flux = work.flux.values().data();
  double* speed = work.speed.values().data();
  double* stress = work.stress.values().data();
  double* visc = work.viscous.values().data();
  double* div = work.divergence.values().data();

  if (mu != 0.0) {
    // div u at cells -1..n (the normal stress of faces 0..n needs cells -1..n).
    for_box(layout, {-1, -1, -1}, {n[0], n[1], n[2]}, [&](std::ptrdiff_t c) {
      double d = 0.0;
      for (int b = 0; b < 3; ++b) {
        d += (uv[b][c + st[b]] - uv[b][c]) * inv_dx[b];
      }
      div[c] = d;
    });
  }

  for (int a = 0; a < 3; ++a) {
    const double* q = uv[a];
    double* out = rhs[a].values().data();
    std::array<int, 3> hi = {n[0] - 1, n[1] - 1, n[2] - 1};
    hi[a] = n[a]; // faces 0..n along the component's axis
    for_box(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t p) {
      out[p] = 0.0;
      visc[p] = 0.0;
    });
    for (int b = 0; b < 3; ++b) {
      const std::ptrdiff_t sb = st[b];
      const std::ptrdiff_t sa = st[a];
      const double* ub = uv[b];
      std::array<int, 3> edge_hi = hi;
      ++edge_hi[b];
      // d u_a/d x_b + d u_b/d x_a on the (a, b) edge below p along b (b != a); the d u_a/d x_b
      // part is left to ImplicitViscosity when it is implicit.
      const auto shear_rate = [&](std::ptrdiff_t p) {
        return own * (q[p] - q[p - sb]) * inv_dx[b] + (ub[p] - ub[p - sa]) * inv_dx[a];
      };
      // Quantities on the low control-volume face of p along b: advecting velocity, upwind
      // MUSCL state times it, and eps tau_ab (normal stress at cell p - 1 when b == a; shear
      // stress on the (a, b) edge otherwise).
      for_box(layout, {0, 0, 0}, edge_hi, [&](std::ptrdiff_t p) {
        const double adv = b == a ? 0.5 * (q[p - sb] + q[p]) : 0.5 * (ub[p] + ub[p - sa]);
        speed[p] = adv;
        flux[p] = adv * muscl_edge_state(q[p - 2 * sb], q[p - sb], q[p], q[p + sb], adv, limiter);
        if (mu == 0.0) {
          return;
        }
        if (b == a) {
          const std::ptrdiff_t c = p - sa;
          stress[p] =
              ep[c] * mu * ((1.0 + own) * (q[c + sa] - q[c]) * inv_dx[a] - 2.0 / 3.0 * div[c]);
        } else {
          const double eps_edge = 0.25 * (ep[p] + ep[p - sa] + ep[p - sb] + ep[p - sa - sb]);
          stress[p] = eps_edge * mu * shear_rate(p);
        }
      });
      // Edges in the plane of a velocity-inflow face carry the incoming gas's eps_g (mac_grid.hpp),
      // not the mean with the zero-gradient ghosts.
      for (int side = 0; mu != 0.0 && b != a && side < 2; ++side) {
        if (!grid.inflow_face(b, side)) {
          continue;
        }
        std::array<int, 3> plane_lo = {0, 0, 0};
        std::array<int, 3> plane_hi = edge_hi;
        plane_lo[b] = plane_hi[b] = side == 0 ? 0 : n[b];
        for_box(layout, plane_lo, plane_hi,
                [&](std::ptrdiff_t p) { stress[p] = kInflowVolumeFraction * mu * shear_rate(p); });
      }
      // Convective form u.grad q = div(a q) - q div(a) (see the header).
      for_box(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t p) {
        out[p] -= ((flux[p + sb] - flux[p]) - q[p] * (speed[p + sb] - speed[p])) * inv_dx[b];
        visc[p] += (stress[p + sb] - stress[p]) * inv_dx[b];
      });
    }
    const std::ptrdiff_t sa = st[a];
    for_box(layout, {0, 0, 0}, hi, [&](std::ptrdiff_t p) {
      const double eps_face = 0.5 * (ep[p] + ep[p - sa]);
      out[p] += visc[p] * inv_rho / eps_face + body[a];
    });
  }
}

} // namespace cfddem::fluid
