// An allocator for the large grid arrays (gas fields, multigrid levels) that asks the kernel for
// transparent huge pages (2 MiB). Where THP is in "madvise" mode (Debian's default) a plain
// allocation is backed by 4 KiB pages: a gas of 515,000 cells (the 1e5 bed) then takes 151,000
// page faults to set up its 620 MB, 1.2-1.4 s on a paravirtualised VM, and the sweeps over
// 4 MB fields miss the TLB. glibc can do the same for every mmap'd chunk
// (GLIBC_TUNABLES=glibc.malloc.hugetlb=1), but only when set in the environment before start,
// and tbbmalloc's TBBMALLOC_USE_HUGE_PAGES takes effect only where THP is "always".
//
// An array of at least 2 MiB is placed on a 2 MiB boundary and its whole 2 MiB pages advised
// MADV_HUGEPAGE; its tail, and smaller arrays, stay on ordinary pages, so the memory held is what
// was asked for. Where THP is off or madvise fails the advice is simply not taken. Values,
// layout and results are unchanged: only the pages behind them differ.
#pragma once

#include <cstddef>
#include <cstdlib>
#include <memory>
#include <new>
#include <vector>

#include <sys/mman.h>

namespace cfddem {

template <class T> struct HugePageAllocator {
  using value_type = T;
  static constexpr std::size_t kHugePage = std::size_t{2} << 20;

  HugePageAllocator() = default;
  template <class U> HugePageAllocator(const HugePageAllocator<U>& /*other*/) noexcept {}

  [[nodiscard]] T* allocate(std::size_t n) {
    const std::size_t bytes = n * sizeof(T);
    if (bytes < kHugePage) {
      return std::allocator<T>{}.allocate(n);
    }
    void* p = std::aligned_alloc(kHugePage, (bytes + kHugePage - 1) / kHugePage * kHugePage);
    if (p == nullptr) {
      throw std::bad_alloc();
    }
    // Best effort: the whole 2 MiB pages of the array (the rounded tail is never touched).
    (void)madvise(p, bytes / kHugePage * kHugePage, MADV_HUGEPAGE);
    return static_cast<T*>(p);
  }

  void deallocate(T* p, std::size_t n) noexcept {
    if (n * sizeof(T) < kHugePage) {
      std::allocator<T>{}.deallocate(p, n);
    } else {
      std::free(p);
    }
  }

  template <class U> bool operator==(const HugePageAllocator<U>& /*other*/) const noexcept {
    return true;
  }
};

// A vector of large-array data on huge pages where the kernel grants them.
template <class T> using HugePageVector = std::vector<T, HugePageAllocator<T>>;

} // namespace cfddem
