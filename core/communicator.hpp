// The ranks of a run seen through one narrow class: reductions, a gather to rank 0 and the
// agreement on a run-time error. The MPI communicator stays inside (its Fortran handle is the
// only state), so dem/ and apps/ use it without including <mpi.h>. With one rank every call
// returns at once and no MPI function is called. Every call is collective over the ranks.
// Time spent inside MPI (waiting for the slowest rank, mostly) is summed in wait_seconds().
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace cfddem {

class Communicator {
public:
  // MPI_COMM_WORLD (MPI must be initialised: ParallelEnv does it).
  static Communicator world();
  // One rank, no MPI at all.
  static Communicator serial() { return Communicator(); }

  int rank() const { return rank_; }
  int size() const { return size_; }

  // In-place element-wise reductions over the ranks.
  void sum(std::span<double> v) const;
  void sum(std::span<std::int64_t> v) const;
  void max(std::span<double> v) const;
  void max(std::span<std::int64_t> v) const;
  void min(std::span<std::int64_t> v) const;
  // Element-wise sum of `sums` and max of `maxes` in one reduction (one latency instead of two:
  // the islands scheme's link rounds).
  void sum_max(std::span<double> sums, std::span<double> maxes) const;
  std::int64_t sum(std::int64_t v) const;
  double max(double v) const;

  // Non-blocking element-wise max: starts the reduction of `v`, which must stay alive and
  // untouched until max_wait() completes it (one at a time), so that other messages can be in
  // flight meanwhile.
  void max_begin(std::span<std::int64_t> v) const;
  void max_wait() const;

  // Rank 0 gets one value per rank (rank order); the others get an empty vector.
  std::vector<double> gather(double v) const;
  // Rank 0 gets every rank's values, concatenated in rank order (output only: O(all) there).
  std::vector<double> gather(std::span<const double> v) const;
  std::vector<std::int64_t> gather(std::span<const std::int64_t> v) const;

  // Every rank passes its error (an empty message when it has none) and a key that orders the
  // errors (the particle id); every rank gets the message of the smallest key, so all of them
  // raise the same error. Empty when no rank has one.
  std::string agree_on_error(std::int64_t key, const std::string& message) const;

  double wait_seconds() const { return wait_; }
  void add_wait(double seconds) const { wait_ += seconds; }

  // For core/ and partition/ sources only (core/communicator_mpi.hpp turns it into MPI_Comm).
  int fortran_handle() const { return handle_; }

private:
  Communicator() = default;
  int rank_ = 0, size_ = 1;
  int handle_ = -1; // MPI_Fint of the communicator; -1: serial
  mutable double wait_ = 0.0;
  mutable std::shared_ptr<void> request_; // the MPI_Request of max_begin (communicator.cpp)
};

} // namespace cfddem
