#include "io/byte_source.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#define ZSTD_STATIC_LINKING_ONLY  // frame headers and decoder size estimates
#include <zstd.h>
#include <zstd_errors.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <optional>

#include "util/error.hpp"

namespace qemflow::io {

struct ByteSource::Zstd {
  ZSTD_DStream* stream = nullptr;
  std::vector<char> input;
  ZSTD_inBuffer in{nullptr, 0, 0};
  size_t last_result = 0;  // 0 when the last frame is complete
  bool file_done = false;
  ~Zstd() { ZSTD_freeDStream(stream); }
};

namespace {

// The header of the first frame of the zstd file open at `fd`, read with pread (the
// file position is left alone); nullopt when there is none to read.
std::optional<ZSTD_frameHeader> first_frame_header(int fd, std::vector<char>& header) {
  header.resize(ZSTD_FRAMEHEADERSIZE_MAX);
  ssize_t got;
  do got = ::pread(fd, header.data(), header.size(), 0);
  while (got < 0 && errno == EINTR);
  header.resize(got < 0 ? 0 : size_t(got));
  ZSTD_frameHeader frame{};
  if (ZSTD_getFrameHeader(&frame, header.data(), header.size()) != 0 || frame.frameType != ZSTD_frame) {
    return std::nullopt;
  }
  return frame;
}

int window_log(uint64_t window) {
  int log = ZSTD_WINDOWLOG_MIN;
  while ((uint64_t{1} << log) < window) ++log;
  return log;
}

}  // namespace

uint64_t zstd_decoder_bytes_to_reserve(const std::filesystem::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return 0;
  std::vector<char> header;
  const auto frame = first_frame_header(fd, header);
  ::close(fd);
  if (!frame) return 0;
  const size_t bytes = ZSTD_estimateDStreamSize_fromFrame(header.data(), header.size());
  const size_t counted = ZSTD_estimateDStreamSize(zstd_window_allowance);
  return ZSTD_isError(bytes) || bytes <= counted ? 0 : bytes - counted;
}

ByteSource::ByteSource(const std::filesystem::path& path, bool zstd, size_t buffer_size)
    : name_(path.string()), buffer_(buffer_size < 4096 ? 4096 : buffer_size) {
  fd_ = ::open(name_.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd_ < 0) throw_bad_input(name_, "cannot open", std::strerror(errno));
  struct stat st {};
  if (::fstat(fd_, &st) == 0) {
    if (S_ISDIR(st.st_mode)) {
      ::close(fd_);
      throw_bad_input(name_, "cannot open", "is a directory");
    }
    file_size_ = static_cast<uint64_t>(st.st_size);
  }
  ::posix_fadvise(fd_, 0, 0, POSIX_FADV_SEQUENTIAL);
  if (zstd) {
    zstd_ = std::make_unique<Zstd>();
    zstd_->stream = ZSTD_createDStream();
    if (!zstd_->stream) throw Error(ErrorKind::resource, name_ + ": cannot create zstd stream");
    // The first frame's window (what zstd_decoder_bytes_to_reserve told the caller to
    // reserve), and zstd's default limit for later frames (see byte_source.hpp).
    std::vector<char> header;
    const auto frame = first_frame_header(fd_, header);
    static_assert(zstd_window_allowance <= uint64_t{1} << ZSTD_WINDOWLOG_LIMIT_DEFAULT);
    const int log = std::max(frame ? window_log(frame->windowSize) : 0, ZSTD_WINDOWLOG_LIMIT_DEFAULT);
    ZSTD_DCtx_setParameter(zstd_->stream, ZSTD_d_windowLogMax, std::min(log, ZSTD_WINDOWLOG_MAX));
    zstd_->input.resize(size_t{1} << 20);
    zstd_->in = {zstd_->input.data(), 0, 0};
  }
}

ByteSource::~ByteSource() {
  if (fd_ >= 0) ::close(fd_);
}

size_t ByteSource::read_file(char* destination, size_t capacity) {
  for (;;) {
    ssize_t got = ::read(fd_, destination, capacity);
    if (got >= 0) {
      file_bytes_read_ += static_cast<uint64_t>(got);
      return static_cast<size_t>(got);
    }
    if (errno == EINTR) continue;
    throw_bad_input(name_, "byte " + std::to_string(file_bytes_read_),
                    std::string("read error: ") + std::strerror(errno));
  }
}

size_t ByteSource::read_decompressed(char* destination, size_t capacity) {
  Zstd& z = *zstd_;
  ZSTD_outBuffer out{destination, capacity, 0};
  while (out.pos == 0) {
    if (z.in.pos == z.in.size) {
      if (z.file_done) break;
      size_t got = read_file(z.input.data(), z.input.size());
      if (got == 0) {
        z.file_done = true;
        break;
      }
      z.in = {z.input.data(), got, 0};
    }
    size_t input_before = file_bytes_read_ - (z.in.size - z.in.pos);
    size_t result = ZSTD_decompressStream(z.stream, &out, &z.in);
    if (ZSTD_isError(result) && ZSTD_getErrorCode(result) == ZSTD_error_frameParameter_windowTooLarge) {
      throw Error(ErrorKind::resource, name_ + ": byte " + std::to_string(input_before) +
                                           " of the compressed file: a zstd frame needs a larger window than "
                                           "the decoder allows (recompress without --long, or as one frame)");
    }
    if (ZSTD_isError(result)) {
      throw_bad_input(name_, "byte " + std::to_string(input_before) + " of the compressed file",
                      std::string("corrupted zstd data (") + ZSTD_getErrorName(result) + ")");
    }
    z.last_result = result;
  }
  if (out.pos == 0 && z.file_done && z.last_result != 0) {
    throw_bad_input(name_, "byte " + std::to_string(file_bytes_read_) + " of the compressed file",
                    "zstd stream is truncated (the last frame is incomplete)");
  }
  return out.pos;
}

bool ByteSource::refill(size_t n) {
  if (begin_ > 0) {
    std::memmove(buffer_.data(), buffer_.data() + begin_, end_ - begin_);
    consumed_before_ += begin_;
    end_ -= begin_;
    begin_ = 0;
  }
  if (n > buffer_.size()) buffer_.resize(std::max(n, buffer_.size() * 2));
  while (end_ < n && !eof_) {
    char* destination = buffer_.data() + end_;
    size_t capacity = buffer_.size() - end_;
    size_t got = zstd_ ? read_decompressed(destination, capacity) : read_file(destination, capacity);
    if (got == 0) eof_ = true;
    end_ += got;
  }
  return end_ >= n;
}

}  // namespace qemflow::io
