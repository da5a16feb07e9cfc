#include "apps/run_directory.hpp"

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstring>
#include <map>
#include <system_error>

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

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

void check_writable(const fs::path& dir) {
  const auto refuse = [&](const std::string& why) {
    throw ConfigError(fmt::format("output directory '{}' (--out, or runs/<name>)", dir.string()),
                      why);
  };
  // Room for the longest file name a run writes in it (checkpoint_<step>.h5.tmp.<pid>).
  constexpr std::size_t kLongestOutput = 48;
  const long name_max = ::pathconf(".", _PC_NAME_MAX);
  for (const fs::path& part : dir)
    if (name_max > 0 && part.native().size() > static_cast<std::size_t>(name_max))
      refuse(fmt::format("the name '{:.20}...' is {} characters long, more than the {} the file "
                         "system allows",
                         part.native(), part.native().size(), name_max));
  if (fs::absolute(dir).native().size() + kLongestOutput >= PATH_MAX)
    refuse(fmt::format("the path is {} characters long; with the run's file names it would pass "
                       "the system's limit of {}",
                       fs::absolute(dir).native().size(), PATH_MAX));
  // The directory itself, or the nearest one above it that exists (where it will be created).
  std::error_code ec;
  fs::path at = fs::absolute(dir);
  while (!fs::exists(at, ec) && at.has_relative_path())
    at = at.parent_path();
  if (!fs::is_directory(at, ec))
    refuse(fmt::format("'{}' is a file, not a directory", at.string()));
  if (::access(at.c_str(), W_OK | X_OK) != 0)
    refuse(fmt::format("'{}' cannot be written: {}", at.string(), std::strerror(errno)));
}

namespace {

// Locks `dir` unless this process holds it; true when it took the lock now.
bool take_lock(const fs::path& dir) {
  // The descriptors stay open (and locked) until the process ends. A second flock from this
  // process on a new descriptor would conflict with its own first one, so each directory once.
  static std::map<fs::path, int> held;
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    return false;
  const fs::path key = fs::weakly_canonical(dir, ec);
  if (held.contains(key))
    return false;
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0)
    throw ConfigError(dir.string(), fmt::format("cannot open the output directory to lock it: {}",
                                                std::strerror(errno)));
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    ::close(fd);
    if (err == EWOULDBLOCK)
      throw ConfigError(dir.string(),
                        "another cfddem run is writing into this directory now (it holds the "
                        "directory's lock); wait for it to finish, or give this run another "
                        "directory (--out, or name=...)");
    throw ConfigError(dir.string(),
                      fmt::format("cannot lock the output directory: {}", std::strerror(err)));
  }
  held.emplace(key, fd);
  return true;
}

} // namespace

void lock_run_directory(const fs::path& dir) {
  (void)take_lock(dir);
}

void create_run_directory(const fs::path& dir) {
  // check_writable cannot foresee every refusal (a special file system such as /proc, a race):
  // one here is still the directory's, before any step or file, so a configuration error.
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec)
    throw ConfigError(fmt::format("output directory '{}' (--out, or runs/<name>)", dir.string()),
                      fmt::format("cannot be created: {}", ec.message()));
  if (take_lock(dir) && !run_outputs_in(dir).empty())
    throw ConfigError(dir.string(),
                      "another cfddem run wrote its outputs into this directory while this run "
                      "was setting up; give this run another directory (--out, or name=...)");
}

} // namespace cfddem::apps
