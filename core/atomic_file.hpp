// Write a whole file under a temporary name, then rename it over the target, so a reader (or a
// crash) never sees a half-written file and the previous version stays until the new one is whole.
#pragma once

#include <string>
#include <string_view>

namespace cfddem {

void write_file_atomically(const std::string& path, std::string_view content);

} // namespace cfddem
