#include "dem/verlet_list.hpp"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.hpp"

namespace cfddem::dem {

namespace {

// Put a row in its canonical order: pairs that do not cross a periodic face first, then those
// that do, each part by increasing index (so the force sum order does not depend on how cells
// were visited). Returns the number of non-crossing pairs. Few pairs cross, so a small stack
// buffer avoids std::stable_partition's heap buffer in all but odd rows.
std::size_t order_row(const ParticleStore& p, const DomainGeometry& g, std::size_t i,
                      std::uint32_t* first, std::uint32_t* last) {
  auto crosses = [&](std::uint32_t j) {
    const double d[3] = {p.x[j] - p.x[i], p.y[j] - p.y[i], p.z[j] - p.z[i]};
    bool c = false;
    for (int a = 0; a < 3; ++a)
      c = c || (g.periodic[a] && std::abs(d[a]) > g.half[a]);
    return c;
  };
  std::sort(first, last);
  const auto nc = std::count_if(first, last, crosses);
  std::uint32_t* w = last;
  if (nc > 0 && nc <= 64) {
    std::uint32_t crossing[64];
    std::size_t q = 0;
    w = first;
    for (auto* it = first; it != last; ++it) {
      if (crosses(*it)) {
        crossing[q++] = *it;
      } else {
        *w++ = *it;
      }
    }
    std::copy(crossing, crossing + q, w);
  } else if (nc > 64) {
    w = std::stable_partition(first, last, [&](std::uint32_t j) { return !crosses(j); });
  }
  return static_cast<std::size_t>(w - first);
}

} // namespace

// Raw separations of non-crossing pairs stay below L/2 while particles move less than skin/2
// each: needs L > 2 (cutoff + skin) on every periodic axis.
bool VerletList::skin_fits(const DomainGeometry& g, double r_max, double skin, int* axis) {
  const double cutoff = 2.0 * r_max + skin;
  for (int a = 0; a < 3; ++a)
    if (g.periodic[a] && g.length[a] <= 2.0 * (cutoff + skin)) {
      if (axis != nullptr)
        *axis = a;
      return false;
    }
  return true;
}

void VerletList::build(ParticleStore& p, const DomainGeometry& g, double skin, RowKind kind) {
  skin_ = skin;
  kind_ = kind;
  const std::size_t n = p.size();
  double rmax = 0.0;
  for (double r : p.radius)
    rmax = std::max(rmax, r);
  const double cutoff = 2.0 * rmax + skin;
  if (int a = 0; n > 0 && !skin_fits(g, rmax, skin, &a)) // none: nothing to list
    throw RunError(fmt::format(
        "periodic axis {} is {:.6g} m long, not more than twice the neighbor cutoff plus skin "
        "{:.6g} m (largest diameter + 2 skins): enlarge the domain or reduce dem.neighbor_skin",
        a, g.length[a], cutoff + skin));

  // Wrap into the periodic box; bin.
  for (std::size_t i = 0; i < n; ++i) {
    p.x[i] = g.wrap(p.x[i], 0), p.y[i] = g.wrap(p.y[i], 1), p.z[i] = g.wrap(p.z[i], 2);
  }
  cells_.bin<false>(g, make_cell_grid(g, cutoff, n, 32.0), p.x.data(), p.y.data(), p.z.data(), n);
  permuted_ = true;
  p.permute(cells_.items());
  if (cells_.grid().half_stencil())
    fill_rows_by_pairs(p, g, n, skin);
  else
    fill_rows<false>(p, g, n, skin);
  ghost_entries_ = 0;
  index_rows(n, n);
}

void VerletList::build_local(const ParticleStore& p, std::size_t rows, double skin) {
  skin_ = skin;
  kind_ = RowKind::half;
  const std::size_t n = p.size();
  double rmax = 0.0;
  for (double r : p.radius)
    rmax = std::max(rmax, r);
  const double cutoff = 2.0 * rmax + skin;
  // The frame: the particles' bounding box, at least one cutoff wide on every axis.
  DomainSpec box;
  box.periodic = {false, false, false};
  box.lo = {0.0, 0.0, 0.0}, box.hi = {0.0, 0.0, 0.0};
  if (n > 0) {
    box.lo = {p.x[0], p.y[0], p.z[0]}, box.hi = box.lo;
    for (std::size_t i = 1; i < n; ++i) {
      const double q[3] = {p.x[i], p.y[i], p.z[i]};
      for (int a = 0; a < 3; ++a)
        box.lo[a] = std::min(box.lo[a], q[a]), box.hi[a] = std::max(box.hi[a], q[a]);
    }
  }
  for (int a = 0; a < 3; ++a)
    box.hi[a] = std::max(box.hi[a], box.lo[a] + cutoff);
  const DomainGeometry g(box);
  cells_.bin<false>(g, make_cell_grid(g, cutoff, n, 32.0), p.x.data(), p.y.data(), p.z.data(), n);
  permuted_ = false;
  fill_rows<true>(p, g, rows, skin);
  // The frame is not periodic, so no pair crosses a face: the second part of each row is its
  // ghost partners (rows are sorted by index and ghosts follow the owned particles).
  ghost_entries_ = 0;
  for (std::size_t i = 0; i < rows; ++i) {
    const auto first = neighbors_.begin() + offsets_[i],
               last = neighbors_.begin() + offsets_[i + 1];
    wrap_begin_[i] = static_cast<std::uint32_t>(
        std::lower_bound(first, last, static_cast<std::uint32_t>(rows)) - neighbors_.begin());
    ghost_entries_ += offsets_[i + 1] - wrap_begin_[i];
  }
  index_rows(rows, p.size());
}

void VerletList::index_rows(std::size_t n, std::size_t store) {
  active_.clear(), tail_rows_.clear();
  listed_.assign(store, 0);
  for (std::size_t i = 0; i < n; ++i) {
    if (offsets_[i + 1] == offsets_[i])
      continue;
    active_.push_back(static_cast<std::uint32_t>(i));
    if (wrap_begin_[i] < offsets_[i + 1])
      tail_rows_.push_back(static_cast<std::uint32_t>(i));
    listed_[i] = 1;
  }
  for (const std::uint32_t j : neighbors_)
    listed_[j] = 1;
  listed_index_.clear();
  for (std::size_t i = 0; i < store; ++i)
    if (listed_[i])
      listed_index_.push_back(static_cast<std::uint32_t>(i));
}

template <bool Indirect>
void VerletList::fill_rows(const ParticleStore& p, const DomainGeometry& g, std::size_t n,
                           double skin) {
  // Count, then fill, each particle's row; rows are independent so the parallel build is
  // deterministic.
  const bool half = kind_ == RowKind::half;
  offsets_.assign(n + 1, 0);
  const std::uint32_t* items = cells_.items().data();
  auto visit_row = [&](std::size_t i, auto&& emit) {
    const double xi = p.x[i], yi = p.y[i], zi = p.z[i], ri = p.radius[i];
    cells_.for_each_around(cells_.coord<false>(xi, 0), cells_.coord<false>(yi, 1),
                           cells_.coord<false>(zi, 2), [&](std::uint32_t q) {
                             const std::uint32_t j = Indirect ? items[q] : q;
                             if (half ? j <= i : j == i)
                               return;
                             const double dx = g.image(p.x[j] - xi, 0),
                                          dy = g.image(p.y[j] - yi, 1),
                                          dz = g.image(p.z[j] - zi, 2);
                             const double rc = ri + p.radius[j] + skin;
                             if (dx * dx + dy * dy + dz * dz < rc * rc)
                               emit(j);
                           });
  };
  // One pass: each chunk of 256 particles writes its rows (sorted, in-box pairs first) into its
  // own buffer, kept between builds; then the chunks are laid end to end. Chunks are fixed by
  // index, so the list does not depend on the thread count.
  constexpr std::size_t kChunk = 256;
  const std::size_t chunks = (n + kChunk - 1) / kChunk;
  if (chunk_rows_.size() < chunks)
    chunk_rows_.resize(chunks);
  wrap_begin_.resize(n);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks, 1),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t c = r.begin(); c != r.end(); ++c) {
                        std::vector<std::uint32_t>& buf = chunk_rows_[c];
                        buf.clear();
                        const std::size_t end = std::min(n, (c + 1) * kChunk);
                        for (std::size_t i = c * kChunk; i < end; ++i) {
                          const std::size_t first = buf.size();
                          visit_row(i, [&](std::uint32_t j) { buf.push_back(j); });
                          offsets_[i + 1] = static_cast<std::uint32_t>(buf.size() - first);
                          // wrap_begin_ holds the row-local split until the offsets are known.
                          wrap_begin_[i] = static_cast<std::uint32_t>(
                              order_row(p, g, i, buf.data() + first, buf.data() + buf.size()));
                        }
                      }
                    });
  for (std::size_t i = 0; i < n; ++i)
    offsets_[i + 1] += offsets_[i];
  neighbors_.resize(offsets_[n]);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks, 1),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t c = r.begin(); c != r.end(); ++c) {
                        const std::size_t first = c * kChunk, end = std::min(n, first + kChunk);
                        std::copy(chunk_rows_[c].begin(), chunk_rows_[c].end(),
                                  neighbors_.begin() + offsets_[first]);
                        for (std::size_t i = first; i < end; ++i)
                          wrap_begin_[i] += offsets_[i];
                      }
                    });
  xr_ = p.x, yr_ = p.y, zr_ = p.z;
}

void VerletList::fill_rows_by_pairs(const ParticleStore& p, const DomainGeometry& g, std::size_t n,
                                    double skin) {
  const bool half = kind_ == RowKind::half;
  const double *x = p.x.data(), *y = p.y.data(), *z = p.z.data(), *rad = p.radius.data();
  // The store is in cell order, so slots are particle indices. A pair's test is the same
  // arithmetic from either end (the image of -d is -image(d) exactly, and r_i + r_j = r_j + r_i),
  // so the pairs kept are exactly those fill_rows keeps.
  // Fixed ranges of slots, each with its own pair buffer (kept between builds): the pairs do
  // not depend on the thread count.
  constexpr std::size_t kSlots = 1024;
  const std::size_t ranges = (n + kSlots - 1) / kSlots;
  if (range_pairs_.size() < ranges)
    range_pairs_.resize(ranges);
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, ranges, 1), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t k = r.begin(); k != r.end(); ++k) {
          std::vector<std::uint32_t>& buf = range_pairs_[k];
          buf.clear();
          cells_.for_each_forward_pair_in_slots(
              k * kSlots, std::min(n, (k + 1) * kSlots), [&](std::uint32_t a, std::uint32_t b) {
                const double dx = g.image(x[b] - x[a], 0), dy = g.image(y[b] - y[a], 1),
                             dz = g.image(z[b] - z[a], 2);
                const double rc = rad[a] + rad[b] + skin;
                if (dx * dx + dy * dy + dz * dz < rc * rc) {
                  buf.push_back(a);
                  buf.push_back(b);
                }
              });
        }
      });
  // Rows: a half list keeps each pair in its lower index's row, a full list in both; then each
  // row takes its canonical order (order_row), so the list does not depend on the order the
  // pairs were found in, nor on the thread count. file(row, partner) for every entry, in range
  // order: once to count the rows, once to fill them.
  auto each_entry = [&](auto&& file) {
    for (std::size_t c = 0; c < ranges; ++c) {
      const std::vector<std::uint32_t>& buf = range_pairs_[c];
      for (std::size_t k = 0; k < buf.size(); k += 2) {
        const std::uint32_t a = buf[k], b = buf[k + 1];
        if (half) {
          file(std::min(a, b), std::max(a, b));
        } else {
          file(a, b);
          file(b, a);
        }
      }
    }
  };
  offsets_.assign(n + 1, 0);
  each_entry([&](std::uint32_t i, std::uint32_t) { ++offsets_[i + 1]; });
  for (std::size_t i = 0; i < n; ++i)
    offsets_[i + 1] += offsets_[i];
  neighbors_.resize(offsets_[n]);
  cursor_.assign(offsets_.begin(), offsets_.end() - 1);
  std::uint32_t* row = neighbors_.data();
  each_entry([&](std::uint32_t i, std::uint32_t j) { row[cursor_[i]++] = j; });
  wrap_begin_.resize(n);
  constexpr std::size_t kChunk = 256;
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, n, kChunk), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i != r.end(); ++i)
          wrap_begin_[i] = offsets_[i] + static_cast<std::uint32_t>(order_row(
                                             p, g, i, row + offsets_[i], row + offsets_[i + 1]));
      });
  xr_ = p.x, yr_ = p.y, zr_ = p.z;
}

void VerletList::restore(std::vector<std::uint32_t> offsets, std::vector<std::uint32_t> neighbors,
                         std::vector<double> x_ref, std::vector<double> y_ref,
                         std::vector<double> z_ref, double skin, const DomainGeometry& g) {
  offsets_ = std::move(offsets), neighbors_ = std::move(neighbors);
  xr_ = std::move(x_ref), yr_ = std::move(y_ref), zr_ = std::move(z_ref);
  skin_ = skin;
  permuted_ = false;
  const std::size_t n = offsets_.empty() ? 0 : offsets_.size() - 1;
  wrap_begin_.assign(n, 0);
  kind_ = RowKind::half;
  ghost_entries_ = 0;
  for (std::size_t i = 0; i < n; ++i) {
    for (std::uint32_t k = offsets_[i]; k < offsets_[i + 1]; ++k)
      if (neighbors_[k] <= i)
        kind_ = RowKind::full;
    // The build put the pairs that cross a periodic face last, judged at the build positions
    // (the reference positions): find where they start.
    std::uint32_t k = offsets_[i];
    for (; k < offsets_[i + 1]; ++k) {
      const std::uint32_t j = neighbors_[k];
      const double d[3] = {xr_[j] - xr_[i], yr_[j] - yr_[i], zr_[j] - zr_[i]};
      bool crosses = false;
      for (int a = 0; a < 3; ++a)
        crosses = crosses || (g.periodic[a] && std::abs(d[a]) > g.half[a]);
      if (crosses)
        break;
    }
    wrap_begin_[i] = k;
  }
  index_rows(n, n);
}

void check_saved_list(std::size_t n, std::span<const std::uint32_t> offsets,
                      std::span<const std::uint32_t> neighbors, std::span<const double> x_ref,
                      std::span<const double> y_ref, std::span<const double> z_ref) {
  if (offsets.empty())
    return;
  if (offsets.size() != n + 1 || offsets.front() != 0 || offsets.back() != neighbors.size() ||
      x_ref.size() != n || y_ref.size() != n || z_ref.size() != n)
    throw RunError("checkpoint: the neighbor list does not fit the particles");
  for (std::size_t i = 0; i < n; ++i)
    if (offsets[i + 1] < offsets[i])
      throw RunError("checkpoint: the neighbor list offsets are not monotonic");
  for (const std::uint32_t j : neighbors)
    if (j >= n)
      throw RunError("checkpoint: a neighbor index is out of range");
}

} // namespace cfddem::dem
