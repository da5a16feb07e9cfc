// A list of contact pairs, each evaluated once, through the explicit scheme's pair pass
// (dem/verlet_passes.hpp): the global steps of the orb scheme (one rank: its candidate pairs; R
// ranks: its rows' pairs) and the R-rank dense mode of the islands scheme (its near rows' pairs).
// The pairs are split into the head, whose raw separation stays the minimum image while no
// particle moves skin/2 from the split, and the tail, taken through the periodic image; the
// contacts of the last pass are kept per block, so that the next pass clears only the forces
// they wrote.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "core/particle_store.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/pair_contacts.hpp"
#include "dem/pair_stream.hpp"
#include "dem/step_model.hpp"
#include "dem/step_report.hpp"

namespace cfddem::dem {

class GlobalPairs {
public:
  // The pairs, in the streams' order: the caller's (then split()), or from_rows().
  std::vector<std::uint32_t> a, b;

  // The pairs of rows over owned + ghost particles (off, nb: CSR over the owned rows): a pair of
  // two owned particles once, from its lower index's row; a pair with a ghost from its owned end
  // (both of its ranks evaluate it, each keeping its own particle's force, as the explicit scheme
  // does); in row order. Returns the pairs counted per step over the ranks (a pair with a ghost
  // on the rank of its lower id, so that the ranks add up to one rank's count).
  std::int64_t from_rows(std::span<const std::uint32_t> off, std::span<const std::uint32_t> nb,
                         std::size_t owned, std::span<const std::int64_t> id);
  // a, b as the head and tail streams at the present positions (each particle moves at most
  // skin/2 before the next split), and the owned particles that can reach a wall while within
  // skin of `ref`.
  void split(const ParticleStore& p, std::size_t owned,
             const std::array<std::span<const double>, 3>& ref, const DomainGeometry& g,
             double skin);
  // The forces of the last pass's contacts and of the particles near a wall back to zero.
  void clear_forces(ParticleStore& p) const;
  // One pass: every pair's contact (step hk), scattered to both particles in the streams' order
  // (head, then tail); overlaps and the largest ratio into `rep`. Wall forces are the caller's.
  void pass(ParticleStore& p, const DomainGeometry& g, const StepModel& m, double hk,
            StepReport& rep);

  std::span<const std::uint32_t> near_wall() const { return near_wall_; }
  std::size_t size() const { return head_.i.size() + tail_.i.size(); }

private:
  PairStream head_, tail_;
  std::vector<PairContacts> head_blocks_, tail_blocks_;
  std::size_t nh_ = 0, nt_ = 0;
  std::vector<std::uint32_t> near_wall_;
};

} // namespace cfddem::dem
