#include "engine/scratch.hpp"

#include <gtest/gtest.h>
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <thread>
#include <algorithm>
#include <numeric>

#include "test_support.hpp"
#include "io/hash64.hpp"
#include "util/error.hpp"

namespace qemflow::engine {
namespace {

using qemflow::testing::TempDir;

TEST(Frame, RoundTripsRecordsTagAndCount) {
  std::vector<uint64_t> values(10000);
  std::iota(values.begin(), values.end(), 7);
  Bytes frame = encode_frame(42, sizeof(uint64_t), values.data(), values.size());
  EXPECT_LT(frame.size(), values.size() * sizeof(uint64_t));
  Bytes out;
  FrameHeader header = decode_frame(frame.data(), frame.size(), sizeof(uint64_t), out, "t");
  EXPECT_EQ(header.tag, 42u);
  EXPECT_EQ(header.count, values.size());
  ASSERT_EQ(out.size(), values.size() * sizeof(uint64_t));
  EXPECT_EQ(std::memcmp(out.data(), values.data(), out.size()), 0);
}

TEST(Frame, PiecesEncodeLikeOneBuffer) {
  std::vector<uint32_t> values(3000);
  std::iota(values.begin(), values.end(), 0);
  std::vector<Piece> pieces{{values.data(), 4000}, {values.data() + 1000, 8000}};
  Bytes frame = encode_frame(0, 4, pieces, 3000);
  Bytes out;
  decode_frame(frame.data(), frame.size(), 4, out, "t");
  EXPECT_EQ(std::memcmp(out.data(), values.data(), out.size()), 0);
}

TEST(Frame, CorruptionIsDetected) {
  std::vector<uint64_t> values(1000, 5);
  Bytes frame = encode_frame(0, 8, values.data(), values.size());
  Bytes out;
  Bytes bad_header = frame;
  bad_header[20] ^= std::byte{1};
  EXPECT_THROW(decode_frame(bad_header.data(), bad_header.size(), 8, out, "t"), Error);
  Bytes bad_payload = frame;
  bad_payload[frame.size() - 6] ^= std::byte{0x40};
  out.clear();
  EXPECT_THROW(decode_frame(bad_payload.data(), bad_payload.size(), 8, out, "t"), Error);
  out.clear();
  EXPECT_THROW(decode_frame(frame.data(), frame.size(), 4, out, "t"), Error);  // wrong record size
}

// for_each_frame reads a frame's header and payload apart; a raw payload becomes the
// records in place (the buffer is only trimmed), a zstd one is decoded.
TEST(Frame, PayloadReadApartFromItsHeaderDecodesBothCodecsAndCatchesCorruption) {
  std::vector<uint32_t> values(3000);
  std::iota(values.begin(), values.end(), 11);
  for (FrameCodec codec : {FrameCodec::uncompressed(), FrameCodec::zstd()}) {
    Bytes frame = encode_frame(5, 4, values.data(), values.size(), codec);
    auto payload_of = [&](const Bytes& f) { return Bytes(f.begin() + frame_header_bytes, f.end()); };
    Bytes payload = payload_of(frame);
    const std::byte* before = payload.data();
    FrameHeader header = decode_frame_payload(frame.data(), payload, 4, "t");
    EXPECT_EQ(header.tag, 5u);
    EXPECT_EQ(header.count, values.size());
    ASSERT_EQ(payload.size(), values.size() * 4);
    EXPECT_EQ(std::memcmp(payload.data(), values.data(), payload.size()), 0);
    if (codec.raw) {
      EXPECT_EQ(payload.data(), before);  // no copy
    }
    Bytes bad = payload_of(frame);
    bad[bad.size() / 2] ^= std::byte{0x10};
    EXPECT_THROW(decode_frame_payload(frame.data(), bad, 4, "t"), Error);
    Bytes short_payload = payload_of(frame);
    short_payload.pop_back();
    EXPECT_THROW(decode_frame_payload(frame.data(), short_payload, 4, "t"), Error);
    Bytes again = payload_of(frame);
    EXPECT_THROW(decode_frame_payload(frame.data(), again, 8, "t"), Error);  // wrong record size
  }
}

TEST(Frame, AWholeFrameDecodesInPlaceBothCodecsAndCatchesCorruption) {
  std::vector<uint32_t> values(3000);
  std::iota(values.begin(), values.end(), 7);
  for (FrameCodec codec : {FrameCodec::uncompressed(), FrameCodec::zstd()}) {
    Bytes frame = encode_frame(9, 4, values.data(), values.size(), codec);
    Bytes decoded;
    FrameHeader header = decode_frame_in_place(frame.data(), frame.size(), 4, decoded, "t");
    EXPECT_EQ(header.tag, 9u);
    EXPECT_EQ(header.count, values.size());
    EXPECT_EQ(header.raw, codec.raw);
    // A raw frame's records are where they lie; a zstd frame's are decoded apart.
    const std::byte* records = codec.raw ? frame.data() + frame_header_bytes : decoded.data();
    EXPECT_EQ(decoded.empty(), codec.raw);
    EXPECT_EQ(std::memcmp(records, values.data(), values.size() * 4), 0);
    Bytes bad = frame;
    bad[frame_header_bytes + 100] ^= std::byte{0x04};
    EXPECT_THROW(decode_frame_in_place(bad.data(), bad.size(), 4, decoded, "t"), Error);
    EXPECT_THROW(decode_frame_in_place(frame.data(), frame.size() - 1, 4, decoded, "t"), Error);
    EXPECT_THROW(decode_frame_in_place(frame.data(), frame.size(), 8, decoded, "t"), Error);  // wrong record size
    EXPECT_THROW(decode_frame_in_place(frame.data(), frame_header_bytes - 1, 4, decoded, "t"), Error);
  }
}

TEST(Frame, RawFramesRoundTripFromPiecesAndCatchCorruption) {
  std::vector<uint32_t> values(3000);
  std::iota(values.begin(), values.end(), 0);
  std::vector<Piece> pieces{{values.data(), 4000}, {values.data() + 1000, 8000}};
  Bytes frame = encode_frame(9, 4, pieces, 3000, FrameCodec::uncompressed());
  // Header, the records as they are, their checksum.
  ASSERT_EQ(frame.size(), frame_header_bytes + values.size() * 4 + 8);
  EXPECT_EQ(std::memcmp(frame.data() + frame_header_bytes, values.data(), values.size() * 4), 0);
  EXPECT_LE(frame.size(), frame_bound(values.size() * 4));
  Bytes out;
  FrameHeader header = decode_frame(frame.data(), frame.size(), 4, out, "t");
  EXPECT_TRUE(header.raw);
  EXPECT_EQ(header.tag, 9u);
  EXPECT_EQ(header.count, 3000u);
  ASSERT_EQ(out.size(), values.size() * 4);
  EXPECT_EQ(std::memcmp(out.data(), values.data(), out.size()), 0);
  for (size_t at : {frame_header_bytes + 5, frame.size() - 3, size_t(8)}) {  // a record, the checksum, the flags
    Bytes bad = frame;
    bad[at] ^= std::byte{0x10};
    out.clear();
    EXPECT_THROW(decode_frame(bad.data(), bad.size(), 4, out, "t"), Error) << at;
  }
  Bytes short_frame(frame.begin(), frame.end() - 1);
  EXPECT_THROW(decode_frame(short_frame.data(), short_frame.size(), 4, out, "t"), Error);
  // Pieces that do not add up to the count are a bug, not a frame.
  EXPECT_THROW(encode_frame(0, 4, pieces, 2999, FrameCodec::uncompressed()), Error);
}

TEST(Frame, ARawFrameWrittenFromPiecesIsTheSameBytes) {
  std::vector<uint8_t> bytes(100'003);
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = uint8_t(i * 2654435761u >> 13);
  // Piece sizes that cut the hash's 32-byte stripes everywhere, and empty pieces.
  for (size_t cut : {1, 7, 31, 32, 33, 4096, 50'000, 100'003}) {
    std::vector<Piece> pieces;
    for (size_t at = 0; at < bytes.size(); at += cut) {
      pieces.push_back({bytes.data() + at, std::min(cut, bytes.size() - at)});
      if (at == 0) pieces.push_back({bytes.data(), 0});
    }
    EXPECT_EQ(checksum_of_pieces(pieces), io::xxh3(bytes.data(), bytes.size())) << cut;
  }
  for (size_t n : {0, 5, 31, 32, 64, 99}) EXPECT_EQ(checksum_of_pieces({{bytes.data(), n}}), io::xxh3(bytes.data(), n)) << n;
  std::vector<Piece> pieces{{bytes.data(), 40'000}, {bytes.data() + 40'000, 60'000}};
  Bytes frame = encode_frame(3, 4, pieces, 25'000, FrameCodec::uncompressed());
  RawFrameEnvelope envelope = raw_frame_envelope(3, 4, pieces, 25'000);
  ASSERT_EQ(envelope.bytes, frame.size());
  EXPECT_EQ(std::memcmp(envelope.header.data(), frame.data(), frame_header_bytes), 0);
  EXPECT_EQ(std::memcmp(envelope.trailer.data(), frame.data() + frame.size() - 8, 8), 0);
  // And append_pieces writes it as one frame that decodes.
  TempDir tmp;
  ScratchStore store(tmp.path(), 1 << 20);
  uint32_t f = store.create_file("raw");
  std::vector<Piece> all{{envelope.header.data(), envelope.header.size()}, pieces[0], pieces[1],
                         {envelope.trailer.data(), envelope.trailer.size()}};
  EXPECT_EQ(store.append_pieces(f, all), 0u);
  store.finalize(f);
  Bytes back(envelope.bytes), out;
  store.read(f, 0, back.data(), back.size());
  EXPECT_EQ(decode_frame(back.data(), back.size(), 4, out, "t").count, 25'000u);
  EXPECT_EQ(std::memcmp(out.data(), bytes.data(), 100'000), 0);
  EXPECT_EQ(store.bytes_written(), envelope.bytes);
}

TEST(Frame, TheDefaultCodecIsZstdUnlessARunSetsIt) {
  std::vector<uint64_t> values(10000, 3);
  EXPECT_FALSE(default_frame_codec().raw);
  Bytes out;
  {
    DefaultFrameCodec raw(FrameCodec::uncompressed());
    Bytes frame = encode_frame(0, 8, values.data(), values.size());
    EXPECT_TRUE(decode_frame(frame.data(), frame.size(), 8, out, "t").raw);
    // An explicit level is zstd whatever the default.
    Bytes zstd = encode_frame(0, 8, values.data(), values.size(), -1);
    EXPECT_FALSE(decode_frame(zstd.data(), zstd.size(), 8, out, "t").raw);
  }
  EXPECT_FALSE(default_frame_codec().raw);
  Bytes frame = encode_frame(0, 8, values.data(), values.size());
  EXPECT_LT(frame.size(), values.size() * 8);
  // Overlapping runs (two jobs in one process) end in any order: the base comes back.
  auto first = std::make_unique<DefaultFrameCodec>(FrameCodec::uncompressed());
  auto second = std::make_unique<DefaultFrameCodec>(FrameCodec::zstd(-3));
  EXPECT_EQ(default_frame_codec(), FrameCodec::zstd(-3));
  first.reset();
  EXPECT_EQ(default_frame_codec(), FrameCodec::zstd(-3));
  second.reset();
  EXPECT_EQ(default_frame_codec(), FrameCodec::zstd());
}

TEST(ScratchStore, ChoosesRawWhenTheDirectoryHasRoomForIt) {
  TempDir tmp;
  EXPECT_TRUE(ScratchStore(tmp.path(), 1 << 20, 4 << 20, ScratchCodec::automatic).codec().raw);
  // Room for the compressed frames only: zstd.
  EXPECT_FALSE(ScratchStore(tmp.path(), 1 << 20, uint64_t(1) << 62, ScratchCodec::automatic).codec().raw);
  EXPECT_FALSE(ScratchStore(tmp.path(), 1 << 20, 4 << 20, ScratchCodec::zstd).codec().raw);
  EXPECT_FALSE(ScratchStore(tmp.path(), 1 << 20).codec().raw);  // the old constructor: zstd
  // Forced raw still needs room for the raw bytes.
  EXPECT_THROW(ScratchStore(tmp.path(), 1 << 20, uint64_t(1) << 62, ScratchCodec::raw), Error);
  EXPECT_EQ(parse_scratch_codec("raw"), ScratchCodec::raw);
  EXPECT_EQ(parse_scratch_codec("auto"), ScratchCodec::automatic);
  EXPECT_EQ(parse_scratch_codec("zstd"), ScratchCodec::zstd);
  EXPECT_FALSE(parse_scratch_codec("lz4"));
  EXPECT_TRUE(std::filesystem::is_empty(tmp.path()));
}

// An automatic store chooses again at each stage, against the free space then: an
// assumed disk (tests) loses what the store has on disk; forced codecs never change.
TEST(ScratchStore, AutomaticChoosesEachStageAgainstTheSpaceLeft) {
  TempDir tmp;
  {
    ScratchStore s(tmp.path(), 1000, 4000, ScratchCodec::automatic, 10000);
    EXPECT_TRUE(s.codec().raw);
    EXPECT_EQ(s.free_bytes(), 10000u);
    const uint32_t f = s.create_file("a");
    const std::vector<std::byte> bytes(7000);
    s.append(f, bytes.data(), bytes.size());
    EXPECT_EQ(s.free_bytes(), 3000u);
    EXPECT_FALSE(s.choose_codec(4000, "next"));  // 3000 left
    EXPECT_FALSE(s.codec().raw);
    EXPECT_TRUE(s.choose_codec(3000, "smaller"));
    EXPECT_TRUE(s.codec().raw);
    s.remove(f);
    EXPECT_EQ(s.free_bytes(), 10000u);
    const auto choices = s.codec_choices();
    ASSERT_EQ(choices.size(), 3u);
    EXPECT_EQ(choices[1].stage, "next");
    EXPECT_EQ(choices[1].free_bytes, 3000u);
    EXPECT_FALSE(choices[1].raw);
  }
  ScratchStore zstd(tmp.path(), 1000, 4000, ScratchCodec::zstd, 10000);
  EXPECT_FALSE(zstd.choose_codec(1, "x"));
  ScratchStore raw(tmp.path(), 1000, 4000, ScratchCodec::raw, 10000);
  EXPECT_TRUE(raw.choose_codec(uint64_t(1) << 62, "x"));
  // Too small even for zstd's estimate: refused up front.
  EXPECT_THROW(ScratchStore(tmp.path(), 20000, 40000, ScratchCodec::automatic, 10000), Error);
}

// A stage whose raw bytes are estimated, not bounded (the states: epochs.cpp): raw with
// room for the estimate and the zstd room, its frames raw up to the estimate (the cap)
// and zstd from the first frame past it to the stage's end; uncapped when the bound
// fits; zstd when neither does. The next choice starts afresh.
TEST(ScratchStore, AnEstimatedStageGoesRawUpToItsCapThenZstd) {
  TempDir tmp;
  ScratchStore s(tmp.path(), 1000, 1000, ScratchCodec::automatic, 10000);
  // The bound (20000) does not fit, the estimate and its room (2 x 3000) do.
  EXPECT_TRUE(s.choose_codec(20000, 3000, 3000, "capped"));
  EXPECT_TRUE(s.frame_codec(2000).raw);
  EXPECT_TRUE(s.frame_codec(1000).raw);  // exactly the cap
  EXPECT_FALSE(s.frame_codec(1).raw);    // past it: zstd
  EXPECT_FALSE(s.codec().raw);
  EXPECT_FALSE(s.frame_codec(1).raw);  // and for the rest of the stage
  auto choices = s.codec_choices();
  ASSERT_EQ(choices.size(), 2u);
  EXPECT_TRUE(choices[1].raw);
  EXPECT_EQ(choices[1].raw_bytes, 6000u);  // what was checked: the estimate and the room
  EXPECT_EQ(choices[1].raw_cap, 3000u);
  EXPECT_TRUE(choices[1].past_cap);
  // The bound fits: uncapped.
  EXPECT_TRUE(s.choose_codec(5000, 3000, 3000, "uncapped"));
  EXPECT_TRUE(s.frame_codec(5000).raw);
  EXPECT_TRUE(s.frame_codec(5000).raw);
  // Neither fits: zstd, frames too.
  EXPECT_FALSE(s.choose_codec(20000, 6000, 6000, "zstd"));
  EXPECT_FALSE(s.frame_codec(1).raw);
  choices = s.codec_choices();
  ASSERT_EQ(choices.size(), 4u);
  EXPECT_EQ(choices[2].raw_cap, 0u);
  EXPECT_FALSE(choices[2].past_cap);
  EXPECT_FALSE(choices[3].raw);
  EXPECT_EQ(choices[3].raw_bytes, 20000u);
  // A forced codec ignores estimates and caps.
  ScratchStore raw(tmp.path(), 1000, 1000, ScratchCodec::raw, 10000);
  EXPECT_TRUE(raw.choose_codec(1u << 30, 1u << 30, 1u << 30, "x"));
  EXPECT_TRUE(raw.frame_codec(1u << 30).raw);
}

TEST(ScratchStore, FilesAreCompleteOnlyWhenFinalizedAndAllGoAtTheEnd) {
  TempDir tmp;
  std::filesystem::path dir;
  {
    ScratchStore store(tmp.path(), 1 << 20);
    dir = store.dir();
    EXPECT_EQ(dir.parent_path(), tmp.path());
    uint32_t f = store.create_file("blocks-3");
    std::string a = "hello ", b = "world";
    EXPECT_EQ(store.append(f, a.data(), a.size()), 0u);
    EXPECT_EQ(store.append(f, b.data(), b.size()), 6u);
    EXPECT_TRUE(std::filesystem::exists(dir / "blocks-3.part"));
    EXPECT_FALSE(std::filesystem::exists(dir / "blocks-3"));
    char buf[5];
    EXPECT_THROW(store.read(f, 6, buf, 5), Error);  // not finalized yet
    store.finalize(f);
    EXPECT_TRUE(std::filesystem::exists(dir / "blocks-3"));
    store.read(f, 6, buf, 5);
    EXPECT_EQ(std::string(buf, 5), "world");
    EXPECT_EQ(store.bytes_written(), 11u);
  }
  EXPECT_FALSE(std::filesystem::exists(dir));
}

// Discarded bytes leave the file's pages (a hole: zeros, same size); the rest stays.
TEST(ScratchStore, DiscardedPagesGoAndTheRestOfTheFileStays) {
  TempDir tmp;
  ScratchStore store(tmp.path(), 1 << 20);
  uint32_t f = store.create_file("blocks-0");
  constexpr size_t page = 4096;
  std::string bytes = std::string(page, 'a') + std::string(page, 'b') + std::string(page, 'c');
  store.append(f, bytes.data(), bytes.size());
  store.finalize(f);
  std::string got(bytes.size(), '?');
  store.read(f, 0, got.data(), got.size());
  ASSERT_EQ(got, bytes);
  store.discard(f, page, page);
  EXPECT_EQ(std::filesystem::file_size(store.dir() / "blocks-0"), bytes.size());
  store.read(f, 0, got.data(), got.size());
  EXPECT_EQ(got.substr(0, page), bytes.substr(0, page));
  EXPECT_EQ(got.substr(2 * page), bytes.substr(2 * page));
  if (got.substr(page, page) == bytes.substr(page, page)) GTEST_SKIP() << "this file system keeps discarded bytes";
  EXPECT_EQ(got.substr(page, page), std::string(page, '\0'));
}

// How many of a file's pages the page cache holds (mincore over a mapping: no fault).
size_t resident_pages(const std::filesystem::path& path, size_t bytes) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return 0;
  void* map = ::mmap(nullptr, bytes, PROT_READ, MAP_SHARED, fd, 0);
  ::close(fd);
  if (map == MAP_FAILED) return 0;
  const size_t page = size_t(::sysconf(_SC_PAGESIZE)), pages = (bytes + page - 1) / page;
  std::vector<unsigned char> in(pages);
  const bool ok = ::mincore(map, bytes, in.data()) == 0;
  ::munmap(map, bytes);
  return ok ? size_t(std::count_if(in.begin(), in.end(), [](unsigned char c) { return c & 1; })) : 0;
}

// will_need is advice, but it must reach the kernel: a frame's pages dropped from the
// page cache come back without a read; a file not finalized, or removed, is left alone.
TEST(ScratchStore, WillNeedBringsAFramesPagesBackIntoThePageCache) {
  TempDir tmp;
  ScratchStore store(tmp.path(), 64 << 20);
  const uint32_t f = store.create_file("state-0");
  const std::string bytes(4 << 20, 'x');
  store.append(f, bytes.data(), bytes.size());
  EXPECT_NO_THROW(store.will_need(f, 0, bytes.size()));
  store.finalize(f);
  const auto path = store.dir() / "state-0";
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  ASSERT_GE(fd, 0);
  ::fdatasync(fd);  // dirty pages cannot be dropped
  ::posix_fadvise(fd, 0, 0, POSIX_FADV_DONTNEED);
  ::close(fd);
  const size_t pages = bytes.size() / size_t(::sysconf(_SC_PAGESIZE));
  if (resident_pages(path, bytes.size()) > pages / 2) GTEST_SKIP() << "the page cache kept the file's pages";
  const uint64_t read_before = store.bytes_read();
  store.will_need(f, 0, bytes.size());
  for (int i = 0; i < 200 && resident_pages(path, bytes.size()) < pages; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  EXPECT_EQ(resident_pages(path, bytes.size()), pages);
  EXPECT_EQ(store.bytes_read(), read_before);
  store.remove(f);
  EXPECT_NO_THROW(store.will_need(f, 0, bytes.size()));
}

// Two jobs of one host on one scratch disk: each store's up-front check takes off what
// the others still expect to write (statvfs sees only what they wrote), so the second
// of two stores that would each fit alone but not together is refused, naming the
// others' share; the claim goes with its store. (Both used to pass the check.)
TEST(ScratchStore, AStoreLeavesRoomForWhatAnotherOnTheDiskStillExpectsToWrite) {
  TempDir tmp;
  struct statvfs fs {};
  ASSERT_EQ(statvfs(tmp.path().c_str(), &fs), 0);
  const uint64_t free = uint64_t(fs.f_bavail) * fs.f_frsize;
  ASSERT_GT(free, 64ull << 20);
  {
    ScratchStore first(tmp.path(), free / 2);
    try {
      ScratchStore second(tmp.path(), free / 2 + free / 8);
      FAIL() << "both stores passed the check";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::resource);
      EXPECT_NE(std::string(e.what()).find("other jobs' scratch there expects"), std::string::npos) << e.what();
    }
    ScratchStore third(tmp.path(), free / 4);  // room beside the first
    EXPECT_LT(third.free_bytes(), free / 2 + free / 16);
    // Raw when the raw bytes fit beside the others' claims, zstd when they do not.
    EXPECT_TRUE(ScratchStore(tmp.path(), 1 << 20, free / 8, ScratchCodec::automatic).codec().raw);
    EXPECT_FALSE(ScratchStore(tmp.path(), 1 << 20, free / 2, ScratchCodec::automatic).codec().raw);
  }
  ScratchStore alone(tmp.path(), free / 2 + free / 8);  // the claims went with their stores
  EXPECT_TRUE(std::filesystem::exists(alone.dir()));
}

TEST(ScratchStore, NotEnoughFreeSpaceIsRefusedUpFront) {
  TempDir tmp;
  try {
    ScratchStore store(tmp.path(), uint64_t(1) << 62);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::resource);
    EXPECT_NE(std::string(e.what()).find("--scratch"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(std::filesystem::is_empty(tmp.path()));
}

TEST(ScratchStore, MissingOrReadOnlyDirectoryIsAResourceError) {
  TempDir tmp;
  EXPECT_THROW(ScratchStore(tmp / "nope", 0), Error);
  if (::geteuid() == 0) GTEST_SKIP() << "root ignores directory permissions";
  std::filesystem::permissions(tmp.path(), std::filesystem::perms::owner_read | std::filesystem::perms::owner_exec);
  try {
    ScratchStore store(tmp.path(), 0);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::resource);
  }
  std::filesystem::permissions(tmp.path(), std::filesystem::perms::owner_all);
}


// The raw frames' checksum (XXH3) must catch what a torn or corrupted write does: any
// flipped bit, bytes moved around (whole stripes and whole 1 KiB blocks), a frame cut
// short or padded with zeros. It is libxxhash's XXH3 (the published value of "").
TEST(RawFrameChecksum, CatchesFlipsMovesAndLengthChanges) {
  std::vector<uint8_t> bytes(5000);
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = uint8_t(i * 2654435761u >> 11);
  EXPECT_EQ(io::xxh3("", 0), 0x2D06800538D394C2ull);
  const uint64_t good = io::xxh3(bytes.data(), bytes.size());
  EXPECT_EQ(io::xxh3(bytes.data(), bytes.size()), good);
  for (size_t at = 0; at < bytes.size(); at += 7) {
    for (int bit : {0, 5, 7}) {
      bytes[at] ^= uint8_t(1 << bit);
      EXPECT_NE(io::xxh3(bytes.data(), bytes.size()), good) << at << " bit " << bit;
      bytes[at] ^= uint8_t(1 << bit);
    }
  }
  auto swapped = [&](size_t a, size_t b, size_t n) {
    std::vector<uint8_t> copy = bytes;
    std::swap_ranges(copy.begin() + int64_t(a), copy.begin() + int64_t(a + n), copy.begin() + int64_t(b));
    return io::xxh3(copy.data(), copy.size());
  };
  EXPECT_NE(swapped(0, 64, 64), good);      // two stripes of one block
  EXPECT_NE(swapped(0, 1024, 1024), good);  // two blocks
  EXPECT_NE(swapped(8, 16, 8), good);       // two words of one stripe
  EXPECT_NE(io::xxh3(bytes.data(), bytes.size() - 1), good);
  std::vector<uint8_t> padded = bytes;
  padded.push_back(0);
  EXPECT_NE(io::xxh3(padded.data(), padded.size()), good);
  std::vector<uint8_t> zeros(64, 0);
  EXPECT_NE(io::xxh3(zeros.data(), 64), io::xxh3(zeros.data(), 63));
  EXPECT_NE(io::xxh3(zeros.data(), 0), io::xxh3(zeros.data(), 1));
}

TEST(RawFrameChecksum, AnySplitIntoPiecesGivesTheSameSum) {
  std::vector<uint8_t> bytes(20'000);
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = uint8_t(i * 40503u >> 7);
  const uint64_t whole = io::xxh3(bytes.data(), bytes.size());
  for (size_t cut : {1, 12, 63, 64, 65, 1000, 1024, 1025, 7777}) {
    io::Xxh3Stream sum;
    for (size_t at = 0; at < bytes.size(); at += cut) sum.add(bytes.data() + at, std::min(cut, bytes.size() - at));
    EXPECT_EQ(sum.finish(), whole) << cut;
  }
}

}  // namespace
}  // namespace qemflow::engine
