#include "apps/coupled_checkpoint.hpp"

#include <algorithm>
#include <numeric>
#include <stdexcept>
#include <type_traits>
#include <unordered_map>

#include <fmt/format.h>

#include "apps/rank_checkpoint.hpp"
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

template <class Scheme>
void write_coupled_checkpoint(const std::string& path, Checkpoint c, Scheme& scheme,
                              const ParticleStore& particles, const GasCoupling& gas,
                              const CoupledLoopState& loop, const GasBlock& block,
                              const Communicator& comm) {
  if constexpr (std::is_same_v<Scheme, dem::DistributedExplicitScheme>) {
    scheme.canonicalize();
    gather_rank_particles(scheme, particles, comm, c);
  } else {
    gather_subiterated(scheme, particles, comm, c);
  }
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

namespace {

// This rank's share of the held gas force (the checkpoint's particles `taken` by rank_share);
// empty when no gas step came before the checkpoint.
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

} // namespace

void restore_coupled_scheme(const Checkpoint& ck, const std::vector<std::uint32_t>& taken,
                            const dem::ContactHistory& history,
                            dem::DistributedExplicitScheme& scheme) {
  const auto f = held_share(ck, taken);
  scheme.set_external_force(f[0], f[1], f[2]);
  scheme.restore(
      {ck.state.steps, ck.state.particle_steps, ck.state.pair_evaluations, ck.state.builds},
      history);
}

template <class Scheme>
void restore_coupled_scheme(const Checkpoint& ck, const std::vector<std::uint32_t>& taken,
                            typename SubiteratedState<Scheme>::State state, Scheme& scheme) {
  scheme.restore_state(std::move(state));
  const auto f = held_share(ck, taken);
  scheme.set_external_force(f[0], f[1], f[2]);
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

template void write_coupled_checkpoint(const std::string&, Checkpoint,
                                       dem::DistributedExplicitScheme&, const ParticleStore&,
                                       const GasCoupling&, const CoupledLoopState&, const GasBlock&,
                                       const Communicator&);
template void write_coupled_checkpoint(const std::string&, Checkpoint, dem::DistributedOrbScheme&,
                                       const ParticleStore&, const GasCoupling&,
                                       const CoupledLoopState&, const GasBlock&,
                                       const Communicator&);
template void write_coupled_checkpoint(const std::string&, Checkpoint,
                                       dem::IslandsScheme&, const ParticleStore&,
                                       const GasCoupling&, const CoupledLoopState&, const GasBlock&,
                                       const Communicator&);
template void restore_coupled_scheme(const Checkpoint&, const std::vector<std::uint32_t>&,
                                     dem::OrbScheme::State, dem::DistributedOrbScheme&);
template void restore_coupled_scheme(const Checkpoint&, const std::vector<std::uint32_t>&,
                                     dem::IslandsScheme::State, dem::IslandsScheme&);

} // namespace cfddem::apps
