// The CLI's replacement of the global operator new and its matching deletes (the array,
// nothrow and sized forms call these; a sanitizer sees malloc paired with free): once
// engine::tune_allocator(..., huge_pages) asked for it, every allocation from
// engine::huge_page_advice_from() bytes up (its own mapping, at or above the mmap
// threshold) is advised huge pages before it is touched, so each patch's big
// std::vectors fault in 2 MiB at a time without a change of type. Otherwise one
// relaxed load more per allocation. While an engine::RetainedBuffers scope is open, big
// buffers freed are kept for its next big allocations (engine/retained_buffers.hpp).
// Kept out of the engine library so a host program embedding qemflow keeps its own
// operator new.
#include <cstdlib>
#include <new>

#include "engine/process_memory.hpp"
#include "engine/retained_buffers.hpp"

void* operator new(std::size_t size) {
  if (size == 0) size = 1;
  // A big buffer an engine::RetainedBuffers scope kept: its pages are in memory already.
  if (void* kept = qemflow::engine::take_retained_buffer(size)) return kept;
  void* p;
  // As the standard's operator new: call the new handler until malloc succeeds or
  // there is none.
  while (!(p = std::malloc(size))) {
    const std::new_handler handler = std::get_new_handler();
    if (!handler) throw std::bad_alloc();
    handler();
  }
  const size_t from = qemflow::engine::huge_page_advice_from();
  if (from && size >= from) qemflow::engine::advise_huge_pages(p, static_cast<char*>(p) + size);
  return p;
}

void operator delete(void* p) noexcept {
  if (!qemflow::engine::retain_buffer(p)) std::free(p);
}
void operator delete(void* p, std::size_t) noexcept { operator delete(p); }
