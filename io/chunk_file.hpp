#pragma once
// Scratch chunks (DESIGN.md §2): fixed-size records compressed as one zstd frame
// behind a 64-byte header, so a pipeline can compress on a compute thread
// (encode_chunk), write on the I/O thread (ChunkFileWriter::append of the encoded
// bytes), read back on the I/O thread (ChunkFileReader::next_encoded) and
// decompress on a compute thread (decode_chunk).
//
// Header, little-endian: "QFCHUNK1", u32 version (1), u32 kind (caller's tag),
// u32 record size, u32 header size (64), u64 record count, u64 raw bytes
// (count x record size), u64 compressed bytes, u64 XXH64 of the compressed bytes,
// u64 XXH64 of the 56 header bytes before it.
//
// Scratch is written only by us, so damage there is a bug or a failing disk, not
// bad user input: every truncation, corruption or mismatch throws
// Error(internal) "FILE: chunk at byte N: PROBLEM (scratch corrupted)". No call
// ever returns records that failed a check.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace qemflow::io {

inline constexpr size_t chunk_header_size = 64;
inline constexpr uint32_t chunk_format_version = 1;

struct ChunkHeader {
  uint32_t kind = 0;
  uint32_t record_size = 0;
  uint64_t record_count = 0;
  uint64_t raw_bytes = 0;
  uint64_t compressed_bytes = 0;
  uint64_t payload_checksum = 0;
  uint64_t encoded_size() const { return chunk_header_size + compressed_bytes; }
};

struct DecodedChunk {
  uint32_t kind = 0;
  uint32_t record_size = 0;
  uint64_t record_count = 0;
  std::vector<std::byte> bytes;  // record_count * record_size bytes

  // A copy of the records as T (T trivially copyable, sizeof(T) == record_size,
  // else Error(internal)).
  template <class T>
  std::vector<T> records() const {
    check_record_type(sizeof(T));
    std::vector<T> out(record_count);
    if (!bytes.empty()) std::memcpy(out.data(), bytes.data(), bytes.size());
    return out;
  }
  void check_record_type(size_t size) const;
};

// Compresses `count` records of `record_size` bytes; returns header + frame.
std::vector<std::byte> encode_chunk(uint32_t kind, uint32_t record_size, const void* records,
                                    uint64_t count, int level = 3);
template <class T>
std::vector<std::byte> encode_chunk(uint32_t kind, std::span<const T> records, int level = 3) {
  return encode_chunk(kind, sizeof(T), records.data(), records.size(), level);
}

// Checks magic, version and header checksum of the first 64 bytes. `offset` is
// where the chunk starts in `file`, for messages.
ChunkHeader parse_chunk_header(std::span<const std::byte> header, const std::string& file,
                               uint64_t offset = 0);
// `chunk` must be exactly one encoded chunk; validates everything and decompresses.
DecodedChunk decode_chunk(std::span<const std::byte> chunk, const std::string& file_for_errors,
                          uint64_t offset = 0);

// Appends encoded chunks to a temporary file beside `path`; commit() renames it
// into place, destruction without commit() removes it. Write failures are
// Error(resource) naming the file.
class ChunkFileWriter {
 public:
  explicit ChunkFileWriter(const std::filesystem::path& path, size_t buffer_size = size_t{1} << 20);
  ~ChunkFileWriter();
  ChunkFileWriter(const ChunkFileWriter&) = delete;
  ChunkFileWriter& operator=(const ChunkFileWriter&) = delete;

  // Returns the byte offset at which the chunk starts (for read_encoded_at).
  uint64_t append(std::span<const std::byte> encoded_chunk);
  uint64_t append(uint32_t kind, uint32_t record_size, const void* records, uint64_t count,
                  int level = 3) {
    return append(encode_chunk(kind, record_size, records, count, level));
  }
  void commit();
  uint64_t bytes_written() const;
  uint64_t chunk_count() const { return chunks_; }

 private:
  struct Sink;
  std::unique_ptr<Sink> sink_;
  uint64_t chunks_ = 0;
};

// Reads chunks back, sequentially or at known offsets. Holds no more than one
// chunk's bytes.
class ChunkFileReader {
 public:
  explicit ChunkFileReader(const std::filesystem::path& path);
  ~ChunkFileReader();
  ChunkFileReader(const ChunkFileReader&) = delete;
  ChunkFileReader& operator=(const ChunkFileReader&) = delete;

  // The next chunk's encoded bytes (header checked, payload not yet), or nullopt
  // at a clean end of file.
  std::optional<std::vector<std::byte>> next_encoded();
  // next_encoded() + decode_chunk().
  std::optional<DecodedChunk> next();
  std::vector<std::byte> read_encoded_at(uint64_t offset);
  DecodedChunk read_at(uint64_t offset) { return decode_chunk(read_encoded_at(offset), name_, offset); }
  // Byte offset of the chunk next() returns.
  uint64_t offset() const { return offset_; }
  const std::string& name() const { return name_; }

 private:
  size_t read_exactly(uint64_t offset, void* destination, size_t size);  // returns bytes read

  std::string name_;
  int fd_ = -1;
  uint64_t offset_ = 0;
};

}  // namespace qemflow::io
