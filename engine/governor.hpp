#pragma once
// The memory governor: one byte budget per process, shared by every job in it.
//
// Contract
// - Anything big (a block, a batch, a buffer, a window of vertices) is materialized
//   only under a Lease. A Lease is a byte reservation granted under the cap and
//   returned by RAII; it can shrink, grow (if room), or be split.
// - Grants: all-or-nothing (try_acquire), partial (any amount in [min, max]: the
//   caller must adapt to what it got — smaller batch, earlier spill), blocking
//   (acquire waits until at least min is free), or "notify me" (acquire_or_notify,
//   for a producer that must never block its thread, e.g. the I/O thread).
// - A request whose minimum could never fit (min > budget - baseline) fails up front
//   with Error(resource) naming the smallest budget that would do.
// - The baseline is the process's own overhead (binary, thread stacks, allocator and
//   library state) measured at start; it is reserved once and never leased.
// - Accounting is per owner (a node's name): current, peak, total granted, number of
//   grants, denials and waits, so the report can say who held what.
// - Jobs side by side (a host running several at once): each job that leases in
//   steps (a patch lease held while its gather leases frame buffers) reserves its
//   memory first, as one lease taken while it holds nothing, and runs on a governor of
//   its own made from that reservation (the reserving constructor). Inside, its stages
//   size themselves from its capacity as a lone run's do; across jobs the only wait is
//   for the reservation, so no job holds memory while it waits for another's, and the
//   reservations together stay within this governor's capacity.
// Thread safety: every member may be called from any thread.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <list>
#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace qemflow::engine {

class Governor;

// Memory the process holds outside any lease that it can give back on demand: big
// buffers freed by a stage and kept for its next allocations (retained_buffers.hpp).
// A governor with one registered (set_reclaimable) counts what it holds as in use at
// every grant: before it grants, it has the holder give back what the grant would not
// leave room for. So leases plus held memory stay within the capacity after every
// grant; between grants, what is held only grows into room the leases leave.
class ReclaimableMemory {
 public:
  virtual ~ReclaimableMemory() = default;
  virtual uint64_t held() const = 0;           // bytes held now
  virtual void reclaim(uint64_t bytes) = 0;    // gives back at least `bytes`, where it can
};

class Lease {
 public:
  Lease() = default;
  Lease(Lease&& other) noexcept;
  Lease& operator=(Lease&& other) noexcept;
  Lease(const Lease&) = delete;
  Lease& operator=(const Lease&) = delete;
  ~Lease() { release(); }

  uint64_t bytes() const { return bytes_; }
  explicit operator bool() const { return governor_ != nullptr; }
  // Gives back everything above `bytes` (no-op if already smaller).
  void shrink_to(uint64_t bytes);
  // Takes `extra` more bytes if they are free right now; false (unchanged) if not.
  bool try_grow(uint64_t extra);
  // Moves `bytes` (at most all) of this lease into a new lease of the same owner, or
  // of `owner` (the bytes then count as that owner's from now on). No waiting: this is
  // how a job hands out parts of a reservation it already holds.
  Lease split(uint64_t bytes);
  Lease split(uint64_t bytes, const std::string& owner);
  // Takes `other`'s bytes into this lease (back to this lease's owner); `other` ends empty.
  void merge(Lease&& other);
  void release();

 private:
  friend class Governor;
  Lease(Governor* governor, void* owner, uint64_t bytes)
      : governor_(governor), owner_(owner), bytes_(bytes) {}
  Governor* governor_ = nullptr;
  void* owner_ = nullptr;  // the owner's accounting record inside the governor
  uint64_t bytes_ = 0;
};

struct OwnerStats {
  std::string owner;
  uint64_t current = 0;
  uint64_t peak = 0;
  uint64_t granted_total = 0;  // sum of all grants (bytes)
  uint64_t grants = 0;
  uint64_t partial_grants = 0;  // granted less than asked
  uint64_t denials = 0;         // try_* refused, or a notify/wait was needed
};

class Governor {
 public:
  // `budget`: the whole process's cap (--mem-budget). `baseline`: bytes the process
  // needs for itself; must be below budget (else Error(resource)).
  Governor(uint64_t budget, uint64_t baseline);
  // A job's own governor inside `parent`: waits (holding nothing) until `bytes` of the
  // parent's capacity are free, takes them as one lease of `owner`, held until this
  // governor is destroyed, and grants its leases from them alone. Its capacity() is
  // `bytes`; budget() is the parent's baseline plus `bytes` (the process budget that would
  // give a lone run this capacity: the budget its error messages name). Throws
  // Error(resource) up front if `bytes` can never fit the parent (naming the parent's
  // minimum budget), Error(cancelled) if `stop` returns true while it waits
  // (parent.wake_all() wakes the wait). Reservations are admitted in the order they
  // were asked for: one that would fit waits behind an earlier one that does not, so a
  // job that needs the whole budget is not starved by a stream of smaller ones. Only
  // reservations queue; leases taken directly from the parent (a running job's, or
  // run_reencode's) are granted whenever they fit, so a running job never waits behind
  // a job that waits for it. Must be destroyed before the parent.
  Governor(Governor& parent, const std::string& owner, uint64_t bytes, const std::function<bool()>& stop = {});
  Governor(const Governor&) = delete;
  Governor& operator=(const Governor&) = delete;

  uint64_t budget() const { return budget_; }
  uint64_t baseline() const { return baseline_; }
  uint64_t capacity() const { return budget_ - baseline_; }  // what leases may hold
  uint64_t in_use() const;
  // in_use() without the lock (a value it held a moment ago): for a ReclaimableMemory
  // deciding whether to hold more, which must not take the lock.
  uint64_t in_use_now() const { return in_use_now_.load(std::memory_order_relaxed); }
  // Registers `memory` (nullptr: none), which must outlive its registration; grants
  // then reclaim from it (under the governor's lock: `memory` must never take it).
  void set_reclaimable(ReclaimableMemory* memory);
  uint64_t peak_in_use() const;
  uint64_t available() const;

  // Throws Error(resource) if `bytes` could never be granted, naming the minimum budget.
  void require_fits(const std::string& owner, uint64_t bytes) const;

  // All or nothing; an empty Lease if not free now.
  Lease try_acquire(const std::string& owner, uint64_t bytes);
  // As much as is free now, clamped to [min, max]; empty if less than min is free.
  Lease try_acquire_partial(const std::string& owner, uint64_t min, uint64_t max);
  // Blocks until at least `min` is free, then grants up to `max`. `stop` is polled on
  // every wake-up (wake_all() wakes waiters); if it returns true, returns an empty Lease.
  Lease acquire(const std::string& owner, uint64_t min, uint64_t max,
                const std::function<bool()>& stop = {});
  // A working set held across a pass: blocks until `min` is free, then grants
  // share(free) clamped to [min, free], `free` being what is free at the grant (under
  // the lock). Sizing from available() and then acquiring lets two jobs count the same
  // free bytes, so together they could hold everything and leave their streams nothing
  // to read with (they would wait forever); a share computed here leaves what the
  // share function leaves.
  Lease acquire_share(const std::string& owner, uint64_t min,
                      const std::function<uint64_t(uint64_t free)>& share,
                      const std::function<bool()>& stop = {});
  // Grants now if at least `min` is free; else returns empty and calls `on_available`
  // once (from whichever thread releases memory, outside the lock) when `min` may fit.
  // The callback must be cheap and must not block (e.g. re-queue a task).
  Lease acquire_or_notify(const std::string& owner, uint64_t min, uint64_t max,
                          std::function<void()> on_available);

  // Runs every pending notify callback and wakes blocked acquires (e.g. on cancel).
  void wake_all();
  // Reservations (the reserving constructor) waiting for their turn or their bytes.
  size_t queued_reservations() const;

  std::vector<OwnerStats> owners() const;

  // Jobs (engine::Job registers itself) alive on the root governor and on every governor
  // reserved from it, and how many ever started there: a job alone at both ends of a
  // window, with no start in between, was alone through it (job.hpp, SoleJobPeakWindow).
  int jobs_alive() const;
  uint64_t jobs_started() const;
  void job_started();
  void job_ended();
  // Observers are called (outside the lease lock, one call at a time) with the new
  // in-use total after every change; for trace counters. Jobs sharing a governor each
  // add their own (a traced re-encode leases from the shared one directly);
  // remove_observer returns once no call of it is running, so its captures may go.
  uint64_t add_observer(std::function<void(uint64_t in_use)> observer);
  void remove_observer(uint64_t id);

 private:
  friend class Lease;
  struct Owner {
    OwnerStats stats;
  };
  struct Waiter {
    uint64_t min;
    std::function<void()> callback;
  };
  Owner* owner_record(const std::string& owner);  // under lock
  Lease grant(Owner* owner, uint64_t bytes, uint64_t asked);  // under lock
  void make_room(uint64_t bytes);                              // under lock, before a grant
  Lease grant_when_free(const std::string& owner, uint64_t min, uint64_t max, bool wait,
                        const std::function<bool()>& stop, std::function<void()>* on_available,
                        const std::function<uint64_t(uint64_t)>* share = nullptr);
  void give_back(void* owner, uint64_t bytes);
  void* move_bytes(void* from, void* to, uint64_t bytes);  // accounting only
  void* record_for(const std::string& owner);
  bool take_more(void* owner, uint64_t bytes);
  void notify_after_release(std::unique_lock<std::mutex>& lock);
  // The reserving constructor's grant: in arrival order among reservations (FIFO).
  Lease admit(const std::string& owner, uint64_t bytes, const std::function<bool()>& stop);

  Governor* root() { return parent_ ? parent_->root() : this; }
  const Governor* root() const { return parent_ ? parent_->root() : this; }

  const uint64_t budget_;
  const uint64_t baseline_;
  Governor* const parent_ = nullptr;
  Lease reservation_;  // of the parent: this governor's capacity
  std::atomic<int> jobs_alive_{0};  // counted on the root only
  std::atomic<uint64_t> jobs_started_{0};
  mutable std::mutex mutex_;
  std::condition_variable released_;
  uint64_t in_use_ = 0;
  std::atomic<uint64_t> in_use_now_{0};  // in_use_, for in_use_now()
  ReclaimableMemory* reclaimable_ = nullptr;
  uint64_t peak_ = 0;
  std::map<std::string, Owner> owners_;
  std::list<Waiter> waiters_;
  std::list<uint64_t> admissions_;  // tickets of the waiting reservations, oldest first
  uint64_t next_admission_ = 0;
  void notify_observers(uint64_t in_use);
  std::mutex observers_mutex_;  // held while observers run, never with mutex_
  std::vector<std::pair<uint64_t, std::function<void(uint64_t)>>> observers_;
  uint64_t next_observer_ = 0;
  std::atomic<bool> observed_{false};
};

}  // namespace qemflow::engine
