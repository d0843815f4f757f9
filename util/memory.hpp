#pragma once
// Giving a vector's storage back before the vector goes out of scope: the governor's
// lease for an array is returned right after it, so the memory must go with it.
#include <cstddef>
#include <cstdint>
#include <memory>
#include <new>
#include <utility>
#include <vector>

namespace qemflow {

// Frees a vector's storage. `v = {}` would keep the capacity (it assigns an empty
// initializer list): memory resident and no longer lent, as the loader's positions
// were through every epoch (24 B per input vertex).
template <class T, class Allocator>
void release_memory(std::vector<T, Allocator>& v) {
  std::vector<T, Allocator>().swap(v);
}

// Leaves new elements uninitialized: a buffer about to be filled by a read or a
// decoder must not be zeroed first (that was a fifth of the pipeline's time).
template <class T>
struct UninitializedAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = UninitializedAllocator<U>;
  };
  UninitializedAllocator() = default;
  template <class U>
  UninitializedAllocator(const UninitializedAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};
using Bytes = std::vector<std::byte, UninitializedAllocator<std::byte>>;
template <class T>
using UninitializedVector = std::vector<T, UninitializedAllocator<T>>;

// The pages of `page` bytes (a power of two) that lie wholly inside [begin, end): the
// range madvise may be given without touching a neighbour's bytes. Empty (first >=
// second) when there is none.
inline std::pair<uintptr_t, uintptr_t> whole_pages(const void* begin, const void* end, uintptr_t page) {
  return {(reinterpret_cast<uintptr_t>(begin) + page - 1) & ~(page - 1), reinterpret_cast<uintptr_t>(end) & ~(page - 1)};
}

}  // namespace qemflow
