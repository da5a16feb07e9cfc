// The multigrid's row kernels on a padded level (fluid/multigrid_poisson.cpp): the 7-point
// operator's values along one x row, in copies for baseline x86-64, x86-64-v3 (AVX2) and
// x86-64-v4 (AVX-512) (core/simd_level.hpp). Every copy does each cell's operations in the order
// of multigrid_poisson.cpp's apply_at (no contraction, no reassociation), so the results are
// bitwise the same at every level; only the speed differs.
//
// Why: the loops that computed these values cell by cell inside the restriction and CG's A p
// did not vectorize (GCC could not tell the output row from the level's arrays). Written to
// scratch through restrict parameters they do. The red-black relaxation keeps its own loop: its
// cells sit at stride 2, and a whole-row version (every cell computed, the colour's copied back)
// measured no faster at AVX2, the pass being bound by the level's memory traffic.
#pragma once

#include "core/simd_level.hpp"

#include <cstddef>

namespace cfddem::fluid::multigrid_rows {

// A row of a level: its first cell's padded index, its length, the y and z strides.
struct Row {
  std::ptrdiff_t c0, n, sy, sz;
};

// The sum over a cell's faces of K_f x_neighbour (low x face, high x face, then y and z): the
// operator's off-diagonal part, which apply_at and the row kernels below share.
[[gnu::always_inline]] inline double neighbours(const double* kx, const double* ky,
                                                const double* kz, const double* x, std::ptrdiff_t c,
                                                std::ptrdiff_t sy, std::ptrdiff_t sz) {
  return kx[c] * x[c - 1] + kx[c + 1] * x[c + 1] + ky[c] * x[c - sy] + ky[c + sy] * x[c + sy] +
         kz[c] * x[c - sz] + kz[c + sz] * x[c + sz];
}

// t[i] = (A x) at cell c0 + i: diag x - sum K_f x_nb (apply_at).
[[gnu::always_inline]] inline void apply_values_body(const double* d, const double* kx,
                                                     const double* ky, const double* kz,
                                                     const double* x, double* t, const Row& r) {
  const std::ptrdiff_t sy = r.sy, sz = r.sz;
  for (std::ptrdiff_t i = 0; i < r.n; ++i) {
    const std::ptrdiff_t c = r.c0 + i;
    t[i] = d[c] * x[c] - neighbours(kx, ky, kz, x, c, sy, sz);
  }
}

// t[i] = (b - A x) at cell c0 + i.
[[gnu::always_inline]] inline void residual_values_body(const double* b, const double* d,
                                                        const double* kx, const double* ky,
                                                        const double* kz, const double* x,
                                                        double* t, const Row& r) {
  const std::ptrdiff_t sy = r.sy, sz = r.sz;
  for (std::ptrdiff_t i = 0; i < r.n; ++i) {
    const std::ptrdiff_t c = r.c0 + i;
    t[i] = b[c] - (d[c] * x[c] - neighbours(kx, ky, kz, x, c, sy, sz));
  }
}

// The copies, one type per instruction set. Not inlined, with restrict parameters: GCC keeps the
// restrict of the parameters of a function it calls, not of one it inlines, and these loops
// vectorize only with it (t is scratch, never one of the level's arrays).
#define CFDDEM_MULTIGRID_ROWS(NAME, ...)                                                           \
  struct NAME {                                                                                    \
    [[gnu::noinline __VA_ARGS__]] static void                                                      \
    apply_values(const double* __restrict d, const double* __restrict kx,                          \
                 const double* __restrict ky, const double* __restrict kz,                         \
                 const double* __restrict x, double* __restrict t, const Row& r) {                 \
      apply_values_body(d, kx, ky, kz, x, t, r);                                                   \
    }                                                                                              \
    [[gnu::noinline __VA_ARGS__]] static void                                                      \
    residual_values(const double* __restrict b, const double* __restrict d,                        \
                    const double* __restrict kx, const double* __restrict ky,                      \
                    const double* __restrict kz, const double* __restrict x, double* __restrict t, \
                    const Row& r) {                                                                \
      residual_values_body(b, d, kx, ky, kz, x, t, r);                                             \
    }                                                                                              \
  };
CFDDEM_SIMD_COPY_TYPES(CFDDEM_MULTIGRID_ROWS, Rows)
#undef CFDDEM_MULTIGRID_ROWS

// Calls f with the row kernels' copy for `level`.
template <class F> void with_rows_at(SimdLevel level, F&& f) {
  with_copy_at<RowsX86_64, RowsV3, RowsV4>(level, f);
}

} // namespace cfddem::fluid::multigrid_rows
