// The run directory holds the outputs of one run only. A fresh run refuses a directory that
// already holds a run's outputs (diagnostics.csv, run.json, snapshots, checkpoints, temporary
// files a stopped run left) unless told to overwrite; overwriting removes exactly those files
// first and leaves anything else in the directory alone. A restart continues the run whose
// checkpoint it reads, so its directory may hold that run's outputs (the checkpoint among them).
// While a run writes into a directory it holds an advisory lock on it, so a second run started
// into the same directory at the same time is refused instead of mixing its files with the first.
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

// Refuses (ConfigError naming --out) an output directory no run could write: a name longer than
// the file system allows, a path through a file, or a directory (or the nearest existing one
// above it) that cannot be written (read-only, no permission). Checked before a run starts, so
// the run does not stop at its first file.
void check_writable(const std::filesystem::path& dir);

// Takes an advisory lock (flock(2), exclusive) on the directory `dir` and holds it for the rest of
// the process; the kernel releases it when the process ends, by exit, signal or crash. Throws
// ConfigError naming the directory when another process holds it. Does nothing when `dir` does
// not exist yet (the run that creates it locks it then), or when this process holds it already.
void lock_run_directory(const std::filesystem::path& dir);

// A run creating its directory: creates and locks it. The directory did not exist, or was not
// locked, when prepare_run_directory looked; if it holds run outputs now, a run that started
// alongside wrote them in between (and may have ended): refused, naming the directory.
void create_run_directory(const std::filesystem::path& dir);

} // namespace cfddem::apps
