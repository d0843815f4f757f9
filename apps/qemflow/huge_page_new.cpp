// The CLI's replacement of the global operator new (the array and nothrow forms call
// it; delete frees with free as before): once engine::tune_allocator(..., huge_pages)
// asked for it, every allocation from engine::huge_page_advice_from() bytes up (its own
// mapping, at or above the mmap threshold) is advised huge pages before it is touched,
// so each patch's big std::vectors fault in 2 MiB at a time without a change of type.
// Otherwise one relaxed load more per allocation. Kept out of the engine library so a
// host program embedding qemflow keeps its own operator new.
#include <cstdlib>
#include <new>

#include "engine/process_memory.hpp"

void* operator new(std::size_t size) {
  void* p = std::malloc(size ? size : 1);
  if (!p) throw std::bad_alloc();
  const size_t from = qemflow::engine::huge_page_advice_from();
  if (from && size >= from) qemflow::engine::advise_huge_pages(p, static_cast<char*>(p) + size);
  return p;
}
