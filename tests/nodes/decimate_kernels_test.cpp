// The decimator's speed-ups keep every bit of its output: the rewritten kernels give the
// same doubles as the formulas they replaced, on random inputs that reach every branch.
// The references below are the replaced code, verbatim (decimator.hpp's contract: any
// reformulation of the arithmetic would change the output).
#include <Eigen/Dense>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <random>
#include <vector>

#include "nodes/decimate/quadric.hpp"

namespace qemflow::nodes {
namespace {

Vec3 sub(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
double dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// point_triangle_distance2 as it was before FanDeviation shared its edge vectors.
double reference_distance2(const Vec3& x, const Vec3& a, const Vec3& b, const Vec3& c) {
  auto at = [](const Vec3& o, const Vec3& u, double s, const Vec3& v, double t) {
    return Vec3{o[0] + s * u[0] + t * v[0], o[1] + s * u[1] + t * v[1], o[2] + s * u[2] + t * v[2]};
  };
  auto dist2 = [&](const Vec3& y) {
    const Vec3 d = sub(x, y);
    return dot(d, d);
  };
  const Vec3 ab = sub(b, a), ac = sub(c, a), ax = sub(x, a);
  const double d1 = dot(ab, ax), d2 = dot(ac, ax);
  if (d1 <= 0.0 && d2 <= 0.0) return dist2(a);
  const Vec3 bx = sub(x, b);
  const double d3 = dot(ab, bx), d4 = dot(ac, bx);
  if (d3 >= 0.0 && d4 <= d3) return dist2(b);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return dist2(at(a, ab, d1 / (d1 - d3), ac, 0.0));
  const Vec3 cx = sub(x, c);
  const double d5 = dot(ab, cx), d6 = dot(ac, cx);
  if (d6 >= 0.0 && d5 <= d6) return dist2(c);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return dist2(at(a, ab, 0.0, ac, d2 / (d2 - d6)));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const Vec3 bc = sub(c, b);
    return dist2(at(b, bc, (d4 - d3) / ((d4 - d3) + (d5 - d6)), bc, 0.0));
  }
  const double sum = va + vb + vc;
  if (!(sum > 0.0)) return std::min({dist2(a), dist2(b), dist2(c)});
  return dist2(at(a, ab, vb / sum, ac, vc / sum));
}

// collapse_deviation as it was: over a copied fan, one distance call per point.
double reference_deviation(const Vec3& a, double area_a, const Vec3& b, double area_b,
                           const std::vector<Triangle3>& fan) {
  if (fan.empty()) return 0.0;
  double nearest_a = std::numeric_limits<double>::infinity(), nearest_b = nearest_a;
  for (const Triangle3& t : fan) {
    nearest_a = std::min(nearest_a, reference_distance2(a, t[0], t[1], t[2]));
    nearest_b = std::min(nearest_b, reference_distance2(b, t[0], t[1], t[2]));
  }
  return area_a / 3.0 * nearest_a + area_b / 3.0 * nearest_b;
}

uint64_t bits(double x) { return std::bit_cast<uint64_t>(x); }

// A fan around a centre like the decimator's moved fans: every triangle shares the
// collapse position p; the ring is jittered off its plane, sometimes degenerate.
struct RandomFan {
  Vec3 a, b;
  std::vector<Triangle3> triangles;
};
RandomFan random_fan(std::mt19937& rng) {
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  auto near = [&](const Vec3& c, double r) { return Vec3{c[0] + r * unit(rng), c[1] + r * unit(rng), c[2] + r * unit(rng)}; };
  const Vec3 centre{100.0 * unit(rng), 100.0 * unit(rng), 100.0 * unit(rng)};  // away from 0: rounding
  const Vec3 p = near(centre, 0.1);
  RandomFan fan{near(p, 1.0), near(p, 1.0), {}};
  const int n = 3 + static_cast<int>(rng() % 10);
  std::vector<Vec3> ring;
  for (int i = 0; i < n; ++i) {
    const double t = 2 * M_PI * i / n;
    ring.push_back({p[0] + std::cos(t), p[1] + std::sin(t), p[2] + 0.3 * unit(rng)});
  }
  if (rng() % 4 == 0) ring[1] = ring[0];                    // a zero-length edge
  if (rng() % 4 == 0) ring[2] = {p[0], p[1], p[2]};         // a degenerate triangle at p
  for (int i = 0; i < n; ++i) {
    // p at any slot: the decimator's moved faces keep their vertex order.
    Triangle3 t{p, ring[i], ring[(i + 1) % n]};
    std::rotate(t.begin(), t.begin() + rng() % 3, t.end());
    fan.triangles.push_back(t);
  }
  return fan;
}

// Sets FanDeviation's kernel version for a scope (false: the CPU lacks it).
class KernelScope {
 public:
  explicit KernelScope(FanKernel kernel) : before_(fan_kernel()), ok_(use_fan_kernel(kernel)) {}
  ~KernelScope() { use_fan_kernel(before_); }
  bool ok() const { return ok_; }

 private:
  FanKernel before_;
  bool ok_;
};

void expect_triangle_distances_are_the_replaced_formula() {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> unit(-2.0, 2.0);
  for (int i = 0; i < 200000; ++i) {
    std::array<Vec3, 4> v;
    for (auto& q : v) q = {unit(rng), unit(rng), unit(rng)};
    if (i % 7 == 0) v[3] = v[2];  // degenerate
    if (i % 11 == 0) v[2] = {0.5 * (v[1][0] + v[3][0]), 0.5 * (v[1][1] + v[3][1]), 0.5 * (v[1][2] + v[3][2])};
    // Non-finite coordinates fail every region test: the degenerate branch.
    if (i % 13 == 0) v[1 + rng() % 3][rng() % 3] = std::numeric_limits<double>::quiet_NaN();
    if (i % 17 == 0) v[1 + rng() % 3][rng() % 3] = std::numeric_limits<double>::infinity();
    // Small integers: points on the regions' boundaries (the tests' ties).
    if (i % 5 == 0)
      for (auto& q : v)
        for (double& c : q) c = std::round(c);
    ASSERT_EQ(bits(point_triangle_distance2(v[0], v[1], v[2], v[3])),
              bits(reference_distance2(v[0], v[1], v[2], v[3])))
        << "case " << i;
    // FanDeviation's two lanes (a second point in another region of the same triangle).
    const Vec3 other{unit(rng), unit(rng), unit(rng)};
    FanDeviation deviation(v[0], other);
    deviation.add(v[1], v[2], v[3]);
    ASSERT_EQ(bits(deviation.charge(3.0, 3.0)),
              bits(reference_deviation(v[0], 3.0, other, 3.0, {{v[1], v[2], v[3]}})))
        << "case " << i;
  }
}

void expect_fan_deviation_is_the_copied_fan_charge() {
  std::mt19937 rng(11);
  for (int i = 0; i < 20000; ++i) {
    const RandomFan fan = random_fan(rng);
    const double area_a = 0.1 + (rng() % 1000) * 1e-3, area_b = 0.1 + (rng() % 1000) * 1e-3;
    FanDeviation deviation(fan.a, fan.b);
    for (const auto& t : fan.triangles) deviation.add(t[0], t[1], t[2]);
    const double expected = reference_deviation(fan.a, area_a, fan.b, area_b, fan.triangles);
    ASSERT_EQ(bits(deviation.charge(area_a, area_b)), bits(expected)) << "case " << i;
    ASSERT_EQ(bits(collapse_deviation(fan.a, area_a, fan.b, area_b, fan.triangles)), bits(expected));
  }
  EXPECT_EQ(FanDeviation({0, 0, 0}, {1, 0, 0}).charge(1.0, 1.0), 0.0);  // no fan: no charge
}

// Fans of 1..13 random triangles (every block size and padding of every version),
// degenerate, non-finite and on-boundary ones included, points a and b too.
std::vector<double> random_fan_charges() {
  std::mt19937 rng(23);
  std::uniform_real_distribution<double> unit(-2.0, 2.0);
  auto point = [&](int i) {
    Vec3 q{unit(rng), unit(rng), unit(rng)};
    if (i % 3 == 0)
      for (double& c : q) c = std::round(c);
    if (rng() % 97 == 0) q[rng() % 3] = std::numeric_limits<double>::quiet_NaN();
    if (rng() % 89 == 0) q[rng() % 3] = (rng() % 2 ? 1 : -1) * std::numeric_limits<double>::infinity();
    return q;
  };
  std::vector<double> charges;
  for (int i = 0; i < 30000; ++i) {
    const Vec3 a = point(i), b = rng() % 8 == 0 ? a : point(i);
    std::vector<Triangle3> fan(1 + rng() % 13);
    for (auto& t : fan) {
      t = {point(i), point(i), point(i)};
      if (rng() % 5 == 0) t[rng() % 3] = t[rng() % 3];  // a repeated vertex (or none)
      if (rng() % 9 == 0) t[2] = {0.5 * (t[0][0] + t[1][0]), 0.5 * (t[0][1] + t[1][1]), 0.5 * (t[0][2] + t[1][2])};
      if (rng() % 11 == 0) t[rng() % 3] = rng() % 2 ? a : b;  // a point on the fan
    }
    FanDeviation deviation(a, b);
    for (const auto& t : fan) deviation.add(t[0], t[1], t[2]);
    charges.push_back(deviation.charge(1.5, 2.5));
    const double expected = reference_deviation(a, 1.5, b, 2.5, fan);
    EXPECT_EQ(bits(charges.back()), bits(expected)) << "case " << i;
    if (bits(charges.back()) != bits(expected)) break;
  }
  return charges;
}

TEST(DecimateKernels, TheDefaultKernelIsAvx2WhereTheCpuHasIt) {
  // AVX-512 was not clearly faster than AVX2 (nodes/decimate/README.md, session 12).
  const bool avx2 = __builtin_cpu_supports("avx2") && !std::getenv("QEMFLOW_FAN_KERNEL");
  if (avx2) {
    EXPECT_EQ(fan_kernel(), FanKernel::kAvx2);
  }
}

TEST(DecimateKernels, TriangleDistancesAreTheReplacedFormulaBitForBit) {
  expect_triangle_distances_are_the_replaced_formula();
}

TEST(DecimateKernels, FanDeviationIsTheCopiedFanChargeBitForBit) {
  expect_fan_deviation_is_the_copied_fan_charge();
}

// The fallback of a CPU without AVX2, forced.
TEST(DecimateKernels, TheSse2FallbackGivesTheSameBits) {
  const KernelScope sse2(FanKernel::kSse2);
  ASSERT_TRUE(sse2.ok());
  ASSERT_EQ(fan_kernel(), FanKernel::kSse2);
  expect_triangle_distances_are_the_replaced_formula();
  expect_fan_deviation_is_the_copied_fan_charge();
}

TEST(DecimateKernels, EveryKernelVersionGivesTheSameBitsAsTheOthers) {
  std::vector<double> sse2;
  {
    const KernelScope scope(FanKernel::kSse2);
    sse2 = random_fan_charges();
  }
  int versions = 1;
  for (FanKernel kernel : {FanKernel::kAvx2, FanKernel::kAvx512}) {
    const KernelScope scope(kernel);
    if (!scope.ok()) continue;  // the CPU lacks it
    ++versions;
    const std::vector<double> charges = random_fan_charges();
    ASSERT_EQ(charges.size(), sse2.size());
    for (size_t i = 0; i < charges.size(); ++i) ASSERT_EQ(bits(charges[i]), bits(sse2[i])) << "case " << i;
    if (kernel == FanKernel::kAvx512) expect_fan_deviation_is_the_copied_fan_charge();
  }
  if (__builtin_cpu_supports("avx512f")) {
    EXPECT_EQ(versions, 3);
  }
}

// collapse_position's fast path as it was, with Eigen (the fallback is unchanged).
Vec3 reference_position(const Quadric& Q, const Vec3& lo, const Vec3& hi) {
  const auto& q = Q.q;
  Eigen::Matrix3d A;
  A << q[0], q[1], q[2], q[1], q[3], q[4], q[2], q[4], q[5];
  const Eigen::Vector3d b(q[6], q[7], q[8]);
  const double trace = q[0] + q[3] + q[5];
  const double det = A.determinant();
  if (trace > 0.0 && det > 1e-7 * trace * trace * trace) {
    const Eigen::Vector3d x = A.inverse() * (-b);
    return {x[0], x[1], x[2]};
  }
  return collapse_position(Q, lo, hi);  // the fallback's or the midpoint's
}

TEST(DecimateKernels, CollapsePositionIsEigensInverseBitForBit) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> unit(-1.0, 1.0), exponent(-10.0, 10.0);
  int fast = 0;
  for (int i = 0; i < 200000; ++i) {
    Quadric Q;
    if (i % 3 == 0) {  // any symmetric matrix, scaled
      for (double& x : Q.q) x = unit(rng) * std::pow(10.0, exponent(rng));
    } else {  // a sum of 1-5 weighted planes, as the decimator builds them
      const int planes = 1 + static_cast<int>(rng() % 5);
      for (int k = 0; k < planes; ++k) {
        Vec3 n{unit(rng), unit(rng), unit(rng)};
        const double len = std::sqrt(dot(n, n));
        n = {n[0] / len, n[1] / len, n[2] / len};
        Q += plane_quadric(n, {unit(rng), unit(rng), unit(rng)}, std::pow(10.0, exponent(rng)));
      }
    }
    const Vec3 lo{unit(rng), unit(rng), unit(rng)}, hi{unit(rng), unit(rng), unit(rng)};
    const Vec3 got = collapse_position(Q, lo, hi), want = reference_position(Q, lo, hi);
    for (int c = 0; c < 3; ++c) ASSERT_EQ(bits(got[c]), bits(want[c])) << "case " << i << " coordinate " << c;
    const double trace = Q.q[0] + Q.q[3] + Q.q[5];
    fast += trace > 0.0 && std::isfinite(got[0]) && got != Vec3{0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])};
  }
  EXPECT_GT(fast, 100000);  // most cases take the fast path
}

}  // namespace
}  // namespace qemflow::nodes
