// Neighbor search: a cell list (counting sort of particles into cells) feeding a Verlet list in
// CSR form. A full list (every pair in both particles' rows) lets each particle sum its own forces
// in a fixed order with no scatter to j (the islands scheme's kernels). A half list (each pair
// once, in the row of its lower index: RowKind::half) is what the explicit scheme's contact pass
// reads: each pair's force is computed once and then added to both particles in a fixed order
// (dem/verlet_passes.hpp). The list holds pairs within r_i + r_j + skin; it stays valid until
// some particle has moved more than skin/2 since the build.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "core/particle_store.hpp"
#include "dem/cell_list.hpp"
#include "dem/domain_geometry.hpp"

namespace cfddem::dem {

// Which pairs a row holds: every partner (full), or only partners of higher index (half).
enum class RowKind { full, half };

class VerletList {
public:
  // Wrap positions into the periodic box, sort particles by cell (locality: neighbors are near
  // in memory; the store is permuted and `order()` says how), and build the list.
  // Throws RunError if a periodic length is shorter than twice the cutoff.
  void build(ParticleStore& p, const DomainGeometry& g, double skin, RowKind kind = RowKind::full);
  // Whether build() takes `skin` for particles of radius up to r_max: every periodic length
  // above twice the cutoff plus skin, 2 (2 r_max + 2 skin).
  static bool skin_fits(const DomainGeometry& g, double r_max, double skin, int* axis = nullptr);

  // Permutation applied to the store by the last build: new index k = old index order()[k].
  std::span<const std::uint32_t> order() const {
    return permuted_ ? cells_.items() : std::span<const std::uint32_t>();
  }
  std::span<const std::uint32_t> offsets() const { return offsets_; }
  // Each row lists first the pairs that do not cross a periodic face (their raw separation is
  // already the minimum image for the list's lifetime), then, from wrap_begin()[i], those that do.
  // The hot loop applies the periodic image only to the second part. In a rank-local list
  // (build_local) the second part is instead the pairs whose partner is a ghost copy: the part
  // that waits for the ghosts' new positions.
  std::span<const std::uint32_t> wrap_begin() const { return wrap_begin_; }
  // Rows whose second part (from wrap_begin) is not empty.
  std::span<const std::uint32_t> tail_rows() const { return tail_rows_; }
  // The listed particles' indices, increasing: those some row names (its own or a partner's),
  // the only ones that can have a contact force until the next build.
  std::span<const std::uint32_t> listed_index() const { return listed_index_; }
  RowKind kind() const { return kind_; }
  // Entries whose partner is a ghost copy (build_local only; 0 otherwise).
  std::size_t ghost_entries() const { return ghost_entries_; }
  std::span<const std::uint32_t> neighbors() const { return neighbors_; }
  // Reference positions of the last build (for the displacement test).
  std::span<const double> x_ref() const { return xr_; }
  std::span<const double> y_ref() const { return yr_; }
  std::span<const double> z_ref() const { return zr_; }
  // Particles with a non-empty row (the only ones that can have a contact until the next build).
  std::span<const std::uint32_t> active() const { return active_; }
  double skin() const { return skin_; }
  // Restart: reinstate a list saved from offsets()/neighbors()/x_ref()... exactly (the rows keep
  // their order, so forces sum in the same order as in the run that saved them). Check it first
  // with check_saved_list. The kind is read from the rows (half when no row names a lower index).
  void restore(std::vector<std::uint32_t> offsets, std::vector<std::uint32_t> neighbors,
               std::vector<double> x_ref, std::vector<double> y_ref, std::vector<double> z_ref,
               double skin, const DomainGeometry& g);
  std::size_t pair_count() const {
    return kind_ == RowKind::half ? neighbors_.size() : neighbors_.size() / 2;
  }

  // Rank-local half list (the explicit scheme on R ranks): rows for particles [0, rows) only (the
  // owned ones), whose partners are owned particles of higher index, then ghost copies (any
  // particle of the store from `rows` on, already at the periodic image they are needed at). No
  // periodic wrap or image, and the store is not reordered (ghost indices belong to the exchange
  // plan; order() is empty): the cells cover the particles' bounding box, not the domain. Rows
  // are in increasing index order, as build()'s, so the ghost partners come last in each row
  // (from wrap_begin()).
  void build_local(const ParticleStore& p, std::size_t rows, double skin);
  // Cells of the last build's grid (the memory a build needs grows with it).
  std::size_t cell_count() const { return cells_.grid().count(); }

private:
  // Rows of particles [0, rows) from the binned cells (Indirect: cell members through the
  // cell list's items; else the store is in cell order).
  template <bool Indirect>
  void fill_rows(const ParticleStore& p, const DomainGeometry& g, std::size_t rows, double skin);
  // The same rows for the whole store in cell order (build()), from each close pair found once
  // (a cell against itself and its 13 forward neighbours): half the candidate tests of
  // fill_rows, which visits all 27 cells around every particle. Needs half_stencil().
  void fill_rows_by_pairs(const ParticleStore& p, const DomainGeometry& g, std::size_t n,
                          double skin);

  // After the rows [0, n) are in place over a store of `store` particles: active_, tail_rows_,
  // listed_, listed_index_.
  void index_rows(std::size_t n, std::size_t store);

  CellList cells_;
  bool permuted_ = false; // the last build sorted the store by cell (order() = cells_.items())
  std::vector<std::uint32_t> tail_rows_, listed_index_, offsets_, wrap_begin_, active_, neighbors_;
  std::vector<std::uint8_t> listed_; // index_rows()'s scratch: 1 per listed particle
  RowKind kind_ = RowKind::full;
  std::size_t ghost_entries_ = 0;
  std::vector<double> xr_, yr_, zr_;
  std::vector<std::vector<std::uint32_t>> chunk_rows_; // per-chunk row buffers of the build
  // fill_rows_by_pairs: per range of slots, the close pairs (a, b) of the cells that begin in
  // it, as a, b, a, b, ...; and each row's next free entry while they are scattered into rows.
  std::vector<std::vector<std::uint32_t>> range_pairs_;
  std::vector<std::uint32_t> cursor_;
  double skin_ = 0.0;
};

// A saved list (offsets, neighbors, reference positions) for a store of n particles: throws
// RunError saying what does not fit, so a restart never indexes out of range. An empty list
// (never built) passes.
void check_saved_list(std::size_t n, std::span<const std::uint32_t> offsets,
                      std::span<const std::uint32_t> neighbors, std::span<const double> x_ref,
                      std::span<const double> y_ref, std::span<const double> z_ref);

} // namespace cfddem::dem
