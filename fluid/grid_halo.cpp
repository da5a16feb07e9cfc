#include "fluid/grid_halo.hpp"

#include <map>
#include <stdexcept>

#include <fmt/format.h>

namespace cfddem::fluid {

namespace {

// The global index space a field lives on: cells, or faces normal to `centring`.
struct FieldSpace {
  std::array<int, 3> cells{};
  std::array<bool, 3> periodic{};
  int centring = kCellCentred;

  // Box b owns point g along axis a: its cells, and the last face of a non-periodic axis.
  [[nodiscard]] bool owns(const CellBox& b, int a, int g) const {
    return (b.lo[a] <= g && g < b.hi[a]) ||
           (a == centring && !periodic[a] && g == cells[a] && b.hi[a] == cells[a]);
  }
  // Largest index along an axis (faces of a non-periodic axis: cells[a]).
  [[nodiscard]] int last(int a) const {
    return a == centring && !periodic[a] ? cells[a] : cells[a] - 1;
  }
};

// Calls visit(local index in box b's layout, owner rank, owner's local index) for every ghost
// point of box b that lies in some box, in b's layout order (so that the owner and b list the
// points they share in the same order).
template <class Visit>
void for_each_exchanged_ghost(const FieldSpace& space, const std::vector<CellBox>& boxes,
                              const std::vector<GridLayout>& layouts, std::size_t b,
                              Visit&& visit) {
  const CellBox& box = boxes[b];
  const GridLayout& layout = layouts[b];
  const std::array<int, 3> n = box.cells();
  int hint = static_cast<int>(b);
  std::array<int, 3> l{};
  std::array<int, 3> g{};
  for (l[2] = -kGhostLayers; l[2] <= n[2] + kGhostLayers; ++l[2]) {
    for (l[1] = -kGhostLayers; l[1] <= n[1] + kGhostLayers; ++l[1]) {
      const bool row_owned =
          space.owns(box, 1, box.lo[1] + l[1]) && space.owns(box, 2, box.lo[2] + l[2]);
      for (l[0] = -kGhostLayers; l[0] <= n[0] + kGhostLayers; ++l[0]) {
        if (row_owned && space.owns(box, 0, box.lo[0] + l[0])) {
          continue;
        }
        bool inside = true;
        for (int a = 0; a < 3 && inside; ++a) {
          g[a] = box.lo[a] + l[a];
          if (space.periodic[a]) {
            g[a] = wrap_index(g[a], space.cells[a]);
          } else {
            inside = g[a] >= 0 && g[a] <= space.last(a);
          }
        }
        if (!inside) {
          continue; // outside a wall, inflow or outflow face: the boundary condition's
        }
        const auto holds = [&](int r) {
          const CellBox& o = boxes[static_cast<std::size_t>(r)];
          return space.owns(o, 0, g[0]) && space.owns(o, 1, g[1]) && space.owns(o, 2, g[2]);
        };
        if (!holds(hint)) {
          hint = -1;
          for (int r = 0; r < static_cast<int>(boxes.size()) && hint < 0; ++r) {
            hint = holds(r) ? r : -1;
          }
          if (hint < 0) {
            throw std::invalid_argument(
                fmt::format("fluid halo: no box holds point ({}, {}, {}): the boxes do not tile "
                            "the grid",
                            g[0], g[1], g[2]));
          }
        }
        const CellBox& o = boxes[static_cast<std::size_t>(hint)];
        visit(layout.index(l), hint,
              layouts[static_cast<std::size_t>(hint)].index(g[0] - o.lo[0], g[1] - o.lo[1],
                                                            g[2] - o.lo[2]));
      }
    }
  }
}

// Box b's padded region (with periodic images) reaches box `me`.
bool near(const FieldSpace& space, const CellBox& b, const CellBox& me) {
  for (int a = 0; a < 3; ++a) {
    bool overlap = false;
    for (const int shift : {-space.cells[a], 0, space.cells[a]}) {
      if (shift != 0 && !space.periodic[a]) {
        continue;
      }
      const int lo = b.lo[a] - kGhostLayers + shift;
      const int hi = b.hi[a] + kGhostLayers + shift; // inclusive: the extra face slot
      overlap = overlap || (lo <= me.hi[a] && me.lo[a] <= hi);
    }
    if (!overlap) {
      return false;
    }
  }
  return true;
}

} // namespace

GridHalo::GridHalo(const MacGrid& grid, std::vector<CellBox> boxes, const Communicator& comm)
    : comm_(comm), boxes_(std::move(boxes)) {
  const auto me = static_cast<std::size_t>(comm.rank());
  if (boxes_.size() != static_cast<std::size_t>(comm.size()) || !(boxes_[me] == grid.box())) {
    throw std::invalid_argument(
        fmt::format("fluid halo: {} boxes for {} ranks, or rank {}'s grid is not its box",
                    boxes_.size(), comm.size(), comm.rank()));
  }
  std::vector<GridLayout> layouts;
  layouts.reserve(boxes_.size());
  for (const CellBox& b : boxes_) {
    layouts.emplace_back(b.cells());
  }
  for (int centring = kCellCentred; centring < 3; ++centring) {
    FieldSpace space;
    space.cells = grid.global_cells();
    space.centring = centring;
    for (int a = 0; a < 3; ++a) {
      space.periodic[a] = grid.periodic(a);
    }
    std::map<int, HaloExchange::Link> links;
    for (std::size_t b = 0; b < boxes_.size(); ++b) {
      if (b != me && !near(space, boxes_[b], boxes_[me])) {
        continue;
      }
      for_each_exchanged_ghost(space, boxes_, layouts, b,
                               [&](std::size_t local, int owner, std::size_t at_owner) {
                                 if (b == me) {
                                   HaloExchange::Link& l = links[owner];
                                   l.rank = owner;
                                   l.recv.push_back(local);
                                 }
                                 if (owner == static_cast<int>(me)) {
                                   HaloExchange::Link& l = links[static_cast<int>(b)];
                                   l.rank = static_cast<int>(b);
                                   l.send.push_back(at_owner);
                                 }
                               });
    }
    std::vector<HaloExchange::Link> sorted;
    for (auto& [rank, link] : links) {
      sorted.push_back(std::move(link));
    }
    plans_[static_cast<std::size_t>(centring + 1)] = HaloExchange(comm, std::move(sorted));
  }
}

void GridHalo::fill(GridField& f, int centring) const {
  plan(centring).forward(f.values());
}

void GridHalo::fill(std::span<GridField* const> fields, int centring) const {
  std::vector<std::span<double>> spans;
  spans.reserve(fields.size());
  for (GridField* f : fields) {
    spans.push_back(f->values());
  }
  plan(centring).forward(spans);
}

void GridHalo::add_ghosts_to_owners(GridField& f, int centring) const {
  plan(centring).reverse_add(f.values());
}

void fill_cell_ghosts(const MacGrid& grid, const GridHalo* halo, GridField& q, CellGhosts mode) {
  if (halo != nullptr) {
    halo->fill(q, kCellCentred);
  }
  fill_cell_ghosts(grid, q, mode);
}

void fill_velocity_ghosts(const MacGrid& grid, const GridHalo* halo, int comp, GridField& f) {
  if (halo != nullptr) {
    halo->fill(f, comp);
  }
  fill_velocity_ghosts(grid, comp, f);
}

void fill_velocity_ghosts(const MacGrid& grid, const GridHalo* halo, std::array<GridField, 3>& u) {
  // The components are separate fields: all exchanges first, then one fill of all three.
  for (int comp = 0; halo != nullptr && comp < 3; ++comp) {
    halo->fill(u[comp], comp);
  }
  fill_velocity_ghosts(grid, u);
}

} // namespace cfddem::fluid
