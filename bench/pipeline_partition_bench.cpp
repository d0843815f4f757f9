// The partition stage of the real out-of-core path, end to end: load into blocks,
// partition_stage (samples, graph, FCM, planes), then every face classified from the
// blocks. Prints the times and the peak RSS; optionally dumps the per-face owners for
// bench/partition_picture.py (the QPRT format partition_bench writes).
//
//   pipeline_partition_bench IN.ply[.zst] [--mem-budget=512M] [--clusters=N] [--threads=N]
//                            [--dump=OUT.bin] [--force-out-of-core]
#include <chrono>
#include <cstdio>
#include <fstream>
#include <string>

#include "config/size.hpp"
#include "engine/blocks.hpp"
#include "engine/process_memory.hpp"
#include "engine/scratch.hpp"
#include "io/indexed_mesh.hpp"
#include "nodes/pipeline/partition_stage.hpp"

using namespace qemflow;

namespace {

std::string flag(int argc, char** argv, const std::string& name) {
  for (int i = 2; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--" + name) return "1";
    if (a.rfind("--" + name + "=", 0) == 0) return a.substr(name.size() + 3);
  }
  return "";
}

double since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s IN [--mem-budget=SIZE] [--clusters=N] [--threads=N] [--dump=OUT.bin] [--force-out-of-core]\n", argv[0]);
    return 2;
  }
  const std::filesystem::path input = argv[1];
  const std::string budget_text = flag(argc, argv, "mem-budget"), clusters_text = flag(argc, argv, "clusters");
  const std::string threads_text = flag(argc, argv, "threads"), dump = flag(argc, argv, "dump");
  const uint64_t budget = config::parse_size(budget_text.empty() ? "512M" : budget_text);
  engine::tune_allocator();
  engine::Governor governor(budget, engine::measure_baseline());
  engine::Job job(governor, {}, {.threads = threads_text.empty() ? 0 : std::stoi(threads_text)});
  engine::ScratchStore scratch(std::filesystem::temp_directory_path(), 0);
  engine::LoadOptions load;
  load.force_out_of_core = !flag(argc, argv, "force-out-of-core").empty();

  auto t0 = std::chrono::steady_clock::now();
  engine::LoadedMesh mesh = engine::load_into_blocks(job, scratch, input, load);
  const double load_s = since(t0);
  // The partition stage does not need resident positions.
  mesh.vertices.resident = {};
  mesh.resident_lease.release();

  auto t1 = std::chrono::steady_clock::now();
  nodes::pipeline::PartitionOptions options;
  if (!clusters_text.empty()) options.clusters = uint32_t(std::stoul(clusters_text));
  const nodes::pipeline::Partition partition = nodes::pipeline::partition_blocks(job, scratch, mesh, options);
  const double partition_s = since(t1);

  auto t2 = std::chrono::steady_clock::now();
  std::vector<uint64_t> owned(partition.clusters, 0);
  std::vector<uint32_t> owner;
  if (!dump.empty()) owner.assign(mesh.face_count, UINT32_MAX);
  engine::for_each_frame(job, scratch, "classify", "classify", nodes::pipeline::all_block_frames(mesh),
                         mesh.block_record_size, {},
                         [&](const engine::FrameHeader& header, engine::Bytes& records, engine::Lease&) {
                           std::vector<engine::BlockFace> faces(header.count);
                           engine::unpack_block_faces(records.data(), header.count, mesh.block_record_size, faces.data());
                           for (const auto& face : faces) {
                             uint32_t o = partition.owner_of(face);
                             ++owned[o];
                             if (!owner.empty()) owner[face.id] = o;
                           }
                         },
                         0);
  const double classify_s = since(t2);
  uint64_t smallest = UINT64_MAX, largest = 0;
  for (uint64_t n : owned) smallest = std::min(smallest, n), largest = std::max(largest, n);
  std::printf("%s: %llu faces (%llu dropped, %llu welded vertices), %s dereference, budget %s\n", input.c_str(),
              (unsigned long long)mesh.face_count, (unsigned long long)mesh.dropped_faces,
              (unsigned long long)mesh.welded_vertices, mesh.out_of_core ? "out-of-core" : "resident",
              config::format_size(budget).c_str());
  std::printf("load %.2f s | partition %.2f s (%u clusters, %llu samples, radius %g, %u FCM iterations) | "
              "classify %.2f s | owned faces per patch %llu..%llu | peak RSS %s\n",
              load_s, partition_s, partition.clusters, (unsigned long long)partition.samples, partition.radius,
              partition.fcm_iterations, classify_s, (unsigned long long)smallest, (unsigned long long)largest,
              config::format_size(engine::peak_resident_bytes()).c_str());

  std::printf("stages:");
  for (const engine::StageStats* stage : job.stages()) std::printf(" %s %.2f s", stage->name.c_str(), stage->seconds);
  std::printf("\n");

  if (!dump.empty()) {
    // The picture needs the mesh itself: small meshes only (read in memory).
    io::IndexedMesh indexed = io::read_mesh(input);
    std::ofstream file(dump, std::ios::binary);
    auto put = [&](const void* data, size_t bytes) { file.write(static_cast<const char*>(data), std::streamsize(bytes)); };
    const uint32_t counts[2] = {uint32_t(indexed.vertices.size()), uint32_t(indexed.triangles.size())};
    put("QPRT", 4);
    put(counts, sizeof counts);
    for (const auto& v : indexed.vertices) {
      const float xyz[3] = {float(v[0]), float(v[1]), float(v[2])};
      put(xyz, sizeof xyz);
    }
    for (const auto& t : indexed.triangles) {
      const uint32_t abc[3] = {uint32_t(t[0]), uint32_t(t[1]), uint32_t(t[2])};
      put(abc, sizeof abc);
    }
    // Dropped faces (no owner) are drawn with patch 0's colour; they have no area.
    for (uint32_t& o : owner) o = o == UINT32_MAX ? 0 : o;
    put(owner.data(), owner.size() * sizeof(uint32_t));
    if (!file) return 1;
  }
  return 0;
}
