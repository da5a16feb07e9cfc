#include "apps/diagnostics_file.hpp"

#include <cerrno>
#include <cstring>
#include <stdexcept>

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>

#include "core/atomic_file.hpp"
#include "core/error.hpp"

namespace cfddem::apps {

DiagnosticsFile::DiagnosticsFile(std::string path, std::vector<std::string> columns,
                                 const std::string& kept)
    : path_(std::move(path)), columns_(std::move(columns)) {
  const std::string header = fmt::format("{}\n", fmt::join(columns_, ",")) + kept;
  write_file_atomically(path_, header);
  fd_ = ::open(path_.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
  if (fd_ < 0)
    throw RunError(fmt::format("cannot open '{}' to append rows: {}", path_, std::strerror(errno)));
  size_ = static_cast<long long>(header.size());
}

DiagnosticsFile::~DiagnosticsFile() {
  if (fd_ >= 0)
    ::close(fd_);
}

DiagnosticsFile::DiagnosticsFile(DiagnosticsFile&& o) noexcept
    : path_(std::move(o.path_)), columns_(std::move(o.columns_)), fd_(o.fd_), size_(o.size_) {
  o.fd_ = -1;
}

void DiagnosticsFile::add_row(const std::vector<double>& values) {
  add_rows({values});
}

void DiagnosticsFile::add_rows(const std::vector<std::vector<double>>& rows) {
  std::string text;
  for (const std::vector<double>& values : rows) {
    if (values.size() != columns_.size())
      throw std::logic_error("diagnostics row has the wrong number of columns");
    for (std::size_t k = 0; k < values.size(); ++k)
      text += fmt::format(k ? fmt::runtime(",{:.17g}") : fmt::runtime("{:.17g}"), values[k]);
    text += '\n';
  }
  std::size_t done = 0;
  while (done < text.size()) {
    const ::ssize_t n = ::write(fd_, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR)
      continue;
    if (n <= 0) {
      const int err = n < 0 ? errno : ENOSPC;
      // Cut a partly written row off again: the file keeps whole rows only.
      if (done > 0 && ::ftruncate(fd_, static_cast<off_t>(size_)) != 0) {
        // Nothing more to do: the error below names the file.
      }
      throw RunError(fmt::format("writing a row to '{}' failed: {}", path_, std::strerror(err)));
    }
    done += static_cast<std::size_t>(n);
  }
  size_ += static_cast<long long>(text.size());
}

} // namespace cfddem::apps
