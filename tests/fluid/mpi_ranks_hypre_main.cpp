// GoogleTest main for the fluid tests run under mpirun with several ranks: MPI and hypre live
// for the whole program, every rank runs every test (the solver calls are collective), only
// rank 0 prints, and the program fails on every rank if a test failed on any.
#include <HYPRE_utilities.h>
#include <gtest/gtest.h>
#include <mpi.h>

#include "core/mpi_start.hpp"

int main(int argc, char** argv) {
  cfddem::init_mpi(&argc, &argv, MPI_THREAD_SINGLE);
  HYPRE_Init();
  ::testing::InitGoogleTest(&argc, argv);
  int rank = 0;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  if (rank != 0) {
    auto& listeners = ::testing::UnitTest::GetInstance()->listeners();
    delete listeners.Release(listeners.default_result_printer());
  }
  int failed = RUN_ALL_TESTS();
  MPI_Allreduce(MPI_IN_PLACE, &failed, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
  HYPRE_Finalize();
  MPI_Finalize();
  return failed;
}
