// The partition stage on loaded blocks: every face gets an owner in [0, C), every
// cluster owns faces, and the owners (and the planes, to the bit) are the same for 1
// and 2 threads and for different block sizes; C from the budget when not given.
#include <gtest/gtest.h>

#include <algorithm>

#include "engine/blocks.hpp"
#include "engine/scratch.hpp"
#include "io/indexed_mesh.hpp"
#include "nodes/partition_test_surfaces.hpp"
#include "nodes/pipeline/partition_stage.hpp"
#include "nodes/pipeline/patch_count.hpp"
#include "test_support.hpp"

namespace qemflow::nodes::pipeline {
namespace {

using qemflow::testing::TempDir;

std::filesystem::path write_blob(const TempDir& dir) {
  auto surface = partition::shapes::icosphere(5, 0.25, {1.0, 0.7, 1.3});  // 20480 faces
  io::IndexedMesh mesh;
  mesh.vertices = surface.vertices;
  mesh.triangles = surface.triangles;
  io::write_mesh(dir / "blob.ply", mesh);
  return dir / "blob.ply";
}

struct Partitioned {
  Partition partition;
  std::vector<uint32_t> owner;  // by face id
};

Partitioned run(const std::filesystem::path& path, const TempDir& dir, uint32_t clusters, int threads,
        uint64_t faces_per_block, bool out_of_core = false) {
  engine::Governor governor(256ull << 20, 0);
  engine::Job job(governor, {}, {.threads = threads});
  engine::ScratchStore scratch(dir.path(), 0);
  engine::LoadOptions load{.faces_per_block = faces_per_block, .window_vertices = out_of_core ? 1'500u : 0u,
                           .range_faces = out_of_core ? 2'000u : 0u, .force_out_of_core = out_of_core};
  engine::LoadedMesh mesh = engine::load_into_blocks(job, scratch, path, load);
  Partitioned r;
  r.partition = partition_blocks(job, scratch, mesh, {.clusters = clusters, .samples = 5'000});
  r.owner.assign(mesh.face_count, UINT32_MAX);
  engine::for_each_frame(job, scratch, "check", "check", all_block_frames(mesh), mesh.block_record_size, {},
                         [&](const engine::FrameHeader& header, engine::Bytes& records, engine::Lease&) {
                           std::vector<engine::BlockFace> faces(header.count);
                           engine::unpack_block_faces(records.data(), header.count, mesh.block_record_size, faces.data());
                           for (const auto& face : faces) r.owner[face.id] = r.partition.owner_of(face);
                         },
                         0);
  return r;
}

TEST(PipelinePartition, EveryFaceOwnedEveryClusterOwnsFacesSameForThreadsAndBlockSizes) {
  TempDir dir;
  auto path = write_blob(dir);
  for (uint32_t clusters : {2u, 4u, 8u}) {
    SCOPED_TRACE(clusters);
    Partitioned a = run(path, dir, clusters, 1, 1'000);
    EXPECT_EQ(a.partition.clusters, clusters);
    EXPECT_GE(a.partition.samples, 3'000u);
    std::vector<uint64_t> owned(clusters, 0);
    for (uint32_t o : a.owner) {
      ASSERT_LT(o, clusters);
      ++owned[o];
    }
    for (uint32_t c = 0; c < clusters; ++c) EXPECT_GT(owned[c], a.owner.size() / clusters / 4) << "cluster " << c;
    Partitioned b = run(path, dir, clusters, 2, 4'000);
    EXPECT_TRUE(a.owner == b.owner);
    EXPECT_TRUE(a.partition.classifier.planes == b.partition.classifier.planes);
  }
  Partitioned ooc = run(path, dir, 4, 2, 700, true);
  Partitioned in = run(path, dir, 4, 1, 3'000);
  EXPECT_TRUE(ooc.owner == in.owner);
}

TEST(PipelinePartition, OneClusterMeansNoPartition) {
  TempDir dir;
  Partitioned r = run(write_blob(dir), dir, 1, 2, 2'000);
  EXPECT_EQ(r.partition.clusters, 1u);
  EXPECT_EQ(r.partition.samples, 0u);
  EXPECT_TRUE(std::all_of(r.owner.begin(), r.owner.end(), [](uint32_t o) { return o == 0; }));
}

TEST(PatchCount, FollowsTheBudget) {
  // 512 MiB: 0.6 × 512 MiB / (110 B × 1.5 × 2 patches) = 976k faces per patch.
  EXPECT_EQ(faces_per_patch(512ull << 20), 976'128u);
  EXPECT_EQ(patch_count_for_budget(20'000'000, 512ull << 20), 21u);
  EXPECT_EQ(patch_count_for_budget(500'000, 512ull << 20), 1u);    // fits: in core
  EXPECT_EQ(patch_count_for_budget(200'000'000, 4ull << 30), 26u);
  EXPECT_EQ(patch_count_for_budget(uint64_t(1) << 40, 1ull << 20), 256u);  // capped
}

}  // namespace
}  // namespace qemflow::nodes::pipeline
