// core/sparse_exchange.hpp over an MPI communicator of some of a run's ranks (partition/'s rank
// groups in the parallel ORB): `rank` and `size` are this rank's place in `comm`; the time
// inside MPI adds to `run`'s wait.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include <mpi.h>

#include "core/communicator.hpp"

namespace cfddem {

void sparse_exchange(const Communicator& run, MPI_Comm comm, int rank, int size,
                     std::span<const std::int64_t> send_counts, std::span<const double> send,
                     std::vector<std::int64_t>& recv_counts, std::vector<double>& recv, int stride,
                     bool counts_known);

} // namespace cfddem
