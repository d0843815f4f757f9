#include "gen/generator.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <unordered_map>

#include "util/error.hpp"

namespace qemflow::gen {
namespace {

using io::IndexedMesh;

struct Topology {
  uint64_t edges = 0;
  std::string problem;  // empty when closed, oriented and 2-manifold
};

// Checks, for a triangle soup with vertex ids: indices in range, no repeated corner,
// every directed edge at most once and its reverse present (so: closed, consistently
// oriented, every edge in exactly two faces), and each vertex's faces one cycle.
Topology check_topology(const IndexedMesh& mesh) {
  Topology result;
  const uint64_t n = mesh.vertices.size();
  auto key = [n](uint64_t a, uint64_t b) { return a * n + b; };
  std::unordered_map<uint64_t, uint64_t> directed;  // edge -> face
  directed.reserve(mesh.triangles.size() * 3);
  for (uint64_t f = 0; f < mesh.triangles.size(); ++f) {
    const Triangle& t = mesh.triangles[f];
    for (int c = 0; c < 3; ++c) {
      if (t[c] >= n) return {0, "face " + std::to_string(f) + " index out of range"};
      if (t[c] == t[(c + 1) % 3]) return {0, "face " + std::to_string(f) + " repeats a vertex"};
      if (!directed.emplace(key(t[c], t[(c + 1) % 3]), f).second)
        return {0, "directed edge used twice (non-manifold or inconsistently oriented) at face " +
                       std::to_string(f)};
    }
  }
  for (const auto& [edge, face] : directed)
    if (!directed.count(key(edge % n, edge / n)))
      return {0, "boundary edge " + std::to_string(edge / n) + "-" + std::to_string(edge % n)};
  result.edges = directed.size() / 2;
  // Link of each vertex: face (v, a, b) contributes a -> b; a manifold vertex's link
  // is one cycle through all its neighbours.
  std::vector<std::vector<std::pair<uint64_t, uint64_t>>> link(n);
  for (const Triangle& t : mesh.triangles)
    for (int c = 0; c < 3; ++c) link[t[c]].emplace_back(t[(c + 1) % 3], t[(c + 2) % 3]);
  for (uint64_t v = 0; v < n; ++v) {
    if (link[v].size() < 3) return {0, "vertex " + std::to_string(v) + " has fewer than 3 faces"};
    std::map<uint64_t, uint64_t> next(link[v].begin(), link[v].end());
    if (next.size() != link[v].size()) return {0, "vertex " + std::to_string(v) + " fan repeats"};
    uint64_t at = link[v][0].first, steps = 0;
    do {
      auto it = next.find(at);
      if (it == next.end()) return {0, "vertex " + std::to_string(v) + " fan is open"};
      at = it->second;
      ++steps;
    } while (at != link[v][0].first && steps <= link[v].size());
    if (steps != link[v].size()) return {0, "vertex " + std::to_string(v) + " has several fans"};
  }
  return result;
}

Point sub(const Point& a, const Point& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
Point cross(const Point& a, const Point& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double dot(const Point& a, const Point& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
Point face_normal(const IndexedMesh& mesh, const Triangle& t) {
  return cross(sub(mesh.vertices[t[1]], mesh.vertices[t[0]]), sub(mesh.vertices[t[2]], mesh.vertices[t[0]]));
}

struct Geometry {
  double min_area_ratio = 0;  // smallest face area / mean face area
  double volume = 0;          // signed; positive when faces point outward
  double min_neighbour_cos = 1;  // smallest cosine between normals of faces sharing an edge
};

Geometry measure_geometry(const IndexedMesh& mesh) {
  Geometry g;
  std::vector<Point> normals;
  normals.reserve(mesh.triangles.size());
  double total = 0, smallest = INFINITY;
  for (const Triangle& t : mesh.triangles) {
    const Point n = face_normal(mesh, t);
    const double area = std::sqrt(dot(n, n)) / 2;
    total += area;
    smallest = std::min(smallest, area);
    g.volume += dot(mesh.vertices[t[0]], cross(mesh.vertices[t[1]], mesh.vertices[t[2]])) / 6;
    normals.push_back({n[0] / (2 * area), n[1] / (2 * area), n[2] / (2 * area)});
  }
  g.min_area_ratio = smallest / (total / static_cast<double>(mesh.triangles.size()));
  const uint64_t n = mesh.vertices.size();
  std::unordered_map<uint64_t, uint64_t> face_of_edge;
  for (uint64_t f = 0; f < mesh.triangles.size(); ++f)
    for (int c = 0; c < 3; ++c) face_of_edge[mesh.triangles[f][c] * n + mesh.triangles[f][(c + 1) % 3]] = f;
  for (uint64_t f = 0; f < mesh.triangles.size(); ++f)
    for (int c = 0; c < 3; ++c) {
      const auto other = face_of_edge.find(mesh.triangles[f][(c + 1) % 3] * n + mesh.triangles[f][c]);
      if (other != face_of_edge.end())
        g.min_neighbour_cos = std::min(g.min_neighbour_cos, dot(normals[f], normals[other->second]));
    }
  return g;
}

template <typename Real>
bool has_duplicate_positions(const std::vector<Point>& points) {
  std::vector<std::array<Real, 3>> copy;
  copy.reserve(points.size());
  for (const Point& p : points)
    copy.push_back({static_cast<Real>(p[0]), static_cast<Real>(p[1]), static_cast<Real>(p[2])});
  std::sort(copy.begin(), copy.end());
  return std::adjacent_find(copy.begin(), copy.end()) != copy.end();
}

struct Case {
  std::string shape;
  uint64_t faces;
};

class GeneratedShape : public ::testing::TestWithParam<Case> {};

TEST_P(GeneratedShape, IsAClosedOrientedManifoldWithExactCounts) {
  const GenOptions options{GetParam().shape, GetParam().faces, 7};
  const GenPlan expected = plan(options);
  const IndexedMesh mesh = generate_in_memory(options);
  SCOPED_TRACE(expected.layout);

  EXPECT_EQ(mesh.triangles.size(), options.faces + options.faces % 2);
  EXPECT_EQ(expected.face_count, mesh.triangles.size());
  EXPECT_EQ(expected.vertex_count, mesh.vertices.size());

  const Topology topology = check_topology(mesh);
  ASSERT_EQ(topology.problem, "");
  const auto euler = static_cast<int64_t>(mesh.vertices.size()) - static_cast<int64_t>(topology.edges) +
                     static_cast<int64_t>(mesh.triangles.size());
  EXPECT_EQ(euler, expected.euler_characteristic);
  EXPECT_EQ(expected.euler_characteristic, options.shape == "figure" ? 0 : 2);

  const Geometry geometry = measure_geometry(mesh);
  EXPECT_GT(geometry.min_area_ratio, 0.02) << "a face is (nearly) degenerate";
  EXPECT_GT(geometry.volume, 0) << "faces point inward";
  // Steep terrain meets its walls at up to ~135 degrees; a fold would be near -1.
  EXPECT_GT(geometry.min_neighbour_cos, -0.85) << "the surface folds back on itself";
  EXPECT_FALSE(has_duplicate_positions<double>(mesh.vertices));
  EXPECT_FALSE(has_duplicate_positions<float>(mesh.vertices)) << "positions collide once written as float";
}

INSTANTIATE_TEST_SUITE_P(Sizes, GeneratedShape,
                         ::testing::Values(Case{"blob", 200}, Case{"blob", 2001}, Case{"blob", 50000},
                                           Case{"blob", 150000}, Case{"terrain", 200}, Case{"terrain", 3333},
                                           Case{"terrain", 60000}, Case{"figure", 200}, Case{"figure", 4567},
                                           Case{"figure", 100000}),
                         [](const auto& info) {
                           return info.param.shape + "_" + std::to_string(info.param.faces);
                         });

// The checker itself must be able to fail: a flipped face, a missing face and a
// pinched vertex are each reported.
TEST(TopologyCheck, CatchesBrokenMeshes) {
  const IndexedMesh good = generate_in_memory({"blob", 1000, 1});
  ASSERT_EQ(check_topology(good).problem, "");
  IndexedMesh flipped = good;
  std::swap(flipped.triangles[10][0], flipped.triangles[10][1]);
  EXPECT_NE(check_topology(flipped).problem, "");
  IndexedMesh holed = good;
  holed.triangles.pop_back();
  EXPECT_NE(check_topology(holed).problem, "");
  // Two copies sharing one vertex: every edge still has two faces, but that vertex has two fans.
  IndexedMesh pinched = good;
  const auto n = good.vertices.size();
  pinched.vertices.insert(pinched.vertices.end(), good.vertices.begin() + 1, good.vertices.end());
  for (Triangle t : good.triangles) {
    for (auto& v : t) v = v == 0 ? 0 : v + n - 1;
    pinched.triangles.push_back(t);
  }
  EXPECT_NE(check_topology(pinched).problem.find("several fans"), std::string::npos)
      << check_topology(pinched).problem;
}

// A star-shaped surface around the origin never folds: every face must see the origin
// from behind (positive orientation relative to it), which the radial construction
// promises even at the coarsest size where the cube map distorts most.
TEST(GeneratedBlob, IsStarShapedAroundTheOrigin) {
  for (uint64_t faces : {200, 5000}) {
    const IndexedMesh mesh = generate_in_memory({"blob", faces, 3});
    for (const Triangle& t : mesh.triangles)
      ASSERT_GT(dot(mesh.vertices[t[0]], cross(mesh.vertices[t[1]], mesh.vertices[t[2]])), 0);
  }
}

// The top of the slab is a heightfield: seen from above no top face is flipped.
TEST(GeneratedTerrain, TopIsAHeightfieldAndBottomIsFlat) {
  const IndexedMesh mesh = generate_in_memory({"terrain", 20000, 3});
  uint64_t bottom = 0, top = 0;
  for (const Triangle& t : mesh.triangles) {
    const Point n = face_normal(mesh, t);
    const double z0 = mesh.vertices[t[0]][2], z1 = mesh.vertices[t[1]][2], z2 = mesh.vertices[t[2]][2];
    if (z0 == 0 && z1 == 0 && z2 == 0) {
      ++bottom;
      EXPECT_LT(n[2], 0);
    } else if (std::fabs(n[2]) > 1e-9 && std::max({z0, z1, z2}) > 0.1 &&
               std::fabs(mesh.vertices[t[0]][0]) < 0.999 && std::fabs(mesh.vertices[t[0]][1]) < 0.999) {
      ++top;
      EXPECT_GT(n[2], 0);
    }
  }
  EXPECT_GT(bottom, 5000u);
  EXPECT_GT(top, 5000u);
}

TEST(Generate, IsDeterministicAndSeedDependent) {
  for (const auto& shape : shape_names()) {
    const IndexedMesh a = generate_in_memory({shape, 30000, 11});
    const IndexedMesh b = generate_in_memory({shape, 30000, 11});
    const IndexedMesh c = generate_in_memory({shape, 30000, 12});
    EXPECT_EQ(a.vertices, b.vertices) << shape;
    EXPECT_EQ(a.triangles, b.triangles) << shape;
    EXPECT_NE(a.vertices, c.vertices) << shape;
  }
}

TEST(Generate, DoesNotDependOnTheThreadCount) {
  for (const auto& shape : shape_names()) {
    IndexedMesh one, two;
    {
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
      one = generate_in_memory({shape, 120000, 5});
    }
    {
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 2);
      two = generate_in_memory({shape, 120000, 5});
    }
    EXPECT_EQ(one.vertices, two.vertices) << shape;
    EXPECT_EQ(one.triangles, two.triangles) << shape;
  }
}

// The sink sees begin(), every vertex, then every triangle, in bounded batches.
TEST(Generate, StreamsVerticesThenTrianglesInBoundedBatches) {
  struct Recorder final : MeshSink {
    uint64_t declared_vertices = 0, declared_triangles = 0, vertices_seen = 0, triangles_seen = 0;
    size_t largest_batch = 0;
    bool order_ok = true;
    void begin(uint64_t v, uint64_t t) override {
      declared_vertices = v;
      declared_triangles = t;
    }
    void vertices(const Point*, size_t count) override {
      if (triangles_seen) order_ok = false;
      vertices_seen += count;
      largest_batch = std::max(largest_batch, count);
    }
    void triangles(const Triangle*, size_t count) override {
      if (vertices_seen != declared_vertices) order_ok = false;
      triangles_seen += count;
      largest_batch = std::max(largest_batch, count);
    }
  };
  for (const auto& shape : shape_names()) {
    Recorder recorder;
    generate({shape, 400000, 1}, recorder);
    EXPECT_TRUE(recorder.order_ok) << shape;
    EXPECT_EQ(recorder.vertices_seen, recorder.declared_vertices) << shape;
    EXPECT_EQ(recorder.triangles_seen, 400000u) << shape;
    EXPECT_LT(recorder.largest_batch, 100000u) << shape;
  }
}

// Every size from the minimum up fits exactly (centres make up the remainder).
TEST(Plan, HitsEveryEvenFaceCountExactly) {
  for (const auto& shape : shape_names()) {
    for (uint64_t faces = minimum_faces; faces < 6000; ++faces) {
      const GenPlan p = plan({shape, faces, 1});
      ASSERT_EQ(p.face_count, faces + faces % 2) << shape;
      // Closed: V - E + F = chi with E = 3F/2.
      ASSERT_EQ(static_cast<int64_t>(p.vertex_count) - static_cast<int64_t>(p.face_count) / 2,
                p.euler_characteristic)
          << shape << " " << faces;
    }
    for (uint64_t faces : std::initializer_list<uint64_t>{1'000'000, 300'000'000, 1'000'000'001, maximum_faces}) {
      const GenPlan p = plan({shape, faces, 1});
      EXPECT_EQ(p.face_count, faces + faces % 2) << shape;
    }
  }
}

void expect_usage_error(const GenOptions& options, const std::string& needle) {
  try {
    plan(options);
    ADD_FAILURE() << "accepted shape '" << options.shape << "' faces " << options.faces;
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::usage);
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

TEST(Plan, RejectsUnknownShapesAndTooFewFaces) {
  expect_usage_error({"teapot", 1000, 1}, "shapes: blob, terrain, figure");
  expect_usage_error({"blob", minimum_faces - 1, 1}, "at least 200");
  expect_usage_error({"figure", 0, 1}, "at least 200");
  expect_usage_error({"blob", maximum_faces + 1, 1}, "too large");
}

TEST(ParseFaceCount, AcceptsDecimalSuffixes) {
  EXPECT_EQ(parse_face_count("12345"), 12345u);
  EXPECT_EQ(parse_face_count("20k"), 20'000u);
  EXPECT_EQ(parse_face_count("2M"), 2'000'000u);
  EXPECT_EQ(parse_face_count("1.5M"), 1'500'000u);
  EXPECT_EQ(parse_face_count("300M"), 300'000'000u);
  EXPECT_EQ(parse_face_count("1g"), 1'000'000'000u);
  for (const char* bad : {"", "M", "2X", "2MB", "-5", "1.2.3M", "99999999999999999999"}) {
    try {
      parse_face_count(bad);
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::usage) << bad;
    }
  }
}

}  // namespace
}  // namespace qemflow::gen
