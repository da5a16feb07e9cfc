// The MPI side of core/communicator.hpp, for the sources that call MPI themselves (core's
// communication layer and partition/): the communicator handle and a scope that times MPI waits.
#pragma once

#include <chrono>

#include <mpi.h>

#include "core/communicator.hpp"

namespace cfddem {

inline MPI_Comm mpi_comm(const Communicator& c) {
  return MPI_Comm_f2c(c.fortran_handle());
}

// Adds the scope's wall time to the communicator's MPI wait.
class MpiWait {
public:
  explicit MpiWait(const Communicator& c) : c_(c), t0_(std::chrono::steady_clock::now()) {}
  ~MpiWait() {
    c_.add_wait(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count());
  }
  MpiWait(const MpiWait&) = delete;
  MpiWait& operator=(const MpiWait&) = delete;

private:
  const Communicator& c_;
  std::chrono::steady_clock::time_point t0_;
};

} // namespace cfddem
