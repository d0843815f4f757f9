#pragma once
// Buffered sequential input from one file, zstd-decompressed on the fly when asked.
// Holds one buffer (4 MiB by default, grown only when a caller needs a longer
// contiguous run). A parser asks for at least N contiguous bytes with fill(), reads
// them through data(), then consume()s what it used. Unconsumed bytes stay in front,
// so data() always points at the first byte not yet consumed.
// Errors: missing/unreadable file and corrupted or truncated zstd data throw
// Error(bad_input) naming the file.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace qemflow::io {

// A .zst input's decoder holds its frames' window (up to 2 GiB; `zstd --long=27`
// makes 128 MiB) beside ByteSource's buffers. Windows up to zstd_window_allowance (every
// zstd level up to -19 chooses windowLog 23 or less) are the caller's own overhead to
// count; zstd_decoder_bytes_to_reserve(path) is what the decoder of the file's first
// frame needs beyond that (ZSTD_estimateDStreamSize_fromFrame, less the same estimate
// for the allowance): 0 for a small window, or a file with no zstd frame header to
// read. The caller reserves it before it reads. A later frame of a concatenated file
// (`cat a.zst b.zst`) may need a larger window than the first; it still decodes up to
// zstd's default limit (128 MiB, windowLog 27; review14 found such files refused as
// corrupt when the limit was the first frame's), and that excess is not reserved:
// finding it would mean walking every frame's blocks before reading. A frame past
// both that limit and the first frame's window is refused as a resource error.
inline constexpr uint64_t zstd_window_allowance = uint64_t{8} << 20;
uint64_t zstd_decoder_bytes_to_reserve(const std::filesystem::path& path);

class ByteSource {
 public:
  static constexpr size_t default_buffer_size = size_t{4} << 20;

  ByteSource(const std::filesystem::path& path, bool zstd,
             size_t buffer_size = default_buffer_size);
  ~ByteSource();
  ByteSource(const ByteSource&) = delete;
  ByteSource& operator=(const ByteSource&) = delete;

  const char* data() const { return buffer_.data() + begin_; }
  size_t available() const { return end_ - begin_; }
  // Makes at least `n` bytes available; false if the stream ends first (then every
  // remaining byte is available).
  bool fill(size_t n) { return available() >= n || refill(n); }
  // Never moves bytes: what data() showed stays in place until the next fill().
  void consume(size_t n) { begin_ += n; }
  // True once every byte of the stream has been consumed.
  bool at_end() { return !fill(1); }

  // Offset of data() in the (decompressed) stream: what error messages call "byte N".
  uint64_t offset() const { return consumed_before_ + begin_; }
  // Bytes taken from the file itself (compressed bytes for .zst), for progress.
  uint64_t file_bytes_read() const { return file_bytes_read_; }
  uint64_t file_size() const { return file_size_; }
  const std::string& name() const { return name_; }

 private:
  bool refill(size_t n);
  size_t read_file(char* destination, size_t capacity);  // 0 at end of file
  size_t read_decompressed(char* destination, size_t capacity);

  std::string name_;
  int fd_ = -1;
  uint64_t file_size_ = 0;
  uint64_t file_bytes_read_ = 0;
  std::vector<char> buffer_;
  size_t begin_ = 0;
  size_t end_ = 0;
  uint64_t consumed_before_ = 0;
  bool eof_ = false;

  struct Zstd;
  std::unique_ptr<Zstd> zstd_;
};

}  // namespace qemflow::io
