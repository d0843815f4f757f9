#pragma once
// Big buffers kept for reuse while a scope is open, instead of unmapped when freed.
//
// Why: an out-of-core pass builds every patch from fresh mappings (the gather's
// records, the halo BFS, the decimator's arrays), and the kernel zeroes each page of a
// fresh mapping when it is first touched. On 20M faces under 4G (patches of ~4M faces)
// that zeroing took 8% of the CPU samples, a fifth of them with the other core idle
// (docs/history.md, session 27). A buffer freed while a RetainedBuffers scope is open
// is kept, its pages resident, and handed to a later allocation that fits in it (the
// smallest kept buffer at least as large, if at most about twice as large; its pages
// past the size asked for go back to the OS), so those pages are reused as they are.
//
// Memory: the scope registers itself with a governor as ReclaimableMemory. It keeps a
// buffer only while the governor's leases leave room for everything it holds, and the
// governor has it unmap kept buffers (largest first) before any grant they would
// crowd out: leases plus kept pages stay within the capacity. A buffer handed out
// again stays counted (as "lent", at the pages it held) until it is freed: its new
// user's lease covers the pages that user touches, and those it leaves as they were
// are still held here. Lent pages cannot be unmapped; a grant they would crowd out
// goes ahead all the same (never waiting on its own job's buffers), so those pages can
// then be memory no lease counts. In the out-of-core pass a buffer is reused by the
// same array of the next patch, of about the same size: the pages it does not touch
// again are few.
//
// One scope at a time in the process (a second, nested or on another thread, keeps
// nothing). Buffers come from the replacement operator new of
// apps/qemflow/huge_page_new.cpp, which calls the hooks below; without it (a library
// host with its own allocator) a scope keeps nothing. Only allocations of at least
// huge_page_advice_from() bytes count (each its own mapping), so nothing is kept
// unless tune_allocator asked for huge pages (the out-of-core command).
#include <cstddef>
#include <cstdint>

#include "engine/governor.hpp"

namespace qemflow::engine {

class RetainedBuffers final : public ReclaimableMemory {
 public:
  explicit RetainedBuffers(Governor& governor);
  ~RetainedBuffers() override;  // unmaps what it keeps
  RetainedBuffers(const RetainedBuffers&) = delete;
  RetainedBuffers& operator=(const RetainedBuffers&) = delete;

  uint64_t held() const override;  // kept and lent bytes
  void reclaim(uint64_t bytes) override;

  // What this scope did so far (zeros when another scope was open at its start).
  struct Counts {
    uint64_t kept_bytes = 0, lent_bytes = 0;
    uint64_t reused = 0;     // allocations served from kept buffers
    uint64_t reused_bytes = 0;
    uint64_t unmapped = 0;   // kept buffers unmapped to make room for a grant (reclaim)
  };
  Counts counts() const;

 private:
  Governor& governor_;
  bool open_ = false;
};

// The hooks of a replacement operator new / delete (cheap while no scope is open):
// a kept buffer for `size` bytes, or nullptr (allocate afresh);
void* take_retained_buffer(size_t size) noexcept;
// whether the freed `p` was kept (true: the caller must not free it).
bool retain_buffer(void* p) noexcept;

}  // namespace qemflow::engine
