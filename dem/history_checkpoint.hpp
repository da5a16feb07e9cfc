// A sub-iterated scheme's tangential history (friction) in a checkpoint: the records as rows
// over the checkpoint's particles (contact_history.hpp's checkpoint form), under a group.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/state_io.hpp"
#include "dem/contact_history.hpp"

namespace cfddem::dem {

// Nothing without records.
void save_history(StateWriter& w, const std::string& group, const ContactHistory& h,
                  const std::vector<std::int64_t>& ids);
// Empty when the group holds no rows (history_offsets tells).
ContactHistory restore_history(StateReader& r, const std::string& group,
                               const std::vector<std::int64_t>& ids);

} // namespace cfddem::dem
