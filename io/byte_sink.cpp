#include "io/byte_sink.hpp"

#include <fcntl.h>
#include <unistd.h>
#include <zstd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <random>

#include "util/error.hpp"

namespace qemflow::io {

struct ByteSink::Zstd {
  ZSTD_CCtx* context = nullptr;
  std::vector<char> output;
  ~Zstd() { ZSTD_freeCCtx(context); }
};

std::filesystem::path temporary_path_for(const std::filesystem::path& destination) {
  static thread_local std::mt19937_64 random{std::random_device{}()};
  char suffix[64];
  std::snprintf(suffix, sizeof suffix, ".tmp-%ld-%016llx", static_cast<long>(::getpid()),
                static_cast<unsigned long long>(random()));
  return std::filesystem::path(destination.string() + suffix);
}

ByteSink::ByteSink(const std::filesystem::path& path, int zstd_level, size_t buffer_size)
    : name_(path.string()),
      destination_(path),
      temporary_(temporary_path_for(path)),
      buffer_(buffer_size < 4096 ? 4096 : buffer_size) {
  fd_ = ::open(temporary_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd_ < 0) fail("cannot create output file", errno);
  if (zstd_level > 0) {
    zstd_ = std::make_unique<Zstd>();
    zstd_->context = ZSTD_createCCtx();
    if (!zstd_->context) fail("cannot create zstd context", ENOMEM);
    ZSTD_CCtx_setParameter(zstd_->context, ZSTD_c_compressionLevel, zstd_level);
    ZSTD_CCtx_setParameter(zstd_->context, ZSTD_c_checksumFlag, 1);
    zstd_->output.resize(ZSTD_CStreamOutSize() * 4);
  }
}

ByteSink::~ByteSink() {
  if (fd_ >= 0) ::close(fd_);
  if (!committed_) {
    std::error_code ignored;
    std::filesystem::remove(temporary_, ignored);
  }
}

void ByteSink::fail(const std::string& what, int error_number) {
  throw Error(ErrorKind::resource, name_ + ": " + what + ": " + std::strerror(error_number));
}

void ByteSink::write_file(const char* bytes, size_t n) {
  while (n > 0) {
    ssize_t put = ::write(fd_, bytes, n);
    if (put < 0) {
      if (errno == EINTR) continue;
      fail("cannot write", errno);
    }
    if (put == 0) fail("cannot write", ENOSPC);
    bytes += put;
    n -= static_cast<size_t>(put);
  }
}

void ByteSink::flush_buffer() {
  if (used_ == 0) return;
  if (zstd_) {
    ZSTD_inBuffer in{buffer_.data(), used_, 0};
    while (in.pos < in.size) {
      ZSTD_outBuffer out{zstd_->output.data(), zstd_->output.size(), 0};
      size_t result = ZSTD_compressStream2(zstd_->context, &out, &in, ZSTD_e_continue);
      if (ZSTD_isError(result)) {
        throw Error(ErrorKind::internal,
                    name_ + ": zstd compression failed: " + ZSTD_getErrorName(result));
      }
      write_file(zstd_->output.data(), out.pos);
    }
  } else {
    write_file(buffer_.data(), used_);
  }
  flushed_ += used_;
  used_ = 0;
}

void ByteSink::write(const void* bytes, size_t n) {
  const char* p = static_cast<const char*>(bytes);
  // Large blocks (pre-encoded batches) skip the copy: the writing thread only hands
  // them to the kernel.
  if (!zstd_ && n >= std::min(buffer_.size(), direct_write_bytes)) {
    flush_buffer();
    write_file(p, n);
    flushed_ += n;
    return;
  }
  while (n > 0) {
    if (used_ == buffer_.size()) flush_buffer();
    size_t take = std::min(n, buffer_.size() - used_);
    std::memcpy(buffer_.data() + used_, p, take);
    used_ += take;
    p += take;
    n -= take;
  }
}

void ByteSink::commit() {
  if (committed_) throw Error(ErrorKind::internal, name_ + ": committed twice");
  flush_buffer();
  if (zstd_) {
    ZSTD_inBuffer in{nullptr, 0, 0};
    size_t remaining;
    do {
      ZSTD_outBuffer out{zstd_->output.data(), zstd_->output.size(), 0};
      remaining = ZSTD_compressStream2(zstd_->context, &out, &in, ZSTD_e_end);
      if (ZSTD_isError(remaining)) {
        throw Error(ErrorKind::internal,
                    name_ + ": zstd compression failed: " + ZSTD_getErrorName(remaining));
      }
      write_file(zstd_->output.data(), out.pos);
    } while (remaining != 0);
  }
  int fd = fd_;
  fd_ = -1;
  if (::close(fd) != 0) fail("cannot write", errno);
  if (std::rename(temporary_.c_str(), destination_.c_str()) != 0) {
    fail("cannot rename " + temporary_.string() + " into place", errno);
  }
  committed_ = true;
}

}  // namespace qemflow::io
