#include "io/chunk_file.hpp"

#include <fcntl.h>
#include <unistd.h>
#include <zstd.h>

#include <bit>
#include <cerrno>

#include "io/byte_sink.hpp"
#include "io/hash64.hpp"
#include "util/error.hpp"

namespace qemflow::io {

namespace {

static_assert(std::endian::native == std::endian::little, "chunk headers are stored little-endian");

constexpr char chunk_magic[8] = {'Q', 'F', 'C', 'H', 'U', 'N', 'K', '1'};
constexpr size_t checksummed_header_bytes = 56;

[[noreturn]] void corrupted(const std::string& file, uint64_t offset, const std::string& problem) {
  throw Error(ErrorKind::internal,
              file + ": chunk at byte " + std::to_string(offset) + ": " + problem + " (scratch corrupted)");
}

template <class T>
void store(std::byte* at, T value) {
  std::memcpy(at, &value, sizeof(T));
}
template <class T>
T load(const std::byte* at) {
  T value;
  std::memcpy(&value, at, sizeof(T));
  return value;
}

}  // namespace

void DecodedChunk::check_record_type(size_t size) const {
  if (size != record_size) {
    throw Error(ErrorKind::internal, "chunk of kind " + std::to_string(kind) + " has records of " +
                                         std::to_string(record_size) + " bytes, asked for " +
                                         std::to_string(size));
  }
}

std::vector<std::byte> encode_chunk(uint32_t kind, uint32_t record_size, const void* records,
                                    uint64_t count, int level) {
  if (record_size == 0) throw Error(ErrorKind::internal, "encode_chunk: record size 0");
  const uint64_t raw = count * record_size;
  const size_t bound = ZSTD_compressBound(raw);
  std::vector<std::byte> chunk(chunk_header_size + bound);
  size_t compressed = ZSTD_compress(chunk.data() + chunk_header_size, bound, records, raw, level);
  if (ZSTD_isError(compressed)) {
    throw Error(ErrorKind::internal, std::string("encode_chunk: zstd failed: ") + ZSTD_getErrorName(compressed));
  }
  chunk.resize(chunk_header_size + compressed);
  std::byte* h = chunk.data();
  std::memcpy(h, chunk_magic, 8);
  store<uint32_t>(h + 8, chunk_format_version);
  store<uint32_t>(h + 12, kind);
  store<uint32_t>(h + 16, record_size);
  store<uint32_t>(h + 20, static_cast<uint32_t>(chunk_header_size));
  store<uint64_t>(h + 24, count);
  store<uint64_t>(h + 32, raw);
  store<uint64_t>(h + 40, compressed);
  store<uint64_t>(h + 48, xxh64(h + chunk_header_size, compressed));
  store<uint64_t>(h + 56, xxh64(h, checksummed_header_bytes));
  return chunk;
}

ChunkHeader parse_chunk_header(std::span<const std::byte> header, const std::string& file, uint64_t offset) {
  if (header.size() < chunk_header_size) {
    corrupted(file, offset, "truncated header (" + std::to_string(header.size()) + " of " +
                                std::to_string(chunk_header_size) + " bytes)");
  }
  const std::byte* h = header.data();
  if (std::memcmp(h, chunk_magic, 8) != 0) corrupted(file, offset, "bad magic (not a qemflow chunk)");
  if (load<uint64_t>(h + 56) != xxh64(h, checksummed_header_bytes)) {
    corrupted(file, offset, "header checksum mismatch");
  }
  uint32_t version = load<uint32_t>(h + 8);
  if (version != chunk_format_version) {
    corrupted(file, offset, "unsupported chunk format version " + std::to_string(version));
  }
  if (load<uint32_t>(h + 20) != chunk_header_size) corrupted(file, offset, "unexpected header size");
  ChunkHeader parsed;
  parsed.kind = load<uint32_t>(h + 12);
  parsed.record_size = load<uint32_t>(h + 16);
  parsed.record_count = load<uint64_t>(h + 24);
  parsed.raw_bytes = load<uint64_t>(h + 32);
  parsed.compressed_bytes = load<uint64_t>(h + 40);
  parsed.payload_checksum = load<uint64_t>(h + 48);
  if (parsed.record_size == 0 || parsed.raw_bytes % parsed.record_size != 0 ||
      parsed.raw_bytes / parsed.record_size != parsed.record_count) {
    corrupted(file, offset, "record count x record size does not match the raw byte count");
  }
  return parsed;
}

DecodedChunk decode_chunk(std::span<const std::byte> chunk, const std::string& file, uint64_t offset) {
  ChunkHeader header = parse_chunk_header(chunk, file, offset);
  if (chunk.size() != header.encoded_size()) {
    corrupted(file, offset, "size mismatch: header says " + std::to_string(header.encoded_size()) +
                                " bytes, have " + std::to_string(chunk.size()));
  }
  const std::byte* payload = chunk.data() + chunk_header_size;
  if (xxh64(payload, header.compressed_bytes) != header.payload_checksum) {
    corrupted(file, offset, "checksum mismatch");
  }
  unsigned long long content = ZSTD_getFrameContentSize(payload, header.compressed_bytes);
  if (content != header.raw_bytes) corrupted(file, offset, "zstd frame size does not match the header");
  DecodedChunk decoded;
  decoded.kind = header.kind;
  decoded.record_size = header.record_size;
  decoded.record_count = header.record_count;
  decoded.bytes.resize(header.raw_bytes);
  size_t got = ZSTD_decompress(decoded.bytes.data(), decoded.bytes.size(), payload, header.compressed_bytes);
  if (ZSTD_isError(got) || got != header.raw_bytes) {
    corrupted(file, offset, std::string("zstd frame does not decode: ") +
                                (ZSTD_isError(got) ? ZSTD_getErrorName(got) : "short output"));
  }
  return decoded;
}

struct ChunkFileWriter::Sink {
  ByteSink bytes;
  Sink(const std::filesystem::path& path, size_t buffer_size) : bytes(path, 0, buffer_size) {}
};

ChunkFileWriter::ChunkFileWriter(const std::filesystem::path& path, size_t buffer_size)
    : sink_(std::make_unique<Sink>(path, buffer_size)) {}

ChunkFileWriter::~ChunkFileWriter() = default;

uint64_t ChunkFileWriter::append(std::span<const std::byte> encoded_chunk) {
  uint64_t offset = sink_->bytes.bytes_written();
  sink_->bytes.write(encoded_chunk.data(), encoded_chunk.size());
  ++chunks_;
  return offset;
}

void ChunkFileWriter::commit() { sink_->bytes.commit(); }

uint64_t ChunkFileWriter::bytes_written() const { return sink_->bytes.bytes_written(); }

ChunkFileReader::ChunkFileReader(const std::filesystem::path& path) : name_(path.string()) {
  fd_ = ::open(name_.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd_ < 0) {
    throw Error(ErrorKind::internal, name_ + ": cannot open scratch file: " + std::strerror(errno));
  }
}

ChunkFileReader::~ChunkFileReader() {
  if (fd_ >= 0) ::close(fd_);
}

size_t ChunkFileReader::read_exactly(uint64_t offset, void* destination, size_t size) {
  auto* out = static_cast<char*>(destination);
  size_t done = 0;
  while (done < size) {
    ssize_t got = ::pread(fd_, out + done, size - done, static_cast<off_t>(offset + done));
    if (got < 0) {
      if (errno == EINTR) continue;
      throw Error(ErrorKind::internal, name_ + ": cannot read scratch file at byte " +
                                           std::to_string(offset + done) + ": " + std::strerror(errno));
    }
    if (got == 0) break;
    done += static_cast<size_t>(got);
  }
  return done;
}

std::vector<std::byte> ChunkFileReader::read_encoded_at(uint64_t offset) {
  std::vector<std::byte> chunk(chunk_header_size);
  size_t got = read_exactly(offset, chunk.data(), chunk_header_size);
  if (got < chunk_header_size) {
    corrupted(name_, offset, "file ends inside the chunk header (" + std::to_string(got) + " of " +
                                 std::to_string(chunk_header_size) + " bytes)");
  }
  ChunkHeader header = parse_chunk_header(chunk, name_, offset);
  chunk.resize(header.encoded_size());
  got = read_exactly(offset + chunk_header_size, chunk.data() + chunk_header_size, header.compressed_bytes);
  if (got < header.compressed_bytes) {
    corrupted(name_, offset, "truncated: header says " + std::to_string(header.compressed_bytes) +
                                 " compressed bytes, file has " + std::to_string(got));
  }
  return chunk;
}

std::optional<std::vector<std::byte>> ChunkFileReader::next_encoded() {
  std::byte probe;
  if (read_exactly(offset_, &probe, 1) == 0) return std::nullopt;
  std::vector<std::byte> chunk = read_encoded_at(offset_);
  offset_ += chunk.size();
  return chunk;
}

std::optional<DecodedChunk> ChunkFileReader::next() {
  uint64_t at = offset_;
  auto encoded = next_encoded();
  if (!encoded) return std::nullopt;
  return decode_chunk(*encoded, name_, at);
}

}  // namespace qemflow::io
