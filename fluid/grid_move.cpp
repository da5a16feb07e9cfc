#include "fluid/grid_move.hpp"

#include <algorithm>
#include <stdexcept>

#include <fmt/format.h>

#include "fluid/grid_halo.hpp"

namespace cfddem::fluid {

std::array<int, 2> owned_points(const MacGrid& grid, const CellBox& box, int axis, int centring) {
  const int n = grid.global_cells()[static_cast<std::size_t>(axis)];
  const bool high_face = centring == axis && box.hi[axis] == n && !grid.periodic(axis);
  return {box.lo[axis], box.hi[axis] + (high_face ? 1 : 0)};
}

namespace {

// Positions in a box's padded layout of the points in [lo, hi) (global indices), in (k, j, i)
// order: both sides of a link list their common points in this order.
void append_points(const GridLayout& layout, const CellBox& box, const std::array<int, 3>& lo,
                   const std::array<int, 3>& hi, std::size_t offset,
                   std::vector<std::size_t>& out) {
  for (int k = lo[2]; k < hi[2]; ++k) {
    for (int j = lo[1]; j < hi[1]; ++j) {
      for (int i = lo[0]; i < hi[0]; ++i) {
        out.push_back(offset + layout.index(i - box.lo[0], j - box.lo[1], k - box.lo[2]));
      }
    }
  }
}

// The points owned both by box a (under its grid) and box b: empty when hi <= lo on some axis.
bool common_points(const MacGrid& grid, const CellBox& a, const CellBox& b, int centring,
                   std::array<int, 3>& lo, std::array<int, 3>& hi) {
  for (int axis = 0; axis < 3; ++axis) {
    const std::array<int, 2> ra = owned_points(grid, a, axis, centring);
    const std::array<int, 2> rb = owned_points(grid, b, axis, centring);
    lo[axis] = std::max(ra[0], rb[0]);
    hi[axis] = std::min(ra[1], rb[1]);
    if (hi[axis] <= lo[axis]) {
      return false;
    }
  }
  return true;
}

} // namespace

GridMove::GridMove(const MacGrid& from, const MacGrid& to, const std::vector<CellBox>& old_boxes,
                   const std::vector<CellBox>& new_boxes, const Communicator& comm)
    : from_size_(from.layout().size()), to_size_(to.layout().size()) {
  const auto me = static_cast<std::size_t>(comm.rank());
  const auto ranks = static_cast<std::size_t>(comm.size());
  if (old_boxes.size() != ranks || new_boxes.size() != ranks || !(from.box() == old_boxes[me]) ||
      !(to.box() == new_boxes[me]) || from.global_cells() != to.global_cells()) {
    throw std::invalid_argument(fmt::format(
        "grid move: rank {} of {} holds boxes that do not match the {} old and {} new boxes",
        me, ranks, old_boxes.size(), new_boxes.size()));
  }
  for (int c = kCellCentred; c < 3; ++c) {
    std::vector<HaloExchange::Link> links;
    for (std::size_t r = 0; r < ranks; ++r) {
      HaloExchange::Link l;
      l.rank = static_cast<int>(r);
      std::array<int, 3> lo{}, hi{};
      // Sent: my old points that rank r owns now; received: my new points rank r owned.
      if (common_points(from, old_boxes[me], new_boxes[r], c, lo, hi)) {
        append_points(from.layout(), old_boxes[me], lo, hi, 0, l.send);
      }
      if (common_points(from, old_boxes[r], new_boxes[me], c, lo, hi)) {
        append_points(to.layout(), new_boxes[me], lo, hi, from_size_, l.recv);
      }
      if (!l.send.empty() || !l.recv.empty()) {
        links.push_back(std::move(l));
      }
    }
    plans_[static_cast<std::size_t>(c + 1)] = HaloExchange(comm, std::move(links));
  }
}

void GridMove::move(std::span<const double> from, std::span<double> to, int centring) const {
  if (from.size() != from_size_ || to.size() != to_size_ || centring < kCellCentred ||
      centring > 2) {
    throw std::invalid_argument("grid move: a field does not fit the grids the move was made for");
  }
  buffer_.resize(from_size_ + to_size_);
  std::copy(from.begin(), from.end(), buffer_.begin());
  std::copy(to.begin(), to.end(), buffer_.begin() + static_cast<std::ptrdiff_t>(from_size_));
  plans_[static_cast<std::size_t>(centring + 1)].forward(std::span<double>(buffer_));
  std::copy(buffer_.begin() + static_cast<std::ptrdiff_t>(from_size_), buffer_.end(), to.begin());
}

void move_solver_state(const GasSolver& from, GasSolver& to, const GridMove& move) {
  const MacGrid& grid = to.grid();
  const GridHalo* halo = to.halo();
  const GasSolver::State old = from.save_state();
  const auto values = [](const GridField& f) {
    return std::vector<double>(f.values().begin(), f.values().end());
  };
  const auto cells = [&](const std::vector<double>& v, CellGhosts mode) {
    GridField f = grid.make_field();
    move.move(v, f.values(), kCellCentred);
    fill_cell_ghosts(grid, halo, f, mode);
    return values(f);
  };
  GasSolver::State s;
  std::array<GridField, 3> u;
  for (int a = 0; a < 3; ++a) {
    u[static_cast<std::size_t>(a)] = grid.make_field();
    move.move(old.velocity[static_cast<std::size_t>(a)], u[static_cast<std::size_t>(a)].values(),
              a);
  }
  fill_velocity_ghosts(grid, halo, u);
  for (int a = 0; a < 3; ++a) {
    s.velocity[static_cast<std::size_t>(a)] = values(u[static_cast<std::size_t>(a)]);
  }
  s.pressure = cells(old.pressure, CellGhosts::pressure);
  s.volume_fraction = cells(old.volume_fraction, CellGhosts::zero_gradient);
  s.volume_fraction_old = cells(old.volume_fraction_old, CellGhosts::zero_gradient);
  to.restore_state(s);
}

std::size_t GridMove::points_sent() const {
  std::size_t n = 0;
  for (const HaloExchange& plan : plans_) {
    for (const HaloExchange::Link& l : plan.links()) {
      n += l.send.size();
    }
  }
  return n;
}

} // namespace cfddem::fluid
