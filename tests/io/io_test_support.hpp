#pragma once
// Helpers for the io tests: write raw bytes into files, read whole streams with a
// chosen batch size, check error kind and message.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "io/indexed_mesh.hpp"
#include "io/mesh_stream.hpp"
#include "util/error.hpp"

namespace qemflow::io::testing {

inline void write_bytes(const std::filesystem::path& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

inline std::string read_bytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// Appends the raw bytes of a value in little- or big-endian order.
template <class T>
void put(std::string& out, T value, bool big_endian = false) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  if (big_endian) std::reverse(bytes, bytes + sizeof(T));
  out.append(bytes, sizeof(T));
}

// Reads a whole stream with batches of at most `max_elements`, checking the batch
// bookkeeping (first_vertex / first_triangle continuity) along the way.
inline IndexedMesh read_in_batches(const std::filesystem::path& path, size_t max_elements) {
  auto reader = open_mesh_reader(path);
  IndexedMesh mesh;
  MeshBatch batch;
  while (reader->next(batch, max_elements)) {
    EXPECT_EQ(batch.first_vertex, mesh.vertices.size());
    EXPECT_EQ(batch.first_triangle, mesh.triangles.size());
    EXPECT_FALSE(batch.vertices.empty() && batch.triangles.empty());
    for (const auto& t : batch.triangles) {
      for (uint64_t v : t) EXPECT_LT(v, mesh.vertices.size() + batch.vertices.size());
    }
    mesh.vertices.insert(mesh.vertices.end(), batch.vertices.begin(), batch.vertices.end());
    mesh.triangles.insert(mesh.triangles.end(), batch.triangles.begin(), batch.triangles.end());
  }
  EXPECT_FALSE(reader->next(batch, max_elements));
  return mesh;
}

// The message of the Error(bad_input) that reading `path` throws ("" if none).
inline std::string bad_input_message(const std::filesystem::path& path) {
  try {
    read_in_batches(path, 3);
  } catch (const Error& error) {
    EXPECT_EQ(error.kind(), ErrorKind::bad_input) << error.what();
    return error.what();
  }
  ADD_FAILURE() << "reading " << path << " did not fail";
  return "";
}

// Two triangles and a quad over 6 vertices (the quad fans into 2 triangles).
inline IndexedMesh small_mesh() {
  IndexedMesh mesh;
  mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0.1, 0.2, 0.3}, {-1.5, 2.25, 1e-3}};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}, {3, 4, 5}, {5, 4, 1}};
  return mesh;
}

}  // namespace qemflow::io::testing
