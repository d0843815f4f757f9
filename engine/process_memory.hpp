#pragma once
// What the process really holds, from /proc/self/status, and the allocator settings
// that make freed buffers go back to the OS so that resident memory follows leases.
#include <cstddef>
#include <cstdint>

namespace qemflow::engine {

uint64_t resident_bytes();  // VmRSS now
// The process's high-water mark since start: VmHWM, and what it was before each
// reset_peak_resident (a reset opens a window; it does not lower this).
uint64_t peak_resident_bytes();
// Opens a window: keeps VmHWM for peak_resident_bytes, then resets it to the current
// RSS (Linux: "5" > /proc/self/clear_refs); false if refused (the window is then the
// whole run). Not for concurrent use, and it cuts short any other window in the
// process: jobs open theirs through SoleJobPeakWindow (job.hpp), only when alone.
bool reset_peak_resident();
// VmHWM: the high-water mark since the last reset_peak_resident (or start).
uint64_t window_peak_resident_bytes();

// Process-wide glibc settings (call once, before the big work; idempotent; the host's
// choice: the CLI's commands call it, library jobs never do): a fixed
// mmap threshold of 4 MiB, so that every big buffer (vertex windows, face ranges) is
// its own mapping, unmapped on free (glibc's dynamic threshold would otherwise move
// big buffers onto the heap, where freed space stays resident), few arenas, and a low
// trim threshold (1 MiB unless given). Measured on 20M faces at 256M: 256 KiB costs
// 35% more time in page faults; 16 MiB and up lets heap slack push peak RSS to within
// 8% of the budget. The re-encode passes 8 MiB: its frame buffers (1-2 MiB, a few
// in flight) otherwise go back to the OS and fault in again, 236k page faults for
// 20M faces at 256M against 64k (a fifth of its CPU time), peak RSS 94-100 MiB either
// way; the slack (8 MiB an arena, two arenas) stays inside the baseline's margin.
// One arena by default: memory a thread frees goes back to its own arena, where only
// the threads bound to that arena reuse it. With two, a patch built by the threads of
// one arena left its heap part free but resident in that arena while the next patch
// grew the other one: the shuffled 300k at 80M (--clusters 2), 4 runs at once with an
// RSS sampling thread, peaked at 69.5-76.8 MiB in the epochs (7-18 MiB free in the
// arenas at the peak), 66.8-69.4 with one arena (CPU seconds the same within noise).
//
// `huge_pages` (the out-of-core simplify's choice, with an 8 MiB trim and a 2 MiB mmap
// threshold): every allocation through operator new of at least the mmap threshold is
// advised huge pages (advise_huge_pages) before it is touched. A patch's arrays are
// fresh mappings in every pass, each 4 KiB page a fault and a zeroing: the demo (1M at
// 96M) took 0.93-1.0M minor faults, ~2.5 sys-s; with huge pages and the 8 MiB trim
// (the heap's smaller arrays stay resident between patches instead of faulting in
// again) ~0.24M. Resident memory grows by at most the partly touched last huge page of
// an array reserved beyond what it fills, and by the trim's slack: both inside the
// baseline's margin (measure_baseline).
void tune_allocator(int trim_threshold = 1 << 20, int arenas = 1, int mmap_threshold = 4 << 20,
                    bool huge_pages = false);
// Whether tune_allocator asked for huge pages on big allocations (for tests).
bool huge_pages_on_big_allocations();
// The size from which an allocation should be advised huge pages (0: none). Read by
// the replacement operator new in apps/qemflow/huge_page_new.cpp, which the CLI links
// (and the engine's tests); the engine library itself does not replace operator new,
// so a host keeps its own allocator and links that file only if it wants the advice.
size_t huge_page_advice_from();
// Returns freed heap memory to the OS (malloc_trim); cheap enough between passes.
void trim_allocator();

// Gives the whole pages inside [begin, end) of a live buffer back to the OS (madvise
// MADV_DONTNEED: they read as zeros afterwards; the buffer is freed as usual later), so
// that a buffer converted into another block by block is not resident beside the whole
// copy. Returns `end` rounded down to a page: the `begin` of the next call when the
// buffer is released front to back (no page straddling two calls is left behind).
const void* release_pages(const void* begin, const void* end);

// Faults in the whole pages inside [begin, end) of a buffer about to be filled, in one
// call (madvise MADV_POPULATE_WRITE): the kernel zeroes them all the same, but without a
// page-fault exception apiece. Advice: refused (kernels before 5.14), they fault in as
// they are touched.
void populate_pages(void* begin, void* end);

// Asks for transparent huge pages over the whole 2 MiB pages inside [begin, end) of a
// buffer not yet touched (madvise MADV_HUGEPAGE; advice: refused, the buffer keeps
// small pages). For big arrays read at random (vertex positions by index): a 4 KiB
// page per lookup misses the TLB, and each page first touched is its own fault.
// Resident memory stays within the buffer's own mapping.
void advise_huge_pages(const void* begin, const void* end);

// The process's own footprint to reserve as the governor's baseline: RSS now plus a
// margin for what grows later without a lease (thread stacks touched by work, zstd
// contexts, allocator slack, trace buffers). `margin` defaults to 24 MiB.
uint64_t measure_baseline(uint64_t margin = 24ull << 20);

// The baseline a CLI command's governor reserves: measure_baseline(), which moves by
// some 100 KB between runs and every budget-derived size (patch leases, splits, load
// windows) with it, unless QEMFLOW_BASELINE=BYTES (tests, diagnosis; read once per
// process) fixes it, so two runs of one command make the same decisions and report the
// same counts. Error(usage) when the variable is not a positive byte count.
uint64_t command_baseline();

}  // namespace qemflow::engine
