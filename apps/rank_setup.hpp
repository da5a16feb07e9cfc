// What the run loops over R ranks set up alike: this rank's share of the particles, and the
// run directory with diagnostics.csv on rank 0.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "apps/checkpoint.hpp"
#include "apps/diagnostics_file.hpp"
#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "core/scene.hpp"

namespace cfddem::apps {

// Every R-th particle: of the checkpoint's (a restart; its particles are moved out, and `taken`,
// when given, receives their indices in the checkpoint), else of the scene's initial particles,
// built without the others where the initial conditions allow it (make_initial_share). Any
// split will do: the schemes' start() or restore() moves each particle to its owner.
ParticleStore rank_share(const Scene& scene, std::optional<Checkpoint>& ck,
                         const Communicator& comm, std::vector<std::uint32_t>* taken = nullptr);

// Rank 0 creates the run directory and its diagnostics.csv (other ranks get none); collective:
// every rank throws the same ConfigError naming the directory if that fails.
std::optional<DiagnosticsFile> open_root_diagnostics(const Communicator& comm,
                                                     const std::string& out_dir,
                                                     const std::vector<std::string>& columns);

// Rank 0 appends a row (the others hold no file). A failure there (a full disk) is rank 0's
// alone: it is raised as a plain std::runtime_error, which apps/main.cpp answers by ending every
// rank with exit code 3 (a RunError is taken as raised by every rank alike, and would leave the
// others waiting in their next collective call).
void add_root_row(std::optional<DiagnosticsFile>& diag, const std::vector<double>& row);

} // namespace cfddem::apps
