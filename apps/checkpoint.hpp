// Checkpoint/restart of the explicit, orb and islands schemes. A checkpoint holds everything the
// next step reads: every particle field (velocities at the half step the integrator holds, forces,
// rotation), the neighbor list exactly as built (rows in order, reference positions) and the
// tangential contact history, the step counters, the diagnostics rows so far, the snapshot index,
// and the resolved configuration. A run restarted from it continues bit for bit (the cell-list
// order, the force sum order and the rebuild schedule are those of the run that wrote it). There is
// no RNG state to keep: random numbers are drawn only when the initial particles are generated.
//
// With a gas (coupled scenes) it also holds, under /gas, the gas solver's state and the coupling
// counters (GasCoupling::State) and the coupled loop's position (CoupledLoopState); it is written
// at a fluid-step boundary, before the next fluid step. The gas fields are whole-grid datasets
// (apps/gas_grid_io.hpp), so a checkpoint written on R ranks restarts on any number of ranks.
//
// The file (HDF5, checkpoint_<step>.h5) is written under a temporary name and renamed, and carries
// an FNV-1a checksum over all its arrays, so a truncated or corrupt file is refused with a clear
// error (read_checkpoint throws ConfigError) rather than restarting from garbage.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "apps/coupled_step.hpp"
#include "apps/gas_grid_io.hpp"
#include "apps/particle_inlet.hpp"
#include "core/cell_box.hpp"
#include "core/particle_snapshot.hpp"
#include "core/particle_store.hpp"
#include "core/scene.hpp"
#include "dem/scheme_checkpoint.hpp"

namespace cfddem::apps {

// Where the coupled loop stands at a fluid-step boundary. A row or snapshot at fluid time t is
// written by the next particle step (the synchronised state at t needs the forces at t), after
// the gas has moved on: what it takes from the gas at t waits here.
struct CoupledLoopState {
  double time = 0.0; // fluid time reached
  double next_output = 0.0, next_snapshot = 0.0, dt_f_sum = 0.0;
  std::int64_t fluid_steps = 0;
  bool row_pending = false;
  double row_time = 0.0;
  FluidDiagnostics row_fluid;
  bool snapshot_pending = false;
  CellFields snapshot_cells;
  // The gas force the scheme holds over the sub-cycle, in the store's order: the next fluid step
  // replaces it before any use, except when the run resumes at its end (the one particle step
  // past the end, which records the last row, still reads it).
  std::array<std::vector<double>, 3> held_force;
  // Particles through the faces since the start of the run (apps/particle_outflow.hpp): their
  // mass [kg] and count, in and out.
  double mass_in = 0.0, mass_out = 0.0;
  std::int64_t particles_in = 0, particles_out = 0;
  InletState inlet; // rank 0's (apps/particle_inlet.hpp)
  // The particle steps (sub-iterations) of the last fluid step: what a gas regrid at the next
  // fluid-step boundary weighs each particle by (0 before the first step).
  std::int64_t last_n_sub = 0;
};

struct Checkpoint {
  std::string scheme = "explicit";
  double dt = 0.0;
  std::int64_t step = 0;       // the loop resumes at this step (state x(step), v(step - 1/2));
                               // with a gas, the fluid steps taken
  std::int64_t last_row_step = 0;
  std::vector<std::string> columns;
  std::vector<std::vector<double>> rows; // diagnostics rows written so far
  std::vector<SnapshotEntry> snapshots;
  std::string configuration;             // describe_scene as "key = value" lines
  ParticleStore particles;
  dem::SchemeState scheme_state; // the state of `scheme`, written and read by the scheme
  bool gas = false;               // a coupled scene's checkpoint: the three below are set
  std::array<int, 3> gas_cells{}; // the whole gas grid's cells
  GasCoupling::State gas_state;   // one rank: the whole grid; R ranks: this rank's box
  // R ranks: every rank's gas box when written (a gas regrid may have moved them from the count
  // cut). Read back: the boxes the restart's gas takes, empty where it takes the count cut (a
  // checkpoint of another rank count, or one written before the boxes were kept).
  std::vector<CellBox> gas_boxes;
  CoupledLoopState loop;
};

// read_checkpoint, then the checks against the scene it restarts (gas or not, scheme, columns,
// configuration): a ConfigError naming the file and the first thing that differs.
Checkpoint load_checkpoint(const Scene& scene, const std::string& path);
Checkpoint load_checkpoint(const Scene& scene, const std::string& path, const GasBlock& block,
                           const Communicator& comm);
// A checkpoint's fields every loop fills alike: scheme, step length, step, the last row's step,
// the diagnostics so far, the snapshot index and the configuration to check at a restart.
Checkpoint checkpoint_header(const Scene& scene, const std::string& scheme, double dt,
                             std::int64_t step, std::int64_t last_row_step,
                             const std::vector<std::vector<double>>& rows,
                             const std::vector<SnapshotEntry>& snapshots);

// The configuration lines that must match between a checkpoint and the scene it restarts
// (physics and numerics: everything but name, run.* and output.*).
std::string restart_configuration(const Scene& scene);

// Write atomically; throws RunError.
void write_checkpoint(const std::string& path, const Checkpoint& c);
// The same file from R ranks (collective): every rank writes its box `block` of the gas grids
// (c.gas_state holds the box), rank 0 everything else (only its c needs the rest).
void write_checkpoint(const std::string& path, const Checkpoint& c, const GasBlock& block,
                      const Communicator& comm);
// Read and verify; throws ConfigError naming the file and what is wrong.
Checkpoint read_checkpoint(const std::string& path);
// On R ranks (collective): every rank reads the whole file but the gas grids, of which it reads
// its box: its box in the file's gas_boxes where those cut the grid into R boxes, else `block`
// (the count cut; gas_boxes comes back empty). Every rank throws the same ConfigError.
Checkpoint read_checkpoint(const std::string& path, const GasBlock& block,
                           const Communicator& comm);

} // namespace cfddem::apps
