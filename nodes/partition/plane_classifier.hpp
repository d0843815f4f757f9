#pragma once
// The partition classifier (paper §4.4): one ν-SVM with a linear kernel (libsvm) per
// pair of clusters, each reduced to a plane w·x + h = 0 (paper Eqs. 4-5), evaluated as a
// DAG-SVM [Platt et al. 2000]: C−1 plane tests per point.
//
// Contract
// - planes are stored for i < j at pair_index(i, j), normalised so |w| = 1 (or w = 0 when
//   a pair had nothing to separate); w·x + h ≥ 0 votes for i, < 0 for j. margin(x, i, j)
//   is the signed distance to that plane, positive on i's side, for any i ≠ j.
// - classify(x): candidates 0..C−1; test the first against the last and drop the loser
//   until one is left. Pure, thread-safe, bit-identical everywhere.
// - Training (train_plane_classifier) is deterministic: each pair's training set is a
//   fixed stride subsample (≤ max_points_per_class per class, in sample order), features
//   are the positions centred on the sample mean and scaled by the largest coordinate
//   deviation (libsvm converges badly on raw, off-centre coordinates), probability
//   estimates are off (libsvm then never calls rand()). Pairs train in parallel; each
//   pair's result does not depend on the others.
// - serialize()/deserialize(): a tiny byte image (C and the planes) for scratch files.
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "nodes/partition/surface_sampler.hpp"

namespace qemflow::nodes::partition {

struct PlaneClassifier {
  uint32_t classes = 0;
  std::vector<std::array<double, 4>> planes;  // (w0, w1, w2, h) per pair i < j

  static size_t pair_count(uint32_t classes) { return size_t{classes} * (classes - 1) / 2; }
  size_t pair_index(uint32_t i, uint32_t j) const {  // requires i < j < classes
    return size_t{i} * classes - size_t{i} * (i + 1) / 2 + (j - i - 1);
  }
  double margin(const Point& x, uint32_t i, uint32_t j) const;
  uint32_t classify(const Point& x) const;

  std::vector<uint8_t> serialize() const;
  static PlaneClassifier deserialize(std::span<const uint8_t> bytes);
};

struct SvmOptions {
  double nu = 0.1;                     // best agreement in a sweep 0.02..0.4; lowered per pair when infeasible
  uint32_t max_points_per_class = 1000;
  double tolerance = 1e-3;             // libsvm eps
  double cache_megabytes = 16;
};

// labels[i] < classes is the cluster of samples[i].
PlaneClassifier train_plane_classifier(std::span<const SurfaceSample> samples,
                                       std::span<const uint32_t> labels, uint32_t classes,
                                       const SvmOptions& options = {});

// Class of every face, by its barycenter (parallel; labels.size() == faces.size()).
void classify_faces(std::span<const PositionedFace> faces, const PlaneClassifier& classifier,
                    std::span<uint32_t> labels);

Point barycenter(const std::array<Point, 3>& corners);

}  // namespace qemflow::nodes::partition
