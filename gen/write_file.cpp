// generate_to_file lives apart from the core so that programs which only generate in
// memory do not pull in the file writers.
#include <chrono>

#include "gen/generator.hpp"
#include "io/mesh_stream.hpp"

namespace qemflow::gen {
namespace {

class WriterSink final : public MeshSink {
 public:
  explicit WriterSink(std::filesystem::path path) : path_(std::move(path)) {}
  void begin(uint64_t vertex_count, uint64_t triangle_count) override {
    writer_ = io::open_mesh_writer(path_, vertex_count, triangle_count);
  }
  void vertices(const Point* points, size_t count) override { writer_->write_vertices(points, count); }
  void triangles(const Triangle* triangles, size_t count) override {
    writer_->write_triangles(triangles, count);
  }
  io::MeshWriter& writer() { return *writer_; }

 private:
  std::filesystem::path path_;
  std::unique_ptr<io::MeshWriter> writer_;
};

}  // namespace

GenStats generate_to_file(const GenOptions& options, const std::filesystem::path& path) {
  const auto start = std::chrono::steady_clock::now();
  const GenPlan counts = plan(options);
  WriterSink sink(path);
  generate(options, sink);
  sink.writer().commit();
  GenStats stats;
  stats.vertex_count = counts.vertex_count;
  stats.face_count = counts.face_count;
  stats.bytes_written = sink.writer().bytes_written();
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return stats;
}

}  // namespace qemflow::gen
