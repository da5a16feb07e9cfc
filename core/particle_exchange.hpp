// Particles between ranks (LAMMPS's `exchange` and `borders`/`comm->forward`, Cabana's halo as a
// plan built once and replayed): migration moves particles to the rank that owns them now;
// ghosts are copies of other ranks' particles (or periodic images of one's own) appended after
// the owned ones, rebuilt with the neighbor list and refreshed between rebuilds by forward().
// Every field of the store travels (x, v, radius, mass, 1/m, id, and w, 1/I with rotation);
// a forward refreshes x, v (and w: a frictional contact reads the partner's spin);
// forces and torques do not: the scheme recomputes them after each exchange. Sizes go first
// (one all-to-all of counts), then the payload point to point, non-blocking, only between ranks
// that exchange something. A rank's copies to itself (periodic self-images) are plain copies.
// Every call is collective over the communicator.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_store.hpp"

namespace cfddem {

class ParticleExchange {
public:
  explicit ParticleExchange(const Communicator& comm) : comm_(comm) {}

  // dest[i]: the rank that owns local particle i from now on (one per particle of the store).
  // Leavers are removed (the others keep their order); arrivals are appended by source rank,
  // each source's in its own order. Returns the number of particles received.
  // Throws std::invalid_argument for a rank out of range or a dest of the wrong size.
  // payload: per-particle arrays the caller keeps outside the store (one value per particle,
  // e.g. the coupling's external force); they travel and are reordered with the particles.
  std::size_t migrate(ParticleStore& p, std::span<const int> dest,
                      std::span<std::vector<double>* const> payload = {});

  // One ghost copy: local particle `index` to `rank`, its position shifted by `shift` (the
  // periodic image the receiver needs; zeros when none).
  struct Copy {
    int rank = 0;
    std::uint32_t index = 0;
    std::array<double, 3> shift{};
  };
  // Replace the plan by `copies` (any order: sorted by rank here, stably), truncate the store to
  // its `owned` particles and append the received ghosts (by source rank, each in its sender's
  // order). Returns the number of ghosts.
  std::size_t build_ghosts(ParticleStore& p, std::size_t owned, std::vector<Copy> copies);
  // Migration and fresh ghosts in one round of messages (the orb scheme's exchange at every
  // sub-iteration, where both are rebuilt): local particle i goes to dest[i] as an owned particle
  // (stays when dest[i] is this rank) and a copy of it to each rank in `ghosts` (which may name
  // this rank, for a particle that leaves but stays within its halo). The store becomes: stayers
  // in order, then owned arrivals by source rank, then the ghosts by source rank (each source's
  // in its sender's order). `extra`: per-particle columns of the caller (one value per particle
  // of the store) that travel and are laid out the same way. Returns the owned count. Drops any
  // forward plan. Throws std::invalid_argument for a bad rank, index or column size.
  std::size_t redistribute(ParticleStore& p, std::span<const int> dest, std::vector<Copy> ghosts,
                           std::span<std::vector<double>* const> extra = {});
  // Records that follow particles but are not one per particle (a contact's tangential history,
  // any number per particle): `records` holds records of `stride` doubles, record q goes to rank
  // dest[q]. Returns the records this rank receives, by source rank, each source's in its order
  // (its own included). Leaves the ghost plan alone.
  std::vector<double> route(std::span<const int> dest, std::span<const double> records, int stride);
  // Refresh the ghosts' x and v (and w, with rotation) from their owners along the plan
  // (positions shifted again).
  void forward(ParticleStore& p) {
    forward_begin(p);
    forward_end(p);
  }
  // forward() in two halves, so that other work or messages overlap the ones in flight: begin
  // packs the owned values and posts the messages; end waits and writes the ghosts.
  void forward_begin(const ParticleStore& p);
  void forward_end(ParticleStore& p);
  // Refresh caller columns of the ghosts along the same plan (one value per particle of the
  // store, owned then ghosts; unshifted): values a scheme computes on its owned particles that
  // the ranks holding their ghosts must see (the islands scheme's speed bounds). Blocking.
  void forward_columns(std::span<std::vector<double>* const> columns);

  std::size_t owned() const { return owned_; }
  std::size_t ghosts() const { return recv_total_; }
  std::size_t copies_sent() const { return plan_.size(); }

private:
  // Send `send` (per-rank counts of `stride` doubles each, packed in rank order); receive into
  // `recv` with per-rank counts `recv_counts` (known, or exchanged first when `counts_known` is
  // false). Self traffic is copied.
  void exchange(std::span<const std::int64_t> send_counts, std::span<const double> send,
                std::vector<std::int64_t>& recv_counts, std::vector<double>& recv, int stride,
                bool counts_known);

  const Communicator& comm_;
  std::vector<Copy> plan_; // sorted by rank
  std::vector<std::int64_t> send_counts_, recv_counts_;
  std::size_t owned_ = 0, recv_total_ = 0;
  std::vector<double> send_buf_, recv_buf_;
  std::vector<double> fwd_send_, fwd_recv_;
  int fwd_stride_ = 6;             // x, v; and w with rotation
  std::shared_ptr<void> requests_; // std::vector<MPI_Request> of a forward in flight
};

} // namespace cfddem
