#include "apps/diagnostics_file.hpp"

#include <stdexcept>

#include <fmt/format.h>

#include "core/atomic_file.hpp"

namespace cfddem::apps {

DiagnosticsFile::DiagnosticsFile(std::string path, std::vector<std::string> columns)
    : path_(std::move(path)), columns_(std::move(columns)) {
  text_ = fmt::format("{}\n", fmt::join(columns_, ","));
  write_file_atomically(path_, text_);
  last_write_ = std::chrono::steady_clock::now();
}

void DiagnosticsFile::add_row(const std::vector<double>& values) {
  if (values.size() != columns_.size())
    throw std::logic_error("diagnostics row has the wrong number of columns");
  for (std::size_t k = 0; k < values.size(); ++k)
    text_ += fmt::format(k ? fmt::runtime(",{:.17g}") : fmt::runtime("{:.17g}"), values[k]);
  text_ += '\n';
  dirty_ = true;
  if (std::chrono::duration<double>(std::chrono::steady_clock::now() - last_write_).count() >=
      flush_seconds)
    flush();
}

void DiagnosticsFile::flush() {
  if (!dirty_) return;
  write_file_atomically(path_, text_);
  last_write_ = std::chrono::steady_clock::now();
  dirty_ = false;
}

} // namespace cfddem::apps
