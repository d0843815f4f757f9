#include "nodes/partition/surface_sampler.hpp"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "nodes/partition/counter_hash.hpp"
#include "util/error.hpp"

namespace qemflow::nodes::partition {
namespace {

constexpr int kExponentBias = 1100;  // frexp exponents of positive finite doubles: -1073..1024
constexpr int kBinCount = 2200;
// Samples per radius² of surface, measured on a sphere, a torus, the bunny and the
// dragon (0.59-0.60: eight kept candidates per cell fill a little short of the 0.7 of
// saturated random sequential adsorption).
constexpr double kSamplesPerRadiusSquared = 0.6;

Vec3 unit_normal(const std::array<Point, 3>& c) {
  const Vec3 n = cross(sub(c[1], c[0]), sub(c[2], c[0]));
  const double length = norm(n);
  return length > 0 ? scale(n, 1.0 / length) : Vec3{0, 0, 0};
}

bool dart_order(const SurfaceSampler::Candidate& a, const SurfaceSampler::Candidate& b) {
  if (a.key != b.key) return a.key < b.key;
  if (a.face_id != b.face_id) return a.face_id < b.face_id;
  return a.k < b.k;
}

Vec3 widen(const std::array<float, 3>& n) { return {n[0], n[1], n[2]}; }

// The grid cells (edge `radius`) that hold darts, each with the dense ids of its 27
// neighbours (itself first, −1 where no dart lies): built once, so the sequential
// dart loop below does no hashing.
struct DartCells {
  std::vector<uint32_t> cell_of_dart;
  std::vector<int32_t> neighbours;  // 27 per cell
  size_t cell_count = 0;
};

DartCells index_dart_cells(const std::vector<SurfaceSampler::Candidate>& darts, double radius) {
  const double inverse_cell = 1.0 / radius;
  DartCells index;
  CellMap dense(darts.size() / 4);
  std::vector<Cell> cells;
  index.cell_of_dart.resize(darts.size());
  for (size_t i = 0; i < darts.size(); ++i) {
    const Cell cell = cell_of(darts[i].position, inverse_cell);
    const uint32_t id = dense.insert(cell, static_cast<uint32_t>(cells.size()));
    if (id == cells.size()) cells.push_back(cell);
    index.cell_of_dart[i] = id;
  }
  index.cell_count = cells.size();
  index.neighbours.reserve(cells.size() * 27);
  for (const Cell& cell : cells) {
    index.neighbours.push_back(static_cast<int32_t>(dense.find(cell)));
    for_each_neighbour_cell(cell, [&](const Cell& near) {
      if (near == cell) return;
      const uint32_t found = dense.find(near);
      index.neighbours.push_back(found == CellMap::absent ? -1 : static_cast<int32_t>(found));
    });
  }
  return index;
}

// Random sequential adsorption of the candidates (already in dart order) at `radius`:
// the indices of the accepted candidates.
std::vector<uint32_t> throw_darts(const std::vector<SurfaceSampler::Candidate>& darts,
                                  double radius, const SheetLimits& sheets) {
  const DartCells cells = index_dart_cells(darts, radius);
  const double radius_squared = radius * radius;
  std::vector<uint32_t> head(cells.cell_count, 0);  // per cell: last accepted (+1)
  std::vector<uint32_t> accepted;
  std::vector<uint32_t> next;  // per accepted: previous accepted in its cell (+1)
  for (size_t i = 0; i < darts.size(); ++i) {
    const auto& dart = darts[i];
    const uint32_t home = cells.cell_of_dart[i];
    bool conflict = false;
    for (int n = 0; n < 27 && !conflict; ++n) {
      const int32_t cell = cells.neighbours[size_t{home} * 27 + n];
      if (cell < 0) continue;
      for (uint32_t link = head[cell]; link != 0 && !conflict; link = next[link - 1]) {
        const auto& other = darts[accepted[link - 1]];
        // The arc is never shorter than the chord: far chords need no asin.
        if (squared_distance(dart.position, other.position) >= radius_squared) continue;
        conflict = approx_geodesic(dart.position, widen(dart.normal), other.position,
                                   widen(other.normal), sheets) < radius;
      }
    }
    if (conflict) continue;
    accepted.push_back(static_cast<uint32_t>(i));
    next.push_back(head[home]);
    head[home] = static_cast<uint32_t>(accepted.size());
  }
  return accepted;
}

}  // namespace

double triangle_area(const std::array<Point, 3>& c) {
  return 0.5 * norm(cross(sub(c[1], c[0]), sub(c[2], c[0])));
}

SurfaceAreaSum::SurfaceAreaSum() : bins_(kBinCount, 0) {}

void SurfaceAreaSum::add(double area) {
  if (!(area > 0) || !std::isfinite(area)) return;
  int exponent = 0;
  const double mantissa = std::frexp(area, &exponent);  // area = mantissa · 2^exponent
  const auto integer_mantissa = static_cast<uint64_t>(std::ldexp(mantissa, 53));
  bins_[static_cast<size_t>(exponent + kExponentBias)] += integer_mantissa;
}

void SurfaceAreaSum::add_faces(std::span<const PositionedFace> faces) {
  for (const auto& face : faces) add(triangle_area(face.corners));
}

void SurfaceAreaSum::merge(const SurfaceAreaSum& other) {
  for (size_t i = 0; i < bins_.size(); ++i) bins_[i] += other.bins_[i];
}

double SurfaceAreaSum::total() const {
  long double sum = 0;
  for (size_t i = bins_.size(); i-- > 0;) {
    if (bins_[i] == 0) continue;
    const auto high = static_cast<uint64_t>(bins_[i] >> 64);
    const auto low = static_cast<uint64_t>(bins_[i]);
    const int exponent = static_cast<int>(i) - kExponentBias - 53;
    sum += std::ldexp(static_cast<long double>(high), exponent + 64) +
           std::ldexp(static_cast<long double>(low), exponent);
  }
  return static_cast<double>(sum);
}

double radius_for_sample_count(double area, uint64_t target_count) {
  if (!(area > 0) || target_count == 0)
    throw Error(ErrorKind::internal, "radius_for_sample_count: empty surface or zero target");
  return std::sqrt(kSamplesPerRadiusSquared * area / static_cast<double>(target_count));
}

SurfaceSampler::SurfaceSampler(const SamplerOptions& options)
    : options_(options), inverse_cell_size_(1.0 / options.radius) {
  if (!(options.radius > 0) || !std::isfinite(options.radius) || options.candidates_per_cell == 0 ||
      !(options.candidates_per_area > 0) || options.max_samples == 0)
    throw Error(ErrorKind::internal, "SurfaceSampler: radius, cap and candidate counts must be > 0");
}

void SurfaceSampler::offer(const Candidate& candidate) {
  const uint32_t per_cell = options_.candidates_per_cell;
  const uint32_t cell = cell_slot_.insert(cell_of(candidate.position, inverse_cell_size_),
                                         static_cast<uint32_t>(cell_count_.size()));
  if (cell == cell_count_.size()) {
    cell_count_.push_back(0);
    candidates_.resize(candidates_.size() + per_cell);
    free_slots_ += per_cell;
  }
  Candidate* begin = candidates_.data() + static_cast<size_t>(cell) * per_cell;
  uint32_t& count = cell_count_[cell];
  if (count < per_cell) {
    begin[count++] = candidate;
    --free_slots_;
    return;
  }
  Candidate* largest = std::max_element(begin, begin + per_cell, dart_order);
  if (dart_order(candidate, *largest)) *largest = candidate;
}

void SurfaceSampler::add_faces(std::span<const PositionedFace> faces) {
  const double per_area =
      options_.candidates_per_area / (options_.radius * options_.radius);
  for (const auto& face : faces) {
    const double area = triangle_area(face.corners);
    if (!(area > 0) || !std::isfinite(area)) continue;
    const double expected = area * per_area;
    const double whole = std::floor(expected);
    const uint64_t rounding = counter_hash(options_.seed, face.id, UINT64_MAX);
    const uint64_t count = static_cast<uint64_t>(whole) +
                           (unit_interval(rounding) < expected - whole ? 1 : 0);
    const Vec3 n = unit_normal(face.corners);
    const std::array<float, 3> normal{static_cast<float>(n[0]), static_cast<float>(n[1]),
                                      static_cast<float>(n[2])};
    const Vec3 edge1 = sub(face.corners[1], face.corners[0]);
    const Vec3 edge2 = sub(face.corners[2], face.corners[0]);
    for (uint64_t k = 0; k < count && k < UINT32_MAX; ++k) {
      double u = unit_interval(counter_hash(options_.seed, face.id, 3 * k));
      double v = unit_interval(counter_hash(options_.seed, face.id, 3 * k + 1));
      if (u + v > 1) {
        u = 1 - u;
        v = 1 - v;
      }
      Candidate candidate;
      candidate.key = counter_hash(options_.seed, face.id, 3 * k + 2);
      candidate.face_id = face.id;
      candidate.position = add(face.corners[0], add(scale(edge1, u), scale(edge2, v)));
      candidate.normal = normal;
      candidate.k = static_cast<uint32_t>(k);
      offer(candidate);
    }
  }
}

void SurfaceSampler::merge(SurfaceSampler&& other) {
  const SamplerOptions& o = other.options_;
  if (o.radius != options_.radius || o.seed != options_.seed ||
      o.candidates_per_cell != options_.candidates_per_cell || o.candidates_per_area != options_.candidates_per_area)
    throw Error(ErrorKind::internal, "SurfaceSampler::merge: samplers built with different options");
  const uint32_t per_cell = other.options_.candidates_per_cell;
  for (size_t cell = 0; cell < other.cell_count_.size(); ++cell)
    for (uint32_t i = 0; i < other.cell_count_[cell]; ++i) offer(other.candidates_[cell * per_cell + i]);
  other = SurfaceSampler(other.options_);
}

SampleSet SurfaceSampler::finish() const {
  std::vector<Candidate> darts;
  darts.reserve(kept_candidates());
  const uint32_t per_cell = options_.candidates_per_cell;
  for (size_t cell = 0; cell < cell_count_.size(); ++cell)
    for (uint32_t i = 0; i < cell_count_[cell]; ++i) darts.push_back(candidates_[cell * per_cell + i]);
  std::sort(darts.begin(), darts.end(), dart_order);

  double radius = options_.radius;
  std::vector<uint32_t> accepted;
  for (int attempt = 0;; ++attempt) {
    accepted = throw_darts(darts, radius, options_.sheets);
    if (accepted.size() <= options_.max_samples) break;
    if (attempt == 60) throw Error(ErrorKind::internal, "SurfaceSampler: sample cap unreachable");
    // The count falls about as 1/r² (a surface's samples cover it with disks).
    const double growth = std::sqrt(static_cast<double>(accepted.size()) /
                                    (0.95 * static_cast<double>(options_.max_samples)));
    radius *= std::max(growth, 1.02);
  }

  std::vector<uint32_t> order = accepted;
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) {
    if (darts[a].face_id != darts[b].face_id) return darts[a].face_id < darts[b].face_id;
    return darts[a].k < darts[b].k;
  });
  SampleSet result;
  result.radius = radius;
  result.samples.reserve(order.size());
  for (uint32_t index : order)
    result.samples.push_back({darts[index].position, widen(darts[index].normal), darts[index].face_id});
  return result;
}

SampleSet sample_faces(std::span<const PositionedFace> faces, uint64_t target_count, uint64_t seed,
                       uint64_t max_samples) {
  // Per-thread area sums and samplers merged in whatever order: the result cannot tell.
  constexpr size_t kChunk = 1 << 14;
  tbb::enumerable_thread_specific<SurfaceAreaSum> areas;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, faces.size(), kChunk), [&](const auto& range) {
    areas.local().add_faces(faces.subspan(range.begin(), range.size()));
  });
  SurfaceAreaSum area;
  for (const auto& part : areas) area.merge(part);
  SamplerOptions options;
  options.radius = radius_for_sample_count(area.total(), target_count);
  options.max_samples = max_samples;
  options.seed = seed;
  tbb::enumerable_thread_specific<SurfaceSampler> samplers(options);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, faces.size(), kChunk), [&](const auto& range) {
    samplers.local().add_faces(faces.subspan(range.begin(), range.size()));
  });
  SurfaceSampler sampler(options);
  for (auto& part : samplers) sampler.merge(std::move(part));
  return sampler.finish();
}

}  // namespace qemflow::nodes::partition
