#include "apps/run_outputs.hpp"

#include <algorithm>
#include <cmath>
#include <exception>
#include <filesystem>
#include <fstream>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "apps/rank_setup.hpp"
#include "apps/run_directory.hpp"
#include "core/atomic_file.hpp"
#include "core/error.hpp"

namespace cfddem::apps {

namespace fs = std::filesystem;

namespace {

std::optional<DiagnosticsFile> open_diagnostics(const Communicator& comm, const std::string& dir,
                                                const std::vector<std::string>& columns) {
  if (comm.size() > 1)
    return open_root_diagnostics(comm, dir, columns);
  create_run_directory(dir); // locked before the first file (apps/run_directory.hpp)
  return DiagnosticsFile((fs::path(dir) / "diagnostics.csv").string(), columns);
}

} // namespace

RunOutputs::RunOutputs(const Communicator& comm, std::string out_dir,
                       const std::vector<std::string>& columns)
    : comm_(comm), dir_(std::move(out_dir)), diag_(open_diagnostics(comm_, dir_, columns)) {
  if (comm_.rank() == 0)
    index_.emplace(dir_);
}

void RunOutputs::resume(std::vector<std::vector<double>> rows,
                        const std::vector<SnapshotEntry>& snapshots) {
  for (auto& r : rows)
    add_row(std::move(r));
  if (index_)
    index_->restore(snapshots);
}

void RunOutputs::add_row(std::vector<double> row) {
  if (comm_.size() == 1)
    diag_->add_row(row);
  else
    add_root_row(diag_, row);
  rows_.push_back(std::move(row));
}

namespace {

// The rows of an existing CSV whose first column (time) is at most t + a relative 1e-9, when its
// header is `header`; empty otherwise (no file, another header, unreadable).
std::string rows_up_to(const fs::path& path, const std::string& header, double t) {
  std::ifstream in(path);
  std::string line, kept;
  if (!in || !std::getline(in, line) || line != header)
    return {};
  while (std::getline(in, line)) {
    if (in.eof())
      break; // a row without its newline was cut off: drop it
    try {
      if (std::stod(line.substr(0, line.find(','))) > t + 1e-9 * std::max(1.0, std::abs(t)))
        break;
    } catch (const std::exception&) {
      break;
    }
    kept += line + '\n';
  }
  return kept;
}

} // namespace

void RunOutputs::open_profiles(const std::vector<std::string>& columns,
                               std::optional<double> resume_time, const std::string& resumed_dir) {
  on_root([&] {
    const fs::path path = fs::path(dir_) / "profiles.csv";
    const std::string header = fmt::format("{}", fmt::join(columns, ","));
    std::string kept = resume_time ? rows_up_to(path, header, *resume_time) : std::string{};
    // A restart into a new directory takes the rows from the run it continues, as
    // diagnostics.csv takes them from the checkpoint: both files start at t = 0.
    if (resume_time && kept.empty() && !resumed_dir.empty())
      kept = rows_up_to(fs::path(resumed_dir) / "profiles.csv", header, *resume_time);
    profiles_.emplace(path.string(), columns, kept);
  });
}

void RunOutputs::add_profile_rows(const std::vector<std::vector<double>>& rows) {
  on_root([&] {
    if (profiles_)
      profiles_->add_rows(rows);
  });
}

template <class F> void RunOutputs::on_root(F&& write) const {
  if (comm_.size() == 1) {
    write();
    return;
  }
  std::string error;
  if (comm_.rank() == 0) {
    try {
      write();
    } catch (const std::exception& e) {
      error = e.what();
    }
  }
  if (const std::string m = comm_.agree_on_error(0, error); !m.empty())
    throw RunError(m);
}

void RunOutputs::add_snapshot(const SnapshotFields& f) {
  const SnapshotEntry e = write_particle_snapshot(dir_, f, comm_); // collective
  on_root([&] { index_->add(e); });
}

std::vector<SnapshotEntry> RunOutputs::snapshots() const {
  return index_ ? index_->entries() : std::vector<SnapshotEntry>{};
}

std::string RunOutputs::checkpoint_path(long long step) const {
  return (fs::path(dir_) / fmt::format("checkpoint_{:09d}.h5", step)).string();
}

void RunOutputs::write_checkpoint(long long step, const Checkpoint& c) {
  on_root([&] { apps::write_checkpoint(checkpoint_path(step), c); });
}

void RunOutputs::write_run_json(const nlohmann::ordered_json& j) const {
  if (comm_.rank() == 0)
    write_file_atomically((fs::path(dir_) / "run.json").string(), j.dump(2) + "\n");
}

} // namespace cfddem::apps
