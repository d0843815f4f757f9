// ν-SVM plane classifier and DAG evaluation (nodes/partition/plane_classifier):
// sign convention, margins, DAG order, byte image.
#include <gtest/gtest.h>

#include <cmath>

#include "nodes/partition/counter_hash.hpp"
#include "nodes/partition/plane_classifier.hpp"
#include "util/error.hpp"

namespace qemflow::nodes::partition {
namespace {

// Points scattered around `centre` (±spread per axis), far from the origin on purpose.
void scatter(std::vector<SurfaceSample>& samples, std::vector<uint32_t>& labels, Point centre,
             double spread, uint32_t label, uint32_t count) {
  for (uint32_t n = 0; n < count; ++n) {
    Point p = centre;
    for (int a = 0; a < 3; ++a) p[a] += spread * (2 * unit_interval(counter_hash(label, n, a)) - 1);
    samples.push_back({p, {0, 0, 1}, samples.size()});
    labels.push_back(label);
  }
}

TEST(PartitionClassifier, PlaneSignsFollowTheLabels) {
  for (bool swap : {false, true}) {  // class 1 listed first must not flip the plane
    std::vector<SurfaceSample> samples;
    std::vector<uint32_t> labels;
    const Point left{1000 - 2, 500, 7}, right{1000 + 2, 500, 7};
    scatter(samples, labels, swap ? right : left, 1.5, swap ? 1 : 0, 300);
    scatter(samples, labels, swap ? left : right, 1.5, swap ? 0 : 1, 300);
    const PlaneClassifier c = train_plane_classifier(samples, labels, 2);
    ASSERT_EQ(c.planes.size(), 1u);
    const auto& plane = c.planes[0];
    EXPECT_NEAR(std::hypot(plane[0], plane[1], plane[2]), 1.0, 1e-12);
    EXPECT_LT(plane[0], -0.9);  // normal points from class 1 (x > 1000) to class 0
    for (size_t i = 0; i < samples.size(); ++i) {
      EXPECT_EQ(c.classify(samples[i].position), labels[i]);
      const double m = c.margin(samples[i].position, 0, 1);
      EXPECT_EQ(m > 0, labels[i] == 0);
      EXPECT_EQ(c.margin(samples[i].position, 1, 0), -m);
    }
    // Margin is a distance in world units: the separating plane sits near x = 1000.
    EXPECT_NEAR(c.margin({1000 - 3, 500, 7}, 0, 1), 3.0, 0.6);
  }
}

TEST(PartitionClassifier, DagSeparatesFiveClustersInSpace) {
  std::vector<SurfaceSample> samples;
  std::vector<uint32_t> labels;
  const Point centres[5] = {{0, 0, 0}, {10, 0, 0}, {0, 10, 0}, {0, 0, 10}, {10, 10, 10}};
  for (uint32_t k = 0; k < 5; ++k) scatter(samples, labels, centres[k], 3, k, 200);
  SvmOptions options;
  options.max_points_per_class = 100;  // exercise the subsampling
  const PlaneClassifier c = train_plane_classifier(samples, labels, 5, options);
  EXPECT_EQ(c.planes.size(), 10u);
  size_t right = 0;
  for (size_t i = 0; i < samples.size(); ++i) right += c.classify(samples[i].position) == labels[i];
  EXPECT_EQ(right, samples.size());
}

TEST(PartitionClassifier, ByteImageRoundTrips) {
  std::vector<SurfaceSample> samples;
  std::vector<uint32_t> labels;
  for (uint32_t k = 0; k < 4; ++k) scatter(samples, labels, {5.0 * k, 0, 0}, 1, k, 50);
  const PlaneClassifier c = train_plane_classifier(samples, labels, 4);
  const auto bytes = c.serialize();
  EXPECT_EQ(bytes.size(), 12u + 6 * 32);
  const PlaneClassifier back = PlaneClassifier::deserialize(bytes);
  EXPECT_EQ(back.classes, 4u);
  EXPECT_EQ(back.planes, c.planes);
  auto broken = bytes;
  broken.pop_back();
  EXPECT_THROW(PlaneClassifier::deserialize(broken), Error);
  broken = bytes;
  broken[0] ^= 1;
  EXPECT_THROW(PlaneClassifier::deserialize(broken), Error);
}

TEST(PartitionClassifier, TrainingIsRepeatable) {
  std::vector<SurfaceSample> samples;
  std::vector<uint32_t> labels;
  for (uint32_t k = 0; k < 6; ++k) scatter(samples, labels, {3.0 * (k % 3), 3.0 * (k / 3), 0}, 2, k, 150);
  const PlaneClassifier a = train_plane_classifier(samples, labels, 6);
  const PlaneClassifier b = train_plane_classifier(samples, labels, 6);
  EXPECT_EQ(a.planes, b.planes);
}

}  // namespace
}  // namespace qemflow::nodes::partition
