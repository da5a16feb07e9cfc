#include "core/scene_keys.hpp"

#include <algorithm>
#include <vector>

#include <fmt/format.h>

namespace cfddem {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

constexpr KeyRange above(double lo) {
  return {lo, kInf, true, false};
}
constexpr KeyRange at_least(double lo) {
  return {lo, kInf, false, false};
}
constexpr KeyRange closed(double lo, double hi) {
  return {lo, hi, false, false};
}
constexpr KeyRange open(double lo, double hi) {
  return {lo, hi, true, true};
}
constexpr KeyRange above_up_to(double lo, double hi) {
  return {lo, hi, true, false};
}
constexpr KeyRange at_least_below(double lo, double hi) {
  return {lo, hi, false, true};
}

KeyDefault required(std::string_view when = "") {
  return {KeyDefault::Kind::Required, {}, when};
}
KeyDefault number(double v, std::string_view shown = "") {
  return {KeyDefault::Kind::Value, v, shown};
}
KeyDefault integer(std::int64_t v, std::string_view shown = "") {
  return {KeyDefault::Kind::Value, v, shown};
}
KeyDefault flag(bool v) {
  return {KeyDefault::Kind::Value, v, ""};
}
KeyDefault word(std::string_view v, std::string_view shown = "") {
  return {KeyDefault::Kind::Value, v, shown};
}
KeyDefault vec(double x, double y, double z, std::string_view shown = "") {
  return {KeyDefault::Kind::Value, std::array<double, 3>{x, y, z}, shown};
}
KeyDefault flags(bool x, bool y, bool z) {
  return {KeyDefault::Kind::Value, std::array<bool, 3>{x, y, z}, ""};
}
KeyDefault same_as(std::string_view key) {
  return {KeyDefault::Kind::SameAs, {}, key};
}
KeyDefault derived(std::string_view how) {
  return {KeyDefault::Kind::Derived, {}, how};
}

constexpr std::string_view kPlacements[] = {"random", "lattice"};
constexpr std::string_view kParticleOutflow[] = {"remove", "wall"};
constexpr std::string_view kDistributions[] = {"uniform", "normal", "lognormal"};
constexpr std::string_view kSchemes[] = {"explicit", "orb", "islands"};
constexpr std::string_view kProfileAxes[] = {"none", "x", "y", "z"};
constexpr std::string_view kShapes[] = {"box", "cylinder"};
constexpr std::string_view kAxes[] = {"x", "y", "z"};
constexpr std::string_view kLocalDt[] = {"proximity", "time_to_contact"};
constexpr std::string_view kWeights[] = {"count", "cost"};
constexpr std::string_view kDrags[] = {"bvk", "bvk2", "koch_hill", "wen_yu", "none"};
constexpr std::string_view kCouplings[] = {"two_way", "one_way"};
constexpr std::string_view kKernels[] = {"trilinear", "dpvm", "dpvm_cube", "dpvm_sphere"};
constexpr std::string_view kBoundaries[] = {"periodic", "wall", "inflow", "outflow"};
constexpr std::string_view kPreconditioners[] = {"pfmg", "smg"};
constexpr std::string_view kSolvers[] = {"multigrid", "hypre", "auto"};
constexpr std::string_view kAdvections[] = {"godunov", "mol"};
constexpr std::string_view kViscousSteps[] = {"solve", "factored"};

using T = KeyType;
using S = KeySection;

// The six faces' gas boundaries differ only in name.
SceneKey gas_boundary(std::string_view name) {
  return {.name = name,
          .type = T::String,
          .section = S::Fluid,
          .choices = kBoundaries,
          .fallback = derived("`\"periodic\"` on periodic axes, else `\"wall\"` (no-slip)"),
          .meaning = "gas boundary per face; must agree with `domain.periodic` (periodic exactly "
                     "on periodic axes)"};
}

std::vector<SceneKey> make_table() {
  return {
      // Domain and particles.
      {.name = "name",
       .type = T::String,
       .section = S::DomainParticles,
       .fallback = derived("the scene file's stem (`hcs` for the built-in scene)"),
       .meaning = "run name; outputs go to `runs/<name>` unless `--out` says otherwise; a plain "
                  "name (no `/` or `\\`, no control characters, not `.` or `..`)"},
      {.name = "domain.lo",
       .type = T::Vec3,
       .section = S::DomainParticles,
       .unit = "m",
       .fallback = required(),
       .meaning = "corners of the box; `domain.hi` must exceed `domain.lo` on every axis"},
      {.name = "domain.hi",
       .type = T::Vec3,
       .section = S::DomainParticles,
       .unit = "m",
       .fallback = required(),
       .meaning = "corners of the box; `domain.hi` must exceed `domain.lo` on every axis"},
      {.name = "domain.periodic",
       .type = T::Bool3,
       .section = S::DomainParticles,
       .fallback = flags(true, true, true),
       .meaning = "a non-periodic axis has flat walls at `lo` and `hi`"},
      {.name = "domain.shape",
       .type = T::String,
       .section = S::DomainParticles,
       .choices = kShapes,
       .fallback = word("box"),
       .meaning = "`\"box\"`: the walls of `domain.periodic` alone; `\"cylinder\"`: also a "
                  "curved wall, an axis-aligned circular column inside the box that the particles "
                  "feel with the planar walls' contact law ([theory.md](theory.md) §11); its two "
                  "cross axes must be walled, its own axis may be periodic. With a `[fluid]` "
                  "table the gas sees the column as a staircase of solid cells (theory.md §13; "
                  "at least 4 cells across the diameter, `fluid.solver` not `\"hypre\"`)"},
      {.name = "domain.cylinder_axis",
       .type = T::String,
       .section = S::DomainParticles,
       .choices = kAxes,
       .fallback = word("y"),
       .meaning = "`domain.shape = \"cylinder\"`: the axis the column runs along (our scenes' "
                  "flow and gravity axis is y); the column is centred on the box's other two "
                  "axes"},
      {.name = "domain.cylinder_radius",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = derived("half the smaller of the box's two widths across the axis"),
       .meaning = "`domain.shape = \"cylinder\"`: the column's radius R; at most that default "
                  "(the column lies inside the box)"},
      {.name = "gravity",
       .type = T::Vec3,
       .section = S::DomainParticles,
       .unit = "m/s^2",
       .fallback = vec(0, 0, 0),
       .meaning = "body acceleration"},
      {.name = "particles.file",
       .type = T::String,
       .section = S::DomainParticles,
       .fallback = word("", "none (the generator)"),
       .meaning = "CSV with the header `x,y,z,vx,vy,vz,diameter,density` (SI units; columns in "
                  "any order, CRLF line ends and a UTF-8 byte-order mark accepted); a path in "
                  "the scene is relative to the scene file, one on the command line to the "
                  "working directory. Cannot be combined with the generator keys (those marked "
                  "\"generator\")"},
      {.name = "particles.count",
       .type = T::Integer,
       .section = S::DomainParticles,
       .range = at_least(0),
       .fallback = integer(0),
       .meaning = "generator: number of particles"},
      {.name = "particles.diameter",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = required("without `particles.file` or a distribution"),
       .meaning = "generator: one diameter for every particle (must fit in the domain); or a "
                  "size distribution, the table `particles.diameter = { distribution, mean, "
                  "std, min, max }` below"},
      {.name = "particles.diameter.distribution",
       .type = T::String,
       .section = S::DomainParticles,
       .choices = kDistributions,
       .fallback = derived("none (one size)"),
       .meaning = "generator: diameters drawn from this distribution, truncated to [min, max] by "
                  "redrawing (not clamping), in particle id order from their own seeded stream; "
                  "lognormal takes the diameter's own mean and std"},
      {.name = "particles.diameter.mean",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = required("for `\"normal\"` and `\"lognormal\"`"),
       .meaning = "generator, distribution: mean diameter (not with `\"uniform\"`, whose mean is "
                  "(min + max) / 2)"},
      {.name = "particles.diameter.std",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = required("for `\"normal\"` and `\"lognormal\"`"),
       .meaning = "generator, distribution: standard deviation of the diameter (not with "
                  "`\"uniform\"`)"},
      {.name = "particles.diameter.min",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = required("with a distribution"),
       .meaning = "generator, distribution: smallest diameter"},
      {.name = "particles.diameter.max",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = required("with a distribution"),
       .meaning = "generator, distribution: largest diameter (> min; the packing, cell sizes and "
                  "margins use it)"},
      {.name = "particles.density",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "kg/m^3",
       .range = above(0),
       .fallback = required("without `particles.file`"),
       .meaning = "generator: density"},
      {.name = "particles.temperature",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m^2/s^2",
       .range = at_least(0),
       .fallback = number(0),
       .meaning = "generator: granular temperature T0; Gaussian velocities, total momentum "
                  "removed, rescaled to T0 exactly"},
      {.name = "particles.velocity",
       .type = T::Vec3,
       .section = S::DomainParticles,
       .unit = "m/s",
       .fallback = vec(0, 0, 0),
       .meaning = "generator: mean velocity added to every particle"},
      {.name = "particles.placement",
       .type = T::String,
       .section = S::DomainParticles,
       .choices = kPlacements,
       .fallback = word("random"),
       .meaning = "generator: random non-overlapping positions (seeded), or a simple cubic "
                  "lattice filling the region (spacing at least the largest diameter), whose "
                  "sites are taken x fastest, then y, then z: fewer particles than sites leave "
                  "the last z slab part-filled"},
      {.name = "particles.region_lo",
       .type = T::Vec3,
       .section = S::DomainParticles,
       .unit = "m",
       .fallback = derived("the domain"),
       .meaning = "generator: the box the particles are placed in (non-empty, inside the "
                  "domain)"},
      {.name = "particles.region_hi",
       .type = T::Vec3,
       .section = S::DomainParticles,
       .unit = "m",
       .fallback = derived("the domain"),
       .meaning = "generator: the box the particles are placed in (non-empty, inside the "
                  "domain)"},
      {.name = "particles.seed",
       .type = T::Integer,
       .section = S::DomainParticles,
       .fallback = integer(1),
       .meaning = "seed of the generator's random numbers (positions, velocities); accepted "
                  "with `particles.file` too, where it has no effect"},
      {.name = "particles.allow_overlap",
       .type = T::Bool,
       .section = S::DomainParticles,
       .fallback = flag(false),
       .meaning = "accept initial particles that overlap each other or a wall (otherwise the "
                  "pair, or the particle and the wall, is named and the run refused); two "
                  "particles on the same centre are refused even so"},

      {.name = "particles.outflow",
       .type = T::String,
       .section = S::DomainParticles,
       .choices = kParticleOutflow,
       .fallback = word("remove"),
       .meaning = "particles at a face with fluid.bc = \"outflow\": taken out of the run at the "
                  "start of the fluid step in which they would reach the face (diagnostics.csv "
                  "counts their mass in mass_out), or held back by a wall as at any "
                  "other face (see [theory.md](theory.md) §12)"},

      {.name = "inlet.mass_rate",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "kg/s",
       .range = at_least(0),
       .fallback = number(0),
       .meaning = "particles entering the run through the inlet region: new particles of "
                  "`inlet.diameter` and `inlet.density` (by default `particles.diameter`, or its "
                  "distribution, and `particles.density`) at this mass rate, placed at random "
                  "where they fit; needs a gas (they enter at fluid-step boundaries; see "
                  "[theory.md](theory.md) §12)"},
      {.name = "inlet.recycle",
       .type = T::Bool,
       .section = S::DomainParticles,
       .fallback = flag(false),
       .meaning = "the particles that leave through an outflow face enter again through the inlet "
                  "region (same size and mass, a new id), as in a circulating bed; with "
                  "`inlet.mass_rate` both feed the inlet"},
      {.name = "inlet.region_lo",
       .type = T::Vec3,
       .section = S::DomainParticles,
       .unit = "m",
       .fallback = derived("required with an inlet"),
       .meaning = "the box the entering particles' centres are placed in (non-empty, inside the "
                  "domain)"},
      {.name = "inlet.region_hi",
       .type = T::Vec3,
       .section = S::DomainParticles,
       .unit = "m",
       .fallback = derived("required with an inlet"),
       .meaning = "the box the entering particles' centres are placed in (non-empty, inside the "
                  "domain)"},
      {.name = "inlet.velocity",
       .type = T::Vec3,
       .section = S::DomainParticles,
       .unit = "m/s",
       .fallback = vec(0, 0, 0),
       .meaning = "velocity of an entering particle"},
      {.name = "inlet.diameter",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = derived("the particles' size distribution"),
       .meaning = "inlet.mass_rate: the new particles' diameter (one size), or a size "
                  "distribution of their own, the table `inlet.diameter = { distribution, mean, "
                  "std, min, max }` below; the scene's particles keep theirs"},
      {.name = "inlet.diameter.distribution",
       .type = T::String,
       .section = S::DomainParticles,
       .choices = kDistributions,
       .fallback = derived("none (one size)"),
       .meaning = "inlet.mass_rate: the new particles' diameters drawn from this distribution, "
                  "as `particles.diameter.distribution` draws them (each from its own stream, "
                  "seeded by `inlet.seed` and the particle's serial number)"},
      {.name = "inlet.diameter.mean",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = required("for `\"normal\"` and `\"lognormal\"`"),
       .meaning = "inlet distribution: mean diameter (not with `\"uniform\"`)"},
      {.name = "inlet.diameter.std",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = required("for `\"normal\"` and `\"lognormal\"`"),
       .meaning = "inlet distribution: standard deviation of the diameter (not with "
                  "`\"uniform\"`)"},
      {.name = "inlet.diameter.min",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = required("with an inlet distribution"),
       .meaning = "inlet distribution: smallest diameter"},
      {.name = "inlet.diameter.max",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "m",
       .range = above(0),
       .fallback = required("with an inlet distribution"),
       .meaning = "inlet distribution: largest diameter (> min; the step and cut-offs use it)"},
      {.name = "inlet.density",
       .type = T::Number,
       .section = S::DomainParticles,
       .unit = "kg/m^3",
       .range = above(0),
       .fallback = derived("particles.density"),
       .meaning = "inlet.mass_rate: the new particles' density"},
      {.name = "inlet.seed",
       .type = T::Integer,
       .section = S::DomainParticles,
       .fallback = integer(1),
       .meaning = "seed of the inlet's positions and diameters (a run is bitwise reproducible "
                  "for a given seed, thread and rank count, and across restarts)"},

      // Contacts and time step.
      {.name = "dem.scheme",
       .type = T::String,
       .section = S::Contacts,
       .choices = kSchemes,
       .fallback = word("explicit"),
       .meaning = "how particles are stepped: one global step; the paper's adaptive steps per "
                  "ORB leaf; adaptive steps per contact island (see [schemes.md](schemes.md))"},
      {.name = "dem.spring_constant",
       .type = T::Number,
       .section = S::Contacts,
       .unit = "N/m",
       .range = above(0),
       .fallback = required(),
       .meaning = "normal spring k_n ([theory.md](theory.md) §2.1)"},
      {.name = "dem.restitution",
       .type = T::Number,
       .section = S::Contacts,
       .range = closed(0, 1),
       .fallback = required(),
       .meaning = "restitution coefficient e; sets the dashpot (§2.2)"},
      {.name = "dem.friction",
       .type = T::Number,
       .section = S::Contacts,
       .range = at_least(0),
       .fallback = number(0),
       .meaning = "Coulomb coefficient mu; 0 is frictionless and allocates no rotation fields. "
                  "explicit, orb and islands support friction on any rank count"},
      {.name = "dem.tangential_stiffness_ratio",
       .type = T::Number,
       .section = S::Contacts,
       .range = above(0),
       .fallback = number(2.0 / 7.0, "2/7"),
       .meaning = "k_t / k_n (§2.3)"},
      {.name = "dem.tangential_damping_ratio",
       .type = T::Number,
       .section = S::Contacts,
       .range = at_least(0),
       .fallback = number(0.5),
       .meaning = "eta_t / eta_n (§2.3)"},
      {.name = "dem.wall_spring_constant",
       .type = T::Number,
       .section = S::Contacts,
       .unit = "N/m",
       .range = above(0),
       .fallback = same_as("dem.spring_constant"),
       .meaning = "walls' normal spring"},
      {.name = "dem.wall_restitution",
       .type = T::Number,
       .section = S::Contacts,
       .range = closed(0, 1),
       .fallback = same_as("dem.restitution"),
       .meaning = "walls' restitution"},
      {.name = "dem.wall_friction",
       .type = T::Number,
       .section = S::Contacts,
       .range = at_least(0),
       .fallback = same_as("dem.friction"),
       .meaning = "walls' Coulomb coefficient"},
      {.name = "dem.dt_factor",
       .type = T::Number,
       .section = S::Contacts,
       .range = above(0),
       .fallback = number(0.02),
       .meaning = "dt = tau_p x dt_factor, tau_p = sqrt(m / k) for the lightest particle and "
                  "stiffest spring (0.02 = tau_p/50, the paper's step)"},
      {.name = "dem.dt",
       .type = T::Number,
       .section = S::Contacts,
       .unit = "s",
       .range = at_least(0),
       .fallback = number(0, "0 (use `dem.dt_factor`)"),
       .meaning = "a fixed step, overriding `dem.dt_factor` (as LAMMPS's `timestep`); 0 = use "
                  "`dem.dt_factor`"},
      {.name = "dem.neighbor_skin",
       .type = T::Number,
       .section = S::Contacts,
       .unit = "m",
       .range = above(0),
       .fallback = derived("a quarter of the largest diameter (islands: chosen at each list's "
                           "expiry on one rank, from three times that)"),
       .meaning = "Verlet-list skin; lists are rebuilt when a particle has moved more than half "
                  "of it"},
      {.name = "dem.max_overlap",
       .type = T::Number,
       .section = S::Contacts,
       .range = open(0, 1),
       .fallback = number(0.3),
       .meaning = "an overlap beyond this fraction of the smaller radius stops the explicit "
                  "scheme (exit code 3); orb and islands count it and report it in run.json"},
      {.name = "dem.nsubit",
       .type = T::Integer,
       .section = S::Contacts,
       .range = at_least(1),
       .fallback = integer(10, "10 (islands: \"auto\")"),
       .meaning = "orb and islands: sub-iterations per regrid interval, dt_sp = "
                  "`dem.regrid_interval` / nsubit (with a gas: the fluid step / nsubit, fixed or "
                  "adaptive); islands "
                  "also take \"auto\", their default: the scheme picks nsubit at the end of "
                  "every interval from operation counts (starting at 10; docs/schemes.md), "
                  "or the global mode (everyone on the fine step, the explicit scheme's passes) "
                  "where that costs less, each choice in run.json"},
      {.name = "dem.proximity_radii",
       .type = T::Number,
       .section = S::Contacts,
       .range = above(0),
       .fallback = number(3),
       .meaning = "orb, proximity rule: a leaf steps finely if a pair's centre distance is below "
                  "this many radii ((r_i + r_j)/2 each), or a wall is that close"},
      {.name = "dem.local_dt",
       .type = T::String,
       .section = S::Contacts,
       .choices = kLocalDt,
       .fallback = word("proximity"),
       .meaning = "orb: how a leaf picks its step (§8): a partner or wall within "
                  "`dem.proximity_radii`, or a gap that could close within dt_sp"},
      {.name = "dem.orb_global",
       .type = T::Bool,
       .section = S::Contacts,
       .fallback = flag(true),
       .meaning = "orb, no friction: a sub-iteration in which the leaves that would step "
                  "finely hold more than 3/4 of the particles (over all ranks) runs as global "
                  "steps (every particle on the fine step through the explicit scheme's passes, "
                  "no frozen partners; docs/schemes.md; on R ranks also "
                  "`dem.orb_global_min_per_rank`); false: always the paper's leaf steps (bit for "
                  "bit the same on any rank count)"},
      {.name = "dem.orb_global_min_per_rank",
       .type = T::Integer,
       .section = S::Contacts,
       .range = at_least(0),
       .fallback = integer(10000),
       .meaning = "orb on R > 1 ranks: the global mode also needs at least this many particles "
                  "per rank (the total over R): its ghosts are refreshed before every fine "
                  "step, a wait between the ranks that the leaf steps take once per "
                  "sub-iteration, and that only enough particles per rank repay "
                  "(docs/schemes.md); 0: as one rank"},
      {.name = "dem.regrid_interval",
       .type = T::Number,
       .section = S::Contacts,
       .unit = "s",
       .range = above(0),
       .fallback = number(1e-4, "1e-4"),
       .meaning = "orb and islands: the paper's dt_f, simulated time between ORB rebuilds (with "
                  "a gas it is the fluid step); explicit on R > 1 ranks: the decomposition is "
                  "rebuilt at the first neighbour rebuild after this long"},

      // Partition (ORB, ranks).
      {.name = "partition.orb_levels",
       .type = T::Integer,
       .section = S::Partition,
       .range = closed(0, 20),
       .fallback = integer(4),
       .meaning = "orb: 2^levels leaves (on R ranks the leaves are dealt to ranks; with R > "
                  "2^levels some own none); explicit and islands on R > 1 ranks: the number of "
                  "ORB boxes dealt to ranks, at least 2^(ceil(log2 R) + 2)"},
      {.name = "partition.weights",
       .type = T::String,
       .section = S::Partition,
       .choices = kWeights,
       .fallback = word("count"),
       .meaning = "orb: ORB weights, every particle 1, or the local steps its leaf took since "
                  "the last regrid"},
      {.name = "partition.gas_regrid_interval",
       .type = T::Number,
       .section = S::Partition,
       .unit = "s",
       .range = at_least(0),
       .fallback = number(0, "0 (never)"),
       .meaning = "a gas on R ranks: simulated time between recuts of the gas boxes by a "
                  "weighted ORB (cells and particles move to their new owners); 0: never"},
      {.name = "partition.cell_weight",
       .type = T::Number,
       .section = S::Partition,
       .range = at_least(0),
       .fallback = number(400),
       .meaning = "gas regrids: a cell's weight in particle steps per fluid step (measured on "
                  "`hcs_gas`: one fluid cell step costs about 400 particle steps)"},

      // Run and output.
      {.name = "run.end_time",
       .type = T::Number,
       .section = S::RunOutput,
       .unit = "s",
       .range = above(0),
       .fallback = required(),
       .meaning = "simulated time to run to"},
      {.name = "output.interval",
       .type = T::Number,
       .section = S::RunOutput,
       .unit = "s",
       .range = above(0),
       .fallback = derived("`run.end_time` / 100"),
       .meaning = "simulated time between rows of `diagnostics.csv`"},
      {.name = "output.progress_seconds",
       .type = T::Number,
       .section = S::RunOutput,
       .unit = "s",
       .range = above(0),
       .fallback = number(2),
       .meaning = "wall time between progress lines (on stderr; set-up, between fluid steps, "
                  "and within a fluid step of many gas sub-steps)"},
      {.name = "output.snapshot_interval",
       .type = T::Number,
       .section = S::RunOutput,
       .unit = "s",
       .range = at_least(0),
       .fallback = number(0, "0 (none)"),
       .meaning = "simulated time between HDF5 snapshots (particles, and with a gas the cells), "
                  "indexed by `snapshots.xmf`"},
      {.name = "output.checkpoint_interval",
       .type = T::Number,
       .section = S::RunOutput,
       .unit = "s",
       .range = at_least(0),
       .fallback = number(0, "0 (none)"),
       .meaning = "simulated time between checkpoints `checkpoint_<step>.h5`; orb: rounded up to "
                  "whole regrid intervals; with a gas: at the first fluid-step boundary after "
                  "each multiple"},
      {.name = "output.profile_axis",
       .type = T::String,
       .section = S::RunOutput,
       .choices = kProfileAxes,
       .fallback = word("none"),
       .meaning = "write `profiles.csv` at every `output.interval`: the domain cut into "
                  "`output.profile_bins` equal slabs along this axis, per slab the solids "
                  "fraction, particle velocity and granular temperature, with a gas also eps_g, "
                  "gas velocity, pressure and slip ([outputs.md](outputs.md))"},
      {.name = "output.profile_bins",
       .type = T::Integer,
       .section = S::RunOutput,
       .range = closed(1, 65536),
       .fallback = integer(20),
       .meaning = "number of equal slabs along `output.profile_axis` (at most as many as a gas "
                  "may have cells along an axis: 2e9 slabs failed to allocate, 1e8 wrote for "
                  "minutes a row)"},
      {.name = "output.contact_census",
       .type = T::Bool,
       .section = S::RunOutput,
       .fallback = flag(false),
       .meaning = "take the contact census (contacts, overlaps, coordination numbers, collision "
                  "frequency) at every row of `diagnostics.csv` ([outputs.md](outputs.md)); it "
                  "costs a few explicit steps per row and on R ranks gathers the particles to "
                  "rank 0, so it is off unless asked for (`tools/trade.py` turns it on); off: its "
                  "columns are not written"},

      // Gas.
      {.name = "fluid.cells",
       .type = T::Int3,
       .section = S::Fluid,
       .range = closed(1, 65536),
       .fallback = required(),
       .meaning =
           "cells of the MAC grid per axis (at most 4e9 in all; a cell takes about 1.6 KB, and a "
           "grid beyond the machine's memory is refused)"},
      {.name = "fluid.cell_size",
       .type = T::Vec3,
       .section = S::Fluid,
       .unit = "m",
       .range = at_least(0),
       .fallback = vec(0, 0, 0, "[0, 0, 0] (domain / cells)"),
       .meaning = "cell size per axis, 0 = the domain's length / `fluid.cells`; must tile the "
                  "domain with `fluid.cells`"},
      {.name = "fluid.density",
       .type = T::Number,
       .section = S::Fluid,
       .unit = "kg/m^3",
       .range = above(0),
       .fallback = required(),
       .meaning = "rho_g"},
      {.name = "fluid.viscosity",
       .type = T::Number,
       .section = S::Fluid,
       .unit = "Pa s",
       .range = at_least(0),
       .fallback = required(),
       .meaning = "mu_g"},
      {.name = "fluid.dt",
       .type = T::Number,
       .section = S::Fluid,
       .unit = "s",
       .range = at_least(0),
       .fallback = number(0, "0 (adaptive)"),
       .meaning = "fixed coupling step dt_f (the paper: 1e-4); explicit particles take ceil(dt_f "
                  "/ dt) equal steps in it, orb and islands `dem.nsubit` sub-iterations of dt_f "
                  "/ nsubit; 0: the gas's adaptive step ([gas_step.md](gas_step.md)), which every "
                  "scheme takes (islands \"auto\" keep the sub-iteration length chosen for the "
                  "first fluid step). The drag is held over dt_f: twice the particles' shortest "
                  "drag time m / beta in still gas or more is refused, more than once warns "
                  "([hostile_input.md](hostile_input.md))"},
      {.name = "fluid.cfl",
       .type = T::Number,
       .section = S::Fluid,
       .range = above(0),
       .fallback = derived("0.9 with `fluid.advection` = \"godunov\", 0.4 with \"mol\""),
       .meaning = "Courant number of the gas sub-steps, and of dt_f when adaptive, as "
                  "[gas_step.md](gas_step.md) measures it for each `fluid.advection`; above its "
                  "stable limit (0.95 for Godunov, 0.5 for the method of lines) is refused when "
                  "the run starts"},
      {.name = "fluid.max_dt",
       .type = T::Number,
       .section = S::Fluid,
       .unit = "s",
       .range = above(0),
       .fallback = number(1e-3, "1e-3"),
       .meaning = "cap on the adaptive dt_f (with 1.1x growth per step, 0.1 of the smallest "
                  "drag time and the gas's Courant step with forcing; gas_step.md)"},
      {.name = "fluid.drag",
       .type = T::String,
       .section = S::Fluid,
       .choices = kDrags,
       .fallback = word("bvk"),
       .meaning = "drag law (§4)"},
      {.name = "fluid.coupling",
       .type = T::String,
       .section = S::Fluid,
       .choices = kCouplings,
       .fallback = word("two_way"),
       .meaning = "`\"two_way\"`: the gas feels the particles (their volume and the drag's "
                  "reaction); `\"one_way\"`: it does not (gas fraction 1, no reaction), while "
                  "the particles still feel the gas's drag and pressure force (§9)"},
      {.name = "fluid.deposition",
       .type = T::String,
       .section = S::Fluid,
       .choices = kKernels,
       .fallback = word("trilinear"),
       .meaning = "deposition and interpolation kernel (§7); `\"dpvm\"` and `\"dpvm_cube\"` are "
                  "the same kernel"},
      {.name = "fluid.deposition_width",
       .type = T::Number,
       .section = S::Fluid,
       .range = above_up_to(0, 100),
       .fallback = number(2),
       .meaning = "dpvm kernel width in particle diameters (at most 100: a kernel that wide over "
                  "cells of half a diameter already covers 8e6 cells per particle)"},
      gas_boundary("fluid.bc.x_lo"),
      gas_boundary("fluid.bc.x_hi"),
      gas_boundary("fluid.bc.y_lo"),
      gas_boundary("fluid.bc.y_hi"),
      gas_boundary("fluid.bc.z_lo"),
      gas_boundary("fluid.bc.z_hi"),
      {.name = "fluid.inflow_velocity",
       .type = T::Vec3,
       .section = S::Fluid,
       .unit = "m/s",
       .fallback = vec(0, 0, 0),
       .meaning = "gas velocity on inflow faces"},
      {.name = "fluid.outflow_pressure",
       .type = T::Number,
       .section = S::Fluid,
       .unit = "Pa",
       .fallback = number(0),
       .meaning = "p' on outflow faces"},
      {.name = "fluid.pressure_drop",
       .type = T::Vec3,
       .section = S::Fluid,
       .unit = "Pa",
       .fallback = vec(0, 0, 0),
       .meaning = "pressure drop across each periodic axis, over one period (MFIX's `delp`)"},
      {.name = "fluid.velocity",
       .type = T::Vec3,
       .section = S::Fluid,
       .unit = "m/s",
       .fallback = vec(0, 0, 0),
       .meaning = "initial gas velocity"},
      {.name = "fluid.implicit_viscosity",
       .type = T::Bool,
       .section = S::Fluid,
       .fallback = derived("\"auto\": chosen per fluid step"),
       .meaning = "the viscous Laplacian implicit: removes the viscous term from the gas step's "
                  "Courant limit (cells smaller than particles); solved by Chebyshev iteration "
                  "where the mass term dominates every row, else by multigrid-preconditioned CG "
                  "(one rank) or Jacobi CG (R ranks). Also takes \"auto\", the default: per "
                  "fluid step, implicit when the explicit viscous limit would need more than 1.6 "
                  "times the sub-steps (what the implicit solves cost; gas_step.md), the count "
                  "in run.json"},
      {.name = "fluid.viscous_step",
       .type = T::String,
       .section = S::Fluid,
       .choices = kViscousSteps,
       .fallback = word("factored"),
       .meaning = "how a gas step with the viscous Laplacian implicit takes it: \"factored\" (the "
                  "default), one step of the trapezoidal system's approximate factorization, "
                  "three sweeps of tridiagonal line solves along x, y and z (second order in "
                  "time; the viscous part of the fluidized bed's gas step about 2.3x cheaper; "
                  "on R ranks each box exchanges its lines' ends with the boxes that share "
                  "them); \"solve\", the system solved "
                  "to a relative residual of 1e-10 by Chebyshev iteration or CG (a checkpoint "
                  "written before this key restarts with \"solve\"). "
                  "[gas_step.md](gas_step.md) has the accuracy and cost of each"},
      {.name = "fluid.advection",
       .type = T::String,
       .section = S::Fluid,
       .choices = kAdvections,
       .fallback = word("godunov"),
       .meaning = "the gas step in time: \"godunov\", one stage whose advective fluxes come from "
                  "upwind edge states centred in time (MFIX-Exa's default; one projection, "
                  "second order, Courant number up to 0.95 on an axis); \"mol\", the method of "
                  "lines, Euler or Heun by `fluid.time_order` (a checkpoint written before this "
                  "key restarts with \"mol\"). [gas_step.md](gas_step.md) has the accuracy and "
                  "cost of each"},
      {.name = "fluid.time_order",
       .type = T::Integer,
       .section = S::Fluid,
       .range = closed(1, 2),
       .fallback = integer(2),
       .meaning = "with `fluid.advection` = \"mol\": 2, predictor-corrector (Heun; "
                  "`fluid.projections` says "
                  "how many of its stages are projected); 1, Euler (one projection, first order; "
                  "[gas_step.md](gas_step.md) has "
                  "its measured accuracy cost)"},
      {.name = "fluid.projections",
       .type = T::Integer,
       .section = S::Fluid,
       .range = closed(1, 2),
       .fallback = integer(1),
       .meaning = "pressure solves per gas step with `fluid.advection` = \"mol\" and "
                  "`fluid.time_order` = 2: 1, the predictor "
                  "takes the last step's pressure gradient and only the corrector is projected "
                  "(Bell, Colella & Glaz 1989; second order); 2, each stage projected (Heun as "
                  "before; a checkpoint written before this key restarts with 2). "
                  "[gas_step.md](gas_step.md) has the accuracy and cost of each"},
      {.name = "fluid.tolerance",
       .type = T::Number,
       .section = S::Fluid,
       .range = at_least_below(1e-12, 1),
       .fallback = number(1e-10, "1e-10"),
       .meaning = "relative residual of the projection's PCG (at least 1e-12: the residual's "
                  "round-off floor is near it, 8e-13 on `scenes/fluidized_bed.toml`, and a "
                  "solve that cannot reach its tolerance stops the run)"},
      {.name = "fluid.preconditioner",
       .type = T::String,
       .section = S::Fluid,
       .choices = kPreconditioners,
       .fallback = word("pfmg"),
       .meaning = "the projection's hypre preconditioner (\"smg\" is refused on a periodic axis "
                  "with an odd cell count, where hypre 2.26's SMG fails; there a PFMG solve that "
                  "misses the tolerance stops the run instead of falling back to SMG)"},
      {.name = "fluid.solver",
       .type = T::String,
       .section = S::Fluid,
       .choices = kSolvers,
       .fallback = word("auto"),
       .meaning = "the projection's solver: our geometric multigrid inside CG "
                  "([multigrid.md](multigrid.md); on R ranks its fine levels relax over the "
                  "ranks and a coarse level is gathered onto rank 0), hypre's PCG with "
                  "`fluid.preconditioner`, or `\"auto\"`: the multigrid (fewer instructions than "
                  "hypre on the riser on 1, 2 and 4 ranks), except on a grid whose odd or "
                  "short axes stop its coarsening above 32,768 cells while hypre's PFMG "
                  "coarsens it to at most 32,768 (PFMG stops at an odd period on any level): "
                  "there hypre"},
  };
}

// Optimal string alignment distance: edits, counting a swap of neighbours as one
// ("restitutoin" is one edit from "restitution").
std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::vector<std::size_t>> d(a.size() + 1, std::vector<std::size_t>(b.size() + 1));
  for (std::size_t i = 0; i <= a.size(); ++i)
    d[i][0] = i;
  for (std::size_t j = 0; j <= b.size(); ++j)
    d[0][j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i)
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t cost = a[i - 1] == b[j - 1] ? 0 : 1;
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + cost});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
    }
  return d[a.size()][b.size()];
}

std::string_view last_part(std::string_view key) {
  const auto dot = key.rfind('.');
  return dot == std::string_view::npos ? key : key.substr(dot + 1);
}

std::string number_text(double v) {
  return fmt::format("{}", v);
}

} // namespace

std::span<const SceneKey> scene_keys() {
  static const std::vector<SceneKey> table = make_table();
  return table;
}

const SceneKey* find_scene_key(std::string_view name) {
  for (const SceneKey& k : scene_keys())
    if (k.name == name)
      return &k;
  return nullptr;
}

std::string unknown_key_hint(std::string_view name) {
  // A section given a value ("dem = 3"): its keys cannot be read.
  const std::string prefix = std::string(name) + ".";
  for (const SceneKey& k : scene_keys())
    if (k.name.starts_with(prefix))
      return fmt::format("unknown key: '{}' is a table of keys ([{}] holding {} ...), not a "
                         "value",
                         name, name, k.name);
  // The nearest key: fewest edits, or the same last part in another section
  // ("particles.restitution" for "dem.restitution").
  const SceneKey* best = nullptr;
  std::size_t best_d = 0;
  for (const SceneKey& k : scene_keys()) {
    const std::size_t d = last_part(k.name) == last_part(name) ? 1 : edit_distance(name, k.name);
    if (best == nullptr || d < best_d)
      best = &k, best_d = d;
  }
  const std::size_t close = std::max<std::size_t>(2, name.size() / 4);
  if (best != nullptr && best_d <= close)
    return fmt::format("unknown key (did you mean '{}'? `cfddem keys` and docs/keys.md list the "
                       "keys)",
                       best->name);
  return "unknown key (check the spelling; `cfddem keys` and docs/keys.md list the keys)";
}

std::string toml_text(const KeyDefault::Value& v, bool shortest) {
  const auto num = [shortest](double x) {
    return shortest ? fmt::format("{}", x) : fmt::format("{:.17g}", x);
  };
  struct Visitor {
    decltype(num)& n;
    std::string operator()(std::monostate) const { return ""; }
    std::string operator()(double x) const { return n(x); }
    std::string operator()(std::int64_t x) const { return std::to_string(x); }
    std::string operator()(bool x) const { return x ? "true" : "false"; }
    std::string operator()(std::string_view x) const { return fmt::format("\"{}\"", x); }
    std::string operator()(const std::array<double, 3>& x) const {
      return fmt::format("[{}, {}, {}]", n(x[0]), n(x[1]), n(x[2]));
    }
    std::string operator()(const std::array<bool, 3>& x) const {
      return fmt::format("[{}, {}, {}]", x[0], x[1], x[2]);
    }
  };
  return std::visit(Visitor{num}, v);
}

std::string range_text(const SceneKey& key) {
  const KeyRange& r = key.range;
  const bool has_lo = std::isfinite(r.lo), has_hi = std::isfinite(r.hi);
  const bool whole = key.type == KeyType::Integer || key.type == KeyType::Int3;
  if (has_lo && has_hi) {
    if (whole && !r.lo_open && !r.hi_open)
      return fmt::format("{}..{}", number_text(r.lo), number_text(r.hi));
    return fmt::format("{}{}, {}{}", r.lo_open ? '(' : '[', number_text(r.lo), number_text(r.hi),
                       r.hi_open ? ')' : ']');
  }
  if (has_lo)
    return fmt::format("{} {}", r.lo_open ? ">" : ">=", number_text(r.lo));
  if (has_hi)
    return fmt::format("{} {}", r.hi_open ? "<" : "<=", number_text(r.hi));
  return "";
}

std::span<const std::string_view> restart_free_keys() {
  static constexpr std::string_view keys[] = {
      "name", "run.*", "output.*", "fluid.inflow_velocity", "fluid.velocity", "fluid.bc.*"};
  return keys;
}

bool restart_may_change(std::string_view key) {
  for (const std::string_view k : restart_free_keys())
    if (k.ends_with(".*") ? key.starts_with(k.substr(0, k.size() - 1)) : key == k)
      return true;
  return false;
}

std::string restart_free_keys_text(bool markdown) {
  const auto keys = restart_free_keys();
  std::string text;
  const char* q = markdown ? "`" : "";
  for (std::size_t i = 0; i < keys.size(); ++i)
    text += fmt::format("{}{}{}{}",
                        i == 0                 ? ""
                        : i + 1 == keys.size() ? " and "
                                               : ", ",
                        q, keys[i], q);
  return text;
}

std::string must_be(const SceneKey& key) {
  const bool two_sided = std::isfinite(key.range.lo) && std::isfinite(key.range.hi);
  return fmt::format("must be {}{}", two_sided ? "in " : "", range_text(key));
}

} // namespace cfddem
