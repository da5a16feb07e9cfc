// The rows of the orb scheme over R ranks (dem/orb_scheme.hpp): for each owned
// particle of a rank, its contact candidates among the local particles (owned first, then ghost
// copies at their unshifted positions) and whether some partner is close enough to make its leaf
// take the fine step. Rebuilt at every sub-iteration from a cell list over the whole domain
// (binned at wrapped positions, so unshifted ghosts across a periodic face are found through the
// periodic stencil); each local pair is tested once, a pair of two ghosts not at all. Rows hold
// the partners of the particle's own leaf first, then the others, each segment by particle id:
// the summation order of OrbScheme's rows, which depends on the particles only.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "dem/cell_list.hpp"
#include "dem/domain_geometry.hpp"

namespace cfddem::dem {

// A row's few partners by particle id (insertion sort: rows are short): the orb scheme's summation
// order on any rank count; it depends on the particles only, not on the store's order.
inline void sort_by_id(std::uint32_t* first, std::uint32_t* last, const std::int64_t* id) {
  for (std::uint32_t* i = first + (first != last); i < last; ++i) {
    const std::uint32_t v = *i;
    std::uint32_t* j = i;
    for (; j > first && id[*(j - 1)] > id[v]; --j)
      *j = *(j - 1);
    *j = v;
  }
}

// The orb scheme's proximity test, on any rank count: a leaf takes the fine step when one of its
// particles has a partner whose centre is closer than prox (r_i + r_j) (prox =
// dem.proximity_radii / 2; r2: the squared separation, rs = r_i + r_j) ...
inline bool within_proximity(double r2, double rs, double prox) {
  const double d = prox * rs;
  return r2 < d * d;
}
// ... or, with dem.local_dt = "time_to_contact", when the gap could close within dt_sp at the
// pair's summed speed bounds s = s_i + s_j.
inline bool within_reach(double r2, double rs, double s, double dt_sp) {
  const double reach = rs + s * dt_sp;
  return r2 < reach * reach;
}

class OrbLocalRows {
public:
  struct Input {
    DomainGeometry geom;                     // the whole domain (minimum image)
    std::span<const double> x, y, z, radius; // owned then ghosts
    std::span<const std::int64_t> id;        // owned then ghosts
    std::span<const double> speed;           // with ttc: speed bound per local particle
    std::span<const std::uint32_t> leaf;     // per owned particle
    std::size_t owned = 0;
    double cutoff = 0.0; // >= every distance tested below, < half of each periodic length
    double skin = 0.0;   // contact candidates: centres within r_i + r_j + skin
    double prox = 0.0;   // proximity: centres within prox (r_i + r_j) (not ttc)
    double dt_sp = 0.0;  // ttc: within r_i + r_j + (s_i + s_j) dt_sp
    bool ttc = false;    // dem.local_dt = "time_to_contact"
    // Also list the proximity candidates: pairs (not two ghosts) within prox (r_i + r_j) + skin
    // (not with ttc; the cutoff must cover 2 prox r_max + skin). While no particle has moved
    // skin/2, every pair within the proximity distance is one of them, so the rows and the
    // proximity flags can be kept over several sub-iterations (OrbScheme::rank_keep_rows).
    bool proximity_pairs = false;
  };
  void build(const Input& in);

  // Owned particle i's row: own-leaf partners nb()[off()[i], mid()[i]), others up to off()[i+1].
  std::span<const std::uint32_t> off() const { return off_; }
  std::span<const std::uint32_t> mid() const { return mid_; }
  std::span<const std::uint32_t> nb() const { return nb_; }
  // Owned particles with a non-empty row, increasing.
  std::span<const std::uint32_t> active() const { return active_; }
  // Per owned particle: a partner within the proximity (or reach) distance. Writable: the
  // scheme adds the walls.
  std::span<unsigned char> near() { return near_; }
  // With Input::proximity_pairs: the candidates (a, b) as pairs of local indices, flattened
  // (a0, b0, a1, b1, ...), at least one end owned; empty otherwise.
  std::span<const std::uint32_t> proximity_candidates() const { return prox_; }
  // The proximity flags again at the present positions (the local particles of the build, owned
  // then ghosts), from the proximity candidates, by the build's test (within_proximity): the
  // build's flags wherever no particle has moved skin/2 since it. Walls are the caller's.
  void proximity_flags(const DomainGeometry& g, std::span<const double> x,
                       std::span<const double> y, std::span<const double> z,
                       std::span<const double> radius, double prox);

private:
  void half_stencil(const Input& in);

  CellList cells_;
  std::vector<std::uint32_t> off_, mid_, nb_, active_, scratch_own_, scratch_other_, pair_a_,
      pair_b_, fill_other_;
  std::vector<std::vector<std::uint32_t>> slab_pairs_; // per z slab of cells: pairs (i, j)
  std::vector<std::vector<std::uint32_t>> slab_prox_;  // per z slab: proximity candidates
  std::vector<std::uint32_t> prox_;
  std::array<std::vector<double>, 5> sorted_;          // x, y, z, radius, speed in cell order
  std::vector<unsigned char> near_, cell_has_owned_;
};

} // namespace cfddem::dem
