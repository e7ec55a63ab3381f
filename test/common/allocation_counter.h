// Counts heap allocations by replacing the global operator new: include it
// in exactly one source file of a test binary.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdlib>
#include <functional>
#include <new>

namespace normal_fusion {
namespace test {

inline std::atomic<long> g_allocations{0};
inline std::atomic<bool> g_counting{false};

/// The heap allocations `work` makes (on any thread).
inline long allocationsDuring(const std::function<void()>& work) {
  g_allocations.store(0);
  g_counting.store(true);
  work();
  g_counting.store(false);
  return g_allocations.load();
}

}  // namespace test
}  // namespace normal_fusion

void* operator new(std::size_t size) {
  if (normal_fusion::test::g_counting.load(std::memory_order_relaxed)) {
    normal_fusion::test::g_allocations.fetch_add(1);
  }
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
