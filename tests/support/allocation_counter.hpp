// Counts heap allocations made by the current thread while a guard is alive, by
// replacing the global operator new. Used to prove the per-frame path allocates nothing.
#pragma once

#include <cstddef>

namespace mocapd::testing {

/// Counts allocations on this thread between construction and count().
class ScopedAllocationCounter {
 public:
  ScopedAllocationCounter();
  ~ScopedAllocationCounter();
  ScopedAllocationCounter(const ScopedAllocationCounter&) = delete;
  ScopedAllocationCounter& operator=(const ScopedAllocationCounter&) = delete;
  std::size_t count() const;
};

}  // namespace mocapd::testing
