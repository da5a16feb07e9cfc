// What a process does before MPI_Init: where no MPI launcher started it (a singleton, such as
// `cfddem run` without mpirun or a test program), Open MPI is told that this process runs alone.
#pragma once

#include <cstdlib>

#include <mpi.h>

namespace cfddem {

// An MPI launcher (Open MPI's mpirun, Slurm's srun, MPICH's hydra) leaves one of these in each
// rank's environment; a singleton has none of them. SLURM_PROCID is there in every task srun
// starts, whatever its PMI plugin sets (and in a batch script too, where a run then simply keeps
// Open MPI's defaults): a rank of a multi-node job must never be held to the ob1 PML.
inline bool started_by_mpi_launcher() {
  for (const char* key :
       {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK", "PMI_SIZE", "SLURM_PROCID"}) {
    if (std::getenv(key) != nullptr) {
      return true;
    }
  }
  return false;
}

// For a singleton, before MPI_Init: Open MPI 4.1's defaults start a daemon beside the process
// (so that it could MPI_Comm_spawn, which cfddem never calls) and probe network transports (UCX)
// that one process never uses. `ess_singleton_isolated` skips the daemon and the `ob1` PML takes
// the process's messages to itself through its `self` transport. MPI_Init + MPI_Finalize took
// 0.55 s before and 0.16 s after on the 2-core VM, at every `cfddem check` or `run` and every test
// program. A value the user set is kept (setenv without overwrite); a launched rank is left as
// its launcher set it up; other MPI implementations ignore OMPI_MCA_* variables.
inline void prepare_mpi_init() {
  if (started_by_mpi_launcher()) {
    return;
  }
  setenv("OMPI_MCA_ess_singleton_isolated", "1", 0);
  setenv("OMPI_MCA_pml", "ob1", 0);
}

// MPI_Init_thread at `required` (MPI_THREAD_SINGLE is MPI_Init), after prepare_mpi_init: every
// program of the project starts MPI here (ParallelEnv, the test and benchmark mains), so none
// can start it without the singleton's settings. Returns the level provided.
inline int init_mpi(int* argc, char*** argv, int required) {
  prepare_mpi_init();
  int provided = 0;
  MPI_Init_thread(argc, argv, required, &provided);
  return provided;
}

} // namespace cfddem
