#include "apps/rank_checkpoint.hpp"

#include <algorithm>
#include <numeric>
#include <span>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "core/error.hpp"

namespace cfddem::apps {

void gather_rank_particles(const dem::ExplicitScheme& scheme, const ParticleStore& particles,
                           const Communicator& comm, Checkpoint& c) {
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
  // Friction: the spin and the contact history (records by id) travel to rank 0 as well.
  std::vector<double> spin[4];
  dem::ContactHistory history;
  if (particles.rotation) {
    const std::span<const double> w[] = {{particles.wx.data(), n},
                                         {particles.wy.data(), n},
                                         {particles.wz.data(), n},
                                         {particles.inv_inertia.data(), n}};
    for (int q = 0; q < 4; ++q)
      spin[q] = comm.gather(w[q]);
    const dem::ContactHistory h = scheme.contact_history();
    history.owner = comm.gather(std::span<const std::int64_t>(h.owner));
    history.partner = comm.gather(std::span<const std::int64_t>(h.partner));
    history.hx = comm.gather(std::span<const double>(h.hx));
    history.hy = comm.gather(std::span<const double>(h.hy));
    history.hz = comm.gather(std::span<const double>(h.hz));
  }
  std::string error;
  if (comm.rank() == 0) {
    try {
      auto& st = dem::state_of<dem::ExplicitScheme::State>(c.scheme_state);
      std::vector<std::size_t> order(ids.size());
      std::iota(order.begin(), order.end(), std::size_t{0});
      std::sort(order.begin(), order.end(),
                [&](std::size_t a, std::size_t b) { return ids[a] < ids[b]; });
      c.particles.resize(ids.size());
      std::vector<double>* field[9] = {
          &c.particles.x,      &c.particles.y,    &c.particles.z,
          &c.particles.vx,     &c.particles.vy,   &c.particles.vz,
          &c.particles.radius, &c.particles.mass, &c.particles.inv_mass};
      for (std::size_t i = 0; i < order.size(); ++i) {
        for (int q = 0; q < 9; ++q)
          (*field[q])[i] = all[q][order[i]];
        c.particles.id[i] = ids[order[i]];
      }
      if (particles.rotation) {
        c.particles.enable_rotation();
        std::vector<double>* w[4] = {&c.particles.wx, &c.particles.wy, &c.particles.wz,
                                     &c.particles.inv_inertia};
        for (std::size_t i = 0; i < order.size(); ++i)
          for (int q = 0; q < 4; ++q)
            (*w[q])[i] = spin[q][order[i]];
        // No reference positions: the list itself is rebuilt at a restart.
        dem::HistoryRows rows = dem::history_rows(history, c.particles.id);
        st.offsets = std::move(rows.offsets);
        st.neighbors = std::move(rows.neighbors);
        st.hx = std::move(rows.hx), st.hy = std::move(rows.hy);
        st.hz = std::move(rows.hz);
      }
      const auto cnt = scheme.counters();
      st.steps = cnt.steps, st.particle_steps = cnt.particle_steps;
      st.pair_evaluations = cnt.pair_evaluations, st.builds = cnt.builds;
      st.need_rebuild = true;
      st.skin = scheme.model().skin;
    } catch (const std::exception& e) {
      error = e.what();
    }
  }
  if (const std::string m = comm.agree_on_error(0, error); !m.empty())
    throw RunError(m);
}

dem::ContactHistory saved_contact_history(const Checkpoint& ck) {
  const auto& st = std::get<dem::ExplicitScheme::State>(ck.scheme_state);
  if (st.hx.empty())
    return {}; // no friction (the rows, if any, are a serial list without history) or no contact
  return dem::history_from_rows(ck.particles.id, st.offsets, st.neighbors, st.hx, st.hy, st.hz);
}

template <class Scheme>
void gather_subiterated(Scheme& scheme, const ParticleStore& particles, const Communicator& comm,
                        Checkpoint& c) {
  typename Scheme::State state = scheme.save_state();
  const std::vector<double> own_second = dem::second_values(state);
  const std::size_t n = scheme.owned();
  const std::span<const double> own[] = {{particles.x.data(), n},
                                         {particles.y.data(), n},
                                         {particles.z.data(), n},
                                         {particles.vx.data(), n},
                                         {particles.vy.data(), n},
                                         {particles.vz.data(), n},
                                         {particles.radius.data(), n},
                                         {particles.mass.data(), n},
                                         {particles.inv_mass.data(), n},
                                         state.hprev,
                                         own_second};
  std::vector<double> all[11];
  for (int q = 0; q < 11; ++q)
    all[q] = comm.gather(own[q]);
  const std::vector<std::int64_t> ids =
      comm.gather(std::span<const std::int64_t>(particles.id.data(), n));
  // With friction (orb): the spins and this rank's tangential history records by ids.
  std::vector<double> spin[4];
  if (particles.rotation) {
    const std::vector<double>* w[4] = {&particles.wx, &particles.wy, &particles.wz,
                                       &particles.inv_inertia};
    for (int q = 0; q < 4; ++q)
      spin[q] = comm.gather(std::span<const double>(w[q]->data(), n));
  }
  dem::ContactHistory history;
  if constexpr (requires { state.history; }) {
    const auto& h = state.history;
    const auto owner = comm.gather(std::span<const std::int64_t>(h.owner));
    const auto partner = comm.gather(std::span<const std::int64_t>(h.partner));
    const auto hx = comm.gather(std::span<const double>(h.hx));
    const auto hy = comm.gather(std::span<const double>(h.hy));
    const auto hz = comm.gather(std::span<const double>(h.hz));
    for (std::size_t q = 0; q < owner.size(); ++q)
      history.add(owner[q], partner[q], hx[q], hy[q], hz[q]);
  }
  std::string error;
  if (comm.rank() == 0) {
    try {
      std::vector<std::size_t> order(ids.size());
      std::iota(order.begin(), order.end(), std::size_t{0});
      std::sort(order.begin(), order.end(),
                [&](std::size_t a, std::size_t b) { return ids[a] < ids[b]; });
      c.particles.resize(ids.size());
      std::vector<double> second_all(ids.size());
      state.hprev.resize(ids.size());
      std::vector<double>* field[11] = {
          &c.particles.x,        &c.particles.y,  &c.particles.z,      &c.particles.vx,
          &c.particles.vy,       &c.particles.vz, &c.particles.radius, &c.particles.mass,
          &c.particles.inv_mass, &state.hprev,    &second_all};
      for (std::size_t i = 0; i < order.size(); ++i) {
        for (int q = 0; q < 11; ++q)
          (*field[q])[i] = all[q][order[i]];
        c.particles.id[i] = ids[order[i]];
      }
      if (particles.rotation) {
        c.particles.enable_rotation();
        std::vector<double>* w[4] = {&c.particles.wx, &c.particles.wy, &c.particles.wz,
                                     &c.particles.inv_inertia};
        for (std::size_t i = 0; i < order.size(); ++i)
          for (int q = 0; q < 4; ++q)
            (*w[q])[i] = spin[q][order[i]];
      }
      if constexpr (requires { state.history; })
        state.history = std::move(history);
      dem::set_second_values(state, std::move(second_all));
      c.scheme_state = std::move(state);
    } catch (const std::exception& e) {
      error = e.what();
    }
  }
  if (const std::string m = comm.agree_on_error(0, error); !m.empty())
    throw RunError(m);
}

template <class Scheme>
typename Scheme::State
subiterated_share(Checkpoint& ck, const std::vector<std::uint32_t>& mine, std::size_t particles,
                  const std::string& path) {
  using State = typename Scheme::State;
  State state = std::move(std::get<State>(ck.scheme_state));
  const std::vector<double> second = dem::second_values(state);
  if (state.hprev.size() != particles || second.size() != particles)
    throw ConfigError(path, fmt::format("the {} state does not fit the checkpoint's particles",
                                        dem::scheme_name(dem::SchemeState(std::move(state)))));
  std::vector<double> h, q;
  for (const std::uint32_t i : mine)
    h.push_back(state.hprev[i]), q.push_back(second[i]);
  state.hprev = std::move(h);
  dem::set_second_values(state, std::move(q));
  return state;
}

template void gather_subiterated(dem::OrbScheme&, const ParticleStore&, const Communicator&,
                                 Checkpoint&);
template void gather_subiterated(dem::IslandsScheme&, const ParticleStore&, const Communicator&,
                                 Checkpoint&);
template dem::OrbScheme::State
subiterated_share<dem::OrbScheme>(Checkpoint&, const std::vector<std::uint32_t>&, std::size_t,
                                  const std::string&);
template dem::IslandsScheme::State
subiterated_share<dem::IslandsScheme>(Checkpoint&, const std::vector<std::uint32_t>&, std::size_t,
                                      const std::string&);

} // namespace cfddem::apps
