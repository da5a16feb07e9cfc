// The key table (core/scene_keys.hpp) as text: the short listing of `cfddem --help`, the full
// listing of `cfddem keys`, and docs/keys.md (`cfddem keys --markdown`).
#pragma once

#include <string>

namespace cfddem {

// One line per key: name, type, unit and allowed values, default.
std::string keys_help_text();
// Every key with its meaning, as plain text.
std::string keys_text();
// docs/keys.md: the table per section with the manual's prose around it.
std::string keys_markdown();

} // namespace cfddem
