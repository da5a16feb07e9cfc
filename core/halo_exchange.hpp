// A fixed pattern of copies of array entries between ranks, built once and replayed every step
// (the halo plan of Cabana_Halo.hpp): forward copies owners' values into ghosts, reverse adds
// ghosts into their owners (deposition). Non-blocking point to point, one message per peer and
// call; a rank's copies to itself (periodic images of its own box) need no MPI.
#pragma once

#include <cstddef>
#include <memory>
#include <span>
#include <vector>

#include "core/communicator.hpp"

namespace cfddem {

class HaloExchange {
public:
  // With one peer rank: send[i] of this rank feeds recv[i] of the peer's array (same i), so both
  // sides must list their common points in the same order. A link to this rank itself copies
  // send[i] into recv[i] locally.
  struct Link {
    int rank = 0;
    std::vector<std::size_t> send;
    std::vector<std::size_t> recv;
  };

  HaloExchange() = default;
  // Links sorted by rank, at most one per rank.
  HaloExchange(const Communicator& comm, std::vector<Link> links);

  // Every field: recv positions get the peer's values at its send positions. Collective over
  // the linked ranks; all fields are arrays of the same layout.
  void forward(std::span<const std::span<double>> fields) const;
  void forward(std::span<double> field) const;
  // Reverse: the peer's values at its recv positions are added into send positions, peers in
  // rank order (deterministic), and the recv positions are zeroed: their content moved to the
  // owners, so deposits into the same array can accumulate call after call.
  void reverse_add(std::span<double> field) const;

  [[nodiscard]] const std::vector<Link>& links() const { return links_; }

private:
  void transfer(std::span<const std::span<double>> fields, bool reverse) const;

  Communicator comm_ = Communicator::serial();
  std::vector<Link> links_;
  mutable std::vector<std::vector<double>> out_, in_;
  std::shared_ptr<void> requests_; // std::vector<MPI_Request> (halo_exchange.cpp)
};

} // namespace cfddem
