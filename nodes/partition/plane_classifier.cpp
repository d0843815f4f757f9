#include "nodes/partition/plane_classifier.hpp"

#include <libsvm/svm.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <mutex>

#include "util/error.hpp"

namespace qemflow::nodes::partition {
namespace {

constexpr uint32_t kMagic = 0x4E4C5051;  // "QPLN"
constexpr uint32_t kVersion = 1;

void quiet(const char*) {}

// Positions centred and scaled so every coordinate lies in [-1, 1].
struct FeatureFrame {
  Point centre{0, 0, 0};
  double scale = 1;
};

FeatureFrame frame_of(std::span<const SurfaceSample> samples) {
  FeatureFrame frame;
  for (const auto& s : samples) frame.centre = add(frame.centre, s.position);
  frame.centre = scale(frame.centre, 1.0 / static_cast<double>(samples.size()));
  double largest = 0;
  for (const auto& s : samples)
    for (int a = 0; a < 3; ++a) largest = std::max(largest, std::abs(s.position[a] - frame.centre[a]));
  frame.scale = largest > 0 ? largest : 1;
  return frame;
}

// Every count/limit-th member (all of them when few enough), in sample order.
std::vector<uint32_t> stride_subsample(const std::vector<uint32_t>& members, uint32_t limit) {
  if (members.size() <= limit) return members;
  std::vector<uint32_t> picked(limit);
  for (uint32_t q = 0; q < limit; ++q) picked[q] = members[uint64_t{q} * members.size() / limit];
  return picked;
}

// The plane separating class members `positive` (w·x+h ≥ 0) from `negative`, in
// original coordinates, with |w| = 1.
std::array<double, 4> train_pair(std::span<const SurfaceSample> samples, const FeatureFrame& frame,
                                 const std::vector<uint32_t>& positive,
                                 const std::vector<uint32_t>& negative, const SvmOptions& options) {
  if (positive.empty() || negative.empty())  // nothing to separate: the non-empty side wins
    return {0, 0, 0, positive.empty() ? -1.0 : 1.0};
  const size_t count = positive.size() + negative.size();
  std::vector<svm_node> nodes(count * 4);
  std::vector<svm_node*> rows(count);
  std::vector<double> targets(count);
  for (size_t r = 0; r < count; ++r) {
    const bool is_positive = r < positive.size();
    const Point& p = samples[is_positive ? positive[r] : negative[r - positive.size()]].position;
    for (int a = 0; a < 3; ++a) nodes[r * 4 + a] = {a + 1, (p[a] - frame.centre[a]) / frame.scale};
    nodes[r * 4 + 3] = {-1, 0};
    rows[r] = &nodes[r * 4];
    targets[r] = is_positive ? 1 : -1;
  }
  svm_problem problem{static_cast<int>(count), targets.data(), rows.data()};
  svm_parameter parameter{};
  parameter.svm_type = NU_SVC;
  parameter.kernel_type = LINEAR;
  parameter.cache_size = options.cache_megabytes;
  parameter.eps = options.tolerance;
  parameter.C = 1;
  const double feasible = 2.0 * static_cast<double>(std::min(positive.size(), negative.size())) /
                          static_cast<double>(count);
  parameter.nu = std::min(options.nu, 0.95 * feasible);
  parameter.shrinking = 1;
  parameter.probability = 0;
  if (const char* problem_text = svm_check_parameter(&problem, &parameter))
    throw Error(ErrorKind::internal, std::string("libsvm: ") + problem_text);
  svm_model* model = svm_train(&problem, &parameter);

  // decision(x) = Σ sv_coef·<sv, x> − rho, positive for model->label[0].
  Point w{0, 0, 0};
  for (int k = 0; k < model->l; ++k)
    for (const svm_node* n = model->SV[k]; n->index != -1; ++n) w[n->index - 1] += model->sv_coef[0][k] * n->value;
  double rho = model->rho[0];
  const bool first_is_positive = model->label[0] == 1;
  svm_free_and_destroy_model(&model);
  if (!first_is_positive) {
    w = scale(w, -1);
    rho = -rho;
  }
  // Back to original coordinates: w·(x − c)/s − rho = (w/s)·x − (w·c/s + rho).
  Point world_w = scale(w, 1.0 / frame.scale);
  double h = -(dot(w, frame.centre) / frame.scale + rho);
  const double length = norm(world_w);
  if (length == 0) return {0, 0, 0, h >= 0 ? 1.0 : -1.0};
  return {world_w[0] / length, world_w[1] / length, world_w[2] / length, h / length};
}

}  // namespace

double PlaneClassifier::margin(const Point& x, uint32_t i, uint32_t j) const {
  if (i == j) throw Error(ErrorKind::internal, "PlaneClassifier::margin: i == j");
  if (i > j) return -margin(x, j, i);
  const auto& p = planes[pair_index(i, j)];
  return p[0] * x[0] + p[1] * x[1] + p[2] * x[2] + p[3];
}

uint32_t PlaneClassifier::classify(const Point& x) const {
  uint32_t first = 0;
  uint32_t last = classes - 1;
  while (first < last) {
    if (margin(x, first, last) >= 0) --last;
    else ++first;
  }
  return first;
}

std::vector<uint8_t> PlaneClassifier::serialize() const {
  std::vector<uint8_t> bytes(12 + planes.size() * sizeof(planes[0]));
  const uint32_t head[3] = {kMagic, kVersion, classes};
  std::memcpy(bytes.data(), head, sizeof head);
  std::memcpy(bytes.data() + 12, planes.data(), planes.size() * sizeof(planes[0]));
  return bytes;
}

PlaneClassifier PlaneClassifier::deserialize(std::span<const uint8_t> bytes) {
  uint32_t head[3] = {0, 0, 0};
  if (bytes.size() >= 12) std::memcpy(head, bytes.data(), sizeof head);
  PlaneClassifier classifier;
  classifier.classes = head[2];
  const size_t expected = 12 + pair_count(head[2]) * sizeof(std::array<double, 4>);
  if (head[0] != kMagic || head[1] != kVersion || head[2] == 0 || bytes.size() != expected)
    throw Error(ErrorKind::internal, "PlaneClassifier::deserialize: not a version-1 classifier image");
  classifier.planes.resize(pair_count(head[2]));
  std::memcpy(classifier.planes.data(), bytes.data() + 12, bytes.size() - 12);
  return classifier;
}

PlaneClassifier train_plane_classifier(std::span<const SurfaceSample> samples,
                                       std::span<const uint32_t> labels, uint32_t classes,
                                       const SvmOptions& options) {
  if (classes == 0 || labels.size() != samples.size() || samples.empty())
    throw Error(ErrorKind::internal, "train_plane_classifier: need samples, one label each, classes > 0");
  static std::once_flag silence;
  std::call_once(silence, [] { svm_set_print_string_function(quiet); });

  std::vector<std::vector<uint32_t>> members(classes);
  for (uint32_t i = 0; i < labels.size(); ++i) {
    if (labels[i] >= classes) throw Error(ErrorKind::internal, "train_plane_classifier: label out of range");
    members[labels[i]].push_back(i);
  }
  for (auto& m : members) m = stride_subsample(m, options.max_points_per_class);
  const FeatureFrame frame = frame_of(samples);

  PlaneClassifier classifier;
  classifier.classes = classes;
  classifier.planes.resize(PlaneClassifier::pair_count(classes));
  tbb::parallel_for(size_t{0}, classifier.planes.size(), [&](size_t pair) {
    uint32_t i = 0;  // invert pair_index
    size_t first_of_row = 0;
    while (first_of_row + (classes - 1 - i) <= pair) first_of_row += classes - 1 - i++;
    const uint32_t j = static_cast<uint32_t>(i + 1 + (pair - first_of_row));
    classifier.planes[pair] = train_pair(samples, frame, members[i], members[j], options);
  });
  return classifier;
}

Point barycenter(const std::array<Point, 3>& c) { return scale(add(add(c[0], c[1]), c[2]), 1.0 / 3.0); }

void classify_faces(std::span<const PositionedFace> faces, const PlaneClassifier& classifier,
                    std::span<uint32_t> labels) {
  if (labels.size() != faces.size()) throw Error(ErrorKind::internal, "classify_faces: size mismatch");
  tbb::parallel_for(tbb::blocked_range<size_t>(0, faces.size(), 4096), [&](const tbb::blocked_range<size_t>& range) {
    for (size_t f = range.begin(); f < range.end(); ++f) labels[f] = classifier.classify(barycenter(faces[f].corners));
  });
}

}  // namespace qemflow::nodes::partition
