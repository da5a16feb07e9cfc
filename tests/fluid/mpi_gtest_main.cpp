// GoogleTest main for tests that call hypre: MPI and hypre live for the whole test program.
#include <HYPRE_utilities.h>
#include <gtest/gtest.h>
#include <mpi.h>

#include "core/mpi_start.hpp"

int main(int argc, char** argv) {
  cfddem::init_mpi(&argc, &argv, MPI_THREAD_SINGLE);
  HYPRE_Init();
  ::testing::InitGoogleTest(&argc, argv);
  const int result = RUN_ALL_TESTS();
  HYPRE_Finalize();
  MPI_Finalize();
  return result;
}
