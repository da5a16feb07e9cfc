// The `explicit` scheme: one global time step for every particle (tau_p * dem.dt_factor), velocity
// Verlet in the paper's form (v at half steps, x at whole steps). Each step is two passes: contact
// forces, each pair's once over a half neighbor list and then added to both particles in a fixed
// order, and a branch-free update of every particle that the compiler vectorizes
// (dem/verlet_passes.hpp). It is the baseline every adaptive scheme is measured against, so it is
// written to be as fast as we can.
//
// One class for any rank count. On one rank (no communicator, or one of size 1) the store holds
// the whole system and the list is periodic by minimum image, reused until some particle has
// moved skin/2. On R > 1 ranks (dem/explicit_ranks.cpp) each rank advances the particles it
// owns: the domain is cut into 2^L boxes by the parallel ORB, listed along a Hilbert curve and
// dealt to ranks by the knapsack (partition/rank_decomposition.hpp). A rank's store holds its
// owned particles [0, owned()) and then ghost copies: every particle (or periodic image of one,
// its own included) within the halo 2 r_max + skin of one of its boxes, stored at the image
// position, so the rank-local list needs no periodic wrap. A pair of two owned particles is
// computed once; a pair with a ghost is computed on both its ranks, so each owned particle gets
// its whole force with no reverse communication, summed in a fixed order: bitwise the same
// result for any thread count with the same rank count; different rank counts agree to
// round-off (the sums run in another order).
//
// Update sequence of a step on R ranks (LAMMPS's): forces on owned rows, kick-drift of owned
// particles, then the ghosts' new x and v are posted to the ranks holding them, with one
// reduction of the displacement and fault flags in flight alongside. The forward completes
// during the next step's forces: pairs of two owned particles first, then those with a ghost. When
// some particle on some rank moved more than skin/2, the next step instead wraps, regrids (when
// dem.regrid_interval has passed since the last), migrates to owners and rebuilds ghosts and the
// local list. With friction, angular velocities travel with the particles and ghosts, and each
// row's tangential history is carried over a rebuild keyed by partner id (dem/contact_history.hpp),
// on one rank and across ranks alike.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/contact_history.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/external_force.hpp"
#include "dem/pair_contacts.hpp"
#include "dem/pair_stream.hpp"
#include "dem/step_model.hpp"
#include "dem/step_report.hpp"
#include "dem/travel_bound.hpp"
#include "dem/verlet_list.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::dem {

class ExplicitScheme {
public:
  // One rank: `particles` is the whole system; the step model is made from it.
  ExplicitScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer);
  // Any rank count: `comm` null or of size 1 is one rank (the constructor above, with `model`).
  // On R > 1 ranks `particles` is this rank's share of the initial particles, any split (start()
  // moves each to its owner), and `model` the step model of the whole system, the same on every
  // rank (make_step_model over all initial particles). With friction the store gets rotation.
  ExplicitScheme(const Scene& scene, ParticleStore& particles, const StepModel& model,
                 const Communicator* comm, PhaseTimer& timer);
  // Completes a ghost forward still in flight (collective on R ranks, as every step).
  ~ExplicitScheme();
  ExplicitScheme(const ExplicitScheme&) = delete;
  ExplicitScheme& operator=(const ExplicitScheme&) = delete;

  // Evaluate forces at t = 0 and set the half-step velocity v(-dt/2) = v(0) - a(0) dt/2, so the
  // first step reproduces velocity Verlet started from v(0). Builds the neighbor list (on R
  // ranks first the decomposition and ghosts). Collective.
  void start();
  // One step: x(n) -> x(n+1), v(n-1/2) -> v(n+1/2). Throws RunError naming particle, time, cause
  // (on R ranks every rank throws the same). With record = true the state at time n (x(n) and
  // the synchronised velocity v(n)) is kept for synchronised_previous(). Collective.
  void step(bool record = false);

  double dt() const { return model_.dt; }
  std::int64_t steps_taken() const { return stats_.steps; }
  double time() const { return static_cast<double>(stats_.steps) * model_.dt; }
  // Over all ranks (the same value on every rank).
  std::int64_t particle_steps() const { return stats_.particle_steps; }
  std::int64_t pair_evaluations() const { return stats_.pair_evaluations; }
  std::int64_t neighbor_builds() const { return stats_.builds; }
  // This rank's share of the work since this process started (run.json's rank_counts; not in
  // checkpoints): owned particle steps and the pairs of its list, halved (a pair with a ghost
  // counts on both ranks).
  std::int64_t local_particle_steps() const { return stats_.local_particle_steps; }
  std::int64_t local_pair_evaluations() const { return stats_.local_pair_evaluations; }
  std::int64_t global_count() const;
  // Over all ranks: tangential history records (contacts with a non-zero spring) that moved to
  // another rank with their particle at rebuilds so far (0 on one rank).
  std::int64_t history_migrations() const;
  const StepModel& model() const { return model_; }

  // This rank: owned particles are [0, owned()) of the store, ghosts [owned(), size()). One
  // rank owns every particle and keeps no ghost.
  std::size_t owned() const;
  std::size_t ghosts() const { return p_.size() - owned(); }
  std::size_t local_cells() const { return rows_.list.cell_count(); }
  // ORB levels of the rank decomposition (0 on one rank: no decomposition).
  int levels() const;

  // Per-particle external force [N] on the owned particles [0, owned()) in the store's current
  // order (the gas's drag and pressure force), added in the update pass and held until set again
  // (MFIX-Exa holds it over the particle sub-cycle, docs/theory.md §2); on R ranks carried with
  // the particles when they migrate. Empty spans remove it (on R ranks: on every rank; a rank
  // without particles passes empty spans either way). Without one the update pass is the same
  // instantiation as before (no extra loads). Collective. Throws std::invalid_argument for a
  // wrong size.
  void set_external_force(std::span<const double> fx, std::span<const double> fy,
                          std::span<const double> fz);
  [[nodiscard]] bool has_external_force() const { return ext_.active(); }
  // The force held now, in the store's order (empty: none).
  [[nodiscard]] const ExternalForce& external_force() const { return ext_; }

  // Ownership fixed by the caller instead of the particle ORB (the fluid boxes of a coupled
  // run: partition/cell_box_decomposition.hpp); never regridded. Call before start(); the same
  // decomposition on every rank. Ignored on one rank (it owns everything).
  void set_decomposition(partition::RankDecomposition d);
  // Collective, between steps of a started run: a decomposition set since the last step takes
  // effect now (particles move to their new owners, lists and ghosts are rebuilt), as the next
  // step would do first; so a caller can use the new owners before it. Nothing on one rank.
  void redistribute_now();

  // State at the start of the last step recorded (time() - dt), owned particles: positions x(n)
  // and velocity Verlet's synchronised velocity v(n) = v(n-1/2) + a(n) dt/2.
  struct Synchronised {
    std::span<const double> x, y, z, vx, vy, vz;
  };
  Synchronised synchronised_previous() const {
    return {recorded_.x, recorded_.y, recorded_.z, recorded_.vx, recorded_.vy, recorded_.vz};
  }

  // Checkpoint/restart on one rank: everything beyond the particle store that the next step
  // reads (the neighbor list with its reference positions, tangential history, counters). A
  // scheme built on a restored store and given restore_state() instead of start() continues bit
  // for bit. One rank only (std::logic_error on R ranks: they use canonicalize/restore below).
  struct State {
    std::vector<std::uint32_t> offsets, neighbors;
    std::vector<double> x_ref, y_ref, z_ref;
    std::vector<double> hx, hy, hz;
    double skin = 0.0;
    bool need_rebuild = true;
    std::int64_t steps = 0, particle_steps = 0, pair_evaluations = 0, builds = 0;
  };
  State save_state() const;
  // Throws RunError if the state does not fit the particle store.
  void restore_state(State s);

  // Checkpoint/restart on any rank count. canonicalize() (collective) rebuilds now (on R ranks
  // regrids, and rebuilds ghosts and lists with the owned particles in (cell, id) order): a state
  // that depends only on the particles, not on how they came to be where they are. A checkpoint
  // is written right after it; a restart hands every rank a share of the checkpoint's particles
  // (any split, as at the start), calls restore() instead of start(), and continues bit for bit.
  struct Counters {
    std::int64_t steps = 0, particle_steps = 0, pair_evaluations = 0, builds = 0;
  };
  // With friction a checkpoint also holds the contact history (contact_history(), this rank's
  // records, after canonicalize()); restore() takes the records of all ranks (or any superset
  // of this rank's share's: each rank keeps those whose owner it holds).
  void canonicalize();
  Counters counters() const {
    return {stats_.steps, stats_.particle_steps, stats_.pair_evaluations, stats_.builds};
  }
  ContactHistory contact_history() const;
  void restore(const Counters& c, const ContactHistory& history = {});

  struct Regrid {
    std::int64_t step = 0;
    double imbalance = 1.0; // max / mean particles per rank
  };
  // Empty on one rank, as the decomposition (no leaf).
  const std::vector<Regrid>& regrids() const;
  const partition::RankDecomposition& decomposition() const;

private:
  // The neighbor list and what is kept per entry of it: the tangential history (friction only),
  // and records handed in by restore() that the next rebuild attaches.
  struct Rows {
    VerletList list;
    std::vector<double> hx, hy, hz;
    ContactHistory pending;
    bool need_rebuild = true;
    // The list's pairs laid out flat for the pair passes (with every build or restore of the
    // list: lay_out_pairs), and the contacts of the last passes (buffers kept between steps).
    PairStream head_pairs, tail_pairs;
    std::vector<PairContacts> head, tail;
    std::size_t nh = 0, nt = 0; // blocks of head, tail written by the last pair passes
    bool clear_all = true;      // the next contact pass clears every listed particle's force
    // Owned particles that can touch a wall before the next build (near_walls(), laid out with
    // the pairs): the update pass evaluates wall forces for these only.
    std::vector<std::uint32_t> near_wall;
    // How far the owned particles can have moved since the build (reset by rebuild(), unknown
    // after a restore): the update pass leaves out its displacement test while it cannot fire.
    TravelBound travel;
  };
  // x(n), v(n) of the owned particles at the last recorded step.
  struct Recorded {
    std::vector<double> x, y, z, vx, vy, vz;
  };
  struct Stats {
    std::int64_t steps = 0, particle_steps = 0, pair_evaluations = 0, builds = 0;
    std::int64_t local_particle_steps = 0, local_pair_evaluations = 0;
  };
  // Everything only R > 1 ranks have (dem/explicit_ranks.cpp); null on one rank.
  struct RankPart;

  void rebuild();
  void rebuild_one_rank();
  void lay_out_pairs();
  template <bool Friction>
  void contact_pairs(const DomainGeometry& frame, double dt, StepReport& rep);
  // Forces on the owned particles; on R ranks a forward in flight completes after the pairs of
  // two owned particles.
  void contact(double dt, StepReport& rep);
  // Entries of this rank's list counted as a full list would hold them (a pair of owned
  // particles twice, a pair with a ghost once).
  std::int64_t local_pair_entries2() const;
  template <bool Walls> void update(double dt, StepReport& rep);
  // update_pass over the owned particles with this scheme's list, near-wall list, external force,
  // geometry and model.
  template <bool Walls, bool Friction, bool External> void update_owned(double dt, StepReport& rep);
  void evaluate_and_update(double dt, StepReport& rep);
  void record_synchronised();
  // v(-dt/2) = v(0) - a(0) dt/2 of the owned particles, a(0) from the forces just evaluated.
  void half_kick_start();
  // Throws the RunError of a fault in `rep` ("t = ..., step ...: particle ..."); on R ranks
  // collective: every rank learns whether any has a fault, and all throw the same error.
  void report_fault(const StepReport& rep, double t) const;

  // R ranks (dem/explicit_ranks.cpp).
  void rebuild_ranks();
  void finish_forward();
  // After a step's update: posts the ghost forward and reduces {moved, failed} over the ranks.
  void exchange_after_step(bool& moved, bool& failed);

  const Scene& scene_;
  ParticleStore& p_;
  PhaseTimer& timer_;
  DomainGeometry geom_; // the whole domain: walls and periodic lengths
  StepModel model_;
  Rows rows_;
  ExternalForce ext_;
  Recorded recorded_;
  Stats stats_;
  std::unique_ptr<RankPart> rank_;
};

} // namespace cfddem::dem
