// The resolved, validated scene: every key read once from SceneConfig, with defaults applied and
// impossible values rejected (the error names the key). Physics modules read this, never TOML.
// What each key means, its unit, range and default: the key table, core/scene_keys.cpp (printed
// as docs/keys.md). The member initializers below are the table's defaults (a test checks).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "core/diameter_distribution.hpp"

#include "core/scene_config.hpp"

namespace cfddem {

struct DomainSpec {
  std::array<double, 3> lo{}, hi{};
  std::array<bool, 3> periodic{true, true, true};
  // "box", or "cylinder": a circular column of radius cylinder_radius along cylinder_axis
  // (0 x, 1 y, 2 z), centred on the box's other two axes (docs/theory.md §11).
  std::string shape = "box";
  int cylinder_axis = 1;
  double cylinder_radius = 0.0; // [m]; the parser resolves its default
  double length(int a) const { return hi[a] - lo[a]; }
  double volume() const { return length(0) * length(1) * length(2); }
  bool cylinder() const { return shape == "cylinder"; }
  // The two axes across the cylinder, in increasing order.
  std::array<int, 2> cross_axes() const {
    return {cylinder_axis == 0 ? 1 : 0, cylinder_axis == 2 ? 1 : 2};
  }
  double centre(int a) const { return 0.5 * (lo[a] + hi[a]); }
  // The distance from the cylinder's axis to the nearest point of the box [lo, hi] across it
  // (0 where the box spans the axis).
  double axis_distance_to_box(const std::array<double, 3>& box_lo,
                              const std::array<double, 3>& box_hi) const;
  // Empty when a sphere of radius r can have its centre in the box [lo, hi] inside the column;
  // else the end of the sentence that says why: "<distance> m from it, and a particle of
  // diameter <2r> m needs its centre within <R - r> m (domain.cylinder_radius less its radius)".
  std::string centres_beyond_cylinder(const std::array<double, 3>& box_lo,
                                      const std::array<double, 3>& box_hi, double r) const;
  // The column's cross-section pi R^2 [m^2].
  double cylinder_area() const;
  // The volume the particles move in: the box's, or the column's pi R^2 L.
  double particle_volume() const {
    return cylinder() ? cylinder_area() * length(cylinder_axis) : volume();
  }
};

struct ParticleSpec {
  std::string file;               // CSV x,y,z,vx,vy,vz,diameter,density; empty = generator
  std::int64_t count = 0;         // generator: number of particles
  double diameter = 0.0;          // [m]; with a distribution, its largest value (diameters.max)
  DiameterDistribution diameters; // "fixed" (= diameter) or a truncated distribution
  double density = 0.0;           // [kg/m^3]
  double temperature = 0.0;       // granular temperature T0 [m^2/s^2], Gaussian velocities
  std::array<double, 3> velocity{0, 0, 0}; // mean velocity added to the Gaussian part
  std::uint64_t seed = 1;
  std::string placement = "random";
  std::array<double, 3> region_lo{}, region_hi{}; // where the generator places particles
  bool allow_overlap = false;
  // Particles at the gas's outflow faces: "remove" (they leave the run, apps/particle_outflow.hpp)
  // or "wall" (held back by the particle wall there).
  std::string outflow = "remove";
};

// Particles entering the run (scene table [inlet], apps/particle_inlet.hpp).
struct InletSpec {
  double mass_rate = 0.0; // [kg/s] of new particles
  // The new particles' diameter (0: drawn from the scene's particles.diameter or its
  // distribution) and density (the parser resolves it: particles.density unless given).
  double diameter = 0.0; // [m]; with a distribution, its largest value
  DiameterDistribution diameters; // inlet.diameter = { distribution, ... }; "fixed" otherwise
  double density = 0.0;  // [kg/m^3]
  bool recycle = false;   // particles leaving through an outflow face enter again
  std::array<double, 3> region_lo{}, region_hi{}; // where entering centres are placed [m]
  std::array<double, 3> velocity{};               // [m/s]
  std::uint64_t seed = 1;
  bool enabled() const { return mass_rate > 0.0 || recycle; }
};

struct DemSpec {
  std::string scheme = "explicit";
  double spring_constant = 0.0;                  // k_n [N/m]
  double restitution = 0.0;                      // e
  double friction = 0.0;                         // Coulomb mu
  double tangential_stiffness_ratio = 2.0 / 7.0; // k_t / k_n (MFIX, LIGGGHTS default)
  double tangential_damping_ratio = 0.5;         // eta_t / eta_n (MFIX default)
  double wall_spring_constant = 0.0;
  double wall_restitution = 0.0;
  double wall_friction = 0.0;
  double dt_factor = 0.02;    // dt = tau_p * dt_factor
  double dt = 0.0;            // explicit step [s] (0 = from dt_factor), as LAMMPS `timestep`
  double neighbor_skin = 0.0; // Verlet skin [m]
  double max_overlap = 0.3;   // stop when overlap / smaller radius exceeds this
  // The `orb` scheme (Sitaraman & Grout, Algorithm 2).
  std::int64_t nsubit = 10; // sub-iterations per regrid interval
  // islands: dem.nsubit = "auto", the scheme picks nsubit per interval (dem/subiteration_length);
  // nsubit is then the first interval's count.
  bool nsubit_auto = false;
  double proximity_radii = 3.0; // a pair is close if centre distance < this * (r_i + r_j) / 2
  std::string local_dt = "proximity";
  // orb: global sub-iterations where nearly every leaf steps finely (one rank, no friction).
  bool orb_global = true;
  // orb on R ranks: the global mode only with at least this many particles per rank.
  std::int64_t orb_global_min_per_rank = 10000;
  double regrid_interval = 1e-4; // dt_f [s]: ORB rebuilt this often; dt_sp = this / nsubit
  // orb and islands advance in sub-iterations of a control interval (dem.nsubit per interval).
  bool subiterated() const { return scheme == "orb" || scheme == "islands"; }
};

struct PartitionSpec {
  int orb_levels = 4; // the ORB has 2^orb_levels leaves
  // ORB weights: "count" (every particle weighs 1) or "cost" (particles x local steps of the
  // last regrid interval: each particle weighs the local steps its leaf took).
  std::string weights = "count";
  // A gas on R ranks: every gas_regrid_interval simulated seconds (0: never) the gas boxes are
  // cut again by a weighted ORB, each cell weighing cell_weight (its fluid step, in particle
  // steps) plus the particle steps of the particles in it over the last fluid step; a box's
  // cells and particles then move to their new owner.
  double gas_regrid_interval = 0.0;
  double cell_weight = 400.0;
};

struct RunSpec {
  double end_time = 0.0;
};

struct OutputSpec {
  double interval = 0.0;             // simulated seconds between diagnostics rows
  double progress_seconds = 2.0;     // wall seconds between progress lines
  double snapshot_interval = 0.0;    // simulated seconds between HDF5 snapshots (0: none)
  double checkpoint_interval = 0.0;  // simulated seconds between checkpoints (0: none)
  std::string profile_axis = "none"; // profiles.csv along "x" | "y" | "z"; "none": not written
  std::int64_t profile_bins = 20;    // slabs of profiles.csv
  bool contact_census = false;       // census columns of diagnostics.csv (else NaN)
  // 0, 1, 2 for x, y, z; -1 without profiles.
  [[nodiscard]] int profile_axis_index() const {
    return profile_axis == "x" ? 0 : profile_axis == "y" ? 1 : profile_axis == "z" ? 2 : -1;
  }
};

// The memory a gas cell costs in a run (its fields, the multigrid's levels, the solvers' work
// arrays): 1.49 KB per cell measured on a 100^3 grid (one rank, the default solver, the peak
// resident size less that of a 50^3 grid), rounded up. Scene reading refuses what no machine
// holds; apps/gas_check.hpp what this machine does not.
inline constexpr double kGasBytesPerCell = 1600;

// The gas (scene table [fluid]); absent = no fluid work at all. Names are checked here, the grid
// and boundary conditions by the coupling (apps/coupled_step), which knows the fluid library.
struct FluidSpec {
  bool enabled = false;
  std::array<std::int64_t, 3> cells{}; // fluid.cells [nx, ny, nz]
  std::array<double, 3> cell_size{};   // fluid.cell_size [m]; 0 = extent / cells
  double density = 0.0;                // rho_g [kg/m^3]
  double viscosity = 0.0;              // mu_g [Pa s]
  double dt = 0.0;                     // fixed coupling step dt_f [s]; 0 = from cfl
  double cfl = 0.9;                    // Courant number of the gas sub-steps / adaptive dt_f
  double max_dt = 1e-3;                // adaptive dt_f cap [s]
  std::string drag = "bvk";
  bool one_way = false; // fluid.coupling = "one_way": the gas does not feel the particles
  std::string deposition = "trilinear";
  double deposition_width = 2.0;           // dpvm kernel width in particle diameters
  std::array<std::string, 6> bc{};         // per face x_lo, x_hi, y_lo, y_hi, z_lo, z_hi
  std::array<double, 3> inflow_velocity{}; // gas velocity on inflow faces [m/s]
  double outflow_pressure = 0.0;           // p' on outflow faces [Pa]
  std::array<double, 3> pressure_drop{};   // MFIX's delp across periodic axes [Pa]
  std::array<double, 3> velocity{};        // initial gas velocity [m/s]
  bool implicit_viscosity = false;
  bool implicit_viscosity_auto = true; // "auto" (the default): chosen per fluid step
  std::string viscous_step = "factored"; // the implicit Laplacian: "factored" or "solve"
  std::string advection = "godunov";   // "godunov" (one stage) or "mol" (time_order, projections)
  int time_order = 2;                  // mol: 1, Euler; 2, predictor-corrector (Heun)
  int projections = 1; // time_order 2: 1 (the corrector only) or 2 (each stage projected)
  double tolerance = 1e-10;            // projection PCG relative residual
  std::string preconditioner = "pfmg"; // projection PCG preconditioner
  std::string solver = "auto";         // projection solver
};

struct Scene {
  std::string name;
  DomainSpec domain;
  std::array<double, 3> gravity{0, 0, 0};
  ParticleSpec particles;
  InletSpec inlet;
  DemSpec dem;
  PartitionSpec partition;
  RunSpec run;
  OutputSpec output;
  FluidSpec fluid;
};

// Read and validate every key; throws ConfigError naming the key. A key not in the key table is
// refused, with the nearest key named.
// `default_name` is used when the scene has no `name` key (the file's stem).
Scene read_scene(SceneConfig& config, const std::string& default_name);

} // namespace cfddem

namespace cfddem {
// Every scene key with its resolved value (defaults applied), in a stable order, as TOML text.
std::vector<std::pair<std::string, std::string>> describe_scene(const Scene& scene);
} // namespace cfddem
