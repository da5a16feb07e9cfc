#include "core/halo_exchange.hpp"

#include <stdexcept>

#include "core/communicator_mpi.hpp"
#include "core/message_counts.hpp"

namespace cfddem {

namespace {
constexpr int kHaloTag = 0x4841; // one tag: MPI keeps messages between two ranks in order
} // namespace

HaloExchange::HaloExchange(const Communicator& comm, std::vector<Link> links)
    : comm_(comm), links_(std::move(links)), out_(links_.size()), in_(links_.size()) {
  for (std::size_t i = 0; i < links_.size(); ++i) {
    const Link& l = links_[i];
    if (l.send.size() != l.recv.size() && l.rank == comm.rank()) {
      throw std::invalid_argument("halo exchange: a self link pairs send and recv one to one");
    }
    if (i > 0 && !(links_[i - 1].rank < l.rank)) {
      throw std::invalid_argument("halo exchange: links must be sorted by rank, one per rank");
    }
  }
  requests_ = std::make_shared<std::vector<MPI_Request>>();
}

void HaloExchange::forward(std::span<double> field) const {
  const std::span<double> one[1] = {field};
  transfer(one, false);
}

void HaloExchange::forward(std::span<const std::span<double>> fields) const {
  transfer(fields, false);
}

void HaloExchange::reverse_add(std::span<double> field) const {
  const std::span<double> one[1] = {field};
  transfer(one, true);
}

void HaloExchange::transfer(std::span<const std::span<double>> fields, bool reverse) const {
  if (links_.empty()) {
    return;
  }
  const int me = comm_.rank();
  const std::size_t nf = fields.size();
  auto& requests = *static_cast<std::vector<MPI_Request>*>(requests_.get());
  requests.clear();
  // Forward: this rank's recv positions are written from the peer's send positions; reverse:
  // this rank's send positions gain the peer's recv positions.
  for (std::size_t i = 0; i < links_.size(); ++i) {
    const Link& l = links_[i];
    const std::vector<std::size_t>& incoming = reverse ? l.send : l.recv;
    if (l.rank == me || incoming.empty()) {
      continue;
    }
    in_[i].resize(incoming.size() * nf);
    requests.emplace_back();
    MPI_Irecv(in_[i].data(), static_cast<int>(in_[i].size()), MPI_DOUBLE, l.rank, kHaloTag,
              mpi_comm(comm_), &requests.back());
  }
  for (std::size_t i = 0; i < links_.size(); ++i) {
    const Link& l = links_[i];
    const std::vector<std::size_t>& outgoing = reverse ? l.recv : l.send;
    if (l.rank == me || outgoing.empty()) {
      continue;
    }
    std::vector<double>& buf = out_[i];
    buf.resize(outgoing.size() * nf);
    std::size_t m = 0;
    for (const std::span<double> f : fields) {
      for (const std::size_t p : outgoing) {
        buf[m++] = f[p];
        if (reverse) {
          f[p] = 0.0;
        }
      }
    }
    requests.emplace_back();
    count_messages::point_to_point(static_cast<std::int64_t>(buf.size() * sizeof(double)));
    MPI_Isend(buf.data(), static_cast<int>(buf.size()), MPI_DOUBLE, l.rank, kHaloTag,
              mpi_comm(comm_), &requests.back());
  }
  if (!reverse) {
    // Own periodic images while the messages travel.
    for (const Link& l : links_) {
      if (l.rank != me) {
        continue;
      }
      for (const std::span<double> f : fields) {
        for (std::size_t k = 0; k < l.send.size(); ++k) {
          f[l.recv[k]] = f[l.send[k]];
        }
      }
    }
  }
  if (!requests.empty()) {
    MpiWait w(comm_);
    MPI_Waitall(static_cast<int>(requests.size()), requests.data(), MPI_STATUSES_IGNORE);
  }
  for (std::size_t i = 0; i < links_.size(); ++i) {
    const Link& l = links_[i];
    if (l.rank == me) {
      if (reverse) {
        for (const std::span<double> f : fields) {
          for (std::size_t k = 0; k < l.send.size(); ++k) {
            f[l.send[k]] += f[l.recv[k]];
            f[l.recv[k]] = 0.0;
          }
        }
      }
      continue;
    }
    const std::vector<std::size_t>& incoming = reverse ? l.send : l.recv;
    std::size_t m = 0;
    for (const std::span<double> f : fields) {
      for (const std::size_t p : incoming) {
        if (reverse) {
          f[p] += in_[i][m++];
        } else {
          f[p] = in_[i][m++];
        }
      }
    }
  }
}

} // namespace cfddem
