#include "apps/rank_setup.hpp"

#include <exception>
#include <filesystem>
#include <stdexcept>

#include "apps/run_directory.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"

namespace cfddem::apps {

ParticleStore rank_share(const Scene& scene, std::optional<Checkpoint>& ck,
                         const Communicator& comm, std::vector<std::uint32_t>* taken) {
  if (!ck) return make_initial_share(scene, comm.rank(), comm.size());
  ParticleStore p = std::move(ck->particles);
  std::vector<std::uint32_t> mine;
  for (std::size_t i = static_cast<std::size_t>(comm.rank()); i < p.size();
       i += static_cast<std::size_t>(comm.size()))
    mine.push_back(static_cast<std::uint32_t>(i));
  p.permute(mine);
  if (taken) *taken = std::move(mine);
  return p;
}

std::optional<DiagnosticsFile> open_root_diagnostics(const Communicator& comm,
                                                     const std::string& out_dir,
                                                     const std::vector<std::string>& columns) {
  namespace fs = std::filesystem;
  std::optional<DiagnosticsFile> diag;
  std::string error;
  if (comm.rank() == 0) {
    try {
      create_run_directory(out_dir); // locked before the first file (apps/run_directory.hpp)
      diag.emplace((fs::path(out_dir) / "diagnostics.csv").string(), columns);
    } catch (const std::exception& e) {
      error = e.what();
    }
  }
  if (const std::string e = comm.agree_on_error(0, error); !e.empty())
    throw ConfigError(out_dir, e);
  return diag;
}

void add_root_row(std::optional<DiagnosticsFile>& diag, const std::vector<double>& row) {
  if (!diag)
    return;
  try {
    diag->add_row(row);
  } catch (const RunError& e) {
    throw std::runtime_error(e.what());
  }
}

} // namespace cfddem::apps
