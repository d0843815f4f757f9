#include "engine/governor.hpp"

#include <algorithm>
#include <optional>

#include "config/size.hpp"
#include "engine/trace.hpp"
#include "util/error.hpp"

namespace qemflow::engine {

using config::format_budget;
using config::format_size;

Lease::Lease(Lease&& other) noexcept
    : governor_(other.governor_), owner_(other.owner_), bytes_(other.bytes_) {
  other.governor_ = nullptr;
  other.owner_ = nullptr;
  other.bytes_ = 0;
}

Lease& Lease::operator=(Lease&& other) noexcept {
  if (this != &other) {
    release();
    governor_ = other.governor_;
    owner_ = other.owner_;
    bytes_ = other.bytes_;
    other.governor_ = nullptr;
    other.owner_ = nullptr;
    other.bytes_ = 0;
  }
  return *this;
}

void Lease::release() {
  if (governor_) governor_->give_back(owner_, bytes_);
  governor_ = nullptr;
  owner_ = nullptr;
  bytes_ = 0;
}

void Lease::shrink_to(uint64_t bytes) {
  if (!governor_ || bytes >= bytes_) return;
  governor_->give_back(owner_, bytes_ - bytes);
  bytes_ = bytes;
}

bool Lease::try_grow(uint64_t extra) {
  if (!governor_) return false;
  if (!governor_->take_more(owner_, extra)) return false;
  bytes_ += extra;
  return true;
}

Lease Lease::split(uint64_t bytes) {
  bytes = std::min(bytes, bytes_);
  if (!governor_) return {};
  bytes_ -= bytes;
  return Lease(governor_, owner_, bytes);
}

Lease Lease::split(uint64_t bytes, const std::string& owner) {
  bytes = std::min(bytes, bytes_);
  if (!governor_) return {};
  void* to = governor_->record_for(owner);
  governor_->move_bytes(owner_, to, bytes);
  bytes_ -= bytes;
  return Lease(governor_, to, bytes);
}

void Lease::merge(Lease&& other) {
  if (!other.governor_) return;
  if (!governor_) {
    *this = std::move(other);
    return;
  }
  governor_->move_bytes(other.owner_, owner_, other.bytes_);
  bytes_ += other.bytes_;
  other.governor_ = nullptr;
  other.owner_ = nullptr;
  other.bytes_ = 0;
}

void* Governor::record_for(const std::string& owner) {
  std::lock_guard lock(mutex_);
  return owner_record(owner);
}

void* Governor::move_bytes(void* from, void* to, uint64_t bytes) {
  std::lock_guard lock(mutex_);
  auto& f = static_cast<Owner*>(from)->stats;
  auto& t = static_cast<Owner*>(to)->stats;
  if (&f == &t) return to;
  f.current -= bytes;
  t.current += bytes;
  t.peak = std::max(t.peak, t.current);
  t.granted_total += bytes;
  ++t.grants;
  return to;
}

Governor::Governor(uint64_t budget, uint64_t baseline) : budget_(budget), baseline_(baseline) {
  if (baseline >= budget) {
    throw Error(ErrorKind::resource,
                "--mem-budget " + format_size(budget) + " is below the process's own footprint of " +
                    format_size(baseline) + "; use --mem-budget " +
                    format_budget(baseline + (16u << 20)) + " or more");
  }
}

Governor::Governor(Governor& parent, const std::string& owner, uint64_t bytes, const std::function<bool()>& stop)
    : budget_(parent.baseline() + bytes),
      baseline_(parent.baseline()),
      parent_(&parent),
      reservation_(parent.admit(owner, bytes, stop)) {
  if (!reservation_) throw Error(ErrorKind::cancelled, "cancelled");
}

int Governor::jobs_alive() const { return root()->jobs_alive_.load(); }
uint64_t Governor::jobs_started() const { return root()->jobs_started_.load(); }
void Governor::job_started() {
  // Alive before started, read in the other order by a window (SoleJobPeakWindow): a
  // start it did not count as alive moves the started count it reads at its end.
  ++root()->jobs_alive_;
  ++root()->jobs_started_;
}
void Governor::job_ended() { --root()->jobs_alive_; }

uint64_t Governor::in_use() const {
  std::lock_guard lock(mutex_);
  return in_use_;
}
uint64_t Governor::peak_in_use() const {
  std::lock_guard lock(mutex_);
  return peak_;
}
uint64_t Governor::available() const {
  std::lock_guard lock(mutex_);
  return capacity() - in_use_;
}

void Governor::require_fits(const std::string& owner, uint64_t bytes) const {
  if (bytes <= capacity()) return;
  throw Error(ErrorKind::resource,
              owner + " needs " + format_size(bytes) + " of memory but --mem-budget " +
                  format_size(budget_) + " leaves " + format_size(capacity()) +
                  " after the process's own " + format_size(baseline_) +
                  "; the minimum budget is " + format_budget(bytes + baseline_));
}

Governor::Owner* Governor::owner_record(const std::string& owner) {
  auto [it, inserted] = owners_.try_emplace(owner);
  if (inserted) it->second.stats.owner = owner;
  return &it->second;
}

void Governor::set_reclaimable(ReclaimableMemory* memory) {
  std::lock_guard lock(mutex_);
  reclaimable_ = memory;
}

void Governor::make_room(uint64_t bytes) {
  if (!reclaimable_) return;
  const uint64_t left = capacity() - in_use_ - std::min(bytes, capacity() - in_use_);
  const uint64_t held = reclaimable_->held();
  if (held > left) reclaimable_->reclaim(held - left);
}

Lease Governor::grant(Owner* owner, uint64_t bytes, uint64_t asked) {
  make_room(bytes);
  in_use_ += bytes;
  in_use_now_.store(in_use_, std::memory_order_relaxed);
  peak_ = std::max(peak_, in_use_);
  auto& s = owner->stats;
  s.current += bytes;
  s.peak = std::max(s.peak, s.current);
  s.granted_total += bytes;
  ++s.grants;
  if (bytes < asked) ++s.partial_grants;
  return Lease(this, owner, bytes);
}

Lease Governor::try_acquire(const std::string& owner, uint64_t bytes) {
  return try_acquire_partial(owner, bytes, bytes);
}

// The one grant path. `wait`: block on the condition; `on_available`: register it
// instead of failing; `share`: the grant's size from what is free (else up to `max`).
// Returns an empty lease when nothing was granted.
Lease Governor::grant_when_free(const std::string& owner, uint64_t min, uint64_t max, bool wait,
                                const std::function<bool()>& stop,
                                std::function<void()>* on_available,
                                const std::function<uint64_t(uint64_t)>* share) {
  require_fits(owner, min);
  max = std::max(min, max);
  Lease lease;
  uint64_t now = 0;
  {
    std::unique_lock lock(mutex_);
    Owner* record = owner_record(owner);
    std::optional<Waiting> waiting;  // for another lease's release: not compute busy
    bool denied = false;
    while (capacity() - in_use_ < min) {
      if (!denied) ++record->stats.denials;
      denied = true;
      if (on_available) waiters_.push_back({min, std::move(*on_available)});
      if (!wait || (stop && stop())) return {};
      if (!waiting) waiting.emplace();
      released_.wait(lock);
    }
    const uint64_t free = capacity() - in_use_;
    if (share) max = std::clamp<uint64_t>((*share)(free), min, free);
    lease = grant(record, std::min(max, free), max);
    now = in_use_;
  }
  notify_observers(now);
  return lease;
}

Lease Governor::admit(const std::string& owner, uint64_t bytes, const std::function<bool()>& stop) {
  // Before it queues: a refused reservation never waits its turn.
  if (bytes == 0) throw Error(ErrorKind::usage, owner + ": a job's reservation of 0 bytes");
  require_fits(owner, bytes);
  Lease lease;
  uint64_t now = 0;
  {
    std::unique_lock lock(mutex_);
    Owner* record = owner_record(owner);
    // The ticket leaves the line however the wait ends, a stop callback that throws
    // included: left in it, it would hold up every later reservation for good. The
    // reservation behind may be first now, or fit beside this one: wake it. (Destroyed
    // before `lock`, so under the mutex.)
    struct Ticket {
      std::list<uint64_t>& line;
      std::condition_variable& released;
      std::list<uint64_t>::iterator at;
      ~Ticket() {
        line.erase(at);
        released.notify_all();
      }
    } ticket{admissions_, released_, admissions_.insert(admissions_.end(), next_admission_++)};
    bool denied = false;
    while (admissions_.begin() != ticket.at || capacity() - in_use_ < bytes) {
      if (!denied) ++record->stats.denials;
      denied = true;
      if (stop && stop()) return {};
      released_.wait(lock);
    }
    lease = grant(record, bytes, bytes);
    now = in_use_;
  }
  notify_observers(now);
  return lease;
}

size_t Governor::queued_reservations() const {
  std::lock_guard lock(mutex_);
  return admissions_.size();
}

Lease Governor::try_acquire_partial(const std::string& owner, uint64_t min, uint64_t max) {
  return grant_when_free(owner, min, max, false, {}, nullptr);
}

Lease Governor::acquire(const std::string& owner, uint64_t min, uint64_t max,
                        const std::function<bool()>& stop) {
  return grant_when_free(owner, min, max, true, stop, nullptr);
}

Lease Governor::acquire_share(const std::string& owner, uint64_t min,
                               const std::function<uint64_t(uint64_t free)>& share,
                               const std::function<bool()>& stop) {
  return grant_when_free(owner, min, min, true, stop, nullptr, &share);
}

Lease Governor::acquire_or_notify(const std::string& owner, uint64_t min, uint64_t max,
                                  std::function<void()> on_available) {
  return grant_when_free(owner, min, max, false, {}, &on_available);
}

void Governor::give_back(void* owner, uint64_t bytes) {
  uint64_t now = 0;
  std::unique_lock lock(mutex_);
  in_use_ -= bytes;
  in_use_now_.store(in_use_, std::memory_order_relaxed);
  static_cast<Owner*>(owner)->stats.current -= bytes;
  now = in_use_;
  notify_after_release(lock);  // unlocks
  notify_observers(now);
}

bool Governor::take_more(void* owner, uint64_t bytes) {
  uint64_t now = 0;
  {
    std::lock_guard lock(mutex_);
    auto* record = static_cast<Owner*>(owner);
    if (capacity() - in_use_ < bytes) {
      ++record->stats.denials;
      return false;
    }
    make_room(bytes);
    in_use_ += bytes;
    in_use_now_.store(in_use_, std::memory_order_relaxed);
    peak_ = std::max(peak_, in_use_);
    record->stats.current += bytes;
    record->stats.peak = std::max(record->stats.peak, record->stats.current);
    record->stats.granted_total += bytes;
    now = in_use_;
  }
  notify_observers(now);
  return true;
}

// Wakes the waiters whose minimum now fits (in arrival order, each counted against
// what is free so that one release does not wake more than it can feed).
void Governor::notify_after_release(std::unique_lock<std::mutex>& lock) {
  std::vector<std::function<void()>> ready;
  uint64_t free = capacity() - in_use_;
  for (auto it = waiters_.begin(); it != waiters_.end();) {
    if (it->min <= free) {
      free -= it->min;
      ready.push_back(std::move(it->callback));
      it = waiters_.erase(it);
    } else {
      ++it;
    }
  }
  lock.unlock();
  released_.notify_all();
  for (auto& callback : ready) callback();
}

void Governor::wake_all() {
  std::vector<std::function<void()>> ready;
  {
    std::lock_guard lock(mutex_);
    for (auto& waiter : waiters_) ready.push_back(std::move(waiter.callback));
    waiters_.clear();
  }
  released_.notify_all();
  for (auto& callback : ready) callback();
}

std::vector<OwnerStats> Governor::owners() const {
  std::lock_guard lock(mutex_);
  std::vector<OwnerStats> result;
  for (const auto& [name, record] : owners_) result.push_back(record.stats);
  return result;
}

uint64_t Governor::add_observer(std::function<void(uint64_t in_use)> observer) {
  std::lock_guard lock(observers_mutex_);
  observers_.emplace_back(++next_observer_, std::move(observer));
  observed_.store(true, std::memory_order_relaxed);
  return next_observer_;
}

void Governor::remove_observer(uint64_t id) {
  std::lock_guard lock(observers_mutex_);  // waits for a running call
  std::erase_if(observers_, [id](const auto& entry) { return entry.first == id; });
  observed_.store(!observers_.empty(), std::memory_order_relaxed);
}

void Governor::notify_observers(uint64_t in_use) {
  if (!observed_.load(std::memory_order_relaxed)) return;  // untraced runs take no lock
  std::lock_guard lock(observers_mutex_);
  for (const auto& [id, observer] : observers_) observer(in_use);
}

}  // namespace qemflow::engine
