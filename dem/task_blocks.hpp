// for_blocks of the island kernels (dem/islands_kernels.hpp, step_island) as TBB tasks: the
// schemes decide the iteration, the kernels only say which blocks there are. Each block writes
// its own partial, so the result does not depend on the thread count. And for_particle_blocks,
// the same for passes over the particles in index order.
#pragma once

#include <cstddef>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

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

} // namespace cfddem::dem
