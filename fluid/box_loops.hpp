// Loops over boxes of a GridLayout's index space, planes of constant k as TBB tasks. The callers
// write each point from values no other point of the same loop writes, so the result does not
// depend on the thread count or on how TBB splits the planes.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <span>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include "fluid/grid_field.hpp"

namespace cfddem::fluid {

// Calls row(p0, j, k) for every row of the box lo..hi (inclusive): p0 is the linear index of
// (lo[0], j, k); the row's points are p0 .. p0 + hi[0] - lo[0].
template <class Row>
void for_box_rows(const GridLayout& layout, const std::array<int, 3>& lo,
                  const std::array<int, 3>& hi, Row&& row) {
  if (hi[0] < lo[0] || hi[1] < lo[1] || hi[2] < lo[2]) {
    return;
  }
  tbb::parallel_for(tbb::blocked_range<int>(lo[2], hi[2] + 1),
                    [&](const tbb::blocked_range<int>& r) {
                      for (int k = r.begin(); k != r.end(); ++k) {
                        for (int j = lo[1]; j <= hi[1]; ++j) {
                          row(static_cast<std::ptrdiff_t>(layout.index(lo[0], j, k)), j, k);
                        }
                      }
                    });
}

// Calls f(p) for the linear index p of every point of the box lo..hi (inclusive).
template <class F>
void for_box(const GridLayout& layout, const std::array<int, 3>& lo, const std::array<int, 3>& hi,
             F&& f) {
  const std::ptrdiff_t len = hi[0] - lo[0];
  for_box_rows(layout, lo, hi, [&](std::ptrdiff_t row, int, int) {
    for (std::ptrdiff_t p = row; p <= row + len; ++p) {
      f(p);
    }
  });
}

// to = from (layout and values), blocks of the values as TBB tasks when the sizes agree (a copy
// is exact in any order); otherwise a plain assignment (allocates).
inline void copy_field(const GridField& from, GridField& to) {
  if (to.values().size() != from.values().size()) {
    to = from;
    return;
  }
  const std::span<const double> in = from.values();
  const std::span<double> out = to.values();
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, in.size(), 16384),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      std::copy(in.begin() + static_cast<std::ptrdiff_t>(r.begin()),
                                in.begin() + static_cast<std::ptrdiff_t>(r.end()),
                                out.begin() + static_cast<std::ptrdiff_t>(r.begin()));
                    });
}

// Every value of f (ghosts included) set to v, blocks as TBB tasks.
inline void fill_field(GridField& f, double v) {
  const std::span<double> out = f.values();
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, out.size(), 16384),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      std::fill(out.begin() + static_cast<std::ptrdiff_t>(r.begin()),
                                out.begin() + static_cast<std::ptrdiff_t>(r.end()), v);
                    });
}

// Every value of f outside the box lo..hi (inclusive) set to 0: the rows outside it whole, the
// rows through it before lo[0] and after hi[0]; the box's own points are left as they are (a
// pass that writes them all then needs no fill_field of the whole field).
inline void zero_outside(GridField& f, const std::array<int, 3>& lo, const std::array<int, 3>& hi) {
  const GridLayout& layout = f.layout();
  const std::array<int, 3>& n = layout.cells();
  const int row_size = n[0] + 2 * kGhostLayers + 1;
  for (int k = -kGhostLayers; k <= n[2] + kGhostLayers; ++k) {
    for (int j = -kGhostLayers; j <= n[1] + kGhostLayers; ++j) {
      double* row = f.values().data() + layout.index(-kGhostLayers, j, k);
      const bool through = j >= lo[1] && j <= hi[1] && k >= lo[2] && k <= hi[2] && lo[0] <= hi[0];
      if (!through) {
        std::fill(row, row + row_size, 0.0);
        continue;
      }
      std::fill(row, row + (lo[0] + kGhostLayers), 0.0);
      std::fill(row + (hi[0] + 1 + kGhostLayers), row + row_size, 0.0);
    }
  }
}

// Whether a and b (of one size) hold the same values, blocks compared as TBB tasks.
inline bool equal_values(std::span<const double> a, std::span<const double> b) {
  return tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, a.size(), 16384), true,
      [&](const tbb::blocked_range<std::size_t>& r, bool same) {
        return same && std::equal(a.begin() + static_cast<std::ptrdiff_t>(r.begin()),
                                  a.begin() + static_cast<std::ptrdiff_t>(r.end()),
                                  b.begin() + static_cast<std::ptrdiff_t>(r.begin()));
      },
      [](bool x, bool y) { return x && y; });
}

} // namespace cfddem::fluid
