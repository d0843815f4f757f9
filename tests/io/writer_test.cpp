// Writers: temporary file + rename, nothing left behind on abandon or failure,
// contract checks, resource errors naming the file.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>

#include <algorithm>
#include <functional>

#include "io/mesh_stream.hpp"
#include "io_test_support.hpp"
#include "test_support.hpp"

namespace qemflow::io {
namespace {

using qemflow::testing::TempDir;

std::vector<std::string> files_in(const std::filesystem::path& dir) {
  std::vector<std::string> names;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) names.push_back(entry.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

ErrorKind error_kind_of(const std::function<void()>& action, std::string* message = nullptr) {
  try {
    action();
  } catch (const Error& error) {
    if (message) *message = error.what();
    return error.kind();
  }
  ADD_FAILURE() << "no error";
  return ErrorKind::internal;
}

const std::vector<Point> kPoints = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
const std::vector<Triangle> kTriangles = {{0, 1, 2}};

class Writers : public ::testing::TestWithParam<std::string> {};

TEST_P(Writers, WritesToATemporaryNameAndRenamesOnCommit) {
  TempDir dir;
  auto path = dir / ("out" + GetParam());
  auto writer = open_mesh_writer(path, 3, 1);
  writer->write_vertices(kPoints.data(), 3);
  auto during = files_in(dir.path());
  ASSERT_EQ(during.size(), 1u);
  EXPECT_EQ(during[0].rfind("out" + GetParam() + ".tmp-", 0), 0u) << during[0];
  writer->write_triangles(kTriangles.data(), 1);
  writer->commit();
  EXPECT_EQ(files_in(dir.path()), std::vector<std::string>{"out" + GetParam()});
  EXPECT_GT(writer->bytes_written(), 0u);
  EXPECT_EQ(read_mesh(path).triangles, kTriangles);
}

TEST_P(Writers, AbandonedWriterLeavesNothingAndKeepsAnOldFile) {
  TempDir dir;
  auto path = dir / ("out" + GetParam());
  {
    auto writer = open_mesh_writer(path, 3, 1);
    writer->write_vertices(kPoints.data(), 3);
  }
  EXPECT_TRUE(files_in(dir.path()).empty());
  testing::write_bytes(path, "old contents");
  {
    auto writer = open_mesh_writer(path, 3, 1);
    writer->write_vertices(kPoints.data(), 3);
  }
  EXPECT_EQ(files_in(dir.path()), std::vector<std::string>{"out" + GetParam()});
  EXPECT_EQ(testing::read_bytes(path), "old contents");
}

TEST_P(Writers, ContractViolationsAreInternalErrorsAndLeaveNoOutput) {
  TempDir dir;
  auto path = dir / ("out" + GetParam());
  EXPECT_EQ(error_kind_of([&] {
              auto writer = open_mesh_writer(path, 3, 1);
              writer->write_vertices(kPoints.data(), 3);
              writer->commit();  // one triangle short
            }),
            ErrorKind::internal);
  EXPECT_EQ(error_kind_of([&] {
              auto writer = open_mesh_writer(path, 2, 0);
              writer->write_vertices(kPoints.data(), 3);
            }),
            ErrorKind::internal);
  EXPECT_EQ(error_kind_of([&] {
              auto writer = open_mesh_writer(path, 3, 1);
              writer->write_vertices(kPoints.data(), 3);
              Triangle bad{0, 1, 3};
              writer->write_triangles(&bad, 1);
            }),
            ErrorKind::internal);
  EXPECT_EQ(error_kind_of([&] {
              auto writer = open_mesh_writer(path, 3, 0);
              writer->write_vertices(kPoints.data(), 3);
              writer->write_triangles(kTriangles.data(), 1);  // more than declared
            }),
            ErrorKind::internal);
  EXPECT_TRUE(files_in(dir.path()).empty());
}

TEST_P(Writers, UnwritableDirectoryIsAResourceErrorNamingTheFile) {
  TempDir dir;
  auto path = dir / "missing-dir" / ("out" + GetParam());
  std::string message;
  EXPECT_EQ(error_kind_of([&] { open_mesh_writer(path, 3, 1); }, &message), ErrorKind::resource);
  EXPECT_NE(message.find(path.string()), std::string::npos) << message;
}

// A full disk, simulated with a file size limit: the write fails with EFBIG.
TEST_P(Writers, FailedWriteIsAResourceErrorAndLeavesNothing) {
  TempDir dir;
  auto path = dir / ("out" + GetParam());
  std::vector<Point> many(300000, Point{0.123456789, 1.5, -2.25});
  for (size_t i = 0; i < many.size(); ++i) many[i][0] = static_cast<double>(i);
  struct rlimit old_limit {};
  ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &old_limit), 0);
  auto old_handler = signal(SIGXFSZ, SIG_IGN);
  struct rlimit small = old_limit;
  small.rlim_cur = 64 << 10;
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &small), 0);
  std::string message;
  ErrorKind kind = error_kind_of(
      [&] {
        auto writer = open_mesh_writer(path, many.size(), 0);
        writer->write_vertices(many.data(), many.size());
        writer->commit();
      },
      &message);
  setrlimit(RLIMIT_FSIZE, &old_limit);
  signal(SIGXFSZ, old_handler);
  EXPECT_EQ(kind, ErrorKind::resource);
  EXPECT_NE(message.find(path.string() + ": cannot write"), std::string::npos) << message;
  EXPECT_TRUE(files_in(dir.path()).empty());
}

INSTANTIATE_TEST_SUITE_P(Formats, Writers, ::testing::Values(".ply", ".ply.zst", ".obj", ".obj.zst"),
                         [](const auto& info) {
                           std::string name = info.param.substr(1);
                           for (char& c : name) if (c == '.') c = '_';
                           return name;
                         });

TEST(PlyWriter, HeaderSaysFloatOrDoubleAndUcharIntList) {
  TempDir dir;
  write_mesh(dir / "f.ply", IndexedMesh{kPoints, kTriangles});
  write_mesh(dir / "d.ply", IndexedMesh{kPoints, kTriangles}, WriteOptions{.double_precision = true});
  std::string f = testing::read_bytes(dir / "f.ply");
  std::string d = testing::read_bytes(dir / "d.ply");
  EXPECT_NE(f.find("format binary_little_endian 1.0\n"), std::string::npos);
  EXPECT_NE(f.find("property float x\nproperty float y\nproperty float z\n"), std::string::npos);
  EXPECT_NE(d.find("property double x\nproperty double y\nproperty double z\n"), std::string::npos);
  EXPECT_NE(f.find("property list uchar int vertex_indices\nend_header\n"), std::string::npos);
  EXPECT_EQ(f.size() - f.find("end_header\n") - 11, 3u * 12 + 13);
  EXPECT_EQ(d.size() - d.find("end_header\n") - 11, 3u * 24 + 13);
}

TEST(PlyWriter, TrianglesBeforeAllVerticesIsMisuse) {
  TempDir dir;
  EXPECT_EQ(error_kind_of([&] {
              auto writer = open_mesh_writer(dir / "x.ply", 3, 1);
              writer->write_vertices(kPoints.data(), 2);
              writer->write_triangles(kTriangles.data(), 1);
            }),
            ErrorKind::internal);
}

TEST(ObjWriter, FacesMayFollowTheirVerticesInterleaved) {
  TempDir dir;
  auto writer = open_mesh_writer(dir / "x.obj", 4, 2);
  writer->write_vertices(kPoints.data(), 3);
  writer->write_triangles(kTriangles.data(), 1);
  Point last{1, 1, 0};
  writer->write_vertices(&last, 1);
  Triangle second{1, 3, 2};
  writer->write_triangles(&second, 1);
  writer->commit();
  EXPECT_EQ(testing::read_bytes(dir / "x.obj"), "# written by qemflow\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nv 1 1 0\nf 2 4 3\n");
}

TEST(Writers, UnknownExtensionIsAUsageError) {
  TempDir dir;
  EXPECT_EQ(error_kind_of([&] { open_mesh_writer(dir / "x.stl", 0, 0); }), ErrorKind::usage);
  EXPECT_EQ(error_kind_of([&] { open_mesh_writer(dir / "x.zst", 0, 0); }), ErrorKind::usage);
  EXPECT_TRUE(files_in(dir.path()).empty());
}

}  // namespace
}  // namespace qemflow::io
