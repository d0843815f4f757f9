// Scratch chunks: round trips, and every truncation or bit flip is detected as
// Error(internal) instead of returning garbage.
#include "io/chunk_file.hpp"

#include <gtest/gtest.h>

#include <functional>
#include <random>

#include "io/hash64.hpp"
#include "io_test_support.hpp"
#include "test_support.hpp"
#include "util/error.hpp"

namespace qemflow::io {
namespace {

using qemflow::testing::TempDir;

struct Record {
  double position[3];
  uint64_t id;
  bool operator==(const Record&) const = default;
};

std::vector<Record> make_records(size_t n, uint64_t seed) {
  std::mt19937_64 random(seed);
  std::vector<Record> records(n);
  for (size_t i = 0; i < n; ++i) {
    records[i] = {{double(random() % 1000) * 0.25, double(i), -1.5}, random()};
  }
  return records;
}

std::string internal_error_of(const std::function<void()>& action) {
  try {
    action();
  } catch (const Error& error) {
    EXPECT_EQ(error.kind(), ErrorKind::internal) << error.what();
    return error.what();
  }
  return "";
}

TEST(Hash64, MatchesPublishedXxh64Values) {
  EXPECT_EQ(xxh64("", 0), 0xEF46DB3751D8E999ull);
  EXPECT_EQ(xxh64("a", 1), 0xD24EC4F1A98C6E5Bull);
  EXPECT_EQ(xxh64("abc", 3), 0x44BC2CF5AD770999ull);
}

TEST(Chunk, EncodeDecodeRoundTrip) {
  for (size_t n : {0, 1, 7, 1000, 100000}) {
    auto records = make_records(n, n);
    auto encoded = encode_chunk<Record>(42, records);
    ASSERT_GE(encoded.size(), chunk_header_size);
    DecodedChunk decoded = decode_chunk(encoded, "mem");
    EXPECT_EQ(decoded.kind, 42u);
    EXPECT_EQ(decoded.record_size, sizeof(Record));
    EXPECT_EQ(decoded.record_count, n);
    EXPECT_EQ(decoded.records<Record>(), records);
  }
}

TEST(Chunk, WrongRecordTypeIsInternal) {
  auto encoded = encode_chunk<Record>(1, make_records(3, 1));
  DecodedChunk decoded = decode_chunk(encoded, "mem");
  EXPECT_NE(internal_error_of([&] { decoded.records<uint64_t>(); }), "");
}

TEST(Chunk, EveryTruncationIsDetected) {
  auto encoded = encode_chunk<Record>(7, make_records(500, 3));
  for (size_t size = 0; size < encoded.size(); size += (size < 80 ? 1 : 37)) {
    std::span<const std::byte> cut(encoded.data(), size);
    std::string message = internal_error_of([&] { decode_chunk(cut, "scratch.bin", 4096); });
    EXPECT_NE(message.find("scratch.bin: chunk at byte 4096: "), std::string::npos) << size << ": " << message;
    EXPECT_NE(message.find("(scratch corrupted)"), std::string::npos) << message;
  }
}

TEST(Chunk, EveryBitFlipIsDetected) {
  auto encoded = encode_chunk<Record>(7, make_records(50, 4));
  for (size_t byte = 0; byte < encoded.size(); ++byte) {
    for (int bit : {0, 3, 7}) {
      auto damaged = encoded;
      damaged[byte] ^= std::byte(1 << bit);
      std::string message = internal_error_of([&] { decode_chunk(damaged, "s"); });
      EXPECT_NE(message.find("scratch corrupted"), std::string::npos) << "byte " << byte << " bit " << bit;
    }
  }
  auto damaged = encoded;
  damaged[chunk_header_size + 5] ^= std::byte(0x10);
  EXPECT_NE(internal_error_of([&] { decode_chunk(damaged, "s"); }).find("checksum mismatch"), std::string::npos);
}

TEST(ChunkFile, SequentialAndRandomAccessRoundTrip) {
  TempDir dir;
  auto path = dir / "blocks.qfc";
  std::vector<std::vector<Record>> chunks;
  std::vector<uint64_t> offsets;
  {
    ChunkFileWriter writer(path, 4096);  // small buffer: large chunks bypass it
    for (size_t c = 0; c < 20; ++c) {
      chunks.push_back(make_records(c * c * 17, c));
      if (c % 2) {
        offsets.push_back(writer.append(encode_chunk<Record>(uint32_t(c), chunks.back())));
      } else {
        offsets.push_back(writer.append(uint32_t(c), sizeof(Record), chunks.back().data(), chunks.back().size()));
      }
    }
    EXPECT_EQ(writer.chunk_count(), 20u);
    EXPECT_FALSE(std::filesystem::exists(path));
    writer.commit();
  }
  ChunkFileReader reader(path);
  for (size_t c = 0; c < 20; ++c) {
    EXPECT_EQ(reader.offset(), offsets[c]);
    auto chunk = reader.next();
    ASSERT_TRUE(chunk);
    EXPECT_EQ(chunk->kind, c);
    EXPECT_EQ(chunk->records<Record>(), chunks[c]);
  }
  EXPECT_FALSE(reader.next());
  EXPECT_EQ(reader.read_at(offsets[7]).records<Record>(), chunks[7]);
  EXPECT_EQ(reader.read_at(offsets[3]).kind, 3u);
}

TEST(ChunkFile, AbandonedWriterLeavesNothing) {
  TempDir dir;
  {
    ChunkFileWriter writer(dir / "x.qfc");
    writer.append(1, 8, "12345678", 1);
  }
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
}

TEST(ChunkFile, TruncatedFileIsDetectedAtEveryLength) {
  TempDir dir;
  auto path = dir / "t.qfc";
  uint64_t second = 0;
  {
    ChunkFileWriter writer(path);
    writer.append(encode_chunk<Record>(1, make_records(100, 1)));
    second = writer.append(encode_chunk<Record>(2, make_records(100, 2)));
    writer.commit();
  }
  std::string bytes = testing::read_bytes(path);
  auto cut_path = dir / "cut.qfc";
  for (size_t size = 1; size < bytes.size(); size += (size % 64 < 3 ? 1 : 11)) {
    testing::write_bytes(cut_path, bytes.substr(0, size));
    ChunkFileReader reader(cut_path);
    size_t complete = 0;
    std::string message = internal_error_of([&] {
      while (reader.next()) ++complete;
    });
    if (size == second) {
      EXPECT_EQ(message, "");  // a clean end after the first chunk
      EXPECT_EQ(complete, 1u);
      continue;
    }
    uint64_t broken = size < second ? 0 : second;
    EXPECT_NE(message.find("cut.qfc: chunk at byte " + std::to_string(broken) + ": "), std::string::npos)
        << size << ": " << message;
    EXPECT_EQ(complete, size < second ? 0u : 1u);
  }
}

TEST(ChunkFile, MissingScratchFileIsInternal) {
  TempDir dir;
  EXPECT_NE(internal_error_of([&] { ChunkFileReader reader(dir / "none.qfc"); }).find("none.qfc"), std::string::npos);
}

}  // namespace
}  // namespace qemflow::io
