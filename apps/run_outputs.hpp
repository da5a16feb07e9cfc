// The files of a run directory, written alike for one rank and R ranks: diagnostics.csv with the
// rows kept for checkpoints, the particle snapshots and their XDMF index, checkpoint files and
// run.json. On R ranks rank 0 holds the files, snapshots are written collectively, and a failure
// on rank 0 is agreed by every rank (so none is left waiting in a collective call).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/diagnostics_file.hpp"
#include "core/communicator.hpp"
#include "core/particle_snapshot.hpp"

namespace cfddem::apps {

class RunOutputs {
public:
  // Creates the directory and diagnostics.csv with `columns`. One rank: the errors of the file
  // system as they come (a RunError for the file); R ranks: a ConfigError naming the directory
  // on every rank.
  RunOutputs(const Communicator& comm, std::string out_dir,
             const std::vector<std::string>& columns);

  // A restart: the rows and snapshots the checkpoint holds (files missing now are dropped).
  void resume(std::vector<std::vector<double>> rows, const std::vector<SnapshotEntry>& snapshots);
  // Appends a row (written by rank 0 at once; every rank keeps it for checkpoints).
  void add_row(std::vector<double> row);
  [[nodiscard]] const std::vector<std::vector<double>>& rows() const { return rows_; }
  // Collective: every rank's particles into one snapshot file, indexed by rank 0.
  void add_snapshot(const SnapshotFields& f);
  // The snapshots so far (rank 0's; empty on the other ranks).
  [[nodiscard]] std::vector<SnapshotEntry> snapshots() const;
  // <dir>/checkpoint_<step>.h5, and <dir>/run.json.
  [[nodiscard]] std::string checkpoint_path(long long step) const;
  // Rank 0 writes `c` (the other ranks' are ignored); collective.
  void write_checkpoint(long long step, const Checkpoint& c);
  // profiles.csv with `columns` (rank 0). A restart at `resume_time` keeps the rows of an
  // existing file up to that time (the rest is written again) when its header is the same; in a
  // directory without one, those of `resumed_dir`'s (the checkpoint's directory), if it has one.
  void open_profiles(const std::vector<std::string>& columns, std::optional<double> resume_time,
                     const std::string& resumed_dir = {});
  // Appends the rows of one output time in one write (rank 0).
  void add_profile_rows(const std::vector<std::vector<double>>& rows);
  // Rank 0 writes run.json.
  void write_run_json(const nlohmann::ordered_json& j) const;

private:
  // Runs `write` on rank 0; on R ranks every rank raises its error as a RunError.
  template <class F> void on_root(F&& write) const;
  const Communicator& comm_;
  std::string dir_;
  std::optional<DiagnosticsFile> diag_;
  std::optional<DiagnosticsFile> profiles_;
  std::optional<SnapshotIndex> index_;
  std::vector<std::vector<double>> rows_;
};

} // namespace cfddem::apps
