// Engine micro-benchmarks (governor, frame codec, bucket spill) and two drivers for
// bench/reencode.sh:
//   engine_bench reencode IN OUT --mem-budget SIZE [--scratch DIR] [--trace F] [--report F]
//                [--threads N] [--quiet]        the re-encode pipeline (= simplify --ratio 1)
//   engine_bench io-baseline IN SCRATCH_DIR BYTES [SCRATCH_WRITE SCRATCH_READ]
//                read IN and write BYTES through the I/O thread alone: the floor the
//                pipeline's throughput is compared with (and, with the scratch bytes a
//                run moved, the floor for all of its I/O)
#include <benchmark/benchmark.h>

#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <numeric>
#include <string>

#include "config/size.hpp"
#include "engine/governor.hpp"
#include "engine/io_thread.hpp"
#include "engine/reencode.hpp"
#include "engine/scratch.hpp"
#include "io/hash64.hpp"
#include "util/error.hpp"

namespace {

using namespace qemflow;
using namespace qemflow::engine;

void BM_GovernorLeaseCycle(benchmark::State& state) {
  Governor governor(1ull << 30, 0);
  for (auto _ : state) {
    Lease lease = governor.try_acquire("node", 4096);
    benchmark::DoNotOptimize(lease.bytes());
  }
}
BENCHMARK(BM_GovernorLeaseCycle);

std::vector<BlockFace> sample_faces(size_t n) {
  std::vector<BlockFace> faces(n);
  for (size_t i = 0; i < n; ++i) {
    faces[i].id = i;
    faces[i].vertices = {i / 2, i / 2 + 1, i / 2 + 300};
    for (int k = 0; k < 3; ++k) {
      faces[i].positions[k] = {double(float(i * 1e-4 + k)), double(float(i * 2e-4)), double(float(k * 0.5))};
    }
  }
  return faces;
}

void BM_EncodeBlockFrame(benchmark::State& state) {
  auto faces = sample_faces(size_t(state.range(0)));
  for (auto _ : state) {
    Bytes frame = encode_frame(0, sizeof(BlockFace), faces.data(), faces.size());
    benchmark::DoNotOptimize(frame.data());
    state.counters["ratio"] = double(faces.size() * sizeof(BlockFace)) / double(frame.size());
  }
  state.SetBytesProcessed(int64_t(state.iterations()) * int64_t(faces.size() * sizeof(BlockFace)));
}
BENCHMARK(BM_EncodeBlockFrame)->Arg(1 << 14)->Arg(1 << 17);

void BM_DecodeBlockFrame(benchmark::State& state) {
  auto faces = sample_faces(size_t(state.range(0)));
  Bytes frame = encode_frame(0, sizeof(BlockFace), faces.data(), faces.size());
  Bytes out;
  for (auto _ : state) {
    out.clear();
    decode_frame(frame.data(), frame.size(), sizeof(BlockFace), out, "bench");
    benchmark::DoNotOptimize(out.data());
  }
  state.SetBytesProcessed(int64_t(state.iterations()) * int64_t(faces.size() * sizeof(BlockFace)));
}
BENCHMARK(BM_DecodeBlockFrame)->Arg(1 << 14)->Arg(1 << 17);

// The raw frames' checksum (XXH3) against XXH64 (chunk files), over a 1 MiB frame.
void BM_Checksum(benchmark::State& state, uint64_t (*hash)(const void*, size_t)) {
  std::vector<uint64_t> words(1 << 17);
  for (size_t i = 0; i < words.size(); ++i) words[i] = i * 0x9E3779B97F4A7C15ull;
  for (auto _ : state) benchmark::DoNotOptimize(hash(words.data(), words.size() * 8));
  state.SetBytesProcessed(int64_t(state.iterations()) * int64_t(words.size() * 8));
}
BENCHMARK_CAPTURE(BM_Checksum, Xxh3, io::xxh3);
BENCHMARK_CAPTURE(BM_Checksum, Xxh64, [](const void* data, size_t size) { return io::xxh64(data, size); });

int reencode_main(int argc, char** argv) {
  ReencodeCommand command;
  std::vector<std::string> positional;
  for (int i = 2; i < argc; ++i) {
    std::string arg = argv[i];
    auto value = [&] { return i + 1 < argc ? std::string(argv[++i]) : std::string(); };
    if (arg == "--mem-budget") command.mem_budget = config::parse_size(value());
    else if (arg == "--scratch") command.scratch_dir = value();
    else if (arg == "--trace") command.trace_path = value();
    else if (arg == "--report") command.report_path = value();
    else if (arg == "--threads") command.threads = std::stoi(value());
    else if (arg == "--quiet") command.quiet = true;
    else if (arg == "--scratch-codec") {
      auto codec = parse_scratch_codec(value());
      if (!codec) {
        std::fprintf(stderr, "engine_bench: --scratch-codec must be auto, raw or zstd\n");
        return 2;
      }
      command.scratch_codec = *codec;
    }
    else positional.push_back(arg);
  }
  if (positional.size() != 2) {
    std::fprintf(stderr, "usage: engine_bench reencode IN OUT --mem-budget SIZE [...]\n");
    return 2;
  }
  command.input = positional[0];
  command.output = positional[1];
  try {
    run_reencode_command(command);
  } catch (const Error& e) {
    std::fprintf(stderr, "engine_bench: %s\n", e.what());
    return exit_code(e.kind());
  }
  return 0;
}

// Reads IN in 4 MiB pieces and writes BYTES to a file in SCRATCH_DIR, every piece a
// task on the I/O thread (no compute at all): the disk-bound floor. With SCRATCH_WRITE
// and SCRATCH_READ, it also writes that many bytes to a scratch file between the two
// and reads that many back (the file again from its start when it is shorter): the
// floor for every byte a run moved through its I/O thread, scratch included. Prints
// the seconds of input + output alone ("seconds") and with the scratch bytes
// ("seconds_with_scratch"), each phase timed on its own.
int io_baseline_main(int argc, char** argv) {
  if (argc != 5 && argc != 7) {
    std::fprintf(stderr, "usage: engine_bench io-baseline IN SCRATCH_DIR BYTES [SCRATCH_WRITE SCRATCH_READ]\n");
    return 2;
  }
  std::string in = argv[2];
  std::filesystem::path out = std::filesystem::path(argv[3]) / "io-baseline.bin";
  std::filesystem::path spill = std::filesystem::path(argv[3]) / "io-baseline-scratch.bin";
  uint64_t to_write = std::stoull(argv[4]);
  uint64_t scratch_write = argc == 7 ? std::stoull(argv[5]) : 0;
  uint64_t scratch_read = argc == 7 ? std::stoull(argv[6]) : 0;
  Trace trace;
  Activity activity;
  uint64_t read_bytes = 0, scratch_read_bytes = 0;
  double phase[4] = {0, 0, 0, 0};  // read input, write scratch, read scratch, write output
  {
    IoThread io(&trace, &activity);
    auto buffer = std::make_shared<std::vector<char>>(4 << 20);
    auto timed = [&](int which, const std::function<void()>& body) {
      auto start = Clock::now();
      io.call("phase", body);
      phase[which] = std::chrono::duration<double>(Clock::now() - start).count();
    };
    auto write_file = [&](const std::filesystem::path& path, uint64_t bytes) {
      std::ofstream file(path, std::ios::binary);
      for (uint64_t left = bytes; left > 0;) {
        uint64_t n = std::min<uint64_t>(left, buffer->size());
        file.write(buffer->data(), std::streamsize(n));
        left -= n;
      }
      file.flush();
      if (!file) throw Error(ErrorKind::resource, path.string() + ": write failed");
    };
    timed(0, [&] {
      std::ifstream file(in, std::ios::binary);
      while (file.read(buffer->data(), std::streamsize(buffer->size())) || file.gcount() > 0) {
        read_bytes += uint64_t(file.gcount());
      }
    });
    if (scratch_write > 0) {
      timed(1, [&] { write_file(spill, scratch_write); });
      timed(2, [&] {
        while (scratch_read_bytes < scratch_read) {
          std::ifstream file(spill, std::ios::binary);
          while (scratch_read_bytes < scratch_read &&
                 (file.read(buffer->data(), std::streamsize(std::min<uint64_t>(buffer->size(), scratch_read - scratch_read_bytes))) ||
                  file.gcount() > 0)) {
            scratch_read_bytes += uint64_t(file.gcount());
          }
        }
      });
      std::filesystem::remove(spill);
    }
    timed(3, [&] { write_file(out, to_write); });
  }
  std::filesystem::remove(out);
  std::printf("{\"read_bytes\": %llu, \"written_bytes\": %llu, \"scratch_written_bytes\": %llu, "
              "\"scratch_read_bytes\": %llu, \"seconds\": %.3f, \"seconds_with_scratch\": %.3f}\n",
              static_cast<unsigned long long>(read_bytes), static_cast<unsigned long long>(to_write),
              static_cast<unsigned long long>(scratch_write), static_cast<unsigned long long>(scratch_read_bytes),
              phase[0] + phase[3], phase[0] + phase[1] + phase[2] + phase[3]);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc > 1 && std::strcmp(argv[1], "reencode") == 0) return reencode_main(argc, argv);
  if (argc > 1 && std::strcmp(argv[1], "io-baseline") == 0) return io_baseline_main(argc, argv);
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
