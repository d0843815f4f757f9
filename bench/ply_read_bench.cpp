// Streaming PLY read throughput on one core: binary little-endian (the fast path),
// big-endian, and .zst; the bulk path (raw ranges alone: the I/O thread's share; and
// with their decode); plus the writer (plain and .zst) and the pre-encoded write
// (appending alone: the I/O thread's share; and with the encoding). The input, a ~3M-face grid, is generated into /tmp at start
// with qemflow's own writer (a big-endian copy is converted by hand) and removed at
// exit. Bytes/s counts the uncompressed PLY bytes, so the three rows compare.
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "io/mesh_stream.hpp"
#include "io/ply_bulk.hpp"

namespace {

using namespace qemflow;

struct BenchFiles {
  std::filesystem::path dir;
  std::filesystem::path le, be, zst;
  uint64_t ply_bytes = 0;

  BenchFiles() {
    dir = std::filesystem::temp_directory_path() / ("qemflow-ply-bench-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    le = dir / "grid.ply";
    be = dir / "grid_be.ply";
    zst = dir / "grid.ply.zst";
    write_grid(le, false);
    write_grid(zst, false);
    write_grid(be, true);
    ply_bytes = std::filesystem::file_size(le);
  }
  ~BenchFiles() {
    std::error_code ignored;
    std::filesystem::remove_all(dir, ignored);
  }

  // A side x side vertex grid, written one row at a time so that generating it
  // does not dominate the peak RSS reported for reading.
  static constexpr uint64_t side = 1226;

  static void grid_row(uint64_t y, std::vector<Point>& points, std::vector<Triangle>& triangles) {
    points.clear();
    triangles.clear();
    for (uint64_t x = 0; x < side; ++x) {
      points.push_back({x * 0.01, y * 0.01, 0.001 * static_cast<double>((x * 7 + y * 13) % 17)});
      if (x + 1 == side || y + 1 == side) continue;
      uint64_t a = y * side + x;
      triangles.push_back({a, a + 1, a + side});
      triangles.push_back({a + 1, a + side + 1, a + side});
    }
  }

  template <class T>
  static void put_be(std::string& out, T value) {
    char bytes[sizeof(T)];
    std::memcpy(bytes, &value, sizeof(T));
    for (size_t i = sizeof(T); i-- > 0;) out.push_back(bytes[i]);
  }

  static void write_grid(const std::filesystem::path& path, bool big_endian) {
    const uint64_t vertex_count = side * side, triangle_count = 2 * (side - 1) * (side - 1);
    std::vector<Point> points;
    std::vector<Triangle> triangles;
    if (!big_endian) {
      auto writer = io::open_mesh_writer(path, vertex_count, triangle_count);
      for (uint64_t y = 0; y < side; ++y) {
        grid_row(y, points, triangles);
        writer->write_vertices(points.data(), points.size());
      }
      for (uint64_t y = 0; y < side; ++y) {
        grid_row(y, points, triangles);
        writer->write_triangles(triangles.data(), triangles.size());
      }
      writer->commit();
      return;
    }
    std::ofstream out(path, std::ios::binary);
    std::string bytes = "ply\nformat binary_big_endian 1.0\nelement vertex " + std::to_string(vertex_count) +
                        "\nproperty float x\nproperty float y\nproperty float z\nelement face " +
                        std::to_string(triangle_count) +
                        "\nproperty list uchar int vertex_indices\nend_header\n";
    for (int pass = 0; pass < 2; ++pass) {
      for (uint64_t y = 0; y < side; ++y) {
        grid_row(y, points, triangles);
        if (pass == 0) {
          for (const auto& p : points) {
            for (double c : p) put_be(bytes, static_cast<float>(c));
          }
        } else {
          for (const auto& t : triangles) {
            bytes.push_back(3);
            for (uint64_t v : t) put_be(bytes, static_cast<int32_t>(v));
          }
        }
        out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
        bytes.clear();
      }
    }
  }
};

BenchFiles& files() {
  static BenchFiles instance;
  return instance;
}

void read_all(benchmark::State& state, const std::filesystem::path& path) {
  uint64_t triangles = 0;
  for (auto _ : state) {
    auto reader = io::open_mesh_reader(path);
    io::MeshBatch batch;
    triangles = 0;
    while (reader->next(batch, 1 << 16)) triangles += batch.triangles.size();
    benchmark::DoNotOptimize(triangles);
  }
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * files().ply_bytes));
  state.counters["triangles"] = static_cast<double>(triangles);
}

void BM_ReadPlyLittleEndian(benchmark::State& state) { read_all(state, files().le); }
void BM_ReadPlyBigEndian(benchmark::State& state) { read_all(state, files().be); }
void BM_ReadPlyZstd(benchmark::State& state) { read_all(state, files().zst); }

// The bulk path: the I/O thread's part alone (raw 4 MiB ranges), and that plus the
// compute thread's decode, both on this one core.
void read_bulk(benchmark::State& state, const std::filesystem::path& path, bool decode) {
  uint64_t triangles = 0;
  for (auto _ : state) {
    auto reader = io::open_ply_bulk_reader(path);
    io::RawChunk chunk;
    io::MeshBatch batch;
    triangles = 0;
    while (reader->read(chunk, size_t{4} << 20)) {
      if (!decode) continue;
      reader->decode(chunk, batch);
      triangles += batch.triangles.size();
    }
    benchmark::DoNotOptimize(triangles);
  }
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * files().ply_bytes));
  state.counters["triangles"] = static_cast<double>(triangles);
}

void BM_ReadPlyBulkBytesOnly(benchmark::State& state) { read_bulk(state, files().le, false); }
void BM_ReadPlyBulkLittleEndian(benchmark::State& state) { read_bulk(state, files().le, true); }
void BM_ReadPlyBulkBigEndian(benchmark::State& state) { read_bulk(state, files().be, true); }

// The grid's body encoded apart (what compute threads do), then: the I/O thread's
// part alone (appending the encoded bytes), and encoding plus appending.
void write_encoded_bench(benchmark::State& state, bool encode_in_loop) {
  auto path = files().dir / "encoded.ply";
  const uint64_t side = BenchFiles::side;
  const uint64_t vertex_count = side * side, triangle_count = 2 * (side - 1) * (side - 1);
  std::vector<Point> points, all_points;
  std::vector<Triangle> triangles, all_triangles;
  for (uint64_t y = 0; y < side; ++y) {
    BenchFiles::grid_row(y, points, triangles);
    all_points.insert(all_points.end(), points.begin(), points.end());
    all_triangles.insert(all_triangles.end(), triangles.begin(), triangles.end());
  }
  std::vector<char> vertex_bytes(vertex_count * 12), triangle_bytes(triangle_count * io::ply_triangle_bytes);
  uint64_t max_index = 0;
  auto encode = [&] {
    io::encode_ply_vertices(all_points.data(), vertex_count, false, vertex_bytes.data());
    io::encode_ply_triangles(all_triangles.data(), triangle_count, triangle_bytes.data(), max_index);
  };
  encode();
  for (auto _ : state) {
    if (encode_in_loop) encode();
    auto writer = io::open_mesh_writer(path, vertex_count, triangle_count);
    const uint64_t step = 1 << 18;
    for (uint64_t v = 0; v < vertex_count; v += step) {
      writer->write_encoded_vertices(vertex_bytes.data() + v * 12, std::min(step, vertex_count - v));
    }
    for (uint64_t t = 0; t < triangle_count; t += step) {
      writer->write_encoded_triangles(triangle_bytes.data() + t * io::ply_triangle_bytes,
                                      std::min(step, triangle_count - t), max_index);
    }
    writer->commit();
  }
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * files().ply_bytes));
  std::filesystem::remove(path);
}

void BM_WritePlyEncodedBytesOnly(benchmark::State& state) { write_encoded_bench(state, false); }
void BM_WritePlyEncodeAndWrite(benchmark::State& state) { write_encoded_bench(state, true); }

// Writing the same grid (row generation included; it is a small part).
void write_bench(benchmark::State& state, const std::string& name) {
  auto path = files().dir / name;
  for (auto _ : state) BenchFiles::write_grid(path, false);
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * files().ply_bytes));
  std::filesystem::remove(path);
}

void BM_WritePly(benchmark::State& state) { write_bench(state, "out.ply"); }
void BM_WritePlyZstd(benchmark::State& state) { write_bench(state, "out.ply.zst"); }

BENCHMARK(BM_ReadPlyLittleEndian)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_ReadPlyBigEndian)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_ReadPlyZstd)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_ReadPlyBulkBytesOnly)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_ReadPlyBulkLittleEndian)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_ReadPlyBulkBigEndian)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_WritePlyEncodedBytesOnly)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_WritePlyEncodeAndWrite)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_WritePly)->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK(BM_WritePlyZstd)->Unit(benchmark::kMillisecond)->MinTime(2.0);

}  // namespace

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  files();  // generate before timing starts
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
