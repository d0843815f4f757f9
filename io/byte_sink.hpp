#pragma once
// Buffered sequential output to a temporary file beside the destination, optionally
// zstd-compressed, published by rename on commit(). Destroying an uncommitted sink
// removes the temporary file, so a failed or abandoned write leaves nothing at the
// destination. Write failures (disk full, unwritable directory) throw
// Error(resource) naming the destination.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace qemflow::io {

class ByteSink {
 public:
  static constexpr size_t default_buffer_size = size_t{4} << 20;
  // write() of at least this many bytes goes straight to the file (no compression).
  static constexpr size_t direct_write_bytes = size_t{256} << 10;

  // zstd_level <= 0 means no compression.
  ByteSink(const std::filesystem::path& path, int zstd_level,
           size_t buffer_size = default_buffer_size);
  ~ByteSink();
  ByteSink(const ByteSink&) = delete;
  ByteSink& operator=(const ByteSink&) = delete;

  // Room for at least `n` bytes (n <= buffer size); write them, then advance(n).
  char* reserve(size_t n) {
    if (buffer_.size() - used_ < n) flush_buffer();
    return buffer_.data() + used_;
  }
  void advance(size_t n) { used_ += n; }
  void write(const void* bytes, size_t n);
  void write(std::string_view text) { write(text.data(), text.size()); }
  size_t buffer_capacity() const { return buffer_.size(); }

  void commit();
  // Bytes handed to the sink so far (before compression).
  uint64_t bytes_written() const { return flushed_ + used_; }
  const std::string& name() const { return name_; }
  const std::filesystem::path& temporary_path() const { return temporary_; }

 private:
  void flush_buffer();
  void write_file(const char* bytes, size_t n);
  [[noreturn]] void fail(const std::string& what, int error_number);

  std::string name_;
  std::filesystem::path destination_;
  std::filesystem::path temporary_;
  int fd_ = -1;
  bool committed_ = false;
  std::vector<char> buffer_;
  size_t used_ = 0;
  uint64_t flushed_ = 0;

  struct Zstd;
  std::unique_ptr<Zstd> zstd_;
};

// "OUT.tmp-<pid>-<random>" in the same directory as `destination`.
std::filesystem::path temporary_path_for(const std::filesystem::path& destination);

}  // namespace qemflow::io
