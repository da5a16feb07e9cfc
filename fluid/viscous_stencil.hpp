// The implicit viscosity's seven-point stencil on its face-coefficient arrays, one definition for
// every pass that applies it: the Chebyshev rows (implicit_viscosity_chebyshev.cpp), the
// factored step's residual (implicit_viscosity_factored.cpp) and the Laplacian of u^n
// (implicit_viscosity.cpp). Kernels only, always inlined into the row loops whose restrict
// parameters let them vectorize; the same operations in the same order wherever they are used,
// so every pass gives the same bits for the same coefficients.
#pragma once

#include <cstddef>

namespace cfddem::fluid::viscous_stencil {

// Where a row's face coefficients come from: the stored arrays k0, k1, k2 (A = -1, and A = -2,
// whose rows also read the stored inverse diagonal), or eps, as
// face_coefficients computes them where no face of the row lies on an inflow plane or beside a
// closed face (a regular row; A = the component's axis): eps of the cell below along A, else the
// (A, b) edge's four cells. The same operations in the same order give the same bits, without
// reading three stored arrays at every iteration.
// The coefficients of unknown p into k (k[2b]: its low face along b, k[2b + 1]: its high face);
// ix, iy, iz: 1 / dx_b^2.
template <int A>
[[gnu::always_inline]] inline void faces_at(const double* k0, const double* k1, const double* k2,
                                            const double* ep, double ix, double iy, double iz,
                                            std::ptrdiff_t p, std::ptrdiff_t sy, std::ptrdiff_t sz,
                                            double (&k)[6]) {
  if constexpr (A < 0) {
    k[0] = k0[p], k[1] = k0[p + 1], k[2] = k1[p], k[3] = k1[p + sy], k[4] = k2[p],
    k[5] = k2[p + sz];
  } else {
    const std::ptrdiff_t s[3] = {1, sy, sz};
    const double inv_dx2[3] = {ix, iy, iz};
    const std::ptrdiff_t sa = s[A];
    for (int b = 0; b < 3; ++b) {
      if (b == A) {
        k[2 * b] = inv_dx2[b] * ep[p - sa];
        k[2 * b + 1] = inv_dx2[b] * ep[p];
        continue;
      }
      const std::ptrdiff_t sb = s[b];
      const std::ptrdiff_t q = p + sb;
      k[2 * b] = inv_dx2[b] * (0.25 * (ep[p] + ep[p - sa] + ep[p - sb] + ep[p - sa - sb]));
      k[2 * b + 1] = inv_dx2[b] * (0.25 * (ep[q] + ep[q - sa] + ep[q - sb] + ep[q - sa - sb]));
    }
  }
}

// div(eps grad x) at unknown p from its face coefficients (the 1 / dx^2 inside them): over the
// axes, k_high (x_high - x_p) - k_low (x_p - x_low); x's ghosts filled.
[[gnu::always_inline]] inline double laplacian_sum(const double (&k)[6], const double* x,
                                                   std::ptrdiff_t p, std::ptrdiff_t sy,
                                                   std::ptrdiff_t sz) {
  const double xp = x[p];
  return (k[1] * (x[p + 1] - xp) - k[0] * (xp - x[p - 1])) +
         (k[3] * (x[p + sy] - xp) - k[2] * (xp - x[p - sy])) +
         (k[5] * (x[p + sz] - xp) - k[4] * (xp - x[p - sz]));
}

// (A x)_p = dg x_p - c div(eps grad x)_p.
[[gnu::always_inline]] inline double apply_at(const double (&k)[6], double dg, const double* x,
                                              std::ptrdiff_t p, std::ptrdiff_t sy,
                                              std::ptrdiff_t sz, double c) {
  return dg * x[p] - c * laplacian_sum(k, x, p, sy, sz);
}

} // namespace cfddem::fluid::viscous_stencil
