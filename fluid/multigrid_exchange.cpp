#include "fluid/multigrid_exchange.hpp"

#include <algorithm>
#include <map>
#include <stdexcept>

#include <fmt/format.h>

#include "core/communicator_mpi.hpp"
#include "core/message_counts.hpp"

namespace cfddem::fluid {

namespace {

// Index of local cell l in a box of n cells padded by one ghost layer.
std::size_t padded_index(const std::array<int, 3>& n, const std::array<int, 3>& l) {
  return static_cast<std::size_t>(l[0] + 1) +
         static_cast<std::size_t>(n[0] + 2) *
             (static_cast<std::size_t>(l[1] + 1) +
              static_cast<std::size_t>(n[1] + 2) * static_cast<std::size_t>(l[2] + 1));
}

bool holds(const CellBox& b, const std::array<int, 3>& g) {
  for (int a = 0; a < 3; ++a) {
    if (g[a] < b.lo[a] || g[a] >= b.hi[a]) {
      return false;
    }
  }
  return true;
}

// Calls visit(index in box b's padded layout, owner rank, index in the owner's layout) for every
// face ghost of box b that lies in the grid (after periodic wrapping), in a fixed order (axis,
// side, then the plane's cells, lowest axis fastest): the owner and b list them alike.
template <class Visit>
void for_each_face_ghost(const std::array<int, 3>& cells, const std::array<bool, 3>& periodic,
                         const std::vector<CellBox>& boxes, std::size_t b, Visit&& visit) {
  const CellBox& box = boxes[b];
  const std::array<int, 3> n = box.cells();
  int hint = static_cast<int>(b);
  for (int a = 0; a < 3; ++a) {
    const int p = a == 0 ? 1 : 0;
    const int q = a == 2 ? 1 : 2;
    for (int side = 0; side < 2; ++side) {
      std::array<int, 3> l{};
      l[a] = side == 0 ? -1 : n[a];
      int ga = box.lo[a] + l[a];
      if (ga < 0 || ga >= cells[a]) {
        if (!periodic[a]) {
          continue; // outside a domain face: the boundary condition's
        }
        ga = (ga + cells[a]) % cells[a];
      }
      for (l[q] = 0; l[q] < n[q]; ++l[q]) {
        for (l[p] = 0; l[p] < n[p]; ++l[p]) {
          std::array<int, 3> g{};
          for (int d = 0; d < 3; ++d) {
            g[d] = d == a ? ga : box.lo[d] + l[d];
          }
          if (!holds(boxes[static_cast<std::size_t>(hint)], g)) {
            hint = -1;
            for (int r = 0; r < static_cast<int>(boxes.size()) && hint < 0; ++r) {
              hint = holds(boxes[static_cast<std::size_t>(r)], g) ? r : -1;
            }
            if (hint < 0) {
              throw std::invalid_argument(fmt::format(
                  "multigrid exchange: no box holds cell ({}, {}, {}): the boxes do not tile "
                  "the grid",
                  g[0], g[1], g[2]));
            }
          }
          const CellBox& o = boxes[static_cast<std::size_t>(hint)];
          visit(padded_index(n, l), hint,
                padded_index(o.cells(), {g[0] - o.lo[0], g[1] - o.lo[1], g[2] - o.lo[2]}));
        }
      }
    }
  }
}

} // namespace

MultigridExchange::MultigridExchange(std::array<int, 3> cells, std::array<bool, 3> periodic,
                                     std::vector<CellBox> boxes, const Communicator& comm)
    : comm_(comm), cells_(cells), boxes_(std::move(boxes)) {
  if (boxes_.size() != static_cast<std::size_t>(comm.size())) {
    throw std::invalid_argument(
        fmt::format("multigrid exchange: {} boxes for {} ranks", boxes_.size(), comm.size()));
  }
  std::int64_t total = 0;
  for (const CellBox& b : boxes_) {
    for (int a = 0; a < 3; ++a) {
      if (b.lo[a] < 0 || b.hi[a] > cells[a] || b.cells(a) < 1) {
        throw std::invalid_argument("multigrid exchange: a box outside the grid or empty");
      }
    }
    counts_.push_back(static_cast<int>(b.count()));
    offsets_.push_back(static_cast<int>(total));
    total += b.count();
  }
  if (total != static_cast<std::int64_t>(cells[0]) * cells[1] * cells[2]) {
    throw std::invalid_argument("multigrid exchange: the boxes do not tile the grid");
  }
  const int me = comm.rank();
  std::map<int, HaloExchange::Link> links;
  const auto link = [&](int r) -> HaloExchange::Link& {
    HaloExchange::Link& l = links[r];
    l.rank = r;
    return l;
  };
  for (std::size_t b = 0; b < boxes_.size(); ++b) {
    for_each_face_ghost(cells, periodic, boxes_, b,
                        [&](std::size_t mine, int owner, std::size_t theirs) {
                          if (static_cast<int>(b) == me) {
                            link(owner).recv.push_back(mine);
                          }
                          if (owner == me) {
                            link(static_cast<int>(b)).send.push_back(theirs);
                          }
                        });
  }
  std::vector<HaloExchange::Link> list;
  for (auto& [r, l] : links) {
    list.push_back(std::move(l));
  }
  plan_ = HaloExchange(comm, std::move(list));
}

void MultigridExchange::gather(std::span<const double> mine, std::span<double> all) const {
  const int me = comm_.rank();
  const bool root = me == 0;
  const std::size_t total = static_cast<std::size_t>(cells_[0]) * cells_[1] * cells_[2];
  if (mine.size() != static_cast<std::size_t>(box().count()) || (root && all.size() != total)) {
    throw std::invalid_argument("multigrid exchange: gather of a vector of another grid");
  }
  if (comm_.size() > 1) {
    by_box_.resize(root ? total : 0);
    count_messages::collective(static_cast<std::int64_t>(mine.size() * sizeof(double)), false);
    MpiWait w(comm_);
    MPI_Gatherv(mine.data(), static_cast<int>(mine.size()), MPI_DOUBLE, by_box_.data(),
                counts_.data(), offsets_.data(), MPI_DOUBLE, 0, mpi_comm(comm_));
  } else {
    by_box_.assign(mine.begin(), mine.end());
  }
  if (!root) {
    return;
  }
  for (std::size_t r = 0; r < boxes_.size(); ++r) {
    const CellBox& b = boxes_[r];
    const double* in = by_box_.data() + offsets_[r];
    for (int k = b.lo[2]; k < b.hi[2]; ++k) {
      for (int j = b.lo[1]; j < b.hi[1]; ++j) {
        const std::size_t row =
            static_cast<std::size_t>(cells_[0]) *
            (static_cast<std::size_t>(j) + static_cast<std::size_t>(cells_[1]) * k);
        std::copy_n(in, b.cells(0), all.data() + row + static_cast<std::size_t>(b.lo[0]));
        in += b.cells(0);
      }
    }
  }
}

void MultigridExchange::scatter(std::span<const double> all, std::span<double> mine) const {
  const bool root = comm_.rank() == 0;
  const std::size_t total = static_cast<std::size_t>(cells_[0]) * cells_[1] * cells_[2];
  if (mine.size() != static_cast<std::size_t>(box().count()) || (root && all.size() != total)) {
    throw std::invalid_argument("multigrid exchange: scatter of a vector of another grid");
  }
  if (root) {
    by_box_.resize(total);
    for (std::size_t r = 0; r < boxes_.size(); ++r) {
      const CellBox& b = boxes_[r];
      double* out = by_box_.data() + offsets_[r];
      for (int k = b.lo[2]; k < b.hi[2]; ++k) {
        for (int j = b.lo[1]; j < b.hi[1]; ++j) {
          const std::size_t row =
              static_cast<std::size_t>(cells_[0]) *
              (static_cast<std::size_t>(j) + static_cast<std::size_t>(cells_[1]) * k);
          out = std::copy_n(all.data() + row + static_cast<std::size_t>(b.lo[0]), b.cells(0), out);
        }
      }
    }
  }
  if (comm_.size() > 1) {
    count_messages::collective(static_cast<std::int64_t>(mine.size() * sizeof(double)), false);
    MpiWait w(comm_);
    MPI_Scatterv(by_box_.data(), counts_.data(), offsets_.data(), MPI_DOUBLE, mine.data(),
                 static_cast<int>(mine.size()), MPI_DOUBLE, 0, mpi_comm(comm_));
  } else {
    std::copy(by_box_.begin(), by_box_.end(), mine.begin());
  }
}

} // namespace cfddem::fluid
