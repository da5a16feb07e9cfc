// The `explicit` scheme over MPI ranks: the same velocity Verlet step as ExplicitScheme (the same
// passes, dem/verlet_passes.hpp), each rank advancing the particles it owns. Ownership: the
// domain is cut into 2^L boxes by the parallel ORB, listed along a Hilbert curve and dealt to
// ranks by the knapsack (partition/rank_decomposition.hpp). Each rank's store holds its owned
// particles [0, owned()) and then ghost copies: every particle (or periodic image of one, its
// own included) within the halo 2 r_max + skin of one of the rank's boxes, stored at the image
// position, so the rank-local cell list and Verlet list need no periodic wrap. The full list
// gives each owned particle its whole force with no reverse communication, summed in a fixed
// row order: bitwise the same result for any thread count with the same rank count; different
// rank counts agree with the serial scheme to round-off (the sums run in another order).
//
// Update sequence of a step (LAMMPS's): forces on owned rows, kick-drift of owned particles,
// then the ghosts' new x and v are posted to the ranks holding them, with one reduction of the
// displacement and fault flags in flight alongside. The forward completes during the next
// step's forces: rows whose neighbours are all owned first, then the ghost-touching ones. When
// some particle on some rank moved more than skin/2, the next step instead wraps, regrids (when
// dem.regrid_interval has passed since the last), migrates to owners and rebuilds ghosts and
// the local list. No array is sized by the domain or the global count.
// With friction, angular velocities travel with particles and ghosts (a contact reads its
// partner's spin), and each owned row's tangential history travels with its particle, keyed by
// partner id (dem/contact_history.hpp), and is reattached to the new list as ExplicitScheme
// carries it over a rebuild. A coupled run fixes the decomposition to the fluid's boxes
// (set_decomposition) and hands in the gas's force per particle (set_external_force).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_exchange.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/contact_history.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/external_force.hpp"
#include "dem/step_report.hpp"
#include "dem/verlet_list.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::dem {

class DistributedExplicitScheme {
public:
  // `particles`: this rank's share of the initial particles, any split (start() moves each to
  // its owner). `model`: the step model of the whole system, the same on every rank
  // (make_step_model over all initial particles). With friction the store gets rotation fields.
  DistributedExplicitScheme(const Scene& scene, ParticleStore& particles, const StepModel& model,
                            const Communicator& comm, PhaseTimer& timer);
  // Completes a ghost forward still in flight (collective, as every step).
  ~DistributedExplicitScheme();
  DistributedExplicitScheme(const DistributedExplicitScheme&) = delete;
  DistributedExplicitScheme& operator=(const DistributedExplicitScheme&) = delete;

  // Ownership fixed by the caller instead of the particle ORB (the fluid boxes of a coupled
  // run: partition/cell_box_decomposition.hpp); never regridded. Call before start(); the same
  // decomposition on every rank.
  void set_decomposition(partition::RankDecomposition d);
  // Collective, between steps of a started run: a decomposition set since the last step takes
  // effect now (particles move to their new owners, lists and ghosts are rebuilt), as the next
  // step would do first; so a caller can use the new owners before it (a gas that moved its
  // boxes deposits the particles they hold).
  void redistribute_now() {
    if (need_rebuild_) rebuild();
  }
  // Collective. External force [N] on the owned particles [0, owned()) in the store's current
  // order (the gas's drag and pressure force), held until the next call and carried with the
  // particles when they migrate. Empty spans on every rank remove it (a rank without particles
  // passes empty spans either way). Throws std::invalid_argument for a wrong size.
  void set_external_force(std::span<const double> fx, std::span<const double> fy,
                          std::span<const double> fz);
  [[nodiscard]] bool has_external_force() const { return ext_.active(); }

  // Collective. As ExplicitScheme::start: decomposition, ghosts, forces at t = 0, v(-dt/2).
  void start();
  // Collective. As ExplicitScheme::step; every rank throws the same RunError on a fault.
  void step(bool record = false);

  double dt() const { return model_.dt; }
  std::int64_t steps_taken() const { return steps_; }
  double time() const { return static_cast<double>(steps_) * model_.dt; }
  // Over all ranks (the same value on every rank).
  std::int64_t particle_steps() const { return particle_steps_; }
  std::int64_t pair_evaluations() const { return pair_evaluations_; }
  // This rank's share of the work since this process started (run.json's rank_counts; not in
  // checkpoints): owned particle steps and the pairs of its list, halved (a pair with a ghost counts on both ranks).
  std::int64_t local_particle_steps() const { return local_particle_steps_; }
  std::int64_t local_pair_evaluations() const { return local_pair_evaluations_; }
  std::int64_t neighbor_builds() const { return builds_; }
  std::int64_t global_count() const { return n_global_; }
  // Over all ranks: tangential history records (contacts with a non-zero spring) that moved to
  // another rank with their particle at rebuilds so far.
  std::int64_t history_migrations() const { return history_migrations_; }
  const StepModel& model() const { return model_; }

  // This rank: owned particles are [0, owned()) of the store, ghosts [owned(), size()).
  std::size_t owned() const { return owned_; }
  std::size_t ghosts() const { return p_.size() - owned_; }
  std::size_t local_cells() const { return list_.cell_count(); }
  int levels() const { return levels_; }

  // x(n), v(n) of the owned particles at the last recorded step (ExplicitScheme's meaning).
  ExplicitScheme::Synchronised synchronised_previous() const {
    return {sx_, sy_, sz_, svx_, svy_, svz_};
  }

  // Checkpoint/restart on R ranks. canonicalize() (collective) regrids now and rebuilds ghosts and
  // lists with the owned particles in (cell, id) order: a state that depends only on the
  // particles, not on how they came to be where they are. A checkpoint is written right after
  // it; a restart hands every rank a share of the checkpoint's particles (any split, as at the
  // start), calls restore() instead of start(), and continues bit for bit.
  struct Counters {
    std::int64_t steps = 0, particle_steps = 0, pair_evaluations = 0, builds = 0;
  };
  // With friction a checkpoint also holds the contact history (contact_history(), this rank's
  // records, after canonicalize()); restore() takes the records of all ranks (or any superset
  // of this rank's share's: each rank keeps those whose owner it holds).
  void canonicalize();
  Counters counters() const { return {steps_, particle_steps_, pair_evaluations_, builds_}; }
  ContactHistory contact_history() const;
  void restore(const Counters& c, const ContactHistory& history = {});

  struct Regrid {
    std::int64_t step = 0;
    double imbalance = 1.0; // max / mean particles per rank
  };
  const std::vector<Regrid>& regrids() const { return regrids_; }
  const partition::RankDecomposition& decomposition() const { return decomposition_; }

private:
  void rebuild();
  void ghost_copies(std::vector<ParticleExchange::Copy>& out) const;
  template <bool Walls, bool Friction> void update(double dt, StepReport& rep);
  template <bool Friction>
  void contact_rows(std::span<const std::uint32_t> rows, double dt, StepReport& rep);
  void evaluate_and_update(double dt, StepReport& rep);
  // Forces on the owned rows; a forward in flight completes after the interior rows.
  void contact(double dt, StepReport& rep);
  void finish_forward();
  void record_synchronised();
  // Collective: every rank learns whether any has a fault, and all throw the same error.
  void agree(const StepReport& rep, double t) const;

  const Scene& scene_;
  ParticleStore& p_;
  const Communicator& comm_;
  PhaseTimer& timer_;
  DomainGeometry geom_;  // the whole domain: walls and periodic lengths
  DomainGeometry local_; // the frame of the rank-local list: no periodic axis
  StepModel model_;
  ParticleExchange exchange_;
  partition::RankDecomposition decomposition_;
  VerletList list_;
  ExternalForce ext_;
  // Tangential history per list entry (friction only), and records handed in by restore() that
  // the next rebuild reattaches.
  std::vector<double> hx_, hy_, hz_;
  ContactHistory pending_;
  bool ext_on_ = false; // set_external_force: on for every rank alike
  bool fixed_decomposition_ = false;
  std::vector<double> sx_, sy_, sz_, svx_, svy_, svz_;
  std::vector<Regrid> regrids_;
  std::size_t owned_ = 0;
  int levels_ = 0;
  double halo_ = 0.0;
  std::int64_t regrid_every_ = 0, last_regrid_ = -1;
  std::int64_t n_global_ = 0, global_pairs_ = 0, history_migrations_ = 0;
  bool need_rebuild_ = true;
  bool forward_pending_ = false; // ghost x, v (w) of the last step still in flight
  std::int64_t steps_ = 0, particle_steps_ = 0, pair_evaluations_ = 0, builds_ = 0;
  std::int64_t local_particle_steps_ = 0, local_pair_evaluations_ = 0;
};

} // namespace cfddem::dem
