// The re-encode pipeline end to end: same vertices and triangles out as in, in both
// dereference modes, with chunk boundaries hit constantly; blocks hold the right
// positions; cancel and write errors leave nothing behind; the trace and the report
// hold what they promise.
#include "engine/reencode.hpp"

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>

#include <algorithm>
#include <fstream>
#include <numeric>
#include <random>
#include <set>
#include <thread>
#include <nlohmann/json.hpp>

#include "engine/blocks.hpp"
#include "engine/scratch.hpp"
#include "engine/trace.hpp"
#include "gen/generator.hpp"
#include "io/indexed_mesh.hpp"
#include "reencode_refusal.hpp"
#include "test_support.hpp"
#include "util/error.hpp"

namespace qemflow::engine {
namespace {

using qemflow::testing::file_bytes;
using qemflow::testing::TempDir;

std::filesystem::path make_mesh(const TempDir& dir, uint64_t faces, const std::string& name = "in.ply") {
  gen::GenOptions options;
  options.faces = faces;
  options.shape = "blob";
  auto path = dir / name;
  gen::generate_to_file(options, path);
  return path;
}

// Triangles as sorted (canonical) lists of vertex index triples.
std::vector<Triangle> sorted(std::vector<Triangle> triangles) {
  std::sort(triangles.begin(), triangles.end());
  return triangles;
}

bool directory_empty(const std::filesystem::path& dir) {
  return std::filesystem::is_empty(dir);
}

void expect_same_mesh(const std::filesystem::path& in, const std::filesystem::path& out) {
  io::IndexedMesh a = io::read_mesh(in), b = io::read_mesh(out);
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  EXPECT_TRUE(a.vertices == b.vertices);  // same order, same bits
  ASSERT_EQ(a.triangles.size(), b.triangles.size());
  EXPECT_TRUE(sorted(a.triangles) == sorted(b.triangles));
}

// One run of a series that must all write the same bytes: the first run's output is the
// reference (and the input's mesh); every later one must equal it byte for byte.
void expect_bytes_of_first_run(std::string& reference, const std::filesystem::path& in,
                               const std::filesystem::path& out, const char* first_run) {
  const std::string bytes = file_bytes(out);
  if (reference.empty()) {
    reference = bytes;
    expect_same_mesh(in, out);
  }
  EXPECT_TRUE(bytes == reference) << "output differs from the " << first_run << "'s";
}

TEST(Reencode, ResidentVerticesGiveTheSameMesh) {
  TempDir dir;
  auto in = make_mesh(dir, 20'000);
  Governor governor(256ull << 20, 0);
  ReencodeOptions options{.input = in, .output = dir / "out.ply", .scratch_dir = dir.path()};
  options.load.faces_per_block = 1'000;  // ~20 blocks
  auto result = run_reencode(governor, options, {});
  EXPECT_FALSE(result.report["out_of_core_dereference"].get<bool>());
  // Triangle-only blocks that fit the budget stay in memory: no scratch at all.
  EXPECT_TRUE(result.report["blocks_in_memory"].get<bool>());
  EXPECT_EQ(result.report["scratch_bytes_written"].get<uint64_t>(), 0u);
  EXPECT_EQ(result.faces, 20'000u);
  expect_same_mesh(in, dir / "out.ply");
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir.path()), {}), 2);  // in, out: scratch gone
}

TEST(Reencode, OutOfCoreDereferenceWithTinyWindowsGivesTheSameMesh) {
  TempDir dir;
  auto in = make_mesh(dir, 30'000, "in.ply.zst");
  uint64_t written[2] = {0, 0};
  for (ScratchCodec codec : {ScratchCodec::raw, ScratchCodec::zstd}) {
    SCOPED_TRACE(codec == ScratchCodec::raw ? "raw" : "zstd");
    Governor governor(64ull << 20, 0);
    ReencodeOptions options{.input = in, .output = dir / "out.obj", .scratch_dir = dir.path()};
    options.load = {.faces_per_block = 2'000, .window_vertices = 997, .range_faces = 1'231, .force_out_of_core = true};
    options.scratch_codec = codec;
    auto result = run_reencode(governor, options, {.progress = {}, .cancel = {}});
    EXPECT_TRUE(result.report["out_of_core_dereference"].get<bool>());
    EXPECT_GT(result.report["local_faces"].get<uint64_t>(), 0u);     // both dereference paths ran
    EXPECT_GT(result.report["spanning_faces"].get<uint64_t>(), 0u);
    EXPECT_EQ(result.report["scratch_codec"], codec == ScratchCodec::raw ? "raw" : "zstd");
    EXPECT_FALSE(result.report["blocks_in_memory"].get<bool>());
    EXPECT_EQ(result.report["block_record_bytes"], id_triangle32_record_size);  // out of core: with face ids
    // One walk over the vertex chunks: every frame written to scratch is read back once.
    EXPECT_EQ(result.report["scratch_bytes_read"], result.report["scratch_bytes_written"]);
    written[codec == ScratchCodec::raw ? 0 : 1] = result.report["scratch_bytes_written"].get<uint64_t>();
    expect_same_mesh(in, dir / "out.obj");
    std::filesystem::remove(dir / "out.obj");
  }
  // Raw frames really are raw (1.97x here since out-of-core records carry face ids).
  EXPECT_GT(2 * written[0], 3 * written[1]);
  EXPECT_FALSE(default_frame_codec().raw);  // the run's default codec ended with it
}

// Vertex frames hold floats only for batches whose coordinates all are floats: a mesh
// whose second half is not float-exact goes out of core through both kinds (and
// windows that hold both), and comes back bit for bit (written as doubles).
TEST(Reencode, OutOfCoreWithFloatAndDoubleVertexFramesGivesTheSameMesh) {
  TempDir dir;
  io::IndexedMesh mesh = io::read_mesh(make_mesh(dir, 20'000));
  for (size_t i = mesh.vertices.size() / 2; i < mesh.vertices.size(); ++i) mesh.vertices[i][1] += 1e-9;
  io::WriteOptions write_options;
  write_options.double_precision = true;
  io::write_mesh(dir / "mixed.ply", mesh, write_options);
  Governor governor(64ull << 20, 0);
  ReencodeOptions options{.input = dir / "mixed.ply", .output = dir / "out.ply", .scratch_dir = dir.path()};
  options.load = {.faces_per_block = 2'000, .window_vertices = 997, .range_faces = 1'231, .force_out_of_core = true};
  options.scratch_codec = ScratchCodec::raw;
  auto result = run_reencode(governor, options, {});
  EXPECT_TRUE(result.report["out_of_core_dereference"].get<bool>());
  expect_same_mesh(dir / "mixed.ply", dir / "out.ply");
}

// DESIGN.md guarantee 1 holds for --ratio 1 too: the same bytes out on every run, with
// any thread count, whether the blocks stay resident or go through scratch. Faces used
// to be filed into blocks in whatever order the compute threads finished their
// batches, so three runs of 2M faces gave three different files.
TEST(Reencode, SameBytesOnEveryRunWithAnyThreadCountResidentOrOutOfCore) {
  TempDir dir;
  auto in = make_mesh(dir, 400'000);
  std::string reference;
  int run = 0;
  for (bool out_of_core : {false, true}) {
    for (int threads : {2, 2, 2, 1}) {
      SCOPED_TRACE("run " + std::to_string(run));
      Governor governor(out_of_core ? 64ull << 20 : 512ull << 20, 0);
      const auto out = dir / ("out" + std::to_string(run++) + ".ply");
      ReencodeOptions options{.input = in, .output = out, .scratch_dir = dir.path(), .threads = threads};
      options.load.faces_per_block = 20'000;
      options.load.force_out_of_core = out_of_core;
      options.scratch_codec = ScratchCodec::raw;
      auto result = run_reencode(governor, options, {});
      EXPECT_EQ(result.report["out_of_core_dereference"].get<bool>(), out_of_core);
      expect_bytes_of_first_run(reference, in, out, "first run");
    }
  }
}

// A generated mesh with every 10th vertex of its first half swapped with one far away:
// many faces span vertex windows out of core.
std::filesystem::path make_spanning_mesh(const TempDir& dir, uint64_t faces) {
  io::IndexedMesh mesh = io::read_mesh(make_mesh(dir, faces, "unshuffled.ply"));
  const size_t n = mesh.vertices.size();
  std::vector<uint64_t> moved(n);
  std::iota(moved.begin(), moved.end(), uint64_t{0});
  for (size_t i = 0; i < n / 2; i += 10) std::swap(moved[i], moved[n - 1 - i]);
  std::vector<Point> vertices(n);
  for (size_t i = 0; i < n; ++i) vertices[moved[i]] = mesh.vertices[i];
  mesh.vertices = std::move(vertices);
  for (auto& t : mesh.triangles)
    for (auto& v : t) v = moved[v];
  io::write_mesh(dir / "spanning.ply", mesh);
  std::filesystem::remove(dir / "unshuffled.ply");
  return dir / "spanning.ply";
}

// Guarantee 1 again, where the bytes depended on memory: out of core, the loader's
// vertex window (and so which faces are local to a window and which span two) comes
// from the memory it got, which the CLI's measured baseline shifts from run to run by
// a few hundred KiB. A block held its local faces first and its spanning ones after,
// so a mesh with faces across windows came out in a different face order whenever
// the baseline moved: `qemflow simplify m.ply out.ply --ratio 1 --mem-budget 48M` on
// 1M faces with 10% of the vertices shuffled gave a different file on each run. The
// resident load files every face in input order, so it differed from both. Failed on
// bc90b0c (review5); out-of-core blocks now carry face ids and are written in
// face-id order, as the resident ones are filed.
TEST(Reencode, SameBytesWhateverBaselineTheGovernorMeasured) {
  TempDir dir;
  make_spanning_mesh(dir, 200'000);
  std::string reference;
  // Out of core with two baselines, then resident (which files faces in input order).
  for (uint64_t baseline : {20ull << 20, 22ull << 20, 0ull}) {
    SCOPED_TRACE("baseline " + std::to_string(baseline));
    const bool out_of_core = baseline != 0;
    Governor governor(out_of_core ? 44ull << 20 : 512ull << 20, baseline);
    const auto out = dir / ("out" + std::to_string(baseline) + ".ply");
    ReencodeOptions options{.input = dir / "spanning.ply", .output = out, .scratch_dir = dir.path()};
    options.load.force_out_of_core = out_of_core;  // window and ranges from the memory the loader got
    auto result = run_reencode(governor, options, {});
    EXPECT_EQ(result.report["out_of_core_dereference"].get<bool>(), out_of_core);
    expect_bytes_of_first_run(reference, dir / "spanning.ply", out, "first run");
  }
}

// The same bytes, resident or out of core, on a mesh with spanning faces, whatever
// the window, the face ranges, the budget, the thread count, the scratch codec, and
// whether blocks go in face-id order whole or in groups of id ranges (a block too
// large for one buffer); PLY output (encoded here) and OBJ (by its writer).
TEST(Reencode, ResidentAndOutOfCoreGiveTheSameBytesOnSpanningFaces) {
  TempDir dir;
  const auto in = make_spanning_mesh(dir, 60'000);
  struct Run {
    uint64_t budget;
    int threads;
    uint64_t window, range, group;  // 0: resident (window) or from the memory
    ScratchCodec codec;
  };
  const Run runs[] = {{512ull << 20, 2, 0, 0, 0, ScratchCodec::automatic},
                      {64ull << 20, 1, 997, 1'231, 0, ScratchCodec::raw},
                      {96ull << 20, 2, 5'003, 20'011, 0, ScratchCodec::zstd},
                      {64ull << 20, 2, 2'000, 3'000, 1'500, ScratchCodec::raw}};
  for (const char* extension : {".ply", ".obj"}) {
    std::string reference;
    for (size_t i = 0; i < std::size(runs); ++i) {
      const Run& run = runs[i];
      SCOPED_TRACE(std::string(extension) + " run " + std::to_string(i));
      Governor governor(run.budget, 0);
      const auto out = dir / ("out" + std::to_string(i) + extension);
      ReencodeOptions options{.input = in, .output = out, .scratch_dir = dir.path(), .threads = run.threads};
      options.load = {.faces_per_block = 6'000, .window_vertices = run.window, .range_faces = run.range,
                      .force_out_of_core = run.window != 0};
      options.group_faces = run.group;
      options.scratch_codec = run.codec;
      auto result = run_reencode(governor, options, {});
      ASSERT_EQ(result.report["out_of_core_dereference"].get<bool>(), run.window != 0);
      if (run.window != 0) {
        EXPECT_GT(result.report["spanning_faces"].get<uint64_t>(), 0u);
        EXPECT_GT(result.report["block_groups_merged"].get<uint64_t>(), 0u);  // chunk order is not id order
        EXPECT_EQ(result.report["block_record_bytes"], id_triangle32_record_size);
      }
      if (run.group != 0) {  // groups of at most 1500 faces
        EXPECT_GE(result.report["block_groups"].get<uint64_t>(), 60'000u / 1'500u);
      }
      expect_bytes_of_first_run(reference, in, out, "resident run");
      std::filesystem::remove(out);
    }
  }
}

// Faces in random input order with tiny windows: a block is many short runs in id
// order, so it is sorted rather than merged (moved together where its raw frames were
// read, or where its zstd frames were decoded, or in place when it goes in groups);
// the bytes are still the resident run's. (The sort made a copy of the whole block
// beside its frames and decoded records, which no lease counted: review12 M1.)
TEST(Reencode, ResidentAndOutOfCoreGiveTheSameBytesWithFacesInRandomOrder) {
  TempDir dir;
  io::IndexedMesh mesh = io::read_mesh(make_mesh(dir, 20'000, "ordered.ply"));
  std::mt19937_64 random(7);
  std::shuffle(mesh.triangles.begin(), mesh.triangles.end(), random);
  io::write_mesh(dir / "shuffled.ply", mesh);
  std::string reference;
  const std::pair<uint64_t, ScratchCodec> runs[] = {{0, ScratchCodec::automatic},
                                                    {0, ScratchCodec::raw},
                                                    {0, ScratchCodec::zstd},
                                                    {900, ScratchCodec::automatic}};
  for (const auto& [group, codec] : runs) {
    const bool out_of_core = !reference.empty();
    SCOPED_TRACE(out_of_core ? "out of core, groups of " + std::to_string(group) + ", codec " +
                                   std::to_string(int(codec))
                             : "resident");
    Governor governor(64ull << 20, 0);
    const auto out = dir / "out.ply";
    ReencodeOptions options{.input = dir / "shuffled.ply", .output = out, .scratch_dir = dir.path()};
    options.load = {.faces_per_block = 20'000, .window_vertices = out_of_core ? 37u : 0u,
                    .range_faces = out_of_core ? 3'001u : 0u, .force_out_of_core = out_of_core};
    options.group_faces = group;
    options.scratch_codec = codec;
    auto result = run_reencode(governor, options, {});
    if (out_of_core) {
      EXPECT_GT(result.report["block_groups_sorted"].get<uint64_t>(), 0u);
      if (codec != ScratchCodec::automatic) {
        EXPECT_EQ(result.report["scratch_codec"].get<std::string>(), codec == ScratchCodec::raw ? "raw" : "zstd");
      }
    }
    expect_bytes_of_first_run(reference, dir / "shuffled.ply", out, "resident run");
  }
}

TEST(Reencode, ObjInputWithUnknownCountsGoesOutOfCore) {
  TempDir dir;
  auto in = make_mesh(dir, 20'000, "in.obj");
  Governor governor(64ull << 20, 0);
  ReencodeOptions options{.input = in, .output = dir / "out.ply", .scratch_dir = dir.path()};
  options.load.window_vertices = 1'500;
  auto result = run_reencode(governor, options, {});
  EXPECT_TRUE(result.report["out_of_core_dereference"].get<bool>());  // no vertex count up front
  expect_same_mesh(in, dir / "out.ply");
}

TEST(Reencode, TwoJobsShareOneGovernor) {
  TempDir dir;
  auto in = make_mesh(dir, 200'000);
  Governor governor(48ull << 20, 0);  // less than two jobs would take alone
  std::vector<std::thread> jobs;
  std::vector<std::string> errors(2);
  for (int j = 0; j < 2; ++j) {
    jobs.emplace_back([&, j] {
      ReencodeOptions options{.input = in, .output = dir / ("out" + std::to_string(j) + ".ply"),
                              .scratch_dir = dir.path(), .threads = 1};
      options.job_name = "job" + std::to_string(j);
      options.load.force_out_of_core = true;
      try {
        run_reencode(governor, options, {});
      } catch (const std::exception& e) {
        errors[j] = e.what();
      }
    });
  }
  for (auto& t : jobs) t.join();
  EXPECT_EQ(errors, (std::vector<std::string>{"", ""}));
  EXPECT_LE(governor.peak_in_use(), governor.capacity());
  EXPECT_EQ(governor.in_use(), 0u);
  std::set<std::string> prefixes;
  for (const auto& owner : governor.owners()) prefixes.insert(owner.owner.substr(0, 5));
  EXPECT_EQ(prefixes, (std::set<std::string>{"job0/", "job1/"}));
  expect_same_mesh(in, dir / "out0.ply");
  expect_same_mesh(in, dir / "out1.ply");
}

// Resident blocks bound for a PLY hold its face records as they will be written (no
// decode to ids and encode back); for an OBJ, u32 ids. The same mesh either way.
TEST(Reencode, ResidentBlocksHoldThePlyOutputsFaceRecords) {
  TempDir dir;
  const auto in = make_mesh(dir, 20'000);
  for (const char* name : {"out.ply", "out.obj", "out.ply.zst"}) {
    SCOPED_TRACE(name);
    Governor governor(256ull << 20, 0);
    ReencodeOptions options{.input = in, .output = dir / name, .scratch_dir = dir.path()};
    options.load = {.faces_per_block = 2'000};
    auto result = run_reencode(governor, options, {});
    EXPECT_TRUE(result.report["blocks_in_memory"].get<bool>());
    EXPECT_EQ(result.report["block_record_bytes"],
              std::string(name) == "out.obj" ? triangle32_record_size : ply_triangle_record_size);
    expect_same_mesh(in, dir / name);
  }
}

TEST(Reencode, DoubleCoordinatesKeepEveryBitInBothModes) {
  TempDir dir;
  gen::GenOptions gen_options;
  gen_options.faces = 5'000;
  io::IndexedMesh mesh = gen::generate_in_memory(gen_options);
  for (Point& p : mesh.vertices) p[0] += 1e-9;  // no longer floats
  io::WriteOptions doubles;
  doubles.double_precision = true;
  io::write_mesh(dir / "in.ply", mesh, doubles);
  for (bool out_of_core : {false, true}) {
    Governor governor(64ull << 20, 0);
    ReencodeOptions options{.input = dir / "in.ply", .output = dir / "out.ply", .scratch_dir = dir.path()};
    options.load = {.faces_per_block = 500, .window_vertices = out_of_core ? 301u : 0u,
                    .range_faces = out_of_core ? 401u : 0u, .force_out_of_core = out_of_core};
    auto result = run_reencode(governor, options, {});
    // Re-encode: triangles only (out of core with their face ids; resident, to a PLY,
    // as its face records).
    EXPECT_EQ(result.report["block_record_bytes"], out_of_core ? id_triangle32_record_size : ply_triangle_record_size);
    expect_same_mesh(dir / "in.ply", dir / "out.ply");
  }
}

TEST(Reencode, BlocksHoldEveryFaceOnceWithItsPositionsInItsCell) {
  TempDir dir;
  auto in = make_mesh(dir, 10'000);
  io::IndexedMesh mesh = io::read_mesh(in);
  for (bool out_of_core : {false, true}) {
    Governor governor(64ull << 20, 0);
    Job job(governor, {}, {.threads = 2});
    ScratchStore scratch(dir.path(), 0);
    LoadOptions load{.faces_per_block = 500, .window_vertices = out_of_core ? 613u : 0u,
                     .range_faces = out_of_core ? 777u : 0u, .force_out_of_core = out_of_core};
    LoadedMesh loaded = load_into_blocks(job, scratch, in, load);
    EXPECT_EQ(loaded.face_count, mesh.triangles.size());
    EXPECT_EQ(loaded.block_record_size, sizeof(PackedBlockFace));  // the generator writes floats
    if (out_of_core) {
      EXPECT_GT(loaded.local_faces, 0u);
      EXPECT_GT(loaded.corner_faces, 0u);
    }
    EXPECT_GT(loaded.grid.count(), 8u);
    std::vector<int> seen(mesh.triangles.size(), 0);
    for (uint32_t cell = 0; cell < loaded.grid.count(); ++cell) {
      uint64_t faces_in_cell = 0;
      for_each_frame(job, scratch, "check", "check", loaded.blocks[cell], loaded.block_record_size,
                     {}, [&](const FrameHeader& header, Bytes& records, Lease&) {
                       std::vector<BlockFace> faces(header.count);
                       unpack_block_faces(records.data(), header.count, loaded.block_record_size, faces.data());
                       for (const BlockFace& face : faces) {
                         ASSERT_LT(face.id, mesh.triangles.size());
                         ++seen[face.id];
                         EXPECT_EQ(face.vertices, mesh.triangles[face.id]);
                         for (int k = 0; k < 3; ++k) EXPECT_EQ(face.positions[k], mesh.vertices[face.vertices[k]]);
                         Point c{};
                         for (int a = 0; a < 3; ++a) c[a] = (face.positions[0][a] + face.positions[1][a] + face.positions[2][a]) / 3;
                         EXPECT_EQ(loaded.grid.cell_of(c), cell);
                         ++faces_in_cell;
                       }
                     }, 0);
      EXPECT_EQ(faces_in_cell, loaded.block_faces[cell]);
    }
    EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](int n) { return n == 1; }));
  }
}

// Resident blocks are leased page by page of each cell: a cell's first page is small,
// so many cells of few faces each stay in memory (a 256 KiB page a cell leased
// 1000 x 256 KiB here, more than the budget, and went to scratch).
TEST(Reencode, ManySmallCellsStayResidentWithinAFewPagesOfTheirRecords) {
  TempDir dir;
  auto in = make_mesh(dir, 10'000);
  Governor governor(64ull << 20, 0);
  Job job(governor, {}, {.threads = 2});
  ScratchStore scratch(dir.path(), 0);
  LoadedMesh loaded = load_into_blocks(job, scratch, in, LoadOptions::verbatim({.faces_per_block = 10}));
  ASSERT_TRUE(loaded.blocks_resident());
  const uint64_t cells = loaded.grid.count();
  EXPECT_GT(cells, 500u);
  const uint64_t records = loaded.face_count * loaded.block_record_size;
  // A page's capacity is whole records, rounded up: a record more a cell at most.
  EXPECT_LE(loaded.resident_blocks_lease.bytes(), 2 * records + cells * ((4 << 10) + loaded.block_record_size));
  uint64_t stored = 0;
  for (const auto& cell : loaded.resident_blocks)
    for (const Bytes& page : cell) stored += page.size();
  EXPECT_EQ(stored, records);
}

TEST(Reencode, CancelMidRunLeavesNoScratchAndNoOutput) {
  TempDir dir, scratch_dir;
  auto in = make_mesh(dir, 100'000);
  Governor governor(32ull << 20, 0);
  auto cancel = std::make_shared<CancelToken>();
  bool fired = false;
  JobHooks hooks;
  hooks.cancel = cancel;
  hooks.progress = [&](double fraction, const std::string&) {
    if (fraction > 0.3 && !fired) {
      fired = true;
      cancel->cancel();
    }
  };
  ReencodeOptions options{.input = in, .output = dir / "out.ply", .scratch_dir = scratch_dir.path()};
  options.load = {.faces_per_block = 5'000, .window_vertices = 4'000, .range_faces = 5'000, .force_out_of_core = true};
  try {
    run_reencode(governor, options, hooks);
    FAIL() << "not cancelled";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::cancelled) << e.what();
  }
  EXPECT_TRUE(fired);
  EXPECT_TRUE(directory_empty(scratch_dir.path()));
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir.path()), {}), 1);  // only the input
  EXPECT_EQ(governor.in_use(), 0u);
}

// A write error injected with a file-size limit (EFBIG), which works even as root.
TEST(Reencode, ScratchWriteErrorEndsCleanlyWithNothingLeftBehind) {
  TempDir dir, scratch_dir;
  auto in = make_mesh(dir, 100'000);
  Governor governor(64ull << 20, 0);
  ReencodeOptions options{.input = in, .output = dir / "out.ply", .scratch_dir = scratch_dir.path()};
  options.load = {.faces_per_block = 5'000, .window_vertices = 4'000, .range_faces = 5'000, .force_out_of_core = true};
  rlimit old{};
  getrlimit(RLIMIT_FSIZE, &old);
  auto old_handler = signal(SIGXFSZ, SIG_IGN);
  rlimit small = old;
  small.rlim_cur = 40'000;
  setrlimit(RLIMIT_FSIZE, &small);
  std::string message;
  ErrorKind kind = ErrorKind::internal;
  try {
    run_reencode(governor, options, {});
  } catch (const Error& e) {
    message = e.what();
    kind = e.kind();
  }
  setrlimit(RLIMIT_FSIZE, &old);
  signal(SIGXFSZ, old_handler);
  EXPECT_EQ(kind, ErrorKind::resource) << message;
  EXPECT_NE(message.find("write failed"), std::string::npos) << message;
  EXPECT_NE(message.find(scratch_dir.path().string()), std::string::npos) << message;
  EXPECT_TRUE(directory_empty(scratch_dir.path()));
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir.path()), {}), 1);
}

// review6: the face-id-order write (blocks whole, or in groups of id ranges) ends
// cleanly when cancelled or when the output cannot be written, and tiny meshes with
// repeated-vertex faces give the resident bytes out of core.
ReencodeOptions write_stage_options(const std::filesystem::path& in, const TempDir& dir, const TempDir& scratch,
                                    uint64_t group) {
  ReencodeOptions options{.input = in, .output = dir / "out.ply", .scratch_dir = scratch.path()};
  options.load = {.faces_per_block = 5'000, .window_vertices = 4'000, .range_faces = 5'000, .force_out_of_core = true};
  options.group_faces = group;
  return options;
}

TEST(Reencode, CancelWhileBlocksGoInFaceIdOrderLeavesNothing) {
  for (uint64_t group : {uint64_t{0}, uint64_t{1'500}}) {
    SCOPED_TRACE("group " + std::to_string(group));
    TempDir dir, scratch_dir;
    auto in = make_mesh(dir, 100'000);
    Governor governor(64ull << 20, 0);
    auto cancel = std::make_shared<CancelToken>();
    bool fired = false;
    JobHooks hooks;
    hooks.cancel = cancel;
    hooks.progress = [&](double fraction, const std::string& stage) {
      if (stage == "write" && fraction > 0.92 && !fired) {  // past the vertices: faces in order
        fired = true;
        cancel->cancel();
      }
    };
    ErrorKind kind = ErrorKind::internal;
    try {
      run_reencode(governor, write_stage_options(in, dir, scratch_dir, group), hooks);
    } catch (const Error& e) {
      kind = e.kind();
    }
    EXPECT_TRUE(fired);
    EXPECT_EQ(kind, ErrorKind::cancelled);
    EXPECT_TRUE(directory_empty(scratch_dir.path()));
    EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir.path()), {}), 1);  // only the input
    EXPECT_EQ(governor.in_use(), 0u);
  }
}

TEST(Reencode, OutputWriteErrorWhileBlocksGoInFaceIdOrderLeavesNothing) {
  for (uint64_t group : {uint64_t{0}, uint64_t{1'500}}) {
    SCOPED_TRACE("group " + std::to_string(group));
    TempDir dir, scratch_dir;
    auto in = make_mesh(dir, 100'000);
    Governor governor(64ull << 20, 0);
    ReencodeOptions options = write_stage_options(in, dir, scratch_dir, group);
    options.scratch_codec = ScratchCodec::zstd;  // scratch files stay under the limit
    rlimit old{};
    getrlimit(RLIMIT_FSIZE, &old);
    auto old_handler = signal(SIGXFSZ, SIG_IGN);
    rlimit small = old;
    small.rlim_cur = 1'200'000;  // the vertices (600 KB) fit, not every face (1.3 MB)
    setrlimit(RLIMIT_FSIZE, &small);
    std::string message;
    bool threw = false;
    try {
      run_reencode(governor, options, {});
    } catch (const Error& e) {
      threw = true;
      message = e.what();
    }
    setrlimit(RLIMIT_FSIZE, &old);
    signal(SIGXFSZ, old_handler);
    EXPECT_TRUE(threw);
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
    EXPECT_TRUE(directory_empty(scratch_dir.path()));
    EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir.path()), {}), 1);
    EXPECT_EQ(governor.in_use(), 0u);
  }
}

TEST(Reencode, TinyMeshOutOfCoreGivesTheResidentBytes) {
  TempDir dir;
  {
    std::ofstream ply(dir / "tiny.ply");  // an unreferenced vertex, faces with repeated vertices
    ply << "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
           "element face 4\nproperty list uchar int vertex_indices\nend_header\n"
           "0 0 0\n1 0 0\n0 1 0\n5 5 5\n0 0 1\n3 0 1 2\n3 2 2 4\n3 4 1 0\n3 0 0 0\n";
  }
  for (const char* extension : {".ply", ".obj"}) {
    std::string reference;
    for (uint64_t group : {uint64_t{0}, uint64_t{0}, uint64_t{1}}) {
      const bool out_of_core = !reference.empty();
      SCOPED_TRACE(std::string(extension) + (out_of_core ? " out of core" : " resident") + ", groups of " +
                   std::to_string(group));
      Governor governor(64ull << 20, 0);
      const auto out = dir / (std::string("out") + extension);
      ReencodeOptions options{.input = dir / "tiny.ply", .output = out, .scratch_dir = dir.path()};
      options.load = {.faces_per_block = 1, .window_vertices = out_of_core ? 1u : 0u,
                      .range_faces = out_of_core ? 1u : 0u, .force_out_of_core = out_of_core};
      options.group_faces = group;
      auto result = run_reencode(governor, options, {});
      EXPECT_EQ(result.faces, 4u);
      EXPECT_EQ(result.report["out_of_core_dereference"].get<bool>(), out_of_core);
      const std::string bytes = file_bytes(out);
      if (reference.empty()) reference = bytes;
      EXPECT_TRUE(bytes == reference) << "output differs from the resident run's";
      std::filesystem::remove(out);
    }
  }
}

// A binary PLY whose faces are quads, triangles and hexagons (two cells of a grid
// joined): fan-triangulated, it has more triangles than its header's face count.
std::filesystem::path make_polygon_mesh(const TempDir& dir, uint32_t n) {
  std::vector<float> xyz;
  for (uint32_t y = 0; y <= n; ++y)
    for (uint32_t x = 0; x <= n; ++x)
      for (float c : {float(x), float(y), float((x * 7 + y * 3) % 5) * 0.1f}) xyz.push_back(c);
  std::vector<std::vector<int32_t>> polygons;
  for (uint32_t y = 0; y < n; ++y) {
    for (uint32_t x = 0; x < n; ++x) {
      const int32_t a = int32_t(y * (n + 1) + x), b = a + 1, c = a + int32_t(n) + 2, d = a + int32_t(n) + 1;
      if ((x + y) % 5 == 0) {
        polygons.push_back({a, b, c});
        polygons.push_back({a, c, d});
      } else if (x % 7 == 3 && x + 1 < n) {
        polygons.push_back({a, b, b + 1, c + 1, c, d});
        ++x;
      } else {
        polygons.push_back({a, b, c, d});
      }
    }
  }
  const auto path = dir / "polygons.ply";
  std::ofstream out(path, std::ios::binary);
  out << "ply\nformat binary_little_endian 1.0\nelement vertex " << xyz.size() / 3
      << "\nproperty float x\nproperty float y\nproperty float z\nelement face " << polygons.size()
      << "\nproperty list uchar int vertex_indices\nend_header\n";
  out.write(reinterpret_cast<const char*>(xyz.data()), std::streamsize(xyz.size() * sizeof(float)));
  for (const auto& polygon : polygons) {
    const auto corners = uint8_t(polygon.size());
    out.write(reinterpret_cast<const char*>(&corners), 1);
    out.write(reinterpret_cast<const char*>(polygon.data()), std::streamsize(polygon.size() * sizeof(int32_t)));
  }
  return path;
}

// Review9 M1: the re-encode refused a valid PLY with polygon faces ("more faces than
// the header declares", exit 3) in every mode: resident blocks and the out-of-core
// local records were both bounded by the header's polygon count.
TEST(Reencode, PolygonFacesAreFanTriangulatedInEveryMode) {
  TempDir dir;
  const auto in = make_polygon_mesh(dir, 300);
  const uint64_t triangles = io::read_mesh(in).triangles.size();
  std::string reference;
  struct Run {
    const char* name;
    uint64_t budget;
    bool out_of_core;
  };
  for (const Run& run : {Run{"resident, blocks in memory", 256ull << 20, false},
                         Run{"resident, blocks in scratch", 20ull << 20, false},
                         Run{"out of core", 64ull << 20, true}}) {
    SCOPED_TRACE(run.name);
    Governor governor(run.budget, 0);
    const auto out = dir / "out.ply";
    ReencodeOptions options{.input = in, .output = out, .scratch_dir = dir.path()};
    options.load = {.faces_per_block = 20'000, .window_vertices = run.out_of_core ? 9'001u : 0u,
                    .range_faces = run.out_of_core ? 7'001u : 0u, .force_out_of_core = run.out_of_core};
    auto result = run_reencode(governor, options, {});
    EXPECT_EQ(result.faces, triangles);
    EXPECT_EQ(result.report["out_of_core_dereference"].get<bool>(), run.out_of_core);
    if (!run.out_of_core) {
      EXPECT_EQ(result.report["blocks_in_memory"].get<bool>(), run.budget > (64ull << 20));
    }
    expect_bytes_of_first_run(reference, in, out, "resident run");
    std::filesystem::remove(out);
    EXPECT_EQ(governor.in_use(), 0u);
  }
}

TEST(Reencode, BadInputEndsWithAOneLineErrorAndNothingLeftBehind) {
  TempDir dir, scratch_dir;
  {
    std::ofstream ply(dir / "bad.ply");
    ply << "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
           "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
           "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 7\n";
  }
  testing::expect_reencode_refused(dir / "bad.ply", dir / "out.ply", scratch_dir.path(), [](const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.ply"), std::string::npos) << e.what();
  });
}

TEST(Reencode, MissingScratchDirectoryIsARefusedUpFront) {
  TempDir dir;
  auto in = make_mesh(dir, 1'000);
  Governor governor(64ull << 20, 0);
  ReencodeOptions options{.input = in, .output = dir / "out.ply", .scratch_dir = dir / "nope"};
  try {
    run_reencode(governor, options, {});
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::resource);
  }
  EXPECT_FALSE(std::filesystem::exists(dir / "out.ply"));
}

TEST(Reencode, BudgetBelowTheLoadersMinimumIsRefusedNamingIt) {
  TempDir dir;
  auto in = make_mesh(dir, 1'000);
  Governor governor(2ull << 20, 0);
  ReencodeOptions options{.input = in, .output = dir / "out.ply", .scratch_dir = dir.path()};
  try {
    run_reencode(governor, options, {});
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::resource);
    EXPECT_NE(std::string(e.what()).find("minimum budget"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(dir / "out.ply"));
}

TEST(Reencode, TraceParsesAndHoldsTheIoThreadsSpansAndCounters) {
  TempDir dir;
  auto in = make_mesh(dir, 20'000);
  Governor governor(64ull << 20, 0);
  ReencodeOptions options{.input = in, .output = dir / "out.ply", .scratch_dir = dir.path(),
                          .trace_path = dir / "trace.json", .report_path = dir / "report.json"};
  options.load = {.faces_per_block = 2'000, .window_vertices = 2'000, .range_faces = 3'000, .force_out_of_core = true};
  const double cpu_before = process_cpu_seconds();
  run_reencode(governor, options, {});
  const double run_cpu = process_cpu_seconds() - cpu_before;  // the report's cpu_seconds counts the whole test process
  std::ifstream trace_file(dir / "trace.json");
  auto trace = nlohmann::json::parse(trace_file);
  int io_tid = -1;
  std::set<std::string> io_spans, counters, threads;
  for (const auto& e : trace["traceEvents"]) {
    if (e["ph"] == "M" && e["name"] == "thread_name") {
      threads.insert(e["args"]["name"].get<std::string>());
      if (e["args"]["name"] == "io") io_tid = e["tid"];
    }
  }
  ASSERT_GE(io_tid, 0);
  size_t compute_spans = 0;
  for (const auto& e : trace["traceEvents"]) {
    if (e["ph"] == "X") {
      EXPECT_GE(e["dur"].get<double>(), 0.0);
      if (e["tid"] == io_tid) io_spans.insert(e["name"].get<std::string>());
      else ++compute_spans;
    }
    if (e["ph"] == "C") counters.insert(e["name"].get<std::string>());
  }
  EXPECT_TRUE(io_spans.count("read input"));
  EXPECT_TRUE(io_spans.count("scratch write"));
  EXPECT_TRUE(io_spans.count("read scratch"));
  EXPECT_TRUE(io_spans.count("write triangles"));
  EXPECT_GT(compute_spans, 0u);
  EXPECT_TRUE(counters.count("governor bytes in use"));
  EXPECT_TRUE(counters.count("io bytes in flight"));
  EXPECT_TRUE(std::any_of(threads.begin(), threads.end(), [](auto& n) { return n.rfind("compute-", 0) == 0; }));

  std::ifstream report_file(dir / "report.json");
  auto report = nlohmann::json::parse(report_file);
  for (const char* key : {"input_faces", "output_faces", "wall_seconds", "peak_rss_bytes", "budget_bytes",
                          "stages", "nodes", "patches", "rounds", "io_busy_seconds", "overlap_seconds"}) {
    EXPECT_TRUE(report.contains(key)) << key;
  }
  EXPECT_EQ(report["output_faces"], 20'000);
  std::set<std::string> stages;
  for (const auto& s : report["stages"]) stages.insert(s["name"].get<std::string>());
  for (const char* s : {"load", "resolve", "write"}) EXPECT_TRUE(stages.count(s)) << s;
  // Every stage's activity is its own share of the run's: the stages do not nest, and
  // the write stage's timer ends before the report reads it (it used to say 0 s).
  double seconds = 0, cpu = 0, io = 0, overlap = 0;
  for (const auto& s : report["stages"]) {
    const double stage_seconds = s["seconds"].get<double>();
    EXPECT_LE(s["io_busy_seconds"].get<double>(), stage_seconds + 1e-6) << s["name"];
    EXPECT_LE(s["overlap_seconds"].get<double>(),
              std::min(s["io_busy_seconds"].get<double>(), s["compute_busy_seconds"].get<double>()) + 1e-6)
        << s["name"];
    if (s["name"] == "write") {
      EXPECT_GT(stage_seconds, 0.0);
      EXPECT_GT(s["io_busy_seconds"].get<double>(), 0.0);  // the output's writes
    }
    seconds += stage_seconds;
    cpu += s["cpu_seconds"].get<double>();
    io += s["io_busy_seconds"].get<double>();
    overlap += s["overlap_seconds"].get<double>();
  }
  EXPECT_LE(seconds, report["wall_seconds"].get<double>());
  EXPECT_LE(cpu, run_cpu);
  EXPECT_GT(cpu, 0.0);
  EXPECT_LE(io, report["io_busy_seconds"].get<double>() + 1e-6);
  EXPECT_LE(overlap, report["overlap_seconds"].get<double>() + 1e-6);
  bool block_writer = false;
  for (const auto& n : report["nodes"]) {
    if (n["name"] == "block writer") block_writer = n["peak_bytes"].get<uint64_t>() > 0;
  }
  EXPECT_TRUE(block_writer);
}

}  // namespace
}  // namespace qemflow::engine
