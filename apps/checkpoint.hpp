// Checkpoint/restart of the explicit and orb schemes. A checkpoint holds everything the next step reads:
// every particle field (velocities at the half step the integrator holds, forces, rotation), the
// neighbor list exactly as built (rows in order, reference positions) and the tangential contact
// history, the step counters, the diagnostics rows so far, the snapshot index, and the resolved
// configuration. A run restarted from it continues bit for bit (the cell-list order, the force
// sum order and the rebuild schedule are those of the run that wrote it). There is no RNG state
// to keep: random numbers are drawn only when the initial particles are generated.
//
// The file (HDF5, checkpoint_<step>.h5) is written under a temporary name and renamed, and carries
// an FNV-1a checksum over all its arrays, so a truncated or corrupt file is refused with a clear
// error (read_checkpoint throws ConfigError) rather than restarting from garbage.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/particle_snapshot.hpp"
#include "core/particle_store.hpp"
#include "core/scene.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/orb_scheme.hpp"

namespace cfddem::apps {

struct Checkpoint {
  std::string scheme = "explicit";
  double dt = 0.0;
  std::int64_t step = 0;       // the loop resumes at this step (state x(step), v(step - 1/2))
  std::int64_t last_row_step = 0;
  std::vector<std::string> columns;
  std::vector<std::vector<double>> rows; // diagnostics rows written so far
  std::vector<SnapshotEntry> snapshots;
  std::string configuration;             // describe_scene as "key = value" lines
  ParticleStore particles;
  dem::ExplicitScheme::State state; // scheme == "explicit"
  dem::OrbScheme::State orb;         // scheme == "orb"
};

// The configuration lines that must match between a checkpoint and the scene it restarts
// (physics and numerics: everything but name, run.* and output.*).
std::string restart_configuration(const Scene& scene);

// Write atomically; throws RunError.
void write_checkpoint(const std::string& path, const Checkpoint& c);
// Read and verify; throws ConfigError naming the file and what is wrong.
Checkpoint read_checkpoint(const std::string& path);

} // namespace cfddem::apps
