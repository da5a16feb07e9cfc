// A sparse all-to-all of doubles between the ranks of a communicator: the per-rank counts first
// (one all-to-all, skipped when the receiver knows them already), then the payload point to
// point, non-blocking, only between ranks that exchange something; a rank's own part is copied.
// The particle exchange (core/particle_exchange.hpp) and the gas routing (apps/gas_routing.hpp)
// send through it (and, over a group of ranks, the parallel ORB: core/sparse_exchange_mpi.hpp).
// Collective over the communicator.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/communicator.hpp"

namespace cfddem {

// send: the items for every rank packed in rank order, send_counts[r] items of `stride` doubles
// for rank r. recv: resized to hold what arrives, by source rank (each source's items in its
// packing order); recv_counts[r]: items from rank r, exchanged first unless counts_known.
void sparse_exchange(const Communicator& comm, std::span<const std::int64_t> send_counts,
                     std::span<const double> send, std::vector<std::int64_t>& recv_counts,
                     std::vector<double>& recv, int stride, bool counts_known);

} // namespace cfddem
