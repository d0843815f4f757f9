#include "engine/scratch.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <sys/uio.h>
#include <climits>
#include <unistd.h>
#include <zstd.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cerrno>
#include <cstring>
#include <map>
#include <memory>
#include <random>

#include "config/size.hpp"
#include "io/hash64.hpp"
#include "util/error.hpp"

namespace qemflow::engine {

namespace {

constexpr char magic[4] = {'Q', 'F', 'C', 'K'};
// Version 3: the raw payload's trailer is XXH3 (version 1 had XXH64, 2 a hand-written XXH3-like sum).
constexpr uint16_t frame_version = 3;
constexpr uint32_t flag_raw = 1;

// The default codec: the base, or the newest live DefaultFrameCodec's. Read on every
// encode_frame without a level, so cached in two atomics; changed under the mutex.
struct DefaultCodecState {
  std::mutex mutex;
  FrameCodec base = FrameCodec::zstd();
  std::vector<std::pair<uint64_t, FrameCodec>> overrides;  // oldest first
  uint64_t next_id = 0;
  std::atomic<bool> raw{false};
  std::atomic<int> level{-1};
  void publish() {  // under the mutex
    FrameCodec now = overrides.empty() ? base : overrides.back().second;
    level.store(now.zstd_level, std::memory_order_relaxed);
    raw.store(now.raw, std::memory_order_relaxed);
  }
};
DefaultCodecState& default_codec_state() {
  static DefaultCodecState state;
  return state;
}

// The scratch stores alive in this process on real disks, with the bytes each expects
// to write there (its claim). What a store has not written yet of its claim is not in
// statvfs's free count, so every other store on that device takes it off what it sees:
// two jobs of one host sharing a scratch disk each find room for their own bytes.
struct DiskClaim {
  dev_t device;
  uint64_t bytes;
};
struct DiskClaims {
  std::mutex mutex;  // taken before any store's own
  std::map<ScratchStore*, DiskClaim> stores;
};
DiskClaims& disk_claims() {
  static DiskClaims claims;
  return claims;
}
// Under the claims' mutex.
uint64_t claimed_by_others(DiskClaims& claims, const ScratchStore* self, dev_t device) {
  uint64_t bytes = 0;
  for (auto& [store, claim] : claims.stores)
    if (store != self && claim.device == device) bytes += claim.bytes - std::min(claim.bytes, store->bytes_on_disk());
  return bytes;
}

uint64_t fnv1a(const std::byte* data, size_t size) {
  uint64_t h = 1469598103934665603ull;
  for (size_t i = 0; i < size; ++i) {
    h ^= uint64_t(data[i]);
    h *= 1099511628211ull;
  }
  return h;
}

template <class T>
void put(std::byte* at, T value) { std::memcpy(at, &value, sizeof value); }
template <class T>
T get(const std::byte* at) {
  T value;
  std::memcpy(&value, at, sizeof value);
  return value;
}

// One compression and one decompression context per thread, reused across frames
// (creating them per frame would dominate small frames).
struct ZstdContexts {
  ZSTD_CCtx* c = ZSTD_createCCtx();
  ZSTD_DCtx* d = ZSTD_createDCtx();
  ~ZstdContexts() {
    ZSTD_freeCCtx(c);
    ZSTD_freeDCtx(d);
  }
};
ZstdContexts& contexts() {
  thread_local ZstdContexts ctx;
  return ctx;
}

void write_header(std::byte* at, uint64_t tag, uint32_t record_size, uint64_t count,
                  uint64_t payload, uint32_t flags) {
  std::memcpy(at, magic, 4);
  put<uint16_t>(at + 4, frame_version);
  put<uint16_t>(at + 6, uint16_t(record_size));
  put<uint32_t>(at + 8, flags);
  put<uint64_t>(at + 12, tag);
  put<uint64_t>(at + 20, count);
  put<uint64_t>(at + 28, payload);
  put<uint64_t>(at + 36, fnv1a(at, 36));
  put<uint32_t>(at + 44, 0);
}

[[noreturn]] void corrupt(const std::string& where, const std::string& problem) {
  throw Error(ErrorKind::internal, "scratch " + where + ": corrupt chunk: " + problem);
}

[[noreturn]] void io_failure(const std::filesystem::path& path, const char* what, int err) {
  throw Error(ErrorKind::resource,
              path.string() + ": " + what + " failed: " + std::strerror(err));
}

}  // namespace

FrameCodec default_frame_codec() {
  auto& state = default_codec_state();
  return {state.raw.load(std::memory_order_relaxed), state.level.load(std::memory_order_relaxed)};
}

void set_default_frame_codec(FrameCodec codec) {
  auto& state = default_codec_state();
  std::lock_guard lock(state.mutex);
  state.base = codec;
  state.publish();
}

DefaultFrameCodec::DefaultFrameCodec(FrameCodec codec) {
  auto& state = default_codec_state();
  std::lock_guard lock(state.mutex);
  id_ = state.next_id++;
  state.overrides.emplace_back(id_, codec);
  state.publish();
}

DefaultFrameCodec::~DefaultFrameCodec() {
  auto& state = default_codec_state();
  std::lock_guard lock(state.mutex);
  std::erase_if(state.overrides, [this](const auto& entry) { return entry.first == id_; });
  state.publish();
}

namespace {
FrameCodec codec_for(int level) {
  return level == default_frame_level ? default_frame_codec() : FrameCodec::zstd(level);
}
}  // namespace

size_t frame_bound(size_t raw_bytes) {
  return frame_header_bytes + std::max(ZSTD_compressBound(raw_bytes), raw_bytes + sizeof(uint64_t));
}

uint64_t checksum_of_pieces(const std::vector<Piece>& pieces) {
  io::Xxh3Stream sum;
  for (const Piece& piece : pieces) sum.add(piece.data, piece.bytes);
  return sum.finish();
}

RawFrameEnvelope raw_frame_envelope(uint64_t tag, uint32_t record_size, const std::vector<Piece>& pieces,
                                    size_t count) {
  size_t raw = count * record_size, at = 0;
  for (const Piece& piece : pieces) at += piece.bytes;
  if (at != raw) throw Error(ErrorKind::internal, "raw_frame_envelope: pieces do not add up to the count");
  RawFrameEnvelope envelope;
  write_header(envelope.header.data(), tag, record_size, count, raw + sizeof(uint64_t), flag_raw);
  put<uint64_t>(envelope.trailer.data(), checksum_of_pieces(pieces));
  envelope.bytes = frame_envelope_bytes + raw;
  return envelope;
}

Bytes encode_frame(uint64_t tag, uint32_t record_size, const void* records, size_t count,
                   int level) {
  return encode_frame(tag, record_size, records, count, codec_for(level));
}

Bytes encode_frame(uint64_t tag, uint32_t record_size, const void* records, size_t count,
                   FrameCodec codec) {
  return encode_frame(tag, record_size, std::vector<Piece>{{records, count * record_size}},
                      count, codec);
}

Bytes encode_frame(uint64_t tag, uint32_t record_size, const std::vector<Piece>& pieces,
                   size_t count, int level) {
  return encode_frame(tag, record_size, pieces, count, codec_for(level));
}

Bytes encode_frame(uint64_t tag, uint32_t record_size, const std::vector<Piece>& pieces,
                   size_t count, FrameCodec codec) {
  size_t raw = count * record_size;
  if (codec.raw) {
    // One copy from the pages into the frame, then the checksum while it is hot.
    Bytes frame(frame_envelope_bytes + raw);
    std::byte* payload = frame.data() + frame_header_bytes;
    size_t at = 0;
    for (const Piece& piece : pieces) {
      if (at + piece.bytes > raw) throw Error(ErrorKind::internal, "encode_frame: pieces exceed the count");
      std::memcpy(payload + at, piece.data, piece.bytes);
      at += piece.bytes;
    }
    if (at != raw) throw Error(ErrorKind::internal, "encode_frame: pieces do not add up to the count");
    put<uint64_t>(payload + raw, io::xxh3(payload, raw));
    write_header(frame.data(), tag, record_size, count, raw + sizeof(uint64_t), flag_raw);
    return frame;
  }
  const int level = codec.zstd_level;
  Bytes frame(frame_header_bytes + ZSTD_compressBound(raw));
  ZSTD_CCtx* cctx = contexts().c;
  ZSTD_CCtx_reset(cctx, ZSTD_reset_session_and_parameters);
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_compressionLevel, level);
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_checksumFlag, 1);
  ZSTD_CCtx_setPledgedSrcSize(cctx, raw);
  ZSTD_outBuffer out{frame.data() + frame_header_bytes, frame.size() - frame_header_bytes, 0};
  for (size_t i = 0; i < pieces.size(); ++i) {
    ZSTD_inBuffer in{pieces[i].data, pieces[i].bytes, 0};
    bool last = i + 1 == pieces.size();
    for (;;) {
      size_t left = ZSTD_compressStream2(cctx, &out, &in, last ? ZSTD_e_end : ZSTD_e_continue);
      if (ZSTD_isError(left)) {
        throw Error(ErrorKind::internal, std::string("zstd: ") + ZSTD_getErrorName(left));
      }
      if (last ? left == 0 : in.pos == in.size) break;
    }
  }
  if (pieces.empty()) {
    ZSTD_inBuffer in{nullptr, 0, 0};
    ZSTD_compressStream2(cctx, &out, &in, ZSTD_e_end);
  }
  write_header(frame.data(), tag, record_size, count, out.pos, 0);
  frame.resize(frame_header_bytes + out.pos);
  return frame;
}

namespace {

// The checked header of a frame whose payload holds `payload_size` bytes.
FrameHeader check_header(const std::byte* frame, size_t payload_size, uint32_t record_size, uint64_t max_records,
                         const std::string& where) {
  if (std::memcmp(frame, magic, 4) != 0) corrupt(where, "bad magic");
  if (get<uint16_t>(frame + 4) != frame_version) corrupt(where, "unknown version");
  if (get<uint64_t>(frame + 36) != fnv1a(frame, 36)) corrupt(where, "header checksum mismatch");
  FrameHeader header;
  header.record_size = get<uint16_t>(frame + 6);
  header.tag = get<uint64_t>(frame + 12);
  header.count = get<uint64_t>(frame + 20);
  header.payload_bytes = get<uint64_t>(frame + 28);
  uint32_t flags = get<uint32_t>(frame + 8);
  if ((flags & ~flag_raw) != 0) corrupt(where, "unknown flags");
  header.raw = (flags & flag_raw) != 0;
  if (header.record_size != record_size) corrupt(where, "unexpected record size");
  if (header.payload_bytes != payload_size) corrupt(where, "payload size mismatch");
  if (header.count > max_records) corrupt(where, "more records than expected");
  if (header.raw && header.payload_bytes != header.count * record_size + sizeof(uint64_t)) {
    corrupt(where, "raw payload size mismatch");
  }
  return header;
}

}  // namespace

FrameHeader decode_frame_payload(const std::byte* header_bytes, Bytes& payload, uint32_t record_size,
                                 const std::string& where) {
  const uint64_t max_records = (uint64_t(1) << 40) / std::max<uint32_t>(record_size, 1);
  FrameHeader header = check_header(header_bytes, payload.size(), record_size, max_records, where);
  const size_t raw = header.count * record_size;
  if (header.raw) {
    if (get<uint64_t>(payload.data() + raw) != io::xxh3(payload.data(), raw)) corrupt(where, "payload checksum mismatch");
    payload.resize(raw);  // the records are the payload: no copy
    return header;
  }
  Bytes records(raw);
  size_t got = ZSTD_decompressDCtx(contexts().d, records.data(), raw, payload.data(), payload.size());
  if (ZSTD_isError(got)) corrupt(where, ZSTD_getErrorName(got));
  if (got != raw) corrupt(where, "payload decodes to the wrong size");
  payload.swap(records);
  return header;
}

FrameHeader decode_frame_in_place(const std::byte* frame, size_t size, uint32_t record_size, Bytes& decoded,
                                  const std::string& where) {
  if (size < frame_header_bytes) corrupt(where, "shorter than its header");
  const uint64_t max_records = (uint64_t(1) << 40) / std::max<uint32_t>(record_size, 1);
  const FrameHeader header = check_header(frame, size - frame_header_bytes, record_size, max_records, where);
  const std::byte* payload = frame + frame_header_bytes;
  const size_t raw = header.count * record_size;
  if (header.raw) {
    if (get<uint64_t>(payload + raw) != io::xxh3(payload, raw)) corrupt(where, "payload checksum mismatch");
    return header;
  }
  decoded.resize(raw);
  size_t got = ZSTD_decompressDCtx(contexts().d, decoded.data(), raw, payload, header.payload_bytes);
  if (ZSTD_isError(got)) corrupt(where, ZSTD_getErrorName(got));
  if (got != raw) corrupt(where, "payload decodes to the wrong size");
  return header;
}

FrameHeader decode_frame_into(const std::byte* frame, size_t size, uint32_t record_size,
                              void* out, uint64_t max_records, const std::string& where) {
  if (size < frame_header_bytes) corrupt(where, "shorter than its header");
  FrameHeader header = check_header(frame, size - frame_header_bytes, record_size, max_records, where);
  size_t raw = header.count * record_size;
  if (header.raw) {
    const std::byte* payload = frame + frame_header_bytes;
    if (get<uint64_t>(payload + raw) != io::xxh3(payload, raw)) corrupt(where, "payload checksum mismatch");
    std::memcpy(out, payload, raw);
    return header;
  }
  size_t got = ZSTD_decompressDCtx(contexts().d, out, raw, frame + frame_header_bytes,
                                   header.payload_bytes);
  if (ZSTD_isError(got)) corrupt(where, ZSTD_getErrorName(got));
  if (got != raw) corrupt(where, "payload decodes to the wrong size");
  return header;
}

FrameHeader decode_frame(const std::byte* frame, size_t size, uint32_t record_size, Bytes& out,
                         const std::string& where) {
  if (size < frame_header_bytes) corrupt(where, "shorter than its header");
  uint64_t count = get<uint64_t>(frame + 20);
  if (count > (uint64_t(1) << 40) / std::max<uint32_t>(record_size, 1)) corrupt(where, "absurd record count");
  size_t start = out.size();
  out.resize(start + count * record_size);
  return decode_frame_into(frame, size, record_size, out.data() + start, count, where);
}

std::optional<ScratchCodec> parse_scratch_codec(const std::string& text) {
  if (text == "auto") return ScratchCodec::automatic;
  if (text == "raw") return ScratchCodec::raw;
  if (text == "zstd") return ScratchCodec::zstd;
  return std::nullopt;
}

ScratchStore::ScratchStore(const std::filesystem::path& parent, uint64_t expected_bytes)
    : ScratchStore(parent, expected_bytes, expected_bytes, ScratchCodec::zstd) {}

ScratchStore::ScratchStore(const std::filesystem::path& parent_in, uint64_t expected_bytes,
                           uint64_t expected_raw_bytes, ScratchCodec choice, std::optional<uint64_t> assumed_free)
    : choice_(choice), assumed_free_(assumed_free) {
  parent_ = parent_in.empty() ? std::filesystem::temp_directory_path() : parent_in;
  const std::filesystem::path& parent = parent_;
  std::error_code ec;
  if (!std::filesystem::is_directory(parent, ec)) {
    const bool exists = std::filesystem::exists(parent, ec);
    throw Error(ErrorKind::resource,
                parent.string() + (exists ? ": scratch path is not a directory" : ": scratch directory does not exist"));
  }
  struct stat parent_stat {};
  if (!assumed_free_ && ::stat(parent.c_str(), &parent_stat) == 0) device_ = parent_stat.st_dev;
  // Checked and claimed under one lock: two stores made at once each see the other.
  // The directory is made after it (a slow disk holds no other store's check up), and
  // the claim goes again if that fails (the destructor does not run).
  DiskClaims& claims = disk_claims();
  std::unique_lock claims_lock(claims.mutex);
  const uint64_t others = device_ ? claimed_by_others(claims, this, *device_) : 0;
  const uint64_t free_now = free_bytes_beside(others);
  const bool known = free_now != UINT64_MAX;
  bool raw = choice == ScratchCodec::raw || (choice == ScratchCodec::automatic && free_now >= expected_raw_bytes);
  record_choice({"start", raw, expected_raw_bytes, free_now});
  if (raw) expected_bytes = expected_raw_bytes;
  if (known) {
    if (free_now < expected_bytes) {
      throw Error(ErrorKind::resource,
                  parent.string() + ": scratch needs about " + config::format_size(expected_bytes) +
                      " free but only " + config::format_size(free_now) + " is available" +
                      (others ? " (other jobs' scratch there expects " + config::format_size(others) + " more)"
                              : std::string()) +
                      "; choose another --scratch DIR");
    }
  }
  if (device_) claims.stores[this] = {*device_, expected_bytes};
  claims_lock.unlock();
  std::random_device rd;
  for (int attempt = 0;; ++attempt) {
    dir_ = parent / ("qemflow-scratch-" + std::to_string(::getpid()) + "-" + std::to_string(rd() % 1000000));
    if (std::filesystem::create_directory(dir_, ec)) break;
    if (ec || attempt > 100) {
      {
        std::lock_guard erase_lock(claims.mutex);
        claims.stores.erase(this);
      }
      throw Error(ErrorKind::resource, parent.string() + ": cannot create a scratch directory" +
                                           (ec ? ": " + ec.message() : std::string()));
    }
  }
}

uint64_t ScratchStore::free_bytes_beside(uint64_t others) {
  if (assumed_free_) {
    std::lock_guard lock(mutex_);
    return *assumed_free_ - std::min(*assumed_free_, on_disk_);
  }
  struct statvfs fs {};
  if (statvfs(parent_.c_str(), &fs) != 0) return UINT64_MAX;
  const uint64_t free = uint64_t(fs.f_bavail) * fs.f_frsize;
  return free - std::min(free, others);
}

uint64_t ScratchStore::free_bytes() {
  DiskClaims& claims = disk_claims();
  std::lock_guard claims_lock(claims.mutex);
  return free_bytes_beside(device_ ? claimed_by_others(claims, this, *device_) : 0);
}

bool ScratchStore::choose_codec(uint64_t raw_bytes, const std::string& stage) {
  return choose_codec(raw_bytes, raw_bytes, 0, stage);  // the estimate is the bound: never capped
}

bool ScratchStore::choose_codec(uint64_t raw_bound, uint64_t raw_estimate, uint64_t zstd_room,
                                const std::string& stage) {
  if (choice_ != ScratchCodec::automatic) return codec().raw;
  DiskClaims& claims = disk_claims();
  std::lock_guard claims_lock(claims.mutex);
  const uint64_t free_now = free_bytes_beside(device_ ? claimed_by_others(claims, this, *device_) : 0);
  const uint64_t capped_need = raw_estimate > UINT64_MAX - zstd_room ? UINT64_MAX : raw_estimate + zstd_room;
  const bool uncapped = free_now >= raw_bound;
  const bool raw = uncapped || free_now >= capped_need;
  const uint64_t cap = uncapped ? 0 : raw_estimate;
  record_choice({stage, raw, uncapped || !raw ? raw_bound : capped_need, free_now,
                 raw_estimate == raw_bound ? 0 : raw_estimate, raw ? cap : 0});
  raw_left_.store(raw && cap ? cap : UINT64_MAX, std::memory_order_relaxed);
  // A raw stage may write its bound (or its cap and the zstd room) on top of what is on disk.
  if (raw && device_) {
    DiskClaim& claim = claims.stores.at(this);
    claim.bytes = std::max(claim.bytes, bytes_on_disk() + (uncapped ? raw_bound : capped_need));
  }
  return raw;
}

FrameCodec ScratchStore::frame_codec(uint64_t raw_frame_bytes) {
  if (!codec_raw_.load(std::memory_order_relaxed)) return FrameCodec::zstd();
  uint64_t left = raw_left_.load(std::memory_order_relaxed);
  while (left != UINT64_MAX) {
    if (left < raw_frame_bytes) {
      // Past the cap: this frame and the stage's rest go zstd (frames already taken
      // raw stay so; they are within the cap).
      codec_raw_.store(false, std::memory_order_relaxed);
      std::lock_guard lock(mutex_);
      if (!choices_.empty()) choices_.back().past_cap = true;
      return FrameCodec::zstd();
    }
    if (raw_left_.compare_exchange_weak(left, left - raw_frame_bytes, std::memory_order_relaxed)) break;
  }
  return FrameCodec::uncompressed();
}

void ScratchStore::record_choice(CodecChoice choice) {
  codec_raw_.store(choice.raw, std::memory_order_relaxed);
  raw_left_.store(UINT64_MAX, std::memory_order_relaxed);
  std::lock_guard lock(mutex_);
  choices_.push_back(std::move(choice));
}

ScratchStore::~ScratchStore() {
  {
    DiskClaims& claims = disk_claims();
    std::lock_guard claims_lock(claims.mutex);
    claims.stores.erase(this);
  }
  for (auto& f : files_) {
    if (f.fd >= 0) ::close(f.fd);
  }
  std::error_code ec;
  std::filesystem::remove_all(dir_, ec);
}

uint32_t ScratchStore::create_file(const std::string& name) {
  std::lock_guard lock(mutex_);
  files_.push_back({name});
  return uint32_t(files_.size() - 1);
}

ScratchStore::File& ScratchStore::file(uint32_t id) {
  std::lock_guard lock(mutex_);
  return files_.at(id);
}

std::filesystem::path ScratchStore::path_of(const File& f) const {
  return dir_ / (f.final ? f.name : f.name + ".part");
}

uint64_t ScratchStore::append(uint32_t id, const void* data, size_t size) {
  File& f = file(id);
  if (f.final) throw Error(ErrorKind::internal, "scratch: append to finalized " + f.name);
  if (f.fd < 0) {
    f.fd = ::open(path_of(f).c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (f.fd < 0) io_failure(path_of(f), "create", errno);
  }
  const char* p = static_cast<const char*>(data);
  size_t left = size;
  uint64_t offset = f.size;
  while (left > 0) {
    ssize_t n = ::pwrite(f.fd, p, left, off_t(f.size));
    if (n < 0) {
      if (errno == EINTR) continue;
      io_failure(path_of(f), "write", errno);
    }
    p += n;
    left -= size_t(n);
    f.size += uint64_t(n);
  }
  std::lock_guard lock(mutex_);
  written_ += size;
  on_disk_ += size;
  peak_on_disk_ = std::max(peak_on_disk_, on_disk_);
  return offset;
}

uint64_t ScratchStore::append_pieces(uint32_t id, const std::vector<Piece>& pieces) {
  File& f = file(id);
  if (f.final) throw Error(ErrorKind::internal, "scratch: append to finalized " + f.name);
  if (f.fd < 0) {
    f.fd = ::open(path_of(f).c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (f.fd < 0) io_failure(path_of(f), "create", errno);
  }
  std::vector<iovec> iov;
  uint64_t size = 0;
  for (const Piece& piece : pieces) {
    if (piece.bytes == 0) continue;
    iov.push_back({const_cast<void*>(piece.data), piece.bytes});
    size += piece.bytes;
  }
  const uint64_t offset = f.size;
  size_t next = 0;
  while (next < iov.size()) {
    int n_iov = int(std::min<size_t>(iov.size() - next, IOV_MAX));
    ssize_t n = ::pwritev(f.fd, iov.data() + next, n_iov, off_t(f.size));
    if (n < 0) {
      if (errno == EINTR) continue;
      io_failure(path_of(f), "write", errno);
    }
    f.size += uint64_t(n);
    // Skip what was written; a short write leaves the rest of a piece for the next call.
    for (size_t left = size_t(n); left > 0;) {
      if (left >= iov[next].iov_len) {
        left -= iov[next].iov_len;
        ++next;
      } else {
        iov[next].iov_base = static_cast<char*>(iov[next].iov_base) + left;
        iov[next].iov_len -= left;
        left = 0;
      }
    }
  }
  std::lock_guard lock(mutex_);
  written_ += size;
  on_disk_ += size;
  peak_on_disk_ = std::max(peak_on_disk_, on_disk_);
  return offset;
}

void ScratchStore::finalize(uint32_t id) {
  File& f = file(id);
  if (f.final) return;
  if (f.fd < 0) {  // never written: an empty file
    f.fd = ::open(path_of(f).c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (f.fd < 0) io_failure(path_of(f), "create", errno);
  }
  if (::close(f.fd) != 0) {
    f.fd = -1;
    io_failure(path_of(f), "close", errno);
  }
  f.fd = -1;
  auto from = path_of(f);
  f.final = true;
  if (std::rename(from.c_str(), path_of(f).c_str()) != 0) io_failure(from, "rename", errno);
}

int ScratchStore::open_for_reading(File& f) {
  if (!f.final) throw Error(ErrorKind::internal, "scratch: read of unfinished " + f.name);
  if (f.fd < 0) {
    // Read-write: discard punches holes through it.
    f.fd = ::open(path_of(f).c_str(), O_RDWR | O_CLOEXEC);
    if (f.fd < 0) io_failure(path_of(f), "open", errno);
  }
  return f.fd;
}

void ScratchStore::will_need(uint32_t id, uint64_t offset, size_t size) {
  File& f = file(id);
  if (!f.final || f.removed) return;
  (void)::posix_fadvise(open_for_reading(f), off_t(offset), off_t(size), POSIX_FADV_WILLNEED);
}

void ScratchStore::read(uint32_t id, uint64_t offset, void* out, size_t size) {
  File& f = file(id);
  open_for_reading(f);
  char* p = static_cast<char*>(out);
  size_t left = size;
  while (left > 0) {
    ssize_t n = ::pread(f.fd, p, left, off_t(offset));
    if (n < 0) {
      if (errno == EINTR) continue;
      io_failure(path_of(f), "read", errno);
    }
    if (n == 0) throw Error(ErrorKind::internal, path_of(f).string() + ": scratch file is truncated");
    p += n;
    left -= size_t(n);
    offset += uint64_t(n);
  }
  std::lock_guard lock(mutex_);
  read_ += size;
}

void ScratchStore::discard(uint32_t id, uint64_t offset, size_t size) {
  File& f = file(id);
  if (!f.final || f.fd < 0) return;
  // Whole pages only: a page shared with a frame not read yet stays (a partial one
  // would be zeroed in place, dirtied for nothing).
  static const uint64_t page = uint64_t(::sysconf(_SC_PAGESIZE));
  const uint64_t begin = (offset + page - 1) / page * page, end = (offset + size) / page * page;
  if (end <= begin) return;
  (void)::fallocate(f.fd, FALLOC_FL_PUNCH_HOLE | FALLOC_FL_KEEP_SIZE, off_t(begin), off_t(end - begin));
}

void ScratchStore::remove(uint32_t id) {
  File& f = file(id);
  if (f.removed) return;
  if (f.fd >= 0) ::close(f.fd);
  f.fd = -1;
  std::error_code ec;
  std::filesystem::remove(path_of(f), ec);
  f.removed = true;
  std::lock_guard lock(mutex_);
  on_disk_ -= std::min(on_disk_, f.size);
}

}  // namespace qemflow::engine
