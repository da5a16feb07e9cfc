#include "core/message_counts.hpp"

#include <atomic>

namespace cfddem {

namespace {
// Relaxed atomics: MPI is called from one thread per rank today, but a count must never be
// lost should a TBB task ever send; only the totals are read, after the loop.
std::atomic<std::int64_t> p2p_messages{0}, p2p_bytes{0}, collectives{0}, collective_bytes{0},
    reductions{0}, orb_search_bytes{0};
} // namespace

MessageCounts message_counts() {
  MessageCounts c;
  c.p2p_messages = p2p_messages.load(std::memory_order_relaxed);
  c.p2p_bytes = p2p_bytes.load(std::memory_order_relaxed);
  c.collectives = collectives.load(std::memory_order_relaxed);
  c.collective_bytes = collective_bytes.load(std::memory_order_relaxed);
  c.reductions = reductions.load(std::memory_order_relaxed);
  c.orb_search_bytes = orb_search_bytes.load(std::memory_order_relaxed);
  return c;
}

namespace count_messages {
void point_to_point(std::int64_t bytes) {
  p2p_messages.fetch_add(1, std::memory_order_relaxed);
  p2p_bytes.fetch_add(bytes, std::memory_order_relaxed);
}
void collective(std::int64_t bytes, bool reduction) {
  collectives.fetch_add(1, std::memory_order_relaxed);
  collective_bytes.fetch_add(bytes, std::memory_order_relaxed);
  if (reduction)
    reductions.fetch_add(1, std::memory_order_relaxed);
}
void orb_search(std::int64_t bytes) {
  orb_search_bytes.fetch_add(bytes, std::memory_order_relaxed);
}
} // namespace count_messages

} // namespace cfddem
