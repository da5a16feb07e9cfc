#include "dem/history_checkpoint.hpp"

namespace cfddem::dem {

void save_history(StateWriter& w, const std::string& group, const ContactHistory& h,
                  const std::vector<std::int64_t>& ids) {
  if (h.size() == 0)
    return;
  const HistoryRows r = history_rows(h, ids);
  w.put(group + "/history_offsets", r.offsets);
  w.put(group + "/history_neighbors", r.neighbors);
  put_xyz(w, group + "/history_", "", r.hx, r.hy, r.hz);
}

ContactHistory restore_history(StateReader& r, const std::string& group,
                               const std::vector<std::int64_t>& ids) {
  if (!r.exists(group + "/history_offsets"))
    return {};
  const auto off = r.uint32s(group + "/history_offsets", ids.size() + 1);
  const auto nb = r.uint32s(group + "/history_neighbors", StateReader::kAny);
  std::vector<double> hx, hy, hz;
  read_xyz(r, group + "/history_", "", nb.size(), hx, hy, hz);
  return history_from_rows(ids, off, nb, hx, hy, hz);
}

} // namespace cfddem::dem
