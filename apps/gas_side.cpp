#include "apps/gas_side.hpp"

#include <array>
#include <stdexcept>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include "apps/coupled_checkpoint.hpp"
#include "apps/gas_rebalance.hpp"
#include "core/error.hpp"
#include "core/next_time.hpp"
#include "fluid/multigrid_poisson.hpp"
#include "fluid/pressure_projection.hpp"
#include "partition/cell_box_decomposition.hpp"

namespace cfddem::apps {

namespace {

// Gas regrids move the boxes only when the predicted largest load drops by more than this
// fraction of the mean, so a balanced run does not churn.
constexpr double kRegridGain = 0.02;

// Boxes of gas cells as a decomposition of the domain (the same on every rank).
partition::RankDecomposition box_decomposition(const Scene& scene,
                                               const std::vector<CellBox>& boxes) {
  const fluid::MacGridSpec spec = fluid_grid_spec(scene);
  std::array<double, 3> spacing{};
  for (int a = 0; a < 3; ++a)
    spacing[a] = spec.spacing[a] > 0.0 ? spec.spacing[a] : spec.extent[a] / spec.cells[a];
  return partition::decomposition_of_cell_boxes(boxes, spec.origin, spacing,
                                                {scene.domain.lo, scene.domain.hi});
}

} // namespace

GasSide::GasSide(const Scene& scene, const Communicator& comm, bool routed,
                 const std::vector<CellBox>& boxes)
    : scene_(scene), comm_(comm), routed_(routed && comm.size() > 1), geom_(scene.domain) {
  if (comm_.size() == 1)
    return;
  boxes0_ =
      boxes.size() == static_cast<std::size_t>(comm_.size()) ? boxes : gas_boxes(scene, &comm_);
  if (routed_)
    routing_.emplace(comm_, box_decomposition(scene_, boxes0_), geom_);
}

partition::RankDecomposition GasSide::box_owners() const {
  return box_decomposition(scene_, boxes0_);
}

void GasSide::prepare(const ParticleStore& p) {
  // The largest radius over every rank's particles: the deposition's reach. Before start() a
  // store holds only its rank's own particles, so this is the maximum the first deposit's
  // particles (owned or routed copies, after start()) would give.
  gas_.emplace(scene_, GasCoupling::largest_radius(p, &comm_), &comm_, boxes0_);
}

void GasSide::attach(const ParticleStore& p, std::size_t owned) {
  if (!gas_)
    throw std::logic_error("GasSide::attach before prepare");
  if (routed_)
    gas_->attach(routing_->route(p, owned), GasCoupling::kAllParticles);
  else
    gas_->attach(p, comm_.size() == 1 ? GasCoupling::kAllParticles : owned);
}

void GasSide::restore(Checkpoint& ck, const std::string& path, CoupledLoopState& loop) {
  try {
    gas_->restore_state(ck.gas_state);
  } catch (const RunError& e) {
    throw ConfigError(path, fmt::format("cannot restart: {}", e.what()));
  }
  loop = std::move(ck.loop);
  loop.held_force = {}; // the scheme holds it
  // A pending snapshot's cells: an R-rank checkpoint leaves them to the gas restored.
  if (loop.snapshot_pending && (loop.snapshot_cells.eps_g.empty() || comm_.size() > 1))
    loop.snapshot_cells = gas_->cell_fields();
}

std::optional<partition::RankDecomposition> GasSide::regrid(const ParticleStore& p,
                                                            std::size_t owned, double t, double tol,
                                                            long long last_n_sub) {
  const double every = scene_.partition.gas_regrid_interval;
  if (comm_.size() == 1 || every <= 0.0)
    return std::nullopt;
  if (next_regrid_ < 0.0) {
    // From the start time on: a restart, whose boxes are those its checkpoint was written from
    // and whose last fluid step's particle steps the checkpoint keeps, regrids when and as the
    // run that wrote it did.
    next_regrid_ = next_time_after(every, every, t - tol);
  }
  if (last_n_sub <= 0 || t < next_regrid_ - tol)
    return std::nullopt;
  next_regrid_ = next_time_after(next_regrid_, every, t + tol);
  // The particles this rank's box deposits now (routed: copies of the particles as they stand,
  // sent to the boxes; those of the last fluid step stood where it began, which a restart at
  // this time does not know), each weighing the particle steps of the last fluid step.
  const ParticleStore& dep = routed_ ? routing_->route(p, owned) : p;
  const std::size_t n = routed_ ? dep.size() : owned;
  std::vector<double> w[3] = {std::vector<double>(n), std::vector<double>(n),
                              std::vector<double>(n)};
  for (std::size_t i = 0; i < n; ++i)
    w[0][i] = geom_.wrap(dep.x[i], 0), w[1][i] = geom_.wrap(dep.y[i], 1),
    w[2][i] = geom_.wrap(dep.z[i], 2);
  const std::vector<double> steps(n, static_cast<double>(last_n_sub));
  GasBalance b;
  try {
    b = balance_gas_boxes(*gas_, w[0], w[1], w[2], steps, scene_.partition.cell_weight, comm_);
  } catch (const std::invalid_argument& e) {
    throw ConfigError("scene key 'fluid.cells'", e.what());
  }
  const bool move =
      b.boxes != gas_->boxes() && b.imbalance_after < b.imbalance_before - kRegridGain;
  std::size_t sent = 0;
  std::optional<partition::RankDecomposition> owners;
  if (move) {
    sent = gas_->rebox(b.boxes);
    if (routed_)
      routing_->set_boxes(box_decomposition(scene_, b.boxes)); // the next route() follows
    else
      owners = box_decomposition(scene_, b.boxes);
  }
  regrids_.push_back({{"time", t},
                      {"imbalance_before", b.imbalance_before},
                      {"imbalance_after", move ? b.imbalance_after : b.imbalance_before},
                      {"moved", move},
                      {"gas_values_sent", comm_.sum(static_cast<std::int64_t>(sent))}});
  return owners;
}

GasSide::Force GasSide::step(const ParticleStore& p, std::size_t owned, double dt_f) {
  if (routed_) {
    gas_->step(routing_->route(p, owned), dt_f);
    routing_->return_force({gas_->force(0), gas_->force(1), gas_->force(2)});
    return {routing_->force(0), routing_->force(1), routing_->force(2)};
  }
  gas_->step(p, dt_f, comm_.size() == 1 ? GasCoupling::kAllParticles : owned);
  return {gas_->force(0), gas_->force(1), gas_->force(2)};
}

void GasSide::write_checkpoint(const std::string& path, Checkpoint c,
                               const ParticleStore& particles, const CoupledLoopState& loop) const {
  if (comm_.size() > 1) {
    // The gas box now (a gas regrid may have moved it from the count cut).
    c.gas_boxes = gas_->boxes();
    const GasBlock block{gas_->solver().grid().global_cells(),
                         gas_->boxes()[static_cast<std::size_t>(comm_.rank())]};
    write_coupled_checkpoint(path, std::move(c), *gas_, loop, block, comm_);
    return;
  }
  c.gas = true;
  c.gas_cells = gas_->solver().grid().global_cells();
  c.gas_state = gas_->save_state();
  c.loop = loop;
  c.loop.held_force = gas_->force_in_order(particles.id);
  apps::write_checkpoint(path, c);
}

std::int64_t GasSide::cell_updates() const {
  const auto& box = gas_->solver().grid().cells();
  return static_cast<std::int64_t>(box[0]) * box[1] * box[2] * gas_->gas_substeps();
}

void GasSide::describe(nlohmann::ordered_json& j, const CoupledLoopState& loop, long long steps_run,
                       double loop_seconds, double fluid_seconds) const {
  j["fluid_steps"] = loop.fluid_steps;
  j["fluid_dt_mean"] =
      loop.fluid_steps > 0 ? loop.dt_f_sum / static_cast<double>(loop.fluid_steps) : 0.0;
  const auto steps = static_cast<double>(steps_run);
  j["gas_substeps"] = gas_->gas_substeps();
  j["implicit_viscosity_steps"] = gas_->implicit_viscosity_steps();
  j["projection_iterations"] = gas_->projection_iterations();
  j["viscous_iterations"] = gas_->viscous_iterations();
  j["projection_fallbacks"] = gas_->projection_fallbacks();
  j["wall_seconds_per_fluid_step"] = steps_run > 0 ? loop_seconds / steps : 0.0;
  const FluidPhaseSeconds& f = gas_->phase_seconds();
  j["fluid_phase_seconds"] = {{"deposition", f.deposition}, {"momentum", f.momentum},
                              {"viscous", f.viscous},       {"projection", f.projection},
                              {"gas_other", f.gas_other},   {"interpolation", f.interpolation}};
  if (comm_.size() > 1)
    j["fluid_phase_seconds"]["note"] = "rank 0's";
  if (comm_.size() == 1)
    return;
  // The multigrid's coarse level gathered onto rank 0: one V-cycle of it per projection
  // iteration while the other ranks wait (docs/multigrid.md, "Gathered coarse level").
  if (const fluid::MultigridPoisson* mg = gas_->solver().projection().multigrid()) {
    const std::array<int, 3> g = mg->gathered_cells();
    j["projection_gathered_cells"] = g;
    j["projection_gathered_definition"] =
        "global cells of the multigrid level gathered onto rank 0 and solved there by one "
        "V-cycle per projection iteration (the first level no axis of which halves over every "
        "rank's box, or of at most 4096 cells); a large one is the projection's serial part";
  }
  const std::vector<double> fluid = comm_.gather(fluid_seconds);
  const std::vector<double> routing = comm_.gather(routing_ ? routing_->seconds() : 0.0);
  const std::vector<double> away =
      comm_.gather(routing_ ? static_cast<double>(routing_->sent_away()) : 0.0);
  j["fluid_seconds"] = fluid;
  std::vector<std::int64_t> cells;
  for (const CellBox& b : gas_->boxes())
    cells.push_back(b.count());
  j["gas_cells_per_rank"] = cells;
  if (routed_) {
    j["decomposition"] = "the gas grid's ORB boxes, one per rank; particles owned by their "
                         "leaf's rank (parallel ORB + knapsack), routed to their gas box's rank "
                         "and their force back once per fluid step (boxes cut by cell count, "
                         "then by weight at gas regrids)";
    double worst = 0.0;
    for (const double r : routing)
      worst = std::max(worst, r);
    j["gas_routing_seconds"] = routing;
    j["gas_routing_seconds_per_fluid_step"] = steps_run > 0 ? worst / steps : 0.0;
    j["gas_routing_copies_away_at_end"] = away;
    j["gas_routing_definition"] = "per rank: wall time packing, sending and unpacking the "
                                  "particle copies to the gas boxes and their forces back "
                                  "(part of the fluid phase); per fluid step: the slowest "
                                  "rank's; copies away: particles of the last fluid step "
                                  "whose gas box is on another rank";
  } else {
    j["decomposition"] = "the gas grid's ORB boxes, one per rank (cut by cell count, then by "
                         "weight at gas regrids); particles owned by the rank whose box holds "
                         "them (settled at neighbor rebuilds and gas regrids)";
  }
  j["gas_regrids"] = regrids_;
}

} // namespace cfddem::apps
