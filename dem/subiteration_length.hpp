// The islands scheme's sub-iteration length under dem.nsubit = "auto": the number m of
// sub-iterations per control interval D (dem.regrid_interval without a gas, fluid.dt with one),
// dt_sp = D / m, chosen at the end of every interval for the next one from counts only (never
// from clocks: the choice, and hence the run, is the same on a rerun, after a restart and for any
// thread count).
//
// The cost of an interval in m sub-iterations is modelled in instructions:
//   C(m) = m [c_o N + c_f a rho B(D/m)] + c_f W,
// N the particles, B(dt) those in an island over a sub-iteration of dt, c_o the per-particle
// bookkeeping of a sub-iteration (speed bound, list check, link scan, free flight), c_f one fine
// particle step with its pairs. An island folds the steps before its first contact and after its
// last one into single steps (islands_kernels.hpp, step_island), so a member costs about a =
// kFreeSteps steps besides the contact steps W, and W, the steps during which a contact acts in
// an island, does not depend on the length (on HCS 1222 at m = 3 .. 20, and on a 10% gas at m =
// 7 .. 25, the measured W changed by 1% and 10%, the nominal steps by 3.7x and 2x): the choice
// needs only the first bracket. B(dt) is counted from the current state: a particle joins an
// island over dt when the link test
//   |x_j - x_i| - (r_i + r_j) < (s_i + s_j) dt + margin
// holds for some row partner (or its wall gap is below s_i dt + margin), i.e. when dt exceeds
// its first-contact time tau_i = min_j (gap_ij - margin) / (s_i + s_j) (the bounds the links
// took); tau_i <= 0 for a particle in contact. So B(D/m) counts the particles with m < D / tau_i,
// one histogram over m for every candidate at once (summed over ranks: every rank chooses alike).
// rho, the ratio of the members measured over the last interval to B at its length (clamped to
// [1/64, 64]), carries what the first-contact count misses (islands raised by their energy bound,
// which grows with the length). Where rho B passes kGlobalFraction of the particles, the
// sub-iteration steps everyone finely: an m whose rho B passes half of it (kSwitchMargin: the
// members fluctuate) is priced so. The chosen m minimises C(m) over [m_lo, m_hi]: m_hi keeps dt_sp
// at least the fine step (shorter gains nothing); m_lo keeps the fastest particle's reach 2 s_max
// dt_sp within half the list's skin (longer sub-iterations would rebuild the list every time, and
// rows beyond the skin are not counted), and with a gas the held force's change bound
// (gas_force_floor). The global mode (every particle on the fine step for the whole interval) is
// weighed against the islands' nominal work, every member on every step after its lead, which is
// what a dense gas pays, where some contact acts in every island at every step. Every count here is
// the same on any rank count (members and nominal steps; the steps an R-rank island spanning ranks
// takes are not).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "dem/domain_geometry.hpp"

namespace cfddem::dem::length {

// Instructions per particle per sub-iteration (speed bound, list check, link scan, free flight)
// and per fine particle step (its force pairs and update), from callgrind on HCS 1222 (islands,
// 3 ms at nsubit 5, 20 and 80; docs/schemes.md): 89 and 270-310.
inline constexpr double kPerParticle = 90.0;
inline constexpr double kPerFineStep = 280.0;
// Instructions per row entry per sub-iteration: the link rounds test every entry of the rows
// (with the island sums and the incremental rounds). From callgrind on a phi 0.3 gas (600
// particles, 12.5 entries per particle, islands auto, 3 ms): link() 1.38e9 instructions over
// about 4,000 sub-iterations of 7,476 entries, 46 per entry; on HCS 1222 (0.36 entries per
// particle) the term is small and kPerParticle holds the rest.
inline constexpr double kPerEntry = 45.0;
// Instructions per particle step of the global mode (every particle on the fine step, through
// the explicit scheme's passes: dem/verlet_passes.hpp), and per pair of its list (each pair
// once), from callgrind on the explicit scheme, whose passes these are: HCS 1222 (0.078 pairs
// per particle, 41 per particle step) and a phi 0.3 gas (600 particles, 2.45 pairs per
// particle, 122 per particle step), list builds included.
inline constexpr double kGlobalPerStep = 38.0;
inline constexpr double kGlobalPerPair = 34.0;
// The global mode's passes also retire more instructions per second than the islands' steps
// (a stream over a half list and a vectorized update, against scattered rows in small tasks): on
// a phi 0.3 gas (5000 particles, 3 ms, 1 thread) every sub-iteration global (nsubit 1) took
// 11.49e9 instructions in 1.02-1.08 s, the islands at nsubit 33 12.41e9 in 1.50-2.16 s, 1.4-1.9x
// fewer per second. The model counts in the islands' instructions: the global mode's count is
// divided by this rate.
inline constexpr double kGlobalRate = 1.5;
// With a gas: the held force's change over one sub-iteration, at the rate it changed over the
// last fluid step, at most this fraction of the largest held acceleration (or |g|).
inline constexpr double kGasChangeBound = 0.1;
// Above this fraction of particles linked or tied, a sub-iteration steps everyone finely (the
// islands scheme's switch, IslandsScheme::kGlobalFraction).
inline constexpr double kGlobalFraction = 0.25;
// The steps a member takes besides its island's contact steps: the lead folded into one, the
// stretch after the last contact folded into one, and the sub-iteration's last fine step
// (measured: 2.9 per member and sub-iteration on HCS 1222 at nsubit 3 .. 20 and on a 10% gas at
// 7 .. 25).
inline constexpr double kFreeSteps = 3.0;
// The members fluctuate from one sub-iteration to the next, and one in which they pass
// kGlobalFraction steps every particle finely (on a 10% gas chosen at an expected 23% of the
// particles, 8 of 150 sub-iterations did, and tripled the force evaluations). The model keeps
// the expected members below this fraction of the switch.
inline constexpr double kSwitchMargin = 0.5;

// The rows and columns the first-contact scan reads: rows of particles [0, n) (both directions:
// each row holds every partner), positions, radii, speed bounds of rows' particles and partners.
struct RowsView {
  std::span<const std::uint32_t> offsets, neighbors;
  const double *x, *y, *z, *radius, *bound;
  std::size_t n;
};

// Adds to hist[c] (size m_hi + 1) each particle of [0, n) with c >= 1 candidates m in
// [1, m_hi] for which it is fine (m < D / tau_i; c = m_hi when tau_i <= 0). Pairs use the
// minimum image; walls of non-periodic axes count.
void first_contact_histogram(const RowsView& v, const DomainGeometry& g, double margin, double D,
                             std::int64_t m_hi, std::span<std::int64_t> hist);

// What the choice saw and why it took its m (one row of run.json's nsubit_choices).
struct Choice {
  std::int64_t m = 1, m_lo = 1, m_hi = 1;
  double busy_estimate = 0.0; // rho B(D / m): the members
  double rho = 1.0;           // Rho::members
  double cost_ratio = 1.0;    // C(m) / C(m_previous): the gain predicted for the change
  int reason = 0;             // Reason
  // The global mode for the next interval: one sub-iteration of D (m = 1) in which every
  // particle takes the fine steps, with no speed bounds or links (reason kGlobal, or kKept).
  bool global = false;
};
enum Reason : int {
  kStart = 0,   // the first interval: dem.nsubit's integer default
  kMinCost = 1, // the model's least cost within [m_lo, m_hi]
  kSkin = 2,    // the least cost lies below m_lo set by the skin
  kGas = 3,     // ... set by the gas force's change bound
  kFine = 4,    // ... above m_hi: dt_sp is the fine step
  kKept = 5,    // the previous m: the best saves less than kMinGain
  kGlobal = 6,  // the global mode costs less than any m
};
// The weight of the newest interval in the running means of the first-contact histogram and of
// the fine counts (about the last 1 / kSmoothing intervals count: a dilute scene has ~10 fine
// particles per sub-iteration, too few for one interval's count to choose by).
inline constexpr double kSmoothing = 0.125;
// The modelled saving below which the previous m is kept.
inline constexpr double kMinGain = 0.1;
// The first-contact histogram walks every row (on HCS 1222 about 1.7 sub-iterations'
// bookkeeping): it is counted at the end of an interval once about this many sub-iterations have
// passed since the last count: at every interval for m >= kCountSpacing (and in the global
// mode), else every ceil(kCountSpacing / m) intervals; the choices in between use its running
// mean and the members measured since.
inline constexpr std::int64_t kCountSpacing = 8;
// Whether the interval numbered `intervals` (from 1) in m sub-iterations ends with a count.
inline bool counts_after(std::int64_t intervals, std::int64_t m, bool global) {
  const std::int64_t every = global || m >= kCountSpacing ? 1 : (kCountSpacing + m - 1) / m;
  return intervals % every == 0;
}
const char* reason_text(int r);

// The measured over the modelled fine count: members (particles in an island per
// sub-iteration) and nominal (member steps after the leads, over K) against B at the length
// they were measured at.
struct Rho {
  double members = 1.0, nominal = 1.0;
  // The members measured per sub-iteration over the last interval, at `at` sub-iterations per
  // interval (0: none). Where they passed the margin below the global switch, every m <= at is
  // priced as stepping everyone (members never fall with a longer sub-iteration) and a shorter m
  // holds at least measured x at / m of them (in proportion to its length, as in a dilute gas):
  // the first-contact count can miss an island's growth by far (a settling bed whose particles
  // were apart a moment ago).
  double measured = 0.0;
  std::int64_t at = 0;
};
// The least-cost m in [m_lo, m_hi] (the smallest m among equals; m_prev kept unless the best
// saves kMinGain of its cost) from hist (first_contact_histogram over all particles, or a running
// mean of it), N particles, D, the fine step, rho, the previous m and which bound set m_lo (kSkin
// or kGas); entries: the rows' entries the link rounds scan per sub-iteration (row_entries()).
// The cost of an interval in m sub-iterations, its contact steps left out:
//   C(m) = m [kPerParticle N + kPerEntry entries + kPerFineStep kFreeSteps rho.members B(D / m)],
// or, where rho.members B(D / m) > kSwitchMargin kGlobalFraction N, m [kPerParticle N + kPerEntry
// entries + c_g N K(D / m)] (everyone on the fine steps: c_g as below, or kPerFineStep without
// pairs). With pairs >= 0 (the global mode's list pairs per particle) the global mode is a
// candidate too:
//   C_g = K(D) N c_g, c_g = (kGlobalPerStep + kGlobalPerPair pairs) / kGlobalRate,
// taken where it costs less than the islands' nominal work at its best,
//   m [kPerParticle N + kPerEntry entries + kPerFineStep rho.nominal B(D / m) K(D / m)]
// (a dense gas, where nearly everyone is in an island and the islands' bookkeeping costs more
// than it saves); prev_global: the previous interval ran in it (it is then the one kept).
Choice choose(std::span<const double> hist, double N, double D, double dt_fine, Rho rho,
              std::int64_t m_lo, std::int64_t m_hi, std::int64_t m_prev, int lo_reason,
              double entries = 0.0, double pairs = -1.0, bool prev_global = false);

// The rows' entries of N equal spheres of radius r in a volume V with a list skin s: each row
// holds the partners within 2 r + s, N / V (4/3) pi (2 r + s)^3 of them. An estimate from global
// quantities, so that every rank count takes the same choice (the rows themselves differ: R
// ranks grow their skin); with several sizes r is the smallest, and it undercounts.
double row_entries(double N, double V, double r, double s);

// m_hi: the most sub-iterations whose dt_sp = D / m is still at least the fine step (>= 1).
std::int64_t most_subiterations(double D, double dt_fine);
// An adaptive fluid.dt: a length dt_sp chosen for one interval taken over another of length A,
// as the fewest sub-iterations that keep dt_sp or shorter (A / m <= dt_sp), within
// 1 .. most_subiterations(A, dt_fine).
std::int64_t subiterations_over(double A, double dt_sp, double dt_fine);
// The fewest sub-iterations with 2 s_max D / m <= skin / 2 (>= 1).
std::int64_t fewest_for_skin(double D, double s_max, double skin);
// The fewest with the gas force's change bound: dA D / m / D <= kGasChangeBound a_ref, i.e.
// m >= dA / (kGasChangeBound a_ref) (dA: the largest change of a held acceleration over the
// last fluid step; a_ref: the largest held acceleration or |g|). 1 without a change.
std::int64_t fewest_for_gas(double dA, double a_ref);

} // namespace cfddem::dem::length
