// Counts of what this rank sends between ranks: point-to-point messages and their bytes,
// collectives and their bytes, and how many of the collectives are reductions. They are a
// function of the run's configuration alone (not of timing), so a scaling model can price a run
// at R ranks from counts measured anywhere (docs/performance_history.md, tools/scaling_model.py).
// Counted where the MPI calls are made (core/ and partition/): halo and particle exchanges,
// reductions, gathers. Not counted: snapshot and checkpoint I/O, and hypre's own messages.
#pragma once

#include <cstdint>

namespace cfddem {

struct MessageCounts {
  std::int64_t p2p_messages = 0; // sends
  std::int64_t p2p_bytes = 0;
  std::int64_t collectives = 0;      // calls this rank took part in
  std::int64_t collective_bytes = 0; // this rank's payload
  std::int64_t reductions = 0;       // collectives that reduce (all-reduce, scan)
  // Of collective_bytes, the parallel ORB's median searches (partition/parallel_orb.cpp): their
  // size depends on the rank groups, not on the tree's depth (the particles), so a scaling
  // model holds them where the rest of a scaled scene's collective payload grows.
  std::int64_t orb_search_bytes = 0;
};

// What this process has counted since it started.
MessageCounts message_counts();

namespace count_messages {
void point_to_point(std::int64_t bytes);
void collective(std::int64_t bytes, bool reduction);
void orb_search(std::int64_t bytes); // after collective(): the same bytes, also counted here
} // namespace count_messages

} // namespace cfddem
