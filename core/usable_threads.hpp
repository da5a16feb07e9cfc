// The threads a parallel pass can run on: the TBB arena's, within the limit --threads sets
// (tbb::global_control, core/parallel_env.hpp). The arena alone counts the cores the process
// may use, which a --threads below that does not change: a pass that cut its work by the arena
// would cut one piece per core even on one thread, run in turn by that thread.
#pragma once

#include <algorithm>
#include <cstddef>

#include <tbb/global_control.h>
#include <tbb/task_arena.h>

namespace cfddem {

inline int usable_threads() {
  return static_cast<int>(std::min<std::size_t>(
      static_cast<std::size_t>(tbb::this_task_arena::max_concurrency()),
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)));
}

} // namespace cfddem
