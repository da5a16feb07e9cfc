// One sub-iteration t -> t + dt_sp of the islands scheme (dem/islands_scheme.hpp), written once
// for any rank count:
//   1. speed bounds, link rounds and islands (find_islands: the neighbor structure that finds
//      the links is the Verlet list on one rank, the rows over owned + ghosts on R ranks);
//   2. the steps: everyone on the fine steps in the dense mode, else lone particles fly free,
//      local islands take their K fine steps as TBB tasks and, on R ranks, the members of
//      islands that span ranks step together;
//   3. the counts, summed over the ranks, then faults, and the counters.
// What differs on R ranks is a handful of verbs of the rank part (islands_ranks.cpp), each a
// no-op or the identity on one rank: keep_start / roll_back (the dense mode may outrun its rows
// and redo the sub-iteration), step_spanning, reduce_counts, check_conservation (migration lost
// no particle) and the agreement on a fault in raise_fault.
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <limits>
#include <span>

#include "core/error.hpp"
#include "dem/flag_dispatch.hpp"
#include "dem/islands_counts.hpp"
#include "dem/islands_rank_part.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/task_blocks.hpp"

namespace cfddem::dem {

void IslandsScheme::subiterate(bool record) {
  steps_ = fine_steps(dt_sp_, model_.dt);
  islands::SubiterationCounts t;
  std::optional<islands::Fault> fault;
  for (;;) { // one attempt, unless the dense mode outran its rows on some rank
    find_islands();
    keep_start();
    PhaseTimer::Scope s(timer_, Phase::force);
    if (record)
      record_state();
    t = global_ ? dense_steps(record) : island_steps(record);
    fault = find_fault();
    t.faults = fault ? 1.0 : 0.0;
    reduce_counts(t);
    if (!(t.outran > 0.0) || t.faults > 0.0)
      break;
    roll_back();
  }
  if (t.faults > 0.0)
    raise_fault(fault);
  check_conservation(t);
  count_subiteration(t, record);
  if (auto_.on) {
    if (!auto_.global_now) { // the islands' fine work, in particles on all K steps
      auto_.fine_sum += st_.last_fine_work;
      auto_.members_sum += st_.last_fine_fraction;
      ++auto_.fine_count;
    }
    if (++auto_.q == nsubit_)
      choose_length(); // the interval's last sub-iteration
  }
}

// Every island of busy particles (a link or a wall) takes the fine steps; the rest fly free.
islands::SubiterationCounts IslandsScheme::island_steps(bool record) {
  // Island members in particle order (ln_.islands.members holds local indices) and their start
  // positions, for the bound check of their steps.
  const std::size_t nb = ln_.busy.size();
  ln_.members.resize(nb);
  x0_.resize(nb), y0_.resize(nb), z0_.resize(nb);
  for (std::size_t k = 0; k < nb; ++k) {
    const std::uint32_t i = ln_.busy[ln_.islands.members[k]];
    ln_.members[k] = i;
    x0_[k] = p_.x[i], y0_[k] = p_.y[i], z0_[k] = p_.z[i];
  }
  // Free flight first, then the islands' tasks (they touch disjoint particles). Recording runs
  // always check walls (one kernel fewer; a periodic axis's bounds are infinite).
  const bool walls = !(geom_.periodic[0] && geom_.periodic[1] && geom_.periodic[2]);
  with_flags([&](auto ext, auto rec, auto w) { free_flight<ext, rec, w>(); }, ext_.active(), record,
             record || walls);
  // Islands spanning ranks step together below (null on one rank: none spans).
  run_islands(record, rank_ ? rank_->spans.data() : nullptr);
  islands::SubiterationCounts t;
  for (const islands::IslandResult& r : results_) // in island order
    t.add(r);
  for (const std::uint32_t i : ln_.busy) {
    if (i >= owned_)
      break; // busy is increasing: ghosts come last
    t.fine_members += 1.0;
  }
  t.particle_steps += static_cast<double>(owned_) - t.fine_members; // one step each
  step_spanning(record, t);
  return t;
}

// Every particle on the fine steps (a dense bed, or "auto" chose it). One rank: the explicit
// scheme's passes over the Verlet list (global_steps), which add their pairs, overlaps and
// largest overlap to the counters as they go (a build inside them reads the count so far). R
// ranks: every owned particle in one set of members (fine_together), checked against half the
// skin since the build: a particle past it may have missed a pair the rows lack (roll back).
islands::SubiterationCounts IslandsScheme::dense_steps(bool record) {
  islands::SubiterationCounts t;
  const auto n = static_cast<double>(owned_);
  t.fine_members = n;
  if (!rank_) {
    global_steps(record);
    t.particle_steps = t.lead_steps = n * static_cast<double>(steps_.K);
    return t;
  }
  t.add(fine_together(record, true));
  t.outran = t.bound_violations;
  t.bound_violations = 0.0;
  return t;
}

// NaN, or an owned particle outside a wall. Free particles were flagged as they flew
// (free_flight); the islands' members are few and are checked here; the dense mode checks all.
// Only a flag pays for the full pass that names the particle (a NaN sum can flag falsely).
std::optional<islands::Fault> IslandsScheme::find_fault() {
  bool flagged = global_ || (fault_flag_ >> 63) != 0;
  fault_flag_ = 0;
  if (!global_) {
    const double inf = std::numeric_limits<double>::infinity();
    for (const std::uint32_t i : ln_.busy) {
      if (i >= owned_)
        break;
      const double q = p_.vx[i] * p_.vx[i] + p_.vy[i] * p_.vy[i] + p_.vz[i] * p_.vz[i] + p_.x[i] +
                       p_.y[i] + p_.z[i];
      bool ok = q > -inf && q < inf;
      for (int a = 0; a < 3; ++a) {
        const double c = a == 0 ? p_.x[i] : a == 1 ? p_.y[i] : p_.z[i];
        ok = ok && (geom_.periodic[a] || (c >= geom_.lo[a] && c <= geom_.hi[a]));
      }
      flagged = flagged || !ok;
    }
    // Only members can reach the curved wall (a free particle is not tied to it).
    if (geom_.cylinder)
      for (const std::uint32_t i : ln_.busy) {
        if (i >= owned_)
          break;
        flagged = flagged || !(cylinder_gap(geom_, p_.x[i], p_.y[i], p_.z[i], 0.0) >= 0.0);
      }
  }
  return flagged ? islands::find_fault(p_, owned_, geom_) : std::nullopt;
}

// The counters from the sub-iteration's counts (over all ranks), then the clock.
void IslandsScheme::count_subiteration(const islands::SubiterationCounts& t, bool record) {
  auto count = [](double v) { return static_cast<std::int64_t>(v); };
  if (global_) {
    ++st_.global_subits;
    for (double& f : fine_)
      ++f;
  } else {
    for (const std::uint32_t i : ln_.busy) {
      if (i >= owned_)
        break;
      ++fine_[i];
    }
  }
  if (!rank_) // an island spanning ranks has no whole size on any rank: R ranks count none
    count_island_sizes();
  st_.particle_steps += count(t.particle_steps), st_.pair_evaluations += count(t.pairs);
  st_.overlap_violations += count(t.overlaps), st_.bound_violations += count(t.bound_violations);
  st_.local_particle_steps += t.local_steps, st_.local_pair_evaluations += t.local_pairs;
  const std::int64_t spanning = count(t.span_members);
  st_.span_subits += spanning > 0, st_.span_particles += spanning;
  st_.span_parts += count(t.span_parts);
  const std::int64_t fine = count(t.fine_members);
  const auto n = static_cast<double>(n_global_);
  st_.last_fine_fraction = n_global_ > 0 ? static_cast<double>(fine) / n : 0.0;
  // The members' steps less the leads alone (what the fine particles cost).
  st_.last_fine_work =
      n_global_ > 0 ? static_cast<double>(count(t.lead_steps)) / (static_cast<double>(steps_.K) * n)
                    : 0.0;
  st_.add_interval(fine, n_global_, steps_.K);
  note_overlap_ratio(t.max_ratio, record);
  age_list(t.bound_violations > 0.0);
  ++st_.subits;
}

// Island sizes (one rank): bin b counts the islands of 2^(b-1) < size <= 2^b members, bin 0 the
// lone particles; the dense mode is one island of everyone.
void IslandsScheme::count_island_sizes() {
  const std::size_t n = p_.size();
  if (n == 0)
    return; // every particle left (an outflow face): no island, and bit_width(n - 1) is 64
  if (global_) {
    st_.size_hist[static_cast<std::size_t>(std::bit_width(static_cast<std::uint64_t>(n) - 1))] += 1;
    return;
  }
  const std::uint32_t nc = ln_.islands.count();
  for (std::uint32_t c = 0; c < nc; ++c)
    ++st_.size_hist[static_cast<std::size_t>(std::bit_width(ln_.islands.size(c) - 1))];
  st_.size_hist[0] += static_cast<std::int64_t>(n - ln_.busy.size());
}

// One rank: a bound on every particle's displacement since the list's build (list_expires):
// each stayed within its bound (members checked, free flight by construction), each bound at
// most bound_max, up to the margin; unknown after a violation or explicit steps. R ranks measure
// their rows' reach instead.
void IslandsScheme::age_list(bool violated) {
  if (rank_)
    return;
  one_.moved = global_ || violated ? std::numeric_limits<double>::infinity()
                                   : one_.moved + (one_.bound_max * dt_sp_ + margin_);
}

// One step of dt_sp for every owned particle not in a fine island: no contact can act on it. The
// busy particles (ln_.busy, increasing) split the store into runs of free particles; each run
// is one branch-free loop (no per-particle island test or select: the runs hold ~99% of a
// dilute store): the explicit scheme's kick-drift with no contact force (islands::free_flight).
// Faults (NaN, or a particle outside a wall) are flagged in the same pass (sign bit of the
// result); find_fault() names the particle only when one is flagged.
template <bool External, bool Record, bool Walls> void IslandsScheme::free_flight() {
  const std::size_t n = owned_;
  // The view and the wall bounds once per pass: a store may hold many short runs.
  const islands::Columns c = cols();
  const std::array<std::span<double>, 3> sv = {rec_.vx, rec_.vy, rec_.vz};
  const WallBounds wb(geom_);
  // Runs of free particles in [b, e): between the busy particles that fall in it.
  auto range = [&](std::size_t b, std::size_t e) {
    std::uint64_t bad = 0;
    auto q = std::lower_bound(ln_.busy.begin(), ln_.busy.end(), static_cast<std::uint32_t>(b));
    for (std::size_t i = b; i < e;) {
      const std::size_t stop = q != ln_.busy.end() ? std::min<std::size_t>(e, *q) : e;
      if (stop > i)
        bad |= islands::free_flight<External, Record, Walls>(c, i, stop, sv, model_.gravity, dt_sp_,
                                                             wb);
      i = stop + 1; // past the busy particle (or past e)
      if (q != ln_.busy.end())
        ++q;
    }
    return bad;
  };
  std::uint64_t bad = 0;
  if (n <= 4096) {
    bad = range(0, n); // small: no task overhead
  } else {
    constexpr std::size_t kBlock = 2048;
    std::vector<std::uint64_t> flags((n + kBlock - 1) / kBlock, 0);
    for_particle_blocks(flags.size(), [&](std::size_t k) {
      flags[k] = range(k * kBlock, std::min(n, (k + 1) * kBlock));
    });
    for (std::uint64_t f : flags)
      bad |= f;
  }
  fault_flag_ |= bad;
}

} // namespace cfddem::dem
