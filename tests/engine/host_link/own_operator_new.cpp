// A host program with its own global allocator, as mimalloc-new-delete.h, a game
// engine's or a daemon's arena gives one, that also uses the qemflow engine (DESIGN §5:
// the library is the product; process-wide state is the host's). It must link.
#include <cstdio>
#include <cstdlib>
#include <new>

#include "engine/process_memory.hpp"

void* operator new(std::size_t n) {
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

int main() { return qemflow::engine::resident_bytes() > 0 ? 0 : 1; }
