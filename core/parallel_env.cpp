#include "core/parallel_env.hpp"

#include <cstdlib>

#include <mpi.h>
#ifdef CFDDEM_HAVE_OPENMP
#include <omp.h>
#endif
#include <tbb/global_control.h>
#include <tbb/info.h>

#include "core/mpi_start.hpp"

namespace cfddem {

int ParallelEnv::resolve_threads(int requested) {
  if (requested > 0)
    return requested;
  if (const char* omp = std::getenv("OMP_NUM_THREADS")) {
    const int n = std::atoi(omp);
    if (n > 0)
      return n;
  }
  // tbb::info respects the process affinity mask, so `--map-by ...:PE=n` gives n.
  return tbb::info::default_concurrency();
}

ParallelEnv::ParallelEnv(int* argc, char*** argv, int threads) {
  int initialised = 0;
  MPI_Initialized(&initialised);
  if (!initialised) {
    init_mpi(argc, argv, MPI_THREAD_FUNNELED);
    we_initialised_mpi_ = true;
  }
  MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &ranks_);
  threads_ = resolve_threads(threads);
  control_ = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                   static_cast<std::size_t>(threads_));
#ifdef CFDDEM_HAVE_OPENMP
  // TBB owns the threads of a rank. hypre (Debian builds it with OpenMP) would otherwise start
  // one OpenMP thread per core in every rank, beside the TBB workers and the other ranks: with
  // R ranks x N threads on R x N cores that oversubscribes the cores (spinning OpenMP workers),
  // and an OpenMP reduction could make the pressure solve depend on the thread count.
  omp_set_num_threads(1);
#endif
}

void ParallelEnv::abort(int code) const {
  MPI_Abort(MPI_COMM_WORLD, code);
  std::abort(); // MPI_Abort does not return; this tells the compiler so
}

ParallelEnv::~ParallelEnv() {
  control_.reset();
  int finalised = 0;
  MPI_Finalized(&finalised);
  if (we_initialised_mpi_ && !finalised)
    MPI_Finalize();
}

} // namespace cfddem
