// shuffle lives apart from the streaming core: it needs the whole mesh in memory.
#include <algorithm>
#include <numeric>
#include <random>

#include "gen/generator.hpp"

namespace qemflow::gen {
namespace {

// Fisher-Yates with a fixed generator and a plain modulo: the same order on every
// platform (std::uniform_int_distribution's draws are the library's choice).
std::vector<uint64_t> permutation(uint64_t n, std::mt19937_64& rng) {
  std::vector<uint64_t> order(n);
  std::iota(order.begin(), order.end(), uint64_t(0));
  for (uint64_t i = n; i > 1; --i) std::swap(order[i - 1], order[rng() % i]);
  return order;
}

}  // namespace

void shuffle(io::IndexedMesh& mesh, uint64_t seed) {
  std::mt19937_64 rng(seed);
  const std::vector<uint64_t> order = permutation(mesh.vertices.size(), rng);  // new i holds old order[i]
  std::vector<uint64_t> new_index(order.size());
  std::vector<Point> vertices(order.size());
  for (uint64_t i = 0; i < order.size(); ++i) {
    new_index[order[i]] = i;
    vertices[i] = mesh.vertices[order[i]];
  }
  mesh.vertices = std::move(vertices);
  const std::vector<uint64_t> face_order = permutation(mesh.triangles.size(), rng);
  std::vector<Triangle> triangles(face_order.size());
  for (uint64_t i = 0; i < face_order.size(); ++i) {
    const Triangle& t = mesh.triangles[face_order[i]];
    triangles[i] = {new_index[t[0]], new_index[t[1]], new_index[t[2]]};
  }
  mesh.triangles = std::move(triangles);
}

}  // namespace qemflow::gen
