// The run directory holds the outputs of one run only. A fresh run refuses a directory that
// already holds a run's outputs (diagnostics.csv, run.json, snapshots, checkpoints, temporary
// files a stopped run left) unless told to overwrite; overwriting removes exactly those files
// first and leaves anything else in the directory alone. A restart continues the run whose
// checkpoint it reads, so its directory may hold that run's outputs (the checkpoint among them).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace cfddem::apps {

// The files of `dir` that a run writes, sorted; empty when `dir` does not exist.
std::vector<std::filesystem::path> run_outputs_in(const std::filesystem::path& dir);

// Rank 0's check (and, with `overwrite`, removal) before a run writes anything: throws
// ConfigError naming the directory and what it holds when a fresh run (`restart` empty) would
// mix its outputs with another run's. With `overwrite`, removes every output but the checkpoint
// `restart` names. Returns the number of files removed.
std::size_t prepare_run_directory(const std::filesystem::path& dir, bool overwrite,
                                  const std::string& restart);

} // namespace cfddem::apps
