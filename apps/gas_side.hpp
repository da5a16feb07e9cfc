// The gas half of the paper's Algorithm 1 for the one time loop (apps/run_loop.hpp), on one rank
// or R: per fluid step, deposit + gas step + particle force (GasCoupling::step), handed to the
// scheme for its particle sub-cycle. The loop holds none without a gas.
//
// On R ranks the gas grid is cut into one box per rank. The explicit scheme owns its particles
// by those boxes (box_owners() is its decomposition), so the gas deposits the owned particles
// directly; a sub-iterated scheme owns them by its own leaves, so each fluid step routes copies
// to the gas boxes and the forces back (`routed`, apps/gas_routing.hpp). Gas regrids
// (partition.gas_regrid_interval) recut the boxes by weight.
#pragma once

#include <array>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/coupled_step.hpp"
#include "apps/gas_routing.hpp"
#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "core/scene.hpp"
#include "dem/domain_geometry.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::apps {

class GasSide {
public:
  using Force = std::array<std::span<const double>, 3>;
  // `scene`: with the particle step the coupling sets (outlives this object). Before the
  // scheme starts: the gas grid cut into `boxes` (a restart's, one per rank: the boxes its
  // checkpoint was written from), or by cell count where that is empty.
  GasSide(const Scene& scene, const Communicator& comm, bool routed,
          const std::vector<CellBox>& boxes);
  // The boxes as the owners of the particles (an unrouted scheme on R ranks).
  [[nodiscard]] partition::RankDecomposition box_owners() const;
  // In the set-up, with this rank's particles before start(): the grid, the solver and their
  // fields (collective), so that their allocation and first touch are not the loop's.
  void prepare(const ParticleStore& p);
  // After start() or a restore: the gas on this rank's `owned` particles (their first deposit).
  void attach(const ParticleStore& p, std::size_t owned);
  // A restart: the gas state and the loop's position (ConfigError naming `path`).
  void restore(Checkpoint& ck, const std::string& path, CoupledLoopState& loop);

  // R ranks, at a fluid-step boundary t: recut the boxes when a regrid is due and it pays;
  // returns the new owners when they moved (for an unrouted scheme). Collective.
  std::optional<partition::RankDecomposition> regrid(const ParticleStore& p, std::size_t owned,
                                                     double t, double tol, long long last_n_sub);
  // Deposit, gas step and the force on the `owned` particles, in the store's order.
  Force step(const ParticleStore& p, std::size_t owned, double dt_f);

  // Fills the gas part of `c` (particles already in it, rank 0's on R ranks) and writes it.
  void write_checkpoint(const std::string& path, Checkpoint c, const ParticleStore& particles,
                        const CoupledLoopState& loop) const;
  // run.json's gas entries; collective (the per-rank ones are gathered). steps_run: the fluid
  // steps this run took (a restart's loop counts on from its checkpoint), for the per-step times.
  void describe(nlohmann::ordered_json& j, const CoupledLoopState& loop, long long steps_run,
                double loop_seconds, double fluid_seconds) const;
  // Gas cell updates of this rank (box cells x gas sub-steps), for rank_counts.
  [[nodiscard]] std::int64_t cell_updates() const;

  [[nodiscard]] GasCoupling& coupling() { return *gas_; }
  [[nodiscard]] const GasCoupling& coupling() const { return *gas_; }

private:
  const Scene& scene_;
  const Communicator& comm_;
  bool routed_;
  dem::DomainGeometry geom_;
  std::vector<CellBox> boxes0_;
  std::optional<GasRouting> routing_;
  std::optional<GasCoupling> gas_;
  double next_regrid_ = -1.0;
  nlohmann::ordered_json regrids_ = nlohmann::ordered_json::array();
};

} // namespace cfddem::apps
