// for_blocks of the island kernels (dem/islands_kernels.hpp, step_island) as TBB tasks: the
// schemes decide the iteration, the kernels only say which blocks there are. Each block writes
// its own partial, so the result does not depend on the thread count. And the static partitions
// of the passes over the particles in index order (for_particle_blocks, for_particle_ranges,
// reduce_particle_ranges), which keep each particle on one thread from step to step.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <span>
#include <utility>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/partitioner.h>

#include "core/usable_threads.hpp"

namespace cfddem::dem {

struct TaskBlocks {
  template <class F> void operator()(std::size_t n, F&& f) const {
    tbb::parallel_for(std::size_t{0}, n, f);
  }
};

// f(b) for the blocks b in [0, n) of a pass over the particles in index order (a kick-drift, a
// free flight), whose blocks cost about the same: a static partition, so each thread takes the
// same blocks at every step and a particle's cache lines stay in one core's caches. With the
// default (stealing) partition the blocks moved between the cores from step to step, and on the
// 2-core VM two threads took twice one thread's CPU time for the islands' global kick-drift of
// the 1e5 bed (no gain in wall time at all; perf, 822 against 1,537 samples).
template <class F> void for_particle_blocks(std::size_t n, F&& f) {
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, n, 1),
      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t b = r.begin(); b != r.end(); ++b)
          f(b);
      },
      tbb::static_partitioner{});
}

// Fewest particles per range task of for_particle_ranges: below 2x this (or on one thread) one
// serial call, which costs less than a second task's start.
inline constexpr std::size_t kParticleRange = 16384;

namespace detail {
// Whether a range pass over n particles is one serial call (small n, or one usable thread).
inline bool one_range(std::size_t n, std::size_t min_range) {
  return n < 2 * min_range || usable_threads() < 2;
}
} // namespace detail

// body(a, b) over ranges covering [0, n): one call on one thread or for small n, else about one
// range per thread (static, as for_particle_blocks). `min_range` is kParticleRange but for
// tests, which force many small ranges.
template <class Body>
void for_particle_ranges(std::size_t n, Body&& body, std::size_t min_range = kParticleRange) {
  if (detail::one_range(n, min_range)) {
    body(std::size_t{0}, n);
    return;
  }
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, n, min_range),
      [&](const tbb::blocked_range<std::size_t>& r) { body(r.begin(), r.end()); },
      tbb::static_partitioner{});
}

// The same ranges as for_particle_ranges, each returning a partial T, combined by T::join (in an
// order that may differ run to run: a join must not depend on it, as a sum of integers or a
// maximum does not). A default T starts every partial, so it must change nothing when joined.
template <class T, class Body> T reduce_particle_ranges(std::size_t n, Body&& body) {
  auto join = [](T a, const T& b) {
    a.join(b);
    return a;
  };
  if (detail::one_range(n, kParticleRange))
    return body(std::size_t{0}, n);
  return tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, n, kParticleRange), T{},
      [&](const tbb::blocked_range<std::size_t>& r, T acc) {
        return join(std::move(acc), body(r.begin(), r.end()));
      },
      join, tbb::static_partitioner{});
}

// The entries of `idx` (increasing) that fall in [a, b): a range's share of a particle list.
inline std::span<const std::uint32_t> listed_in(std::span<const std::uint32_t> idx, std::size_t a,
                                                std::size_t b) {
  const auto first = std::lower_bound(idx.begin(), idx.end(), a);
  return {first, std::lower_bound(first, idx.end(), b)};
}

} // namespace cfddem::dem
