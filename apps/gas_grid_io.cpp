#include "apps/gas_grid_io.hpp"

#include <bit>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "core/error.hpp"
#include "fluid/grid_field.hpp"

namespace cfddem::apps {

namespace {

constexpr int kG = fluid::kGhostLayers;

// Points along an axis of n cells: faces 0..n and kG ghost layers each side.
int padded(int n) {
  return n + 1 + 2 * kG;
}

// This box's points along axis a, as local indices from -kG: all of them (read), or the ones it
// owns (write, checksum): from its first cell, or from the outer ghosts on the domain's low face;
// up to its last cell, or through the last face and the outer ghosts on the domain's high face.
struct Span {
  int from, to; // [from, to)
};
Span all_points(const GasBlock& b, int a) {
  return {-kG, b.box.cells(a) + 1 + kG};
}
Span owned_points(const GasBlock& b, int a) {
  const int n = b.box.cells(a);
  return {b.box.lo[a] == 0 ? -kG : 0, b.box.hi[a] == b.cells[a] ? n + 1 + kG : n};
}

// splitmix64's finaliser: every input bit moves every output bit.
std::uint64_t mix(std::uint64_t x) {
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ULL;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

// The fields in file order, as (dataset, array) pairs (S: the state, const or not).
template <class S> auto fields(S& s, bool with_prev) {
  using Values = decltype(&s.eps_prev);
  struct Field {
    const char* name;
    Values values;
  };
  std::vector<Field> f = {
      {"/gas/u", &s.solver.velocity[0]},         {"/gas/v", &s.solver.velocity[1]},
      {"/gas/w", &s.solver.velocity[2]},         {"/gas/p", &s.solver.pressure},
      {"/gas/eps_g", &s.solver.volume_fraction}, {"/gas/eps_g_old", &s.solver.volume_fraction_old}};
  if (with_prev)
    f.push_back({"/gas/eps_g_prev", &s.eps_prev});
  return f;
}

// Calls visit(local index into the box's padded array, global point index) for the points of
// the spans, z slowest.
template <class F> void for_points(const GasBlock& b, const std::array<Span, 3>& s, F visit) {
  const std::array<int, 3> n = b.box.cells();
  const std::size_t sx = static_cast<std::size_t>(padded(n[0]));
  const std::size_t sy = static_cast<std::size_t>(padded(n[1]));
  const std::uint64_t gx = static_cast<std::uint64_t>(padded(b.cells[0]));
  const std::uint64_t gy = static_cast<std::uint64_t>(padded(b.cells[1]));
  for (int k = s[2].from; k < s[2].to; ++k)
    for (int j = s[1].from; j < s[1].to; ++j)
      for (int i = s[0].from; i < s[0].to; ++i) {
        const std::size_t local =
            static_cast<std::size_t>(i + kG) +
            sx * (static_cast<std::size_t>(j + kG) + sy * static_cast<std::size_t>(k + kG));
        const std::uint64_t global = static_cast<std::uint64_t>(b.box.lo[0] + i + kG) +
                                     gx * (static_cast<std::uint64_t>(b.box.lo[1] + j + kG) +
                                           gy * static_cast<std::uint64_t>(b.box.lo[2] + k + kG));
        visit(local, global);
      }
}

void add_owned(const GasBlock& b, int field, const std::vector<double>& v, GasChecksum& sums) {
  const std::array<Span, 3> own = {owned_points(b, 0), owned_points(b, 1), owned_points(b, 2)};
  GasChecksum part{};
  for_points(b, own, [&](std::size_t local, std::uint64_t global) {
    const std::uint64_t h = mix(std::bit_cast<std::uint64_t>(v[local]) ^
                                mix(global * 8 + static_cast<unsigned>(field)));
    for (int c = 0; c < 4; ++c)
      part[static_cast<std::size_t>(c)] += static_cast<std::int64_t>((h >> (16 * c)) & 0xffff);
  });
  for (std::size_t c = 0; c < 4; ++c)
    sums[c] += part[c];
}

std::vector<hsize_t> dims(const std::array<int, 3>& cells) {
  return {static_cast<hsize_t>(padded(cells[2])), static_cast<hsize_t>(padded(cells[1])),
          static_cast<hsize_t>(padded(cells[0]))};
}

std::size_t box_points(const GasBlock& b) {
  return static_cast<std::size_t>(padded(b.box.cells(0))) * padded(b.box.cells(1)) *
         padded(b.box.cells(2));
}

} // namespace

std::int64_t combine_checksum(const GasChecksum& sums) {
  std::uint64_t h = 0;
  for (std::size_t c = 0; c < 4; ++c)
    h += static_cast<std::uint64_t>(sums[c]) << (16 * c); // modulo 2^64
  return static_cast<std::int64_t>(h);
}

GasChecksum write_gas_grids(h5::File& f, const GasCoupling::State& s, const GasBlock& b,
                            bool collective) {
  GasChecksum sums{};
  const std::array<Span, 3> own = {owned_points(b, 0), owned_points(b, 1), owned_points(b, 2)};
  int q = 0;
  for (const auto& fl : fields(s, !s.eps_prev.empty())) {
    const std::vector<double>& v = *fl.values;
    if (v.size() != box_points(b))
      throw RunError(fmt::format("gas field '{}' has {} values, its box {}", fl.name, v.size(),
                                 box_points(b)));
    add_owned(b, q++, v, sums);
    if (!collective) {
      f.write(fl.name, std::span<const double>(v), dims(b.cells));
      continue;
    }
    std::vector<double> mine;
    for_points(b, own, [&](std::size_t local, std::uint64_t) { mine.push_back(v[local]); });
    const std::vector<hsize_t> start = {static_cast<hsize_t>(b.box.lo[2] + own[2].from + kG),
                                        static_cast<hsize_t>(b.box.lo[1] + own[1].from + kG),
                                        static_cast<hsize_t>(b.box.lo[0] + own[0].from + kG)};
    const std::vector<hsize_t> count = {static_cast<hsize_t>(own[2].to - own[2].from),
                                        static_cast<hsize_t>(own[1].to - own[1].from),
                                        static_cast<hsize_t>(own[0].to - own[0].from)};
    f.write_block(fl.name, mine, dims(b.cells), start, count);
  }
  return sums;
}

std::array<int, 3> gas_grid_cells(const h5::File& f) {
  const std::vector<hsize_t> d = f.shape("/gas/u");
  if (d.size() != 3 || d[0] < 2 * kG + 2 || d[1] < 2 * kG + 2 || d[2] < 2 * kG + 2)
    throw RunError("dataset '/gas/u' is not a 3-D grid of padded points (a checkpoint from a "
                   "cfddem that wrote the gas fields as flat arrays?)");
  return {static_cast<int>(d[2]) - 1 - 2 * kG, static_cast<int>(d[1]) - 1 - 2 * kG,
          static_cast<int>(d[0]) - 1 - 2 * kG};
}

void read_gas_grids(const h5::File& f, const GasBlock& b, GasCoupling::State& s,
                    GasChecksum& sums) {
  const std::array<Span, 3> box = {all_points(b, 0), all_points(b, 1), all_points(b, 2)};
  const std::vector<hsize_t> start = {static_cast<hsize_t>(b.box.lo[2] + box[2].from + kG),
                                      static_cast<hsize_t>(b.box.lo[1] + box[1].from + kG),
                                      static_cast<hsize_t>(b.box.lo[0] + box[0].from + kG)};
  const std::vector<hsize_t> count = {static_cast<hsize_t>(box[2].to - box[2].from),
                                      static_cast<hsize_t>(box[1].to - box[1].from),
                                      static_cast<hsize_t>(box[0].to - box[0].from)};
  int q = 0;
  for (const auto& fl : fields(s, f.exists("/gas/eps_g_prev"))) {
    const std::vector<hsize_t> d = f.shape(fl.name);
    if (d != dims(b.cells))
      throw RunError(fmt::format(
          "gas field '{}' holds a grid of {} cells, the scene's fluid.cells {} x {} x {}: a "
          "checkpoint of another grid",
          fl.name,
          d.size() == 3 ? fmt::format("{} x {} x {}", static_cast<long long>(d[2]) - 1 - 2 * kG,
                                      static_cast<long long>(d[1]) - 1 - 2 * kG,
                                      static_cast<long long>(d[0]) - 1 - 2 * kG)
                        : std::string("an unknown number of"),
          b.cells[0], b.cells[1], b.cells[2]));
    *fl.values = f.read_block(fl.name, start, count);
    add_owned(b, q++, *fl.values, sums);
  }
}

} // namespace cfddem::apps
