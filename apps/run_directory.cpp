#include "apps/run_directory.hpp"

#include <algorithm>
#include <system_error>

#include <fmt/format.h>

#include "core/error.hpp"

namespace cfddem::apps {

namespace fs = std::filesystem;

namespace {

bool starts_with(const std::string& s, std::string_view prefix) {
  return s.size() >= prefix.size() && s.compare(0, prefix.size(), prefix) == 0;
}

// The names a run writes (apps/simulation.cpp and the distributed loops; core/particle_snapshot,
// apps/checkpoint), and the "<name>.tmp.<pid>" files of an interrupted atomic write.
bool is_run_output(const std::string& name) {
  std::string base = name;
  if (const auto t = name.find(".tmp."); t != std::string::npos)
    base = name.substr(0, t);
  if (base == "diagnostics.csv" || base == "run.json" || base == "snapshots.xmf" ||
      base == "profiles.csv")
    return true;
  const bool h5 = base.size() > 3 && base.compare(base.size() - 3, 3, ".h5") == 0;
  return h5 && (starts_with(base, "snapshot_") || starts_with(base, "checkpoint_"));
}

std::string summary(const std::vector<fs::path>& files) {
  std::vector<std::string> names;
  for (std::size_t k = 0; k < files.size() && k < 4; ++k)
    names.push_back(files[k].filename());
  if (files.size() > 4)
    names.push_back(fmt::format("and {} more", files.size() - 4));
  return fmt::format("{}", fmt::join(names, ", "));
}

} // namespace

std::vector<fs::path> run_outputs_in(const fs::path& dir) {
  std::vector<fs::path> out;
  std::error_code ec;
  if (!fs::exists(dir, ec))
    return out;
  if (!fs::is_directory(dir, ec))
    throw ConfigError(dir.string(), "the output directory (--out or runs/<name>) is a file");
  for (const auto& entry : fs::directory_iterator(dir, ec))
    if (entry.is_regular_file(ec) && is_run_output(entry.path().filename().string()))
      out.push_back(entry.path());
  if (ec)
    throw ConfigError(dir.string(), fmt::format("cannot list the directory: {}", ec.message()));
  std::sort(out.begin(), out.end());
  return out;
}

std::size_t prepare_run_directory(const fs::path& dir, bool overwrite, const std::string& restart) {
  const std::vector<fs::path> found = run_outputs_in(dir);
  if (found.empty())
    return 0;
  if (!overwrite) {
    if (!restart.empty())
      return 0; // the run being continued
    throw ConfigError(dir.string(),
                      fmt::format("holds the outputs of an earlier run ({}); a new run would mix "
                                  "its files with them. Give --overwrite to remove them first, "
                                  "or another output directory (--out, or name=...)",
                                  summary(found)));
  }
  std::error_code ec;
  const fs::path keep = restart.empty() ? fs::path() : fs::weakly_canonical(restart, ec);
  std::size_t removed = 0;
  for (const fs::path& f : found) {
    if (!keep.empty() && fs::weakly_canonical(f, ec) == keep)
      continue;
    if (!fs::remove(f, ec) || ec)
      throw ConfigError(f.string(), fmt::format("--overwrite cannot remove it: {}",
                                                ec ? ec.message() : "not removed"));
    ++removed;
  }
  return removed;
}

} // namespace cfddem::apps
