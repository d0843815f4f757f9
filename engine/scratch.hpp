#pragma once
// The scratch store: a private directory of chunk files under --scratch (default: the
// system temp dir) that lives exactly as long as the job. Each file is a sequence of
// frames; a frame is one self-contained chunk of records:
//
//   header (48 bytes, little-endian): magic "QFCK", version u16 = 3, record size u16,
//     flags u32 (bit 0: raw payload), tag u64 (what the frame holds, e.g. its first
//     vertex index), record count u64, payload bytes u64, header checksum u64 (FNV-1a
//     of the above)
//   payload, zstd codec: one zstd frame (fast level, content checksum on) of
//     count × record size
//   payload, raw codec: the count × record size bytes themselves, then their
//     XXH3 (u64, io/hash64.hpp), so corruption is still caught
//
// Which codec: a scratch disk writes and reads raw bytes faster than one core
// compresses them (zstd -1 ~ 400 MB/s per core, the checksum ~ 20 GB/s), so raw is the
// default when the scratch directory has room for it; zstd when space is short
// (ScratchStore chooses; see ScratchCodec). Any decoder reads both.
//
// Contract
// - The constructor checks free space for `expected_bytes` up front (Error(resource)
//   naming the directory and the shortfall) and creates the private directory.
// - Files are written under "NAME.part" and renamed to NAME by finalize(), so a file
//   with its final name is complete; readers only get frames of finalized files.
// - The destructor removes the whole directory: on success, on failure, on cancel.
// - append/read/finalize do blocking file I/O: call them on the I/O thread only.
//   encode_frame/decode_frame are pure CPU: call them on compute threads.
// - Every failure is Error(resource) (disk full, read-only, vanished) or
//   Error(internal) for a corrupt frame, each naming the file.
#include <sys/types.h>

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <mutex>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "util/memory.hpp"

namespace qemflow::engine {

// The buffers of util/memory.hpp, by their engine names.
using qemflow::Bytes;
using qemflow::UninitializedAllocator;
using qemflow::UninitializedVector;

// How frames are encoded. `zstd_level` is used by the zstd codec only.
struct FrameCodec {
  bool raw = false;
  int zstd_level = -1;
  static FrameCodec zstd(int level = -1) { return {false, level}; }
  static FrameCodec uncompressed() { return {true, -1}; }
  bool operator==(const FrameCodec&) const = default;
};
// The codec of frames encoded without an explicit one (the `level` argument left at
// its default): process-wide, zstd -1 unless set; a DefaultFrameCodec sets it for its
// own length (while several are alive the newest one wins, and when none is left the
// base, set_default_frame_codec, applies again). The pipelines never rely on it: every
// frame they write passes its ScratchStore's codec(), so a job beside another with a
// different codec writes what its own store checked the disk for (review15;
// SimplifyOocJobs.AJobWritesItsOwnCodecWhateverTheProcessDefault). Any codec decodes
// anywhere.
FrameCodec default_frame_codec();
void set_default_frame_codec(FrameCodec codec);  // the base
class DefaultFrameCodec {
 public:
  explicit DefaultFrameCodec(FrameCodec codec);
  ~DefaultFrameCodec();
  DefaultFrameCodec(const DefaultFrameCodec&) = delete;
  DefaultFrameCodec& operator=(const DefaultFrameCodec&) = delete;

 private:
  uint64_t id_;
};
// `level` argument meaning "the default codec".
constexpr int default_frame_level = -1000000;

struct FrameHeader {
  uint32_t record_size = 0;
  uint64_t tag = 0;
  uint64_t count = 0;
  uint64_t payload_bytes = 0;
  bool raw = false;
};
constexpr size_t frame_header_bytes = 48;
// A raw frame's bytes beside its records: the header and the checksum after them.
constexpr size_t frame_envelope_bytes = frame_header_bytes + sizeof(uint64_t);

// Worst-case encoded size of `raw_bytes` of records, either codec (for leases).
size_t frame_bound(size_t raw_bytes);
// Encodes count records of record_size bytes each into one frame. `level`: a zstd
// level, or default_frame_level for the process's default codec. zstd level -1 (the
// fast mode): measured on 20M faces, 10% less CPU than level 1 for 3% more bytes.
Bytes encode_frame(uint64_t tag, uint32_t record_size, const void* records, size_t count,
                   int level = default_frame_level);
Bytes encode_frame(uint64_t tag, uint32_t record_size, const void* records, size_t count,
                   FrameCodec codec);
// Streaming variant: the records arrive as several pieces (pages), `count` in total.
struct Piece {
  const void* data;
  size_t bytes;
};
Bytes encode_frame(uint64_t tag, uint32_t record_size, const std::vector<Piece>& pieces,
                   size_t count, int level = default_frame_level);
Bytes encode_frame(uint64_t tag, uint32_t record_size, const std::vector<Piece>& pieces,
                   size_t count, FrameCodec codec);
// A raw frame without copying its records: the header and the checksum trailer to
// write around the pieces (e.g. with ScratchStore::append_pieces), so that spilled
// pages go to the disk as they are. Same bytes as encode_frame with the raw codec.
// XXH3 of the pieces laid end to end (without joining them).
uint64_t checksum_of_pieces(const std::vector<Piece>& pieces);
struct RawFrameEnvelope {
  std::array<std::byte, frame_header_bytes> header;
  std::array<std::byte, sizeof(uint64_t)> trailer;
  uint64_t bytes = 0;  // the whole frame: header + records + trailer
};
RawFrameEnvelope raw_frame_envelope(uint64_t tag, uint32_t record_size, const std::vector<Piece>& pieces,
                                    size_t count);

// Checks and decompresses a frame; appends its records to `out` (resized). `where`
// names the frame in messages.
FrameHeader decode_frame(const std::byte* frame, size_t size, uint32_t record_size, Bytes& out,
                         const std::string& where);

// The same, into a caller's buffer of room for `max_records` records.
FrameHeader decode_frame_into(const std::byte* frame, size_t size, uint32_t record_size,
                              void* out, uint64_t max_records, const std::string& where);

// A frame read as its header (frame_header_bytes) and its payload apart: a raw
// payload is checked and trimmed in place to its records (no copy), a zstd payload is
// decoded into a buffer that replaces it. Either way `payload` ends holding exactly
// the frame's records. Same checks and errors as decode_frame.
FrameHeader decode_frame_payload(const std::byte* header, Bytes& payload, uint32_t record_size,
                                 const std::string& where);

// A whole frame (header and payload) read into a caller's buffer, left there: a raw
// frame's records are checked where they lie (at frame + frame_header_bytes; nothing
// is copied and `decoded` is untouched), a zstd frame's are decoded into `decoded`.
// Same checks and errors as decode_frame.
FrameHeader decode_frame_in_place(const std::byte* frame, size_t size, uint32_t record_size, Bytes& decoded,
                                  const std::string& where);

// Where a frame lives.
struct FrameRef {
  uint32_t file = 0;
  uint64_t offset = 0;
  uint64_t bytes = 0;     // encoded size, header included
  uint64_t count = 0;     // records
  uint64_t tag = 0;
  uint32_t record_size = 0;  // set where one file mixes record sizes (vertex frames)
};

// What a ScratchStore encodes its frames with. automatic: raw when the directory has
// room for the raw bytes (expected_raw_bytes), else zstd when it has room for
// expected_bytes, and again at each choose_codec() (a stage whose raw bytes are bounded,
// or estimated with a cap, then); raw / zstd: forced (each still checked for its own space).
enum class ScratchCodec { automatic, raw, zstd };
// "auto", "raw", "zstd" (nullopt for anything else).
std::optional<ScratchCodec> parse_scratch_codec(const std::string& text);

class ScratchStore {
 public:
  ScratchStore(const std::filesystem::path& parent, uint64_t expected_bytes);
  // expected_bytes: compressed (zstd) estimate; expected_raw_bytes: raw estimate.
  // `assumed_free`: the disk's free bytes when the store was made, instead of statvfs
  // (tests: a disk of that size; what the store has on disk is taken off it as it writes).
  ScratchStore(const std::filesystem::path& parent, uint64_t expected_bytes, uint64_t expected_raw_bytes,
               ScratchCodec choice, std::optional<uint64_t> assumed_free = std::nullopt);
  // The codec chosen for this store's frames (zstd -1 with the two-argument constructor).
  // Read by compute threads as they encode: it changes in choose_codec(), and in
  // frame_codec() when a capped raw stage passes its cap.
  FrameCodec codec() const {
    return codec_raw_.load(std::memory_order_relaxed) ? FrameCodec::uncompressed() : FrameCodec::zstd();
  }
  // Automatic stores: the frames written from now on are raw if the disk has
  // `raw_bytes` free now (a bound on what the stage about to start writes raw, on top
  // of what is on disk), else zstd; forced ones keep their codec. Call it only where no
  // frame is being encoded or written (between stages, the I/O thread drained): a stage
  // writes one codec throughout. Frames self-describe their codec, so earlier frames
  // of the other codec read as before. `stage` names the choice in the report.
  // Returns whether the frames will be raw.
  bool choose_codec(uint64_t raw_bytes, const std::string& stage);
  // The same for a stage whose raw bytes are bounded loosely (`raw_bound`, the worst
  // case) but estimated closely (`raw_estimate`): raw, uncapped, when the bound fits;
  // else raw when `raw_estimate + zstd_room` fits (zstd_room: what the stage may then
  // still write in zstd), with the stage's raw bytes capped at raw_estimate: frames
  // taken with frame_codec() go raw while they fit under the cap and zstd from the
  // first that does not, to the stage's end (the report's choice then says
  // "past_cap"). So such a stage writes at most raw_estimate raw bytes beside its zstd
  // ones, whatever its real size. Same calling rule as above.
  bool choose_codec(uint64_t raw_bound, uint64_t raw_estimate, uint64_t zstd_room, const std::string& stage);
  // The codec to encode a frame of `raw_frame_bytes` (the whole frame, raw) with:
  // codec(), but a capped raw stage (above) turns zstd for good once its frames would
  // pass the cap. Thread-safe (compute threads, each frame as it is encoded).
  FrameCodec frame_codec(uint64_t raw_frame_bytes);
  // Free bytes of the scratch disk now (statvfs, or assumed_free less what is on disk);
  // UINT64_MAX when unknown. On a real disk, less what the process's other stores there
  // still expect to write: each store claims its expected bytes when it is made (and a
  // raw stage's bound at choose_codec), and its claim counts until written or the store
  // ends, so the up-front check and the codec choices see the room left beside them.
  uint64_t free_bytes();
  // The choices made: the constructor's ("start") and each choose_codec()'s, with the
  // raw bound asked for and the free bytes seen (the report's scratch_codec_choices).
  struct CodecChoice {
    std::string stage;
    bool raw = false;
    uint64_t raw_bytes = 0, free_bytes = 0;
    uint64_t raw_estimate = 0;  // an estimated stage's estimate (0: a bound only)
    uint64_t raw_cap = 0;       // a capped raw stage's cap (0: none)
    bool past_cap = false;  // its frames went zstd past the cap
  };
  std::vector<CodecChoice> codec_choices() {
    std::lock_guard lock(mutex_);
    return choices_;
  }
  ~ScratchStore();
  ScratchStore(const ScratchStore&) = delete;
  ScratchStore& operator=(const ScratchStore&) = delete;

  const std::filesystem::path& dir() const { return dir_; }
  // Registers a file (created on first append). Thread-safe.
  uint32_t create_file(const std::string& name);
  // I/O thread only. Returns the frame's offset in the file.
  uint64_t append(uint32_t file, const void* data, size_t size);
  // The same for bytes in several pieces, written in order as one (vectored) write.
  uint64_t append_pieces(uint32_t file, const std::vector<Piece>& pieces);
  void read(uint32_t file, uint64_t offset, void* out, size_t size);
  // Bytes [offset, offset + size) of a finalized file (read at least once) will not be
  // read again: the whole pages among them leave the page cache and the disk now (a
  // hole: zeros; the file keeps its size), so that the writes that follow reuse those pages rather than take fresh
  // ones. Fresh page-cache pages cost several times a reused one here (a VM whose
  // freed memory goes back to the host: 380 MB written into fresh pages took 0.5-1.0
  // CPU-s against 0.09 into pages just freed). Advice: a file system without holes
  // keeps the bytes. I/O thread only.
  void discard(uint32_t file, uint64_t offset, size_t size);
  // Bytes [offset, offset + size) of a finalized file will be read soon: the kernel
  // starts reading those not in the page cache now, without waiting for them, so that
  // scattered frames are read many at a time rather than one pread after another.
  // Advice only. I/O thread only.
  void will_need(uint32_t file, uint64_t offset, size_t size);
  void finalize(uint32_t file);
  void remove(uint32_t file);

  uint64_t bytes_written() const { return written_; }
  uint64_t bytes_read() const { return read_; }
  uint64_t peak_bytes_on_disk() const { return peak_on_disk_; }
  // Bytes of the files not removed yet (written by every append that has returned).
  uint64_t bytes_on_disk() {
    std::lock_guard lock(mutex_);
    return on_disk_;
  }

 private:
  struct File {
    std::string name;
    uint64_t size = 0;
    bool final = false;
    bool removed = false;
    int fd = -1;
  };
  std::filesystem::path path_of(const File& file) const;
  // Sets the codec the choice names and keeps the choice (the report's).
  void record_choice(CodecChoice choice);
  File& file(uint32_t id);
  int open_for_reading(File& f);  // its descriptor, opened on first use
  // free_bytes() with `others` (the other stores' outstanding claims) taken off.
  uint64_t free_bytes_beside(uint64_t others);

  std::filesystem::path dir_, parent_;
  // The codec (raw, or zstd -1) and a capped raw stage's raw bytes left (UINT64_MAX:
  // uncapped): read by compute threads as they encode, set by the choices.
  std::atomic<bool> codec_raw_{false};
  std::atomic<uint64_t> raw_left_{UINT64_MAX};
  ScratchCodec choice_ = ScratchCodec::zstd;
  std::optional<uint64_t> assumed_free_;  // an assumed disk is the store's own: no claims
  std::optional<dev_t> device_;           // the scratch disk, for the claims
  std::vector<CodecChoice> choices_;
  std::mutex mutex_;
  std::deque<File> files_;  // a deque: references stay valid as files are added
  uint64_t written_ = 0, read_ = 0, on_disk_ = 0, peak_on_disk_ = 0;
};

}  // namespace qemflow::engine
