#include "measure/report_json.hpp"

namespace qemflow::measure {
namespace {

nlohmann::json triple(double hausdorff, double mean, double rms) {
  return {{"hausdorff", hausdorff}, {"mean", mean}, {"rms", rms}};
}
nlohmann::json absolute_and_relative(double hausdorff, double mean, double rms, double diagonal) {
  auto rel = [&](double x) { return diagonal > 0 ? x / diagonal : 0.0; };
  return {{"absolute", triple(hausdorff, mean, rms)}, {"relative", triple(rel(hausdorff), rel(mean), rel(rms))}};
}

}  // namespace

nlohmann::json to_json(const BoundingBox& box) {
  if (box.empty) return nullptr;
  return {{"min", box.lo}, {"max", box.hi}, {"diagonal", box.diagonal()}};
}

nlohmann::json to_json(const DirectedDistance& d, double bbox_diagonal) {
  return absolute_and_relative(d.hausdorff, d.mean, d.rms, bbox_diagonal);
}

nlohmann::json to_json(const DistanceReport& r) {
  return {
      {"distances",
       {{"a_to_b", to_json(r.a_to_b, r.bbox_diagonal)},
        {"b_to_a", to_json(r.b_to_a, r.bbox_diagonal)},
        {"symmetric", absolute_and_relative(r.hausdorff, r.mean, r.rms, r.bbox_diagonal)}}},
      {"bbox_diagonal", r.bbox_diagonal},
      {"sample_density", r.sample_density},
      {"samples",
       {{"a_to_b", {{"vertex", r.a_to_b.vertex_samples}, {"face", r.a_to_b.face_samples}}},
        {"b_to_a", {{"vertex", r.b_to_a.vertex_samples}, {"face", r.b_to_a.face_samples}}}}},
      {"flipped_faces", r.flipped_faces},
  };
}

nlohmann::json to_json(const TopologyStats& s) {
  nlohmann::json j = {
      {"vertices", s.vertices},
      {"faces", s.faces},
      {"edges", s.edges},
      {"boundary_edges", s.boundary_edges},
      {"non_manifold_edges", s.non_manifold_edges},
      {"oriented_duplicate_edges", s.oriented_duplicate_edges},
  };
  auto put = [&](const char* name, const std::optional<uint64_t>& v) {
    if (v) j[name] = *v;
  };
  put("unreferenced_vertices", s.unreferenced_vertices);
  put("non_manifold_vertices", s.non_manifold_vertices);
  put("degenerate_faces", s.degenerate_faces);
  put("duplicate_faces", s.duplicate_faces);
  put("connected_components", s.connected_components);
  return j;
}

}  // namespace qemflow::measure
