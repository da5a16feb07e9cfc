// for_blocks of the island kernels (dem/islands_kernels.hpp, step_island) as TBB tasks: the
// schemes decide the iteration, the kernels only say which blocks there are. Each block writes
// its own partial, so the result does not depend on the thread count.
#pragma once

#include <cstddef>

#include <tbb/parallel_for.h>

namespace cfddem::dem {

struct TaskBlocks {
  template <class F> void operator()(std::size_t n, F&& f) const {
    tbb::parallel_for(std::size_t{0}, n, f);
  }
};

} // namespace cfddem::dem
