#include "apps/coupled_checkpoint.hpp"

#include <algorithm>
#include <numeric>
#include <stdexcept>
#include <unordered_map>

#include <fmt/format.h>

#include "apps/rank_checkpoint.hpp"
#include "core/error.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::apps {

GasBlock gas_block(const Scene& scene, const Communicator& comm) {
  return {fluid_grid_spec(scene).cells,
          gas_boxes(scene, &comm)[static_cast<std::size_t>(comm.rank())]};
}

void write_coupled_checkpoint(const std::string& path, Checkpoint c, const GasCoupling& gas,
                              const CoupledLoopState& loop, const GasBlock& block,
                              const Communicator& comm) {
  std::vector<double> force[3];
  for (int a = 0; a < 3; ++a)
    force[a] = comm.gather(gas.force(a));
  const std::vector<std::int64_t> force_ids = comm.gather(gas.force_ids());
  std::string error;
  if (comm.rank() == 0) {
    try {
      // The held force by particle id, in the checkpoint's (id) order.
      std::unordered_map<std::int64_t, std::size_t> at;
      at.reserve(force_ids.size());
      for (std::size_t i = 0; i < force_ids.size(); ++i)
        at.emplace(force_ids[i], i);
      for (auto& h : c.loop.held_force)
        h.resize(c.particles.size());
      for (std::size_t i = 0; i < c.particles.size(); ++i) {
        const auto it = at.find(c.particles.id[i]);
        if (it == at.end())
          throw RunError(fmt::format("particle id {} has no gas force", c.particles.id[i]));
        for (int a = 0; a < 3; ++a)
          c.loop.held_force[static_cast<std::size_t>(a)][i] = force[a][it->second];
      }
    } catch (const std::exception& e) {
      error = e.what();
    }
  }
  if (const std::string m = comm.agree_on_error(0, error); !m.empty())
    throw RunError(m);
  auto held = std::move(c.loop.held_force);
  c.loop = loop;
  c.loop.held_force = std::move(held);
  c.loop.snapshot_cells = CellFields(); // taken again from the gas at the restart
  c.gas = true;
  c.gas_cells = block.cells;
  c.gas_state = gas.save_state();
  write_checkpoint(path, c, block, comm);
}

std::array<std::vector<double>, 3> held_share(const Checkpoint& ck,
                                              const std::vector<std::uint32_t>& taken) {
  std::array<std::vector<double>, 3> f;
  for (std::size_t a = 0; a < 3; ++a) {
    const std::vector<double>& h = ck.loop.held_force[a];
    if (h.empty())
      continue;
    for (const std::uint32_t i : taken)
      f[a].push_back(h[i]);
  }
  return f;
}

} // namespace cfddem::apps
