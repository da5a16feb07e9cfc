// diagnostics.csv: a header row and one row per output interval, numbers written with {:.17g} so
// they round-trip. The header is written atomically (temporary file, rename); each row is then
// appended with one write(2) the moment it is added, so a run that stops (an error, a signal, a
// full disk) leaves every row before the stop on disk. A row that cannot be written whole is cut
// off again (ftruncate), so the file never ends in a torn row.
#pragma once

#include <string>
#include <vector>

namespace cfddem::apps {

class DiagnosticsFile {
public:
  // `kept`: whole rows (each ending in a newline) written after the header in the same atomic
  // write (a restart keeps the rows before its time).
  DiagnosticsFile(std::string path, std::vector<std::string> columns, const std::string& kept = {});
  ~DiagnosticsFile();
  DiagnosticsFile(DiagnosticsFile&& o) noexcept;
  DiagnosticsFile& operator=(DiagnosticsFile&&) = delete;
  DiagnosticsFile(const DiagnosticsFile&) = delete;
  DiagnosticsFile& operator=(const DiagnosticsFile&) = delete;

  // Appends the row to the file now; throws RunError (naming the file and the system's reason)
  // when it cannot.
  void add_row(const std::vector<double>& values);
  // Appends several rows with one write (profiles.csv: every bin of one time, whole or not at
  // all).
  void add_rows(const std::vector<std::vector<double>>& rows);
  const std::vector<std::string>& columns() const { return columns_; }

private:
  std::string path_;
  std::vector<std::string> columns_;
  int fd_ = -1;
  long long size_ = 0; // bytes written whole
};

} // namespace cfddem::apps
