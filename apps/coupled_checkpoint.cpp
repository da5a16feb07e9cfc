#include "apps/coupled_checkpoint.hpp"

#include <algorithm>
#include <numeric>
#include <stdexcept>
#include <unordered_map>

#include <fmt/format.h>

#include "core/error.hpp"
#include "fluid/mac_grid.hpp"

namespace cfddem::apps {

GasBlock gas_block(const Scene& scene, const Communicator& comm) {
  const std::array<int, 3> cells = fluid_grid_spec(scene).cells;
  if (comm.size() == 1)
    return {cells, CellBox{{0, 0, 0}, cells}};
  try {
    return {cells, orb_cell_boxes(cells, comm.size(),
                                  fluid::kMinBoxWidth)[static_cast<std::size_t>(comm.rank())]};
  } catch (const std::invalid_argument& e) {
    throw ConfigError("scene key 'fluid.cells'", e.what());
  }
}

void write_coupled_checkpoint(const std::string& path, Checkpoint c,
                              dem::DistributedExplicitScheme& scheme,
                              const ParticleStore& particles, const GasCoupling& gas,
                              const CoupledLoopState& loop, const GasBlock& block,
                              const Communicator& comm) {
  scheme.canonicalize();
  const std::size_t n = scheme.owned();
  const std::span<const double> own[] = {
      {particles.x.data(), n},      {particles.y.data(), n},    {particles.z.data(), n},
      {particles.vx.data(), n},     {particles.vy.data(), n},   {particles.vz.data(), n},
      {particles.radius.data(), n}, {particles.mass.data(), n}, {particles.inv_mass.data(), n}};
  std::vector<double> all[9];
  for (int q = 0; q < 9; ++q)
    all[q] = comm.gather(own[q]);
  const std::vector<std::int64_t> ids =
      comm.gather(std::span<const std::int64_t>(particles.id.data(), n));
  std::vector<double> force[3];
  for (int a = 0; a < 3; ++a)
    force[a] = comm.gather(gas.force(a));
  const std::vector<std::int64_t> force_ids = comm.gather(gas.force_ids());
  std::string error;
  if (comm.rank() == 0) {
    try {
      std::vector<std::size_t> order(ids.size());
      std::iota(order.begin(), order.end(), std::size_t{0});
      std::sort(order.begin(), order.end(),
                [&](std::size_t a, std::size_t b) { return ids[a] < ids[b]; });
      std::unordered_map<std::int64_t, std::size_t> at;
      at.reserve(force_ids.size());
      for (std::size_t i = 0; i < force_ids.size(); ++i)
        at.emplace(force_ids[i], i);
      c.particles.resize(ids.size());
      std::vector<double>* field[9] = {
          &c.particles.x,      &c.particles.y,    &c.particles.z,
          &c.particles.vx,     &c.particles.vy,   &c.particles.vz,
          &c.particles.radius, &c.particles.mass, &c.particles.inv_mass};
      for (auto& h : c.loop.held_force)
        h.resize(ids.size());
      for (std::size_t i = 0; i < order.size(); ++i) {
        for (int q = 0; q < 9; ++q)
          (*field[q])[i] = all[q][order[i]];
        c.particles.id[i] = ids[order[i]];
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
  // The list is rebuilt at a restart (canonical state): only the counters are kept.
  const auto cnt = scheme.counters();
  c.state.steps = cnt.steps, c.state.particle_steps = cnt.particle_steps;
  c.state.pair_evaluations = cnt.pair_evaluations, c.state.builds = cnt.builds;
  c.state.need_rebuild = true;
  c.state.skin = scheme.model().skin;
  auto held = std::move(c.loop.held_force);
  c.loop = loop;
  c.loop.held_force = std::move(held);
  c.loop.snapshot_cells = CellFields(); // taken again from the gas at the restart
  c.gas = true;
  c.gas_cells = block.cells;
  c.gas_state = gas.save_state();
  write_checkpoint(path, c, block, comm);
}

void restore_coupled_scheme(const Checkpoint& ck, const std::vector<std::uint32_t>& taken,
                            dem::DistributedExplicitScheme& scheme) {
  std::vector<double> f[3];
  for (int a = 0; a < 3; ++a) {
    const std::vector<double>& h = ck.loop.held_force[static_cast<std::size_t>(a)];
    if (h.empty())
      continue; // no gas step before the checkpoint: no force held
    for (const std::uint32_t i : taken)
      f[a].push_back(h[i]);
  }
  scheme.set_external_force(f[0], f[1], f[2]);
  scheme.restore(
      {ck.state.steps, ck.state.particle_steps, ck.state.pair_evaluations, ck.state.builds});
}

void restore_coupled_gas(Checkpoint& ck, const std::string& path, GasCoupling& gas,
                         CoupledLoopState& loop) {
  try {
    gas.restore_state(ck.gas_state);
  } catch (const RunError& e) {
    throw ConfigError(path, fmt::format("cannot restart: {}", e.what()));
  }
  loop = std::move(ck.loop);
  loop.held_force = {}; // the scheme holds it
  // A pending snapshot's cells: this rank's box of the gas at the checkpoint's time.
  if (loop.snapshot_pending)
    loop.snapshot_cells = gas.cell_fields();
}

} // namespace cfddem::apps
