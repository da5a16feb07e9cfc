#include "core/sparse_exchange.hpp"
#include "core/sparse_exchange_mpi.hpp"

#include <algorithm>

#include "core/communicator_mpi.hpp"
#include "core/message_counts.hpp"

namespace cfddem {

void sparse_exchange(const Communicator& c, std::span<const std::int64_t> send_counts,
                     std::span<const double> send, std::vector<std::int64_t>& recv_counts,
                     std::vector<double>& recv, int stride, bool counts_known) {
  sparse_exchange(c, c.size() > 1 ? mpi_comm(c) : MPI_COMM_NULL, c.rank(), c.size(), send_counts,
                  send, recv_counts, recv, stride, counts_known);
}

void sparse_exchange(const Communicator& c, MPI_Comm comm, int me, int ranks,
                     std::span<const std::int64_t> send_counts, std::span<const double> send,
                     std::vector<std::int64_t>& recv_counts, std::vector<double>& recv, int stride,
                     bool counts_known) {
  if (!counts_known) {
    recv_counts.assign(static_cast<std::size_t>(ranks), 0);
    if (ranks == 1) {
      recv_counts[0] = send_counts[0];
    } else {
      count_messages::collective(static_cast<std::int64_t>(ranks * sizeof(std::int64_t)), false);
      MpiWait w(c);
      MPI_Alltoall(send_counts.data(), 1, MPI_INT64_T, recv_counts.data(), 1, MPI_INT64_T, comm);
    }
  }
  std::vector<std::size_t> send_off(static_cast<std::size_t>(ranks) + 1, 0),
      recv_off(static_cast<std::size_t>(ranks) + 1, 0);
  for (int r = 0; r < ranks; ++r) {
    send_off[r + 1] = send_off[r] + static_cast<std::size_t>(send_counts[r] * stride);
    recv_off[r + 1] = recv_off[r] + static_cast<std::size_t>(recv_counts[r] * stride);
  }
  recv.resize(recv_off[ranks]);
  std::copy(send.begin() + static_cast<std::ptrdiff_t>(send_off[me]),
            send.begin() + static_cast<std::ptrdiff_t>(send_off[me + 1]),
            recv.begin() + static_cast<std::ptrdiff_t>(recv_off[me]));
  if (ranks == 1)
    return;
  std::vector<MPI_Request> req;
  req.reserve(2 * static_cast<std::size_t>(ranks));
  constexpr int kTag = 7301;
  for (int r = 0; r < ranks; ++r)
    if (r != me && recv_counts[r] > 0)
      MPI_Irecv(recv.data() + recv_off[r], static_cast<int>(recv_off[r + 1] - recv_off[r]),
                MPI_DOUBLE, r, kTag, comm, &req.emplace_back());
  for (int r = 0; r < ranks; ++r)
    if (r != me && send_counts[r] > 0) {
      count_messages::point_to_point(
          static_cast<std::int64_t>((send_off[r + 1] - send_off[r]) * sizeof(double)));
      MPI_Isend(send.data() + send_off[r], static_cast<int>(send_off[r + 1] - send_off[r]),
                MPI_DOUBLE, r, kTag, comm, &req.emplace_back());
    }
  MpiWait w(c);
  MPI_Waitall(static_cast<int>(req.size()), req.data(), MPI_STATUSES_IGNORE);
}

} // namespace cfddem
