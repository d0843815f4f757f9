#include "io/mesh_writers.hpp"

#include <algorithm>
#include <bit>
#include <charconv>
#include <cstring>
#include <string>

#include "io/byte_sink.hpp"
#include "io/ply_bulk.hpp"
#include "util/error.hpp"

namespace qemflow::io {

namespace {

static_assert(std::endian::native == std::endian::little,
              "the PLY writer copies host values as little-endian");

// Shared bookkeeping: declared counts, what has been written, contract checks.
class CountingWriter : public MeshWriter {
 public:
  CountingWriter(const std::filesystem::path& path, uint64_t vertex_count, uint64_t triangle_count,
                 int zstd_level)
      : sink_(path, zstd_level), vertex_count_(vertex_count), triangle_count_(triangle_count) {}

  uint64_t bytes_written() const override { return sink_.bytes_written(); }

  void commit() override {
    if (vertices_written_ != vertex_count_ || triangles_written_ != triangle_count_) {
      misuse("commit after " + std::to_string(vertices_written_) + " of " +
             std::to_string(vertex_count_) + " vertices and " + std::to_string(triangles_written_) +
             " of " + std::to_string(triangle_count_) + " triangles");
    }
    sink_.commit();
  }

 protected:
  [[noreturn]] void misuse(const std::string& problem) const {
    throw Error(ErrorKind::internal, sink_.name() + ": mesh writer misuse: " + problem);
  }

  void admit_vertices(size_t count) {
    if (count > vertex_count_ - vertices_written_) {
      misuse("more than the declared " + std::to_string(vertex_count_) + " vertices");
    }
  }

  // Index checks against what a reader of the file will accept.
  void admit_triangles(const Triangle* triangles, size_t count, uint64_t index_limit) {
    if (count > triangle_count_ - triangles_written_) {
      misuse("more than the declared " + std::to_string(triangle_count_) + " triangles");
    }
    for (size_t i = 0; i < count; ++i) {
      const Triangle& t = triangles[i];
      if (t[0] >= index_limit || t[1] >= index_limit || t[2] >= index_limit) {
        misuse("triangle " + std::to_string(triangles_written_ + i) + " has vertex index " +
               std::to_string(std::max({t[0], t[1], t[2]})) + " but only " +
               std::to_string(index_limit) + " vertices are available");
      }
    }
  }

  ByteSink sink_;
  uint64_t vertex_count_;
  uint64_t triangle_count_;
  uint64_t vertices_written_ = 0;
  uint64_t triangles_written_ = 0;
};

class PlyWriter final : public CountingWriter {
 public:
  PlyWriter(const std::filesystem::path& path, uint64_t vertex_count, uint64_t triangle_count,
            const WriteOptions& options, int zstd_level)
      : CountingWriter(path, vertex_count, triangle_count, zstd_level),
        double_precision_(options.double_precision) {
    if (vertex_count > (uint64_t{1} << 32)) {
      throw Error(ErrorKind::usage, sink_.name() + ": PLY output cannot index more than 2^32 vertices");
    }
    const char* scalar = double_precision_ ? "double" : "float";
    const char* index = vertex_count > (uint64_t{1} << 31) ? "uint" : "int";
    std::string header = "ply\nformat binary_little_endian 1.0\ncomment written by qemflow\n";
    header += "element vertex " + std::to_string(vertex_count) + "\n";
    for (const char* axis : {"x", "y", "z"}) header += std::string("property ") + scalar + " " + axis + "\n";
    header += "element face " + std::to_string(triangle_count) + "\n";
    header += std::string("property list uchar ") + index + " vertex_indices\nend_header\n";
    sink_.write(header);
  }

  void write_vertices(const Point* points, size_t count) override {
    admit_vertices(count);
    const size_t record = double_precision_ ? 24 : 12;
    const size_t per_flush = sink_.buffer_capacity() / record;
    for (size_t done = 0; done < count;) {
      size_t n = std::min(count - done, per_flush);
      char* out = sink_.reserve(n * record);
      encode_ply_vertices(points + done, n, double_precision_, out);
      sink_.advance(n * record);
      done += n;
    }
    vertices_written_ += count;
  }

  std::optional<bool> ply_vertex_double() const override { return double_precision_; }

  void write_encoded_vertices(const char* bytes, size_t count) override {
    admit_vertices(count);
    sink_.write(bytes, count * (double_precision_ ? 24 : 12));
    vertices_written_ += count;
  }

  void write_encoded_triangles(const char* bytes, size_t count, uint64_t max_index) override {
    if (vertices_written_ != vertex_count_) misuse("PLY triangles written before all vertices");
    if (count > triangle_count_ - triangles_written_) {
      misuse("more than the declared " + std::to_string(triangle_count_) + " triangles");
    }
    if (count > 0 && max_index >= vertex_count_) {
      misuse("triangles " + std::to_string(triangles_written_) + ".." + std::to_string(triangles_written_ + count - 1) +
             " have vertex index " + std::to_string(max_index) + " but only " + std::to_string(vertex_count_) +
             " vertices are available");
    }
    sink_.write(bytes, count * 13);
    triangles_written_ += count;
  }

  void write_triangles(const Triangle* triangles, size_t count) override {
    if (vertices_written_ != vertex_count_) misuse("PLY triangles written before all vertices");
    admit_triangles(triangles, count, vertex_count_);
    const size_t per_flush = sink_.buffer_capacity() / 13;
    for (size_t done = 0; done < count;) {
      size_t n = std::min(count - done, per_flush);
      char* out = sink_.reserve(n * 13);
      uint64_t largest = 0;  // checked above
      encode_ply_triangles(triangles + done, n, out, largest);
      sink_.advance(n * 13);
      done += n;
    }
    triangles_written_ += count;
  }

 private:
  bool double_precision_;
};

class ObjWriter final : public CountingWriter {
 public:
  ObjWriter(const std::filesystem::path& path, uint64_t vertex_count, uint64_t triangle_count,
            const WriteOptions& options, int zstd_level)
      : CountingWriter(path, vertex_count, triangle_count, zstd_level),
        double_precision_(options.double_precision) {
    sink_.write("# written by qemflow\n");
  }

  void write_vertices(const Point* points, size_t count) override {
    admit_vertices(count);
    for (size_t i = 0; i < count; ++i) {
      char* start = sink_.reserve(128);
      char* out = start;
      *out++ = 'v';
      for (double value : points[i]) {
        *out++ = ' ';
        out = double_precision_ ? std::to_chars(out, start + 128, value).ptr
                                : std::to_chars(out, start + 128, static_cast<float>(value)).ptr;
      }
      *out++ = '\n';
      sink_.advance(out - start);
    }
    vertices_written_ += count;
  }

  void write_triangles(const Triangle* triangles, size_t count) override {
    // OBJ may interleave, but a face may only name vertices already written.
    admit_triangles(triangles, count, vertices_written_);
    for (size_t i = 0; i < count; ++i) {
      char* start = sink_.reserve(96);
      char* out = start;
      *out++ = 'f';
      for (uint64_t index : triangles[i]) {
        *out++ = ' ';
        out = std::to_chars(out, start + 96, index + 1).ptr;
      }
      *out++ = '\n';
      sink_.advance(out - start);
    }
    triangles_written_ += count;
  }

 private:
  bool double_precision_;
};

}  // namespace

std::unique_ptr<MeshWriter> open_ply_writer(const std::filesystem::path& path, uint64_t vertex_count,
                                            uint64_t triangle_count, const WriteOptions& options,
                                            int zstd_level) {
  return std::make_unique<PlyWriter>(path, vertex_count, triangle_count, options, zstd_level);
}

std::unique_ptr<MeshWriter> open_obj_writer(const std::filesystem::path& path, uint64_t vertex_count,
                                            uint64_t triangle_count, const WriteOptions& options,
                                            int zstd_level) {
  return std::make_unique<ObjWriter>(path, vertex_count, triangle_count, options, zstd_level);
}

}  // namespace qemflow::io
