// Process-wide parallel environment: MPI (initialised FUNNELED: only the main thread calls MPI)
// and the TBB thread limit. The one place outside partition/ that touches MPI and TBB set-up.
#pragma once

#include <memory>

#include <tbb/global_control.h>

namespace cfddem {

class ParallelEnv {
public:
  // threads <= 0: OMP_NUM_THREADS if set, else the cores available to this process.
  ParallelEnv(int* argc, char*** argv, int threads);
  ~ParallelEnv();
  ParallelEnv(const ParallelEnv&) = delete;
  ParallelEnv& operator=(const ParallelEnv&) = delete;

  int rank() const { return rank_; }
  int ranks() const { return ranks_; }
  int threads() const { return threads_; }
  // End every rank of the job now (MPI_Abort): for an error raised by one rank alone, which
  // would otherwise leave the others waiting in a collective call forever.
  [[noreturn]] void abort(int code) const;
  // Resolve a requested thread count as the constructor does.
  static int resolve_threads(int requested);

private:
  int rank_ = 0, ranks_ = 1, threads_ = 1;
  bool we_initialised_mpi_ = false;
  std::unique_ptr<tbb::global_control> control_;
};

} // namespace cfddem
