// diagnostics.csv: a header row and one row per output interval, numbers written with {:.17g} so
// they round-trip. The whole file is rewritten atomically at each row (small: one row per
// interval), at most once a second and at the end, so a reader never sees a torn row.
#pragma once

#include <chrono>
#include <string>
#include <vector>

namespace cfddem::apps {

class DiagnosticsFile {
public:
  DiagnosticsFile(std::string path, std::vector<std::string> columns);
  // Rows reach the disk at most every `flush_seconds` of wall time, and always on flush().
  void add_row(const std::vector<double>& values);
  void flush();
  const std::vector<std::string>& columns() const { return columns_; }

private:
  std::string path_;
  std::vector<std::string> columns_;
  std::string text_;
  std::chrono::steady_clock::time_point last_write_;
  bool dirty_ = false;
  static constexpr double flush_seconds = 1.0;
};

} // namespace cfddem::apps
