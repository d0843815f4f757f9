// peer_simplify: the peers qemflow is benchmarked against, behind one command line.
//   peer_simplify meshopt|openmesh IN OUT (--target-faces N | --ratio R)
// meshopt:  meshoptimizer's meshopt_simplify (no error limit, default options).
// openmesh: OpenMesh's greedy Decimater with ModQuadricT (no error limit); faces that
//           OpenMesh's half-edge structure rejects (complex edges) are skipped and
//           counted, as any OpenMesh-based tool must.
// Prints one line: tool, input faces, output faces, seconds (simplification only, and
// total). Build: see bench/peers.sh.
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <OpenMesh/Tools/Decimater/DecimaterT.hh>
#include <OpenMesh/Tools/Decimater/ModQuadricT.hh>
#include <meshoptimizer.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "io/indexed_mesh.hpp"

using namespace qemflow;
using Clock = std::chrono::steady_clock;

static double since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

static io::IndexedMesh run_meshopt(const io::IndexedMesh& in, size_t target, double* seconds) {
  std::vector<float> positions(in.vertices.size() * 3);
  for (size_t i = 0; i < in.vertices.size(); ++i)
    for (int k = 0; k < 3; ++k) positions[3 * i + k] = static_cast<float>(in.vertices[i][k]);
  std::vector<unsigned> indices(in.triangles.size() * 3);
  for (size_t f = 0; f < in.triangles.size(); ++f)
    for (int k = 0; k < 3; ++k) indices[3 * f + k] = static_cast<unsigned>(in.triangles[f][k]);
  const auto t = Clock::now();
  std::vector<unsigned> out(indices.size());
  float error = 0;
  const size_t n = meshopt_simplify(out.data(), indices.data(), indices.size(), positions.data(),
                                    in.vertices.size(), 3 * sizeof(float), target * 3, FLT_MAX, 0,
                                    &error);
  *seconds = since(t);
  out.resize(n);
  io::IndexedMesh result;
  std::vector<int64_t> remap(in.vertices.size(), -1);
  for (unsigned v : out)
    if (remap[v] < 0) {
      remap[v] = static_cast<int64_t>(result.vertices.size());
      result.vertices.push_back(in.vertices[v]);
    }
  for (size_t i = 0; i + 2 < out.size(); i += 3)
    result.triangles.push_back({uint64_t(remap[out[i]]), uint64_t(remap[out[i + 1]]), uint64_t(remap[out[i + 2]])});
  return result;
}

static io::IndexedMesh run_openmesh(const io::IndexedMesh& in, size_t target, double* seconds,
                                    double* build_seconds, size_t* rejected) {
  using M = OpenMesh::TriMesh_ArrayKernelT<>;
  const auto tb = Clock::now();
  M mesh;
  std::vector<M::VertexHandle> handles;
  handles.reserve(in.vertices.size());
  for (const auto& p : in.vertices)
    handles.push_back(mesh.add_vertex(M::Point(float(p[0]), float(p[1]), float(p[2]))));
  *rejected = 0;
  for (const auto& t : in.triangles) {
    if (!mesh.add_face(handles[t[0]], handles[t[1]], handles[t[2]]).is_valid()) ++*rejected;
  }
  *build_seconds = since(tb);
  const auto t = Clock::now();
  OpenMesh::Decimater::DecimaterT<M> decimater(mesh);
  OpenMesh::Decimater::ModQuadricT<M>::Handle quadric;
  decimater.add(quadric);
  decimater.module(quadric).unset_max_err();
  decimater.initialize();
  decimater.decimate_to_faces(0, target);
  mesh.garbage_collection();
  *seconds = since(t);
  io::IndexedMesh result;
  for (auto v : mesh.vertices()) {
    const auto p = mesh.point(v);
    result.vertices.push_back({p[0], p[1], p[2]});
  }
  for (auto f : mesh.faces()) {
    Triangle tri{};
    int k = 0;
    for (auto v : mesh.fv_range(f)) tri[k++] = static_cast<uint64_t>(v.idx());
    result.triangles.push_back(tri);
  }
  return result;
}

int main(int argc, char** argv) {
  if (argc != 6) {
    std::fprintf(stderr, "usage: peer_simplify meshopt|openmesh IN OUT --target-faces N|--ratio R\n");
    return 2;
  }
  const std::string tool = argv[1];
  const auto t0 = Clock::now();
  const io::IndexedMesh in = io::read_mesh(argv[2]);
  const size_t target = std::strcmp(argv[4], "--ratio") == 0
                            ? static_cast<size_t>(std::llround(std::atof(argv[5]) * in.triangles.size()))
                            : static_cast<size_t>(std::atoll(argv[5]));
  double seconds = 0, build = 0;
  size_t rejected = 0;
  io::IndexedMesh out;
  if (tool == "meshopt") {
    out = run_meshopt(in, target, &seconds);
  } else if (tool == "openmesh") {
    out = run_openmesh(in, target, &seconds, &build, &rejected);
  } else {
    std::fprintf(stderr, "peer_simplify: unknown tool %s\n", tool.c_str());
    return 2;
  }
  io::write_mesh(argv[3], out);
  std::printf("%s input_faces %zu output_faces %zu target %zu simplify_s %.3f build_s %.3f total_s %.3f rejected_faces %zu\n",
              tool.c_str(), in.triangles.size(), out.triangles.size(), target, seconds, build,
              since(t0), rejected);
  return 0;
}
