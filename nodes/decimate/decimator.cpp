#include "nodes/decimate/decimator.hpp"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>

#include "util/morton.hpp"
#include "util/parallel_fill.hpp"
#include "util/parallel_select.hpp"
#include "util/radix_sort.hpp"

namespace qemflow::nodes {
namespace {

constexpr uint32_t kNone = std::numeric_limits<uint32_t>::max();
// Largest corner-list pool: offsets into it (adj_begin_) are 32-bit.
constexpr uint64_t kMaxPool = std::numeric_limits<uint32_t>::max();
// corner_cost_ values: not computed yet / the edge has no finite cost or position.
constexpr double kUnknownCost = std::numeric_limits<double>::quiet_NaN();
constexpr double kSkipEdge = std::numeric_limits<double>::infinity();
// With a deviation charge, an edge's two corners hold different things: the corner at
// the endpoint with the smaller global id holds the full cost, the other one the
// quadric part negated (sign bit set: -0.0 for a zero part), a lower bound that stays
// valid while the endpoints' quadrics and positions do (only the kept vertex's edges
// lose it, in collapse()); a border edge's one corner holds whichever is known, the
// full cost winning. Full costs are >= +0.0 or kSkipEdge, never negative.
bool is_lower_bound(double stored) { return std::signbit(stored) && !std::isnan(stored); }
bool is_full_cost(double stored) { return !std::signbit(stored) && !std::isnan(stored); }
double load_cost(const UninitializedVector<double>& costs, uint32_t corner) {
  return std::atomic_ref<double>(const_cast<double&>(costs[corner])).load(std::memory_order_relaxed);
}
void store_cost(UninitializedVector<double>& costs, uint32_t corner, double value) {
  std::atomic_ref<double>(costs[corner]).store(value, std::memory_order_relaxed);
}
// falive_: kFaceAlive, and the validity of the edge at each corner (slot k: the two
// bits kEdgeValid / kEdgeInvalid << kValidityShift[k], both clear when unknown); a dead
// face is 0. Read and written concurrently in prepare's passes: atomic, relaxed.
constexpr uint8_t kFaceAlive = 1;
constexpr uint8_t kEdgeValid = 1, kEdgeInvalid = 2;
constexpr unsigned kValidityShift[3] = {1, 3, 5};
uint8_t load_face(const UninitializedVector<uint8_t>& falive, size_t f) {
  return std::atomic_ref<uint8_t>(const_cast<uint8_t&>(falive[f])).load(std::memory_order_relaxed);
}
// Forgets the validity of face f's edges (alive: concurrent forgets store the same value).
void forget_validity(UninitializedVector<uint8_t>& falive, size_t f) {
  if (load_face(falive, f) > kFaceAlive)
    std::atomic_ref<uint8_t>(falive[f]).store(kFaceAlive, std::memory_order_relaxed);
}
// dirty_ value of a vertex whose refresh a round with a known cut skipped.
constexpr uint8_t kDirtyStale = 2;
// dirty_ value of a stale vertex next to a touched one (its edges' deviation charges
// may have changed).
constexpr uint8_t kDirtyStaleNearTouched = 3;

Vec3 sub(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
[[gnu::always_inline]] inline Vec3 triangle_normal(const Vec3& p0, const Vec3& p1, const Vec3& p2) {
  return cross(sub(p1, p0), sub(p2, p0));
}
// |cross| / (longest edge)^2: about the sine of the smallest angle; 0 when degenerate.
double triangle_quality(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& n) {
  const Vec3 e0 = sub(p1, p0), e1 = sub(p2, p1), e2 = sub(p0, p2);
  const double longest = std::max({dot(e0, e0), dot(e1, e1), dot(e2, e2)});
  if (!(longest > 0.0)) return 0.0;
  return std::sqrt(dot(n, n)) / longest;
}
// triangle_quality(...) < limit, without the square root.
bool below_quality(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& n, double limit) {
  const Vec3 e0 = sub(p1, p0), e1 = sub(p2, p1), e2 = sub(p0, p2);
  const double longest = std::max({dot(e0, e0), dot(e1, e1), dot(e2, e2)});
  return dot(n, n) < limit * limit * longest * longest;
}
bool contains(const std::array<uint32_t, 3>& f, uint32_t v) {
  return f[0] == v || f[1] == v || f[2] == v;
}

// Sets a flag shared between threads of a parallel loop to 1, unless it is non-zero
// (flags are only ever raised concurrently: relaxed stores, no read-modify-write).
void raise_flag(uint8_t& flag) {
  std::atomic_ref<uint8_t> f(flag);
  if (!f.load(std::memory_order_relaxed)) f.store(1, std::memory_order_relaxed);
}

// raise_flag for dirty_: 0 -> 1, kDirtyStale -> kDirtyStaleNearTouched (each value has
// one successor, so concurrent relaxed stores agree).
void raise_dirty(uint8_t& flag) {
  std::atomic_ref<uint8_t> f(flag);
  const uint8_t old = f.load(std::memory_order_relaxed);
  if (old == 0) f.store(1, std::memory_order_relaxed);
  if (old == kDirtyStale) f.store(kDirtyStaleNearTouched, std::memory_order_relaxed);
}

template <class F>
void parallel_over(size_t n, F&& body, size_t grain = 1024) {
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, grain),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t i = r.begin(); i != r.end(); ++i) body(i);
                    });
}

// How many of 0..n-1 satisfy `pred`, in parallel (an integer sum: any order gives it).
template <class P>
size_t count_where(size_t n, P&& pred) {
  return tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, n, 4096), size_t{0},
      [&](const tbb::blocked_range<size_t>& r, size_t count) {
        for (size_t i = r.begin(); i < r.end(); ++i) count += pred(i) ? 1 : 0;
        return count;
      },
      std::plus<size_t>());
}

// Slot of the vertex after / before slot k in a face.
constexpr uint32_t kNextSlot[3] = {1, 2, 0};
constexpr uint32_t kPrevSlot[3] = {2, 0, 1};

// Fans up to this size are searched by a plain scan; longer ones (a hub's) through a
// sorted index, so finding each of n entries costs O(log n), not O(n).
constexpr uint32_t kScanFan = 32;

// The first i < n with at(i) == x, or n. `index` is scratch for a fan longer than
// kScanFan (at(i) << 32 | i, sorted; built by the first lookup in a fan, so pass it
// cleared for each new fan).
template <class At>
uint32_t find_in_fan(uint32_t n, At&& at, uint32_t x, std::vector<uint64_t>& index) {
  if (n <= kScanFan) {
    uint32_t i = 0;
    while (i < n && at(i) != x) ++i;
    return i;
  }
  if (index.empty()) {
    index.resize(n);
    for (uint32_t i = 0; i < n; ++i) index[i] = uint64_t{at(i)} << 32 | i;
    std::sort(index.begin(), index.end());
  }
  const auto it = std::lower_bound(index.begin(), index.end(), uint64_t{x} << 32);
  return it != index.end() && (*it >> 32) == x ? static_cast<uint32_t>(*it) : n;
}

// parallel_over with one thread-local Scratch per range (looked up once per range, not
// per element).
template <class S, class F>
void parallel_over_with(size_t n, tbb::enumerable_thread_specific<S>& scratch, F&& body,
                        size_t grain = 1024) {
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, grain),
                    [&](const tbb::blocked_range<size_t>& r) {
                      S& s = scratch.local();
                      for (size_t i = r.begin(); i != r.end(); ++i) body(i, s);
                    });
}

// v's neighbours from its faces: `pairs` = (neighbour << 32 | index in `faces`) sorted,
// and per neighbour, ascending, (neighbour, number of faces shared with v, position of
// its first pair): the faces shared with w are pairs[first, first + count), in
// ascending index. Lets a hub of degree n find an edge's faces without an O(n) scan
// per edge (O(n^2) at setup).
struct Neighbor {
  uint32_t vertex, count, first;
};
void neighbor_faces(uint32_t v, const std::vector<uint32_t>& faces,
                    const std::vector<std::array<uint32_t, 3>>& fv, std::vector<uint64_t>& pairs,
                    std::vector<Neighbor>& out) {
  pairs.clear();
  for (uint32_t i = 0; i < faces.size(); ++i)
    for (uint32_t u : fv[faces[i]])
      if (u != v) pairs.push_back(uint64_t{u} << 32 | i);
  std::sort(pairs.begin(), pairs.end());
  out.clear();
  for (uint32_t j = 0; j < pairs.size(); ++j) {
    const uint32_t u = static_cast<uint32_t>(pairs[j] >> 32);
    if (!out.empty() && out.back().vertex == u)
      ++out.back().count;
    else
      out.push_back({u, 1, j});
  }
}

// Renumbers the patch's vertices along a Z-order (Morton) curve of their positions and
// its faces by their smallest vertex in that order. The rounds visit vertices in local
// order and each visit reads its neighbours' and their faces' state: in this order a
// vertex's rings lie in a few nearby stretches of every array, however the input was
// numbered. Nothing computed depends on local numbering (every order that matters is
// by global ids: candidates by key, sums over a vertex's faces by global face id,
// output by global ids).
void renumber_for_locality(PatchInput& in) {
  const size_t nv = in.positions.size(), nf = in.faces.size();
  // Every loop here is parallel (the setup ran them on one core): each writes its own
  // elements, and the box's min / max are exact whatever the order of the blocks.
  struct Bounds {
    Vec3 lo, hi;
  };
  Bounds none;
  none.lo.fill(std::numeric_limits<double>::infinity());
  none.hi.fill(-std::numeric_limits<double>::infinity());
  // An equal +0.0 / -0.0 keeps the earlier one, as the serial loop did: the blocks are
  // joined left to right.
  auto join = [](Bounds a, const Bounds& b) {
    for (int k = 0; k < 3; ++k) {
      a.lo[k] = std::min(a.lo[k], b.lo[k]);
      a.hi[k] = std::max(a.hi[k], b.hi[k]);
    }
    return a;
  };
  const Bounds box = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, nv, 4096), none,
      [&](const tbb::blocked_range<size_t>& r, Bounds b) {
        for (size_t v = r.begin(); v < r.end(); ++v)
          for (int k = 0; k < 3; ++k) {
            const double x = in.positions[v][k];
            if (std::isfinite(x)) {
              b.lo[k] = std::min(b.lo[k], x);
              b.hi[k] = std::max(b.hi[k], x);
            }
          }
        return b;
      },
      join);
  const Vec3 lo = box.lo, hi = box.hi;
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  if (nv < 2 || !(extent > 0.0) || !std::isfinite(extent)) return;
  const bool mesh = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, nf, 4096), true,
      [&](const tbb::blocked_range<size_t>& r, bool ok) {
        for (size_t f = r.begin(); f < r.end() && ok; ++f) {
          const auto& t = in.faces[f];
          ok = t[0] < nv && t[1] < nv && t[2] < nv;
        }
        return ok;
      },
      std::logical_and<bool>());
  if (!mesh) return;  // not a mesh: left as given
  const double scale = double((1u << 21) - 1) / extent;
  auto lane = [&](double x, int k) -> uint64_t {
    const double q = (x - lo[k]) * scale;  // in [0, 2^21 - 1] when finite
    return std::isfinite(q) ? spread_bits21(static_cast<uint64_t>(std::clamp(q, 0.0, double((1u << 21) - 1)))) : 0;
  };
  // The scratch arrays are UninitializedVectors and the permuted ones are sized by
  // parallel_resize: fresh pages in every patch, faulted in on every thread.
  UninitializedVector<std::pair<uint64_t, uint32_t>> by_code(nv);
  parallel_over(nv, [&](size_t v) {
    const Vec3& p = in.positions[v];
    by_code[v] = {lane(p[0], 0) | lane(p[1], 1) << 1 | lane(p[2], 2) << 2, uint32_t(v)};
  }, 4096);
  // Ties in code are in index order already: the stable radix sort gives std::sort's order.
  radix_sort_by_key(by_code, [](const std::pair<uint64_t, uint32_t>& x) { return x.first; });
  UninitializedVector<uint32_t> old_of(nv), new_of(nv);
  parallel_over(nv, [&](size_t i) {
    old_of[i] = by_code[i].second;
    new_of[by_code[i].second] = uint32_t(i);
  }, 4096);
  release_memory(by_code);
  auto permute = [](auto& values, const UninitializedVector<uint32_t>& from) {
    if (values.empty()) return;
    std::remove_reference_t<decltype(values)> moved;
    parallel_resize(moved, from.size());
    parallel_over(from.size(), [&](size_t i) { moved[i] = values[from[i]]; }, 4096);
    values = std::move(moved);
  };
  permute(in.positions, old_of);
  permute(in.vertex_gids, old_of);
  permute(in.incomplete, old_of);
  permute(in.owned_vertex, old_of);
  permute(in.locked, old_of);
  permute(in.quadrics, old_of);
  permute(in.best_gids, old_of);
  permute(in.best_costs, old_of);
  release_memory(old_of);
  UninitializedVector<uint64_t> by_first(nf);  // smallest new vertex id << 32 | old face index
  parallel_over(nf, [&](size_t f) {
    auto& t = in.faces[f];
    for (uint32_t& v : t) v = new_of[v];
    by_first[f] = uint64_t{std::min({t[0], t[1], t[2]})} << 32 | f;
  }, 4096);
  release_memory(new_of);
  // The low half (the old index) is ascending already: sorting stably by the high half
  // alone gives the same order in 2 radix passes instead of 4-5.
  radix_sort_by_key(by_first, [](uint64_t x) { return x >> 32; });
  UninitializedVector<uint32_t> face_from(nf);
  parallel_over(nf, [&](size_t i) { face_from[i] = static_cast<uint32_t>(by_first[i]); }, 4096);
  release_memory(by_first);
  permute(in.faces, face_from);
  permute(in.face_gids, face_from);
  permute(in.owned_face, face_from);
}

}  // namespace

bool verify_carried_enabled() {
  static const bool on = [] {
    const char* value = std::getenv("QEMFLOW_VERIFY_CARRIED");
    return value && *value && std::strcmp(value, "0") != 0;
  }();
  return on;
}

size_t cost_bin(double cost) {
  return static_cast<size_t>(std::bit_cast<uint64_t>(cost > 0.0 ? cost : 0.0) >> 50);
}
double cost_bin_upper(size_t bin) {
  return std::bit_cast<double>((static_cast<uint64_t>(bin + 1) << 50) - 1);
}

void RoundSummary::add(const RoundSummary& other) {
  for (size_t i = 0; i < kCostBins; ++i) faces_per_bin[i] += other.faces_per_bin[i];
  candidate_faces += other.candidate_faces;
  candidates += other.candidates;
  inexact_candidates += other.inexact_candidates;
}

struct PatchDecimator::Scratch {
  std::vector<uint32_t> fb, faces;
  struct FaceNormal {
    Vec3 normal;
    TrianglePlane plane;
  };
  std::vector<FaceNormal> face_normals;  // compute_quadrics: per entry of `faces`
  std::vector<uint64_t> pairs;
  std::vector<Neighbor> neighbors;
  struct Option {
    EdgeKey key;
    uint32_t other, corner, twin;
    bool exact;         // key.cost is the edge's cost, not only its quadric part (a lower bound)
    bool has_position;  // the cost was computed just now: `position` is the edge's
    Vec3 position;
  };
  std::vector<Option> options;
  // fan_neighbors(): the first fan_size entries of fan_store (sized, never shrunk, so
  // filling it is plain stores rather than push_back's capacity checks).
  std::vector<FanEdge> fan_store;
  std::vector<uint32_t> fan_prev;  // the vertex before v in each of its faces, then those corners
  uint32_t fan_size = 0;
  std::span<const FanEdge> fan() const { return {fan_store.data(), fan_size}; }
  std::vector<uint32_t> next, prev;  // fan_links()
  std::vector<uint64_t> fan_index;    // find_in_fan's index
  std::vector<double> areas;
  // collapse_valid's fold check: the faces of each endpoint (a, then b) that survive the
  // collapse, with their normals after it and the vertices before / after the endpoint.
  struct FanFace {
    Vec3 normal;
    uint32_t from, to;
  };
  std::vector<FanFace> fold[2];
  uint64_t refreshed = 0;  // refresh_best calls (prepare's counter)
  uint64_t scanned = 0;    // faces read by validity checks and charges (prepare's counter)
  uint64_t frozen = 0;     // refreshes skipped at frozen vertices (prepare's counter)
  uint64_t charged = 0;    // deviation charges computed (prepare's counter)
  uint64_t checked = 0;    // validity checks computed (prepare's counter)
};

PatchDecimator::PatchDecimator(PatchInput in, const DecimateParams& params) : params_(params) {
  const size_t nv = in.positions.size();
  auto optional_size_ok = [](size_t size, size_t n) { return size == 0 || size == n; };
  if (in.vertex_gids.size() != nv || in.face_gids.size() != in.faces.size() ||
      !optional_size_ok(in.incomplete.size(), nv) || !optional_size_ok(in.owned_vertex.size(), nv) ||
      !optional_size_ok(in.locked.size(), nv) || !optional_size_ok(in.quadrics.size(), nv) ||
      !optional_size_ok(in.owned_face.size(), in.faces.size()) || !optional_size_ok(in.best_gids.size(), nv) ||
      in.best_costs.size() != in.best_gids.size())
    throw std::invalid_argument("PatchDecimator: array sizes disagree");
  if (nv >= kNone || in.faces.size() >= kNone / 3)
    throw std::invalid_argument("PatchDecimator: patch too large for 32-bit local ids");
  renumber_for_locality(in);
  pos_ = std::move(in.positions);
  vgid_ = std::move(in.vertex_gids);
  // The per-vertex and per-face passes below run in parallel: each writes its own
  // element, or (passthrough faces) runs serially only where there is one.
  vflag_.resize(nv);
  parallel_over(nv, [&](size_t v) {
    uint8_t flags = kOwned;
    if (!in.owned_vertex.empty() && !in.owned_vertex[v]) flags &= ~kOwned;
    if (!in.incomplete.empty() && in.incomplete[v]) flags |= kUntrusted;
    if (!in.locked.empty() && in.locked[v]) flags |= kLocked;
    vflag_[v] = flags;
  }, 4096);
  const bool any_incomplete = count_where(in.incomplete.size(), [&](size_t v) { return in.incomplete[v] != 0; }) > 0;
  if (count_where(in.owned_face.size(), [&](size_t f) { return in.owned_face[f] == 0; }) == 0)
    release_memory(in.owned_face);
  release_memory(in.owned_vertex);
  release_memory(in.incomplete);

  // Faces with a repeated vertex have no normal or manifold structure: pass them
  // through and lock their vertices.
  auto repeated = [&](size_t f) {
    const auto& t = in.faces[f];
    return t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
  };
  if (count_where(in.faces.size(), repeated) > 0) {
    size_t kept = 0;
    for (size_t f = 0; f < in.faces.size(); ++f) {
      const auto& t = in.faces[f];
      if (repeated(f)) {
        if (params_.drop_repeated_vertex_faces) {
          ++dropped_faces_;
          continue;
        }
        passthrough_.push_back(t);
        passthrough_gids_.push_back(in.face_gids[f]);
        passthrough_owned_.push_back(in.owned_face.empty() ? 1 : in.owned_face[f]);
        for (uint32_t v : t) vflag_[v] |= kLocked;
      } else {
        in.faces[kept] = t;
        in.face_gids[kept] = in.face_gids[f];
        if (!in.owned_face.empty()) in.owned_face[kept] = in.owned_face[f];
        ++kept;
      }
    }
    in.faces.resize(kept);
    in.face_gids.resize(kept);
    if (!in.owned_face.empty()) in.owned_face.resize(kept);
  }
  fv_ = std::move(in.faces);
  fgid_ = std::move(in.face_gids);
  fowned_ = std::move(in.owned_face);
  parallel_assign(falive_, fv_.size(), kFaceAlive);
  faces_alive_ = fv_.size();
  parallel_assign(corner_cost_, 3 * fv_.size(), kUnknownCost);

  rebuild_adjacency(0);
  if (in.locked.empty()) lock_nonmanifold_vertices();
  release_memory(in.locked);
  if (in.quadrics.size() == nv) {
    quadric_ = std::move(in.quadrics);
  } else {
    compute_quadrics();
    if (any_incomplete) spread_untrusted(kInitialQuadricRadius);
  }
  untrusted_count_ = count_where(nv, [&](size_t v) { return (vflag_[v] & kUntrusted) != 0; });
  parallel_assign(best_, nv, kNone);
  parallel_assign(best_cost_, nv, 0.0);
  parallel_assign(face_area_, nv, kUnknownCost);
  parallel_assign(partner_, nv, kNone);
  parallel_assign(dirty_, nv, uint8_t{1});
  parallel_assign(touched_, nv, uint8_t{1});
  locked_count_ = count_where(nv, [&](size_t v) { return (vflag_[v] & kLocked) != 0; });
  if (!in.best_gids.empty()) restore_bests(in.best_gids, in.best_costs);
  release_memory(in.best_gids);
  release_memory(in.best_costs);
}

void PatchDecimator::restore_bests(const std::vector<uint64_t>& gids, const std::vector<double>& costs) {
  // A carried best is the global one (the exporting patch computed it where its 2-ring
  // was trusted); here a refresh computes the same only where v's 2-ring is the global
  // one too: no initially untrusted vertex within kBestRadius rings.
  std::vector<uint8_t> dist;
  if (untrusted_count_ > 0) untrusted_distances(kBestRadius, dist);
  UninitializedVector<uint8_t> restored;
  parallel_assign(restored, pos_.size(), uint8_t{0});
  tbb::enumerable_thread_specific<Scratch> scratch;
  parallel_over_with(pos_.size(), scratch, [&](size_t vi, Scratch& s) {
    const uint32_t v = static_cast<uint32_t>(vi);
    const uint64_t gid = gids[v];
    if (gid == kBestUnknown || (!dist.empty() && dist[v] <= kBestRadius)) return;
    uint32_t best = kNone;
    if (gid != kBestNone) {
      if (immovable(v)) return;  // refresh_best gives an immovable vertex none
      // Gids are unique in the patch: the first neighbour with the gid is the one.
      for (uint32_t c : corners_of(v)) {
        const auto& t = fv_[c / 3];
        const uint32_t next = t[kNextSlot[c % 3]], prev = t[kPrevSlot[c % 3]];  // v's neighbours (no repeats)
        best = vgid_[next] == gid ? next : vgid_[prev] == gid ? prev : kNone;
        if (best != kNone) break;
      }
      if (best == kNone) return;  // not a neighbour: not the state the value is for
    }
    // As a refresh leaves it (no best: cost 0); untouched and clean, so the first round
    // skips v unless a touched neighbour makes it near-touched, whose refresh keeps an
    // exact best unless a smaller valid edge appears (it cannot: none changed). The
    // border flag is the touched pass's other output.
    best_[v] = best;
    best_cost_[v] = best == kNone ? 0.0 : costs[v];
    dirty_[v] = 0;
    touched_[v] = 0;
    update_border(v, s);
    restored[v] = 1;
  });
  // partner_ for pairs of restored vertices; the first prepare's update_partners pairs
  // the refreshed ones (it visits the dirty vertices only).
  restored_bests_ = count_where(pos_.size(), [&](size_t v) { return restored[v] != 0; });
  parallel_over(pos_.size(), [&](size_t v) {
    if (!restored[v]) return;
    const uint32_t w = best_[v];
    if (w != kNone && restored[w] && best_[w] == v) partner_[v] = w;
  }, 4096);
  if (verify_carried_enabled() && restored_bests_ > 0) verify_restored_.assign(restored.begin(), restored.end());
}

std::pair<uint32_t, double> PatchDecimator::best_from_scratch(uint32_t v, Scratch& s) const {
  // refresh_best's result without its shortcuts: every unlocked neighbour's edge costed
  // in full (quadric part + deviation charge, as quadric_cost / edge_cost compute them)
  // and checked for validity; the smallest valid key wins. Reads no cached cost or
  // validity (deviation() may fill the face-area cache, a pure function of the state).
  if ((vflag_[v] & kDead) || immovable(v)) return {kNone, 0.0};
  const std::span<const uint32_t> corners = corners_of(v);
  fan_neighbors(v, corners, s);
  uint32_t best = kNone;
  EdgeKey best_key{};
  for (const auto& [w, corner, twin] : s.fan()) {
    if (immovable(w)) continue;
    const Vec3 p = edge_position(v, w);
    double cost = quadric_error(quadric_[v] + quadric_[w], p);
    if (!(std::isfinite(cost) && std::isfinite(p[0] + p[1] + p[2]))) continue;
    if (params_.deviation_weight > 0.0) {
      const bool v_lo = vgid_[v] < vgid_[w];
      cost = cost + params_.deviation_weight * (v_lo ? deviation(v, w, p, s) : deviation(w, v, p, s));
      if (!std::isfinite(cost)) continue;
    }
    const EdgeKey key = EdgeKey::of(cost, vgid_[v], vgid_[w]);
    if (best != kNone && !(key < best_key)) continue;
    if (!collapse_valid(v, corners, s.fan(), w, p, s)) continue;
    best = w;
    best_key = key;
  }
  return {best, best == kNone ? 0.0 : best_key.cost};
}

void PatchDecimator::verify_restored_bests() {
  // Called by the first prepare once the touched vertices' border flags are current
  // (collapse_valid reads both endpoints'), before any refresh: best_ / best_cost_ of a
  // restored vertex are still the carried values.
  std::atomic<uint64_t> worst_gid{~uint64_t{0}};
  std::vector<uint64_t> found(pos_.size(), 0);  // 1 at the mismatches
  tbb::enumerable_thread_specific<Scratch> scratch;
  parallel_over_with(pos_.size(), scratch, [&](size_t vi, Scratch& s) {
    if (!verify_restored_[vi]) return;
    const uint32_t v = static_cast<uint32_t>(vi);
    const auto [w, cost] = best_from_scratch(v, s);
    if (w == best_[v] && std::bit_cast<uint64_t>(cost) == std::bit_cast<uint64_t>(best_cost_[v])) return;
    found[v] = 1;
    uint64_t seen = worst_gid.load();
    while (vgid_[v] < seen && !worst_gid.compare_exchange_weak(seen, vgid_[v])) {
    }
  });
  release_memory(verify_restored_);
  if (worst_gid.load() == ~uint64_t{0}) return;
  uint64_t mismatches = 0;
  uint32_t v = kNone;
  for (uint32_t u = 0; u < pos_.size(); ++u)
    if (found[u]) {
      ++mismatches;
      if (vgid_[u] == worst_gid.load()) v = u;
    }
  Scratch s;
  const auto [w, cost] = best_from_scratch(v, s);
  auto gid_of = [&](uint32_t x) { return x == kNone ? std::string("none") : std::to_string(vgid_[x]); };
  char costs[96];
  std::snprintf(costs, sizeof costs, "cost %.17g, a full refresh cost %.17g", best_cost_[v], cost);
  throw std::logic_error("QEMFLOW_VERIFY_CARRIED: the carried best edge of vertex " + std::to_string(vgid_[v]) +
                         " leads to " + gid_of(best_[v]) + " (" + costs + " to " + gid_of(w) + "); " +
                         std::to_string(mismatches) + " of " + std::to_string(restored_bests_) +
                         " restored bests differ");
}

void PatchDecimator::rebuild_adjacency(size_t extra) {
  // Counting sort of the live corners by vertex: each list in ascending face order.
  const size_t nv = pos_.size();
  parallel_assign(adj_count_, nv, 0u);
  size_t live = 0;
  for (size_t f = 0; f < fv_.size(); ++f) {
    if (!falive_[f]) continue;
    for (uint32_t v : fv_[f]) ++adj_count_[v];
    live += 3;
  }
  if (adj_begin_.capacity() < nv) release_memory(adj_begin_);
  adj_begin_.resize(nv);
  uint32_t at = 0;  // live < 3 * fv_.size() < kNone (checked at construction)
  for (size_t v = 0; v < nv; ++v) {
    adj_begin_[v] = at;
    at += adj_count_[v];
    adj_count_[v] = 0;
  }
  release_memory(adj_);
  // Slack for the merged lists collapses append (see apply_cut), within the 32-bit
  // offsets of adj_begin_.
  if (live + extra > kMaxPool)
    throw std::length_error("PatchDecimator: corner lists exceed 32-bit offsets (patch too large)");
  adj_.reserve(std::min<uint64_t>(live + live / 4 + extra, kMaxPool));
  adj_.resize(live);
  // The placement below is serial and scattered: its fresh pages are faulted in (and
  // zeroed by the kernel) on every thread first.
  parallel_fill(adj_.data(), live, 0u);
  for (size_t f = 0; f < fv_.size(); ++f) {
    if (!falive_[f]) continue;
    for (uint32_t k = 0; k < 3; ++k) {
      const uint32_t v = fv_[f][k];
      adj_[adj_begin_[v] + adj_count_[v]++] = static_cast<uint32_t>(3 * f + k);
    }
  }
}

void PatchDecimator::gather_faces(uint32_t v, std::vector<uint32_t>& out) const {
  out.clear();
  for (uint32_t c : corners_of(v))
    if (falive_[c / 3]) out.push_back(c / 3);
}

void PatchDecimator::lock_nonmanifold_vertices() {
  tbb::enumerable_thread_specific<Scratch> scratch;
  parallel_over_with(pos_.size(), scratch, [&](size_t vi, Scratch& s) {
    const uint32_t v = static_cast<uint32_t>(vi);
    if (vflag_[v] & kLocked) return;
    gather_faces(v, s.faces);
    if (s.faces.empty()) return;
    neighbor_faces(v, s.faces, fv_, s.pairs, s.neighbors);
    bool bad = false;
    // Union-find over the faces around v, joined across manifold edges: more than one
    // fan means a non-manifold vertex.
    const size_t m = s.faces.size();
    s.fb.resize(m);
    std::iota(s.fb.begin(), s.fb.end(), 0u);
    auto find = [&](uint32_t x) {
      while (s.fb[x] != x) x = s.fb[x] = s.fb[s.fb[x]];
      return x;
    };
    size_t components = m;
    for (const auto& [w, count, first] : s.neighbors) {
      if (count > 2) { bad = true; break; }
      if (count != 2) continue;
      uint32_t idx[2];
      int direction[2];
      for (int n = 0; n < 2; ++n) {  // both faces hold the edge, one way or the other
        idx[n] = static_cast<uint32_t>(s.pairs[first + n]);
        const auto& t = fv_[s.faces[idx[n]]];
        for (int k = 0; k < 3; ++k) {
          if (t[k] == v && t[(k + 1) % 3] == w) { direction[n] = 1; break; }
          if (t[k] == w && t[(k + 1) % 3] == v) { direction[n] = -1; break; }
        }
      }
      if (direction[0] == direction[1]) { bad = true; break; }
      const uint32_t ra = find(idx[0]), rb = find(idx[1]);
      if (ra != rb) { s.fb[ra] = rb; --components; }
    }
    if (bad || components > 1) vflag_[v] |= kLocked;
  });
}

void PatchDecimator::compute_quadrics() {
  quadric_.assign(pos_.size(), Quadric{});
  tbb::enumerable_thread_specific<Scratch> scratch;
  parallel_over_with(pos_.size(), scratch, [&](size_t vi, Scratch& s) {
    const uint32_t v = static_cast<uint32_t>(vi);
    // v's faces in ascending global id: the canonical order of every per-vertex sum.
    gather_faces(v, s.faces);
    std::sort(s.faces.begin(), s.faces.end(), [&](uint32_t f, uint32_t g) { return fgid_[f] < fgid_[g]; });
    // Each face's normal and unit normal, once: the face quadrics and the fold test
    // read them, and the face across an edge at v is one of v's faces too.
    s.face_normals.resize(s.faces.size());
    Quadric q;
    for (size_t i = 0; i < s.faces.size(); ++i) {
      const auto& t = fv_[s.faces[i]];
      const Vec3 n = triangle_normal(pos_[t[0]], pos_[t[1]], pos_[t[2]]);
      s.face_normals[i] = {n, triangle_plane(n)};
      q += face_quadric(s.face_normals[i].plane, pos_[t[0]]);
    }
    neighbor_faces(v, s.faces, fv_, s.pairs, s.neighbors);
    auto neighbor_of = [&](uint32_t w) {
      return *std::lower_bound(s.neighbors.begin(), s.neighbors.end(), w,
                               [](const Neighbor& x, uint32_t y) { return x.vertex < y; });
    };
    for (size_t i = 0; i < s.faces.size(); ++i) {
      const uint32_t f = s.faces[i];
      const auto& t = fv_[f];
      const Vec3& n = s.face_normals[i].normal;
      for (int k = 0; k < 3; ++k) {
        const uint32_t p = t[k], r = t[(k + 1) % 3];
        if (p != v && r != v) continue;
        const uint32_t w = p == v ? r : p;
        const Neighbor nw = neighbor_of(w);  // w is in f: listed
        bool constrain = nw.count == 1;
        if (nw.count == 2) {
          // The edge's other face (its index in s.faces).
          const uint32_t g0 = static_cast<uint32_t>(s.pairs[nw.first]);
          const uint32_t g = g0 != i ? g0 : static_cast<uint32_t>(s.pairs[nw.first + 1]);
          constrain = dot(s.face_normals[i].plane.unit, s.face_normals[g].plane.unit) < params_.fold_cos;
        }
        if (constrain) q += boundary_quadric(pos_[p], pos_[r], n, params_.boundary_weight);
      }
    }
    quadric_[v] = q;
  });
}

Vec3 PatchDecimator::edge_position(uint32_t a, uint32_t b) const {
  const bool a_lo = vgid_[a] < vgid_[b];
  return collapse_position(quadric_[a] + quadric_[b], pos_[a_lo ? a : b], pos_[a_lo ? b : a]);
}

EdgeKey PatchDecimator::lme_key(uint32_t v) const {
  const uint32_t w = partner_[v];
  return EdgeKey::of(best_cost_[v], vgid_[v], vgid_[w]);
}

bool PatchDecimator::collapse_valid(uint32_t a, std::span<const uint32_t> corners_a,
                                    std::span<const FanEdge> fan_a, uint32_t b, const Vec3& p, Scratch& s) const {
  // a and b are unlocked, hence manifold: every edge at them has one or two faces.
  // Called in prepare_round, when every list is compact (live faces only).
  const std::span<const uint32_t> corners_b = corners_of(b);
  uint32_t opposite[2];
  int shared = 0;
  for (uint32_t c : corners_a) {
    const auto& t = fv_[c / 3];
    if (!contains(t, b)) continue;
    if (shared == 2) return false;  // non-manifold edge
    opposite[shared++] = t[0] != a && t[0] != b ? t[0] : (t[1] != a && t[1] != b ? t[1] : t[2]);
  }
  if (shared == 0) return false;
  if (shared == 2 && opposite[0] == opposite[1]) return false;
  if (corners_a.size() + corners_b.size() == 2u * shared) return false;  // would erase a component
  // An interior edge joining two border vertices would pinch the surface.
  if (shared == 2 && (vflag_[a] & kBorder) && (vflag_[b] & kBorder)) return false;
  // Link condition: no common neighbour besides the opposite vertices... A vertex's
  // neighbours are the vertices after it in its faces, and the ones before it too
  // when it is on the border (off the border every one before is one after: that is
  // the kBorder flag, up to date for every unlocked live vertex here). fan_a lists
  // a's neighbours (fan_neighbors: the same rule).
  const uint32_t n_a = static_cast<uint32_t>(fan_a.size());
  const bool b_border = (vflag_[b] & kBorder) != 0;
  auto common = [&](uint32_t x) {
    if (x == a || x == opposite[0] || (shared == 2 && x == opposite[1])) return false;
    for (uint32_t j = 0; j < n_a; ++j)
      if (fan_a[j].other == x) return true;
    return false;
  };
  for (uint32_t c : corners_b) {
    const auto& t = fv_[c / 3];
    const uint32_t slot = c % 3;
    if (common(t[(slot + 1) % 3]) || (b_border && common(t[(slot + 2) % 3]))) return false;
  }
  // ...and the links of a and b share no edge (a tetrahedron-like pocket).
  if (shared == 2) {
    const uint32_t c = opposite[0], d = opposite[1];
    bool in_a = false, in_b = false;
    for (uint32_t corner : corners_a) in_a |= contains(fv_[corner / 3], c) && contains(fv_[corner / 3], d);
    for (uint32_t corner : corners_b) in_b |= contains(fv_[corner / 3], c) && contains(fv_[corner / 3], d);
    if (in_a && in_b) return false;
  }
  // Geometry: no face may flip or become (more) degenerate...
  const double fold_limit = params_.new_fold_cos;
  for (int side = 0; side < 2; ++side) {
    const uint32_t other = side ? a : b;
    auto& fan = s.fold[side];
    fan.clear();
    for (uint32_t c : side ? corners_b : corners_a) {
      const auto& t = fv_[c / 3];
      const uint32_t slot = c % 3;
      const Vec3 &p0 = pos_[t[0]], &p1 = pos_[t[1]], &p2 = pos_[t[2]];
      if (contains(t, other)) continue;  // removed by the collapse
      const Vec3 q0 = slot == 0 ? p : p0, q1 = slot == 1 ? p : p1, q2 = slot == 2 ? p : p2;
      const Vec3 n_old = triangle_normal(p0, p1, p2), n_new = triangle_normal(q0, q1, q2);
      if (below_quality(q0, q1, q2, n_new, params_.min_face_quality) &&
          triangle_quality(q0, q1, q2, n_new) < triangle_quality(p0, p1, p2, n_old))
        return false;
      const double old_len2 = dot(n_old, n_old);
      if (old_len2 > 0.0) {
        const double d = dot(n_old, n_new);
        if (d <= 0.0) return false;
        if (d * d < params_.min_normal_cos * params_.min_normal_cos * old_len2 * dot(n_new, n_new)) return false;
      }
      if (fold_limit > -1.0) fan.push_back({n_new, t[kPrevSlot[slot]], t[kNextSlot[slot]]});
    }
  }
  // ...nor fold two faces onto each other where nothing was folded: faces that share an
  // edge at the kept vertex after the collapse (within a's or b's fan, or across (p, c)
  // for an opposite vertex c) may not have normals whose cosine is below new_fold_cos
  // unless a's or b's fan held such a pair before. Per-face turns of up to 78 degrees do
  // not bound it: over several collapses they folded a face back onto its neighbours
  // (28 runs on generated meshes, bench/flips.sh: 29 flipped faces, 8 with this check).
  // Where the surface is folded already (scans' fins, a thin part's rim) collapses go on
  // as before: comparing each pair with its own old fold instead kept the dragon at 0.1%
  // from its target. Reads the faces of a and b, as the rest: radius 1.
  if (fold_limit > -1.0) {
    const double limit2 = fold_limit * fold_limit;
    auto folded = [&](const Vec3& x, const Vec3& y) {
      const double d = dot(x, y);
      // Symmetric in x and y to the bit (the product of the lengths first): both ends of
      // an edge must find the same validity.
      if (fold_limit <= 0.0) return d < 0.0 && d * d > limit2 * (dot(x, x) * dot(y, y));
      const double lengths = dot(x, x) * dot(y, y);
      return lengths > 0.0 && d < fold_limit * std::sqrt(lengths);
    };
    // Around each endpoint, surviving faces i and j share the edge (endpoint, i.to =
    // j.from); the fan is manifold, so each face has one such j at most.
    bool folds = false;
    for (const auto& fan : s.fold)
      for (size_t i = 0; i < fan.size() && !folds; ++i)
        for (const auto& fj : fan)
          if (fan[i].to == fj.from) {
            folds = folded(fan[i].normal, fj.normal);
            break;
          }
    // Across (p, c) for each opposite vertex c, a's surviving face at edge (a, c) and b's
    // at (b, c) become neighbours.
    for (int k = 0; k < shared && !folds; ++k) {
      const Scratch::FanFace *at_a = nullptr, *at_b = nullptr;
      for (const auto& f : s.fold[0])
        if (f.to == opposite[k] || f.from == opposite[k]) at_a = &f;
      for (const auto& f : s.fold[1])
        if (f.to == opposite[k] || f.from == opposite[k]) at_b = &f;
      folds = at_a && at_b && folded(at_a->normal, at_b->normal);
    }
    if (!folds) return true;
    // Rarely reached: was any pair of a's or b's faces folded before?
    for (const std::span<const uint32_t> corners : {corners_a, corners_b})
      for (uint32_t ci : corners) {
        const auto& ti = fv_[ci / 3];
        for (uint32_t cj : corners) {
          const auto& tj = fv_[cj / 3];
          if (ti[kNextSlot[ci % 3]] != tj[kPrevSlot[cj % 3]]) continue;
          if (folded(triangle_normal(pos_[ti[0]], pos_[ti[1]], pos_[ti[2]]),
                     triangle_normal(pos_[tj[0]], pos_[tj[1]], pos_[tj[2]])))
            return true;
          break;
        }
      }
    return false;
  }
  return true;
}

void PatchDecimator::refresh_best(uint32_t v, Scratch& s, bool near_touched_only, const EdgeKey* cut) {
  if ((vflag_[v] & kDead) || immovable(v)) {
    best_[v] = kNone;
    return;
  }
  // Near-touched: v's own faces and edge costs are unchanged; only edges to touched
  // neighbours can have changed validity. The cached best stays unless one of them is
  // now valid and smaller (or the cached best itself leads to a touched vertex).
  EdgeKey bound = EdgeKey::below_all_of(std::numeric_limits<double>::infinity());
  const uint32_t b0 = best_[v];
  if (near_touched_only && b0 != kNone && touched_[b0]) near_touched_only = false;
  if (near_touched_only && b0 != kNone)
    bound = EdgeKey::of(best_cost_[v], vgid_[v], vgid_[b0]);
  if (!near_touched_only) {
    best_[v] = kNone;
    best_cost_[v] = 0.0;
  }
  // prepare_round compacted every list that lost a face: all are live here.
  const std::span<const uint32_t> corners = corners_of(v);
  fan_neighbors(v, corners, s);
  // Every neighbour's id is read below, and often its position and quadric (an
  // unknown cost): start all their loads before the first is needed (session 10:
  // -4.5% CPU on the 2M blob; packing them into one record was slower).
  for (const FanEdge& e : s.fan()) {
    __builtin_prefetch(&vgid_[e.other]);
    __builtin_prefetch(&pos_[e.other]);
    const char* q = reinterpret_cast<const char*>(&quadric_[e.other]);
    __builtin_prefetch(q);
    __builtin_prefetch(q + sizeof(Quadric) - 1);
  }
  s.options.clear();
  const bool charged = params_.deviation_weight > 0.0;
  for (const auto& [w, corner, twin] : s.fan()) {
    if (immovable(w) || (near_touched_only && !touched_[w])) continue;
    // Built in place, field by field: a braced temporary was assembled on the stack
    // from 8-byte stores and copied with 16-byte loads, which cannot be forwarded from
    // those stores (a stall per option); the position likewise.
    Scratch::Option& o = s.options.emplace_back();
    // Unknown costs start from their quadric part, a lower bound of the cost: the
    // deviation part is computed only for options that could still win.
    // A cached quadric part needs no position until the option is charged.
    const CachedCost known = cached_cost(v, w, corner, twin);
    bool has_position = false;
    double cost = known.cost;
    if (std::isnan(cost)) {
      cost = quadric_cost(v, w, corner, twin, o.position);
      has_position = true;
    }
    const EdgeKey key = EdgeKey::of(cost, vgid_[v], vgid_[w]);
    if (cost == kSkipEdge || !(key < bound)) {
      s.options.pop_back();
      continue;
    }
    o.key.cost = key.cost;
    o.key.gid_lo = key.gid_lo;
    o.key.gid_hi = key.gid_hi;
    o.other = w;
    o.corner = corner;
    o.twin = twin;
    o.exact = known.full || !charged;
    o.has_position = has_position;
  }
  // The smallest valid key. An option whose key is only a lower bound gets its exact
  // cost when it is the smallest left; an exact one is checked for validity when it is
  // the smallest left, so the first valid one wins (keys of distinct edges differ).
  bool checked = false;  // some edge at v was checked (and found invalid)
  while (!s.options.empty()) {
    size_t i = 0;
    for (size_t j = 1; j < s.options.size(); ++j)
      if (s.options[j].key < s.options[i].key) i = j;
    Scratch::Option& o = s.options[i];
    // Every edge at v is above the round's known cut (the smallest key, exact or a lower
    // bound, is), so v's best edge is too: it can neither be collapsed nor block a
    // candidate this round. Left stale (no best, so no LME) and refreshed in full by a
    // later round. Decided before charging the smallest option: its lower bound is
    // above the cut already.
    if (cut && !near_touched_only && !checked && *cut < o.key) {
      dirty_[v] = kDirtyStale;
      best_cost_[v] = o.key.cost;  // the floor of v's edge costs (see prepare())
      return;
    }
    if (!o.exact) {
      if (!o.has_position) {
        // The same function of the same inputs as quadric_cost's position: the same bits.
        o.position = edge_position(v, o.other);
        o.has_position = true;
      }
      o.key.cost = edge_cost(v, o.other, o.corner, o.twin, o.key.cost, o.position, s);
      o.exact = true;
      if (o.key.cost != kSkipEdge && o.key < bound) continue;
    } else {
      checked = true;
      if (edge_valid(v, corners, s.fan(), o.other, o.corner, o.twin, o.has_position ? &o.position : nullptr, s)) {
        best_[v] = o.other;
        best_cost_[v] = o.key.cost;
        return;
      }
    }
    o = s.options.back();
    s.options.pop_back();
  }
}

bool PatchDecimator::edge_valid(uint32_t v, std::span<const uint32_t> corners_v,
                                std::span<const FanEdge> fan_v, uint32_t w, uint32_t corner,
                                uint32_t twin, const Vec3* position, Scratch& s) {
  // collapse_valid(v, .., w, p) == collapse_valid(w, .., v, p) (every test is symmetric
  // in the endpoints, and p is the edge's position either way), a function of both
  // endpoints' faces, border flags and their vertices' positions: all of which change
  // only when an endpoint is touched, and then prepare() forgets the edge's validity
  // (it forgets it in every face of a touched vertex, which hold both corners of each
  // of its edges). The edge's smaller corner holds it, so both ends find it.
  const uint32_t at = twin == kNone ? corner : std::min(corner, twin);
  const unsigned shift = kValidityShift[at % 3];
  const uint8_t known = (load_face(falive_, at / 3) >> shift) & 3u;
  if (known) return known == kEdgeValid;
  // The same function of the same inputs as quadric_cost's position: the same bits.
  s.scanned += corners_v.size() + adj_count_[w];
  ++s.checked;
  const bool valid = collapse_valid(v, corners_v, fan_v, w, position ? *position : edge_position(v, w), s);
  std::atomic_ref<uint8_t>(falive_[at / 3])
      .fetch_or(static_cast<uint8_t>((valid ? kEdgeValid : kEdgeInvalid) << shift), std::memory_order_relaxed);
  return valid;
}

// Inlined into refresh_best, its only caller (a call per edge was a tenth of its cost).
[[gnu::always_inline]] inline PatchDecimator::CachedCost PatchDecimator::cached_cost(uint32_t v, uint32_t w, uint32_t corner,
                                                       uint32_t twin) const {
  // The cost depends only on both endpoints' quadrics, positions and faces (with their
  // vertices' positions); its quadric part only on the quadrics and positions.
  // Quadrics and positions change only at a collapse's kept vertex, whose edges'
  // corners collapse() resets; faces change only within the kept vertex's first ring
  // (the touched vertices), whose edges' full costs prepare() resets when the cost has
  // a deviation charge. So a cached value is the value recomputing would give, bit for
  // bit (both ends and both corners of an edge compute the same).
  const bool charged = params_.deviation_weight > 0.0;
  if (twin == kNone || !charged) {
    // Without a charge both corners hold the cost (either may be reset by collapse()).
    const double known = load_cost(corner_cost_, corner);
    if (!std::isnan(known) || twin == kNone)
      return {is_lower_bound(known) ? -known : known, is_full_cost(known)};
    const double other = load_cost(corner_cost_, twin);
    return {other, !std::isnan(other)};
  }
  const bool v_lo = vgid_[v] < vgid_[w];
  const double full = load_cost(corner_cost_, v_lo ? corner : twin);
  if (!std::isnan(full)) return {full, true};
  const double lower = load_cost(corner_cost_, v_lo ? twin : corner);
  return {is_lower_bound(lower) ? -lower : kUnknownCost, false};
}

double PatchDecimator::quadric_cost(uint32_t v, uint32_t w, uint32_t corner, uint32_t twin,
                                    Vec3& position) {
  const Vec3 p = edge_position(v, w);
  position = p;
  double cost = quadric_error(quadric_[v] + quadric_[w], p);
  const bool finite = std::isfinite(cost) && std::isfinite(p[0] + p[1] + p[2]);
  if (!finite) cost = kSkipEdge;
  // Without a charge the quadric part is the cost; a skipped edge stays skipped.
  if (!finite || params_.deviation_weight <= 0.0) {
    store_cost(corner_cost_, corner, cost);
    if (twin != kNone) store_cost(corner_cost_, twin, cost);
  } else {
    // The lower bound goes to the corner the full cost does not use (see is_lower_bound).
    const bool v_lo = vgid_[v] < vgid_[w];
    store_cost(corner_cost_, twin == kNone || !v_lo ? corner : twin, -cost);
  }
  return cost;
}

double PatchDecimator::edge_cost(uint32_t v, uint32_t w, uint32_t corner, uint32_t twin,
                                 double quadric, const Vec3& position, Scratch& s) {
  const bool v_lo = vgid_[v] < vgid_[w];
  s.scanned += adj_count_[v] + adj_count_[w];
  ++s.charged;
  double cost = quadric + params_.deviation_weight * (v_lo ? deviation(v, w, position, s)
                                                           : deviation(w, v, position, s));
  if (!std::isfinite(cost)) cost = kSkipEdge;
  // Only the smaller-gid end's corner: the other keeps the quadric part.
  store_cost(corner_cost_, twin == kNone || v_lo ? corner : twin, cost);
  return cost;
}

double PatchDecimator::deviation(uint32_t a, uint32_t b, const Vec3& p, Scratch& s) const {
  // a has the smaller global id, so both ends of the edge compute the same bits. Corner
  // lists are not in a canonical order after collapses (nor equal to a patch's), so
  // each endpoint's area is summed in ascending order of the face areas (the fan's
  // nearest distance is a minimum: no order). The sum is cached per vertex
  // (face_area_) until prepare() finds the vertex touched.
  FanDeviation fan(pos_[a], pos_[b]);
  double area[2] = {0.0, 0.0};
  for (int side = 0; side < 2; ++side) {
    const uint32_t x = side == 0 ? a : b, other = side == 0 ? b : a;
    std::atomic_ref<double> cached(const_cast<double&>(face_area_[x]));
    area[side] = cached.load(std::memory_order_relaxed);
    const bool sum_areas = std::isnan(area[side]);
    s.areas.clear();
    for (uint32_t c : corners_of(x)) {
      const auto& t = fv_[c / 3];
      if (sum_areas) {
        const Vec3 n = triangle_normal(pos_[t[0]], pos_[t[1]], pos_[t[2]]);
        s.areas.push_back(0.5 * std::sqrt(dot(n, n)));
      }
      if (contains(t, other)) continue;  // removed by the collapse
      // The face moved to the collapse: x (at slot c % 3; `other` is not in it) at p.
      const uint32_t slot = c % 3;
      fan.add(slot == 0 ? p : pos_[t[0]], slot == 1 ? p : pos_[t[1]], slot == 2 ? p : pos_[t[2]]);
    }
    if (sum_areas) {
      std::sort(s.areas.begin(), s.areas.end());
      area[side] = 0.0;
      for (double y : s.areas) area[side] += y;
      cached.store(area[side], std::memory_order_relaxed);
    }
  }
  return fan.charge(area[0], area[1]);
}

void PatchDecimator::fan_links(std::span<const uint32_t> corners, Scratch& s) const {
  const size_t n = corners.size();
  if (s.next.size() < n) {  // only grows: resize() is a call even when the size is right
    s.next.resize(n);
    s.prev.resize(n);
  }
  for (size_t i = 0; i < n; ++i) {
    const uint32_t c = corners[i], slot = c % 3;
    const auto& t = fv_[c / 3];
    s.next[i] = t[kNextSlot[slot]];
    s.prev[i] = t[kPrevSlot[slot]];
  }
}

void PatchDecimator::fan_neighbors(uint32_t v, std::span<const uint32_t> corners, Scratch& s) const {
  // v is unlocked: one consistently oriented fan, so the vertex after v in each face
  // lists every neighbour once, except the first one of a border fan. Each comes with
  // the corner whose edge (corner vertex -> next vertex) joins it to v, and the twin
  // corner of the same edge in the face on its other side (w -> v), if any: both
  // cache the edge's cost.
  const uint32_t n = static_cast<uint32_t>(corners.size());
  if (s.fan_store.size() < 2 * size_t{n}) {  // a border fan lists up to 2n
    s.fan_store.resize(2 * size_t{n});
    s.fan_prev.resize(2 * size_t{n});
  }
  FanEdge* out = s.fan_store.data();
  uint32_t* prev = s.fan_prev.data();
  // fan_prev holds the vertex before v (first n entries) and that corner (prev -> v,
  // next n): the twin loop below then reads no face and divides nothing.
  for (uint32_t i = 0; i < n; ++i) {
    const uint32_t c = corners[i], slot = c % 3, base = c - slot;
    const auto& t = fv_[c / 3];
    out[i] = {t[kNextSlot[slot]], c, kNone};
    prev[i] = t[kPrevSlot[slot]];
    prev[n + i] = base + kPrevSlot[slot];
  }
  uint32_t count = n;
  const bool border = (vflag_[v] & kBorder) != 0;
  s.fan_index.clear();
  for (uint32_t i = 0; i < n; ++i) {
    const uint32_t before = prev[n + i];  // prev -> v
    // The neighbour after v that is prev[i] (the border entries appended at count >= n
    // are not searched).
    const uint32_t at = find_in_fan(n, [&](uint32_t j) { return out[j].other; }, prev[i], s.fan_index);
    if (at != n)
      out[at].twin = before;
    else if (border)
      out[count++] = {prev[i], before, kNone};
  }
  s.fan_size = count;
}

void PatchDecimator::update_border(uint32_t v, Scratch& s) {
  if (vflag_[v] & (kDead | kLocked)) return;
  // v is unlocked (one consistently oriented fan): it is on the border iff the vertex
  // before v in some face is not the vertex after v in any face. v's list is compact.
  const std::span<const uint32_t> corners = corners_of(v);
  fan_links(corners, s);
  const uint32_t n = static_cast<uint32_t>(corners.size());
  bool border = false;
  s.fan_index.clear();
  for (uint32_t i = 0; i < n && !border; ++i)
    border = find_in_fan(n, [&](uint32_t j) { return s.next[j]; }, s.prev[i], s.fan_index) == n;
  vflag_[v] = static_cast<uint8_t>(border ? (vflag_[v] | kBorder) : (vflag_[v] & ~kBorder));
}

void PatchDecimator::compact_list(uint32_t v) {
  uint32_t* list = adj_.data() + adj_begin_[v];
  const uint32_t n = adj_count_[v];
  uint32_t kept = 0;
  for (uint32_t i = 0; i < n; ++i)
    if (load_face(falive_, list[i] / 3)) list[kept++] = list[i];
  adj_count_[v] = kept;
}

void PatchDecimator::compact_storage() {
  // Move live vertices and faces to the front, keeping their relative order, then
  // rebuild the corner lists.
  std::vector<uint32_t> remap(pos_.size(), kNone);
  uint32_t nv = 0;
  for (uint32_t v = 0; v < pos_.size(); ++v) {
    if (vflag_[v] & kDead) continue;
    remap[v] = nv;
    pos_[nv] = pos_[v];
    vgid_[nv] = vgid_[v];
    quadric_[nv] = quadric_[v];
    vflag_[nv] = vflag_[v];
    dirty_[nv] = dirty_[v];
    touched_[nv] = touched_[v];
    best_[nv] = best_[v];
    best_cost_[nv] = best_cost_[v];
    face_area_[nv] = face_area_[v];
    partner_[nv] = partner_[v];
    ++nv;
  }
  pos_.resize(nv);
  vgid_.resize(nv);
  quadric_.resize(nv);
  vflag_.resize(nv);
  dirty_.resize(nv);
  touched_.resize(nv);
  best_.resize(nv);
  best_cost_.resize(nv);
  face_area_.resize(nv);
  partner_.resize(nv);
  for (auto& b : best_) b = b == kNone ? kNone : remap[b];
  for (auto& w : partner_) w = w == kNone ? kNone : remap[w];
  size_t nf = 0;
  for (size_t f = 0; f < fv_.size(); ++f) {
    if (!falive_[f]) continue;
    for (int k = 0; k < 3; ++k) fv_[nf][k] = remap[fv_[f][k]];
    fgid_[nf] = fgid_[f];
    for (int k = 0; k < 3; ++k) corner_cost_[3 * nf + k] = corner_cost_[3 * f + k];
    falive_[nf] = falive_[f];  // alive, with its edges' validity
    if (!fowned_.empty()) fowned_[nf] = fowned_[f];
    ++nf;
  }
  fv_.resize(nf);
  fgid_.resize(nf);
  corner_cost_.resize(3 * nf);
  if (!fowned_.empty()) fowned_.resize(nf);
  falive_.resize(nf);
  for (auto& t : passthrough_)
    for (auto& v : t) v = remap[v];
  rebuild_adjacency(0);
}

void PatchDecimator::prepare_round() { prepare(nullptr); }

void PatchDecimator::prepare_round(const RoundCut& cut) { prepare(&cut.key); }

void PatchDecimator::prepare_owned_summary_round() {
  prepare(nullptr, !fowned_.empty() || std::any_of(vflag_.begin(), vflag_.end(),
                                                   [](uint8_t f) { return !(f & (kOwned | kDead)); }));
  final_ = true;
}

std::vector<uint8_t> PatchDecimator::near_owned() const {
  std::vector<uint8_t> dist(pos_.size(), static_cast<uint8_t>(kOwnedSummaryRadius + 1));
  std::vector<uint32_t> frontier;
  auto seed = [&](uint32_t v) {
    if (dist[v] == 0) return;
    dist[v] = 0;
    frontier.push_back(v);
  };
  for (uint32_t v = 0; v < pos_.size(); ++v)
    if ((vflag_[v] & (kOwned | kDead)) == kOwned) seed(v);
  for (size_t f = 0; f < fv_.size(); ++f)
    if (falive_[f] && (fowned_.empty() || fowned_[f]))
      for (uint32_t v : fv_[f]) seed(v);
  spread_distances(kOwnedSummaryRadius, std::move(frontier), dist);
  for (uint8_t& d : dist) d = d <= kOwnedSummaryRadius;
  return dist;
}

void PatchDecimator::prepare(const EdgeKey* cut, bool near_owned_only) {
  if (final_) throw std::logic_error("PatchDecimator: prepared after prepare_owned_summary_round");
  if (fv_.size() > 4096 && faces_alive_ * 2 < fv_.size()) compact_storage();
  const size_t nv = pos_.size();
  // The touched and dirty vertices are found by their flags, not gathered in lists:
  // in the first rounds every vertex is both, and such lists (4 B per vertex each,
  // twice while they grow) were the largest part of the in-core peak memory.
  tbb::enumerable_thread_specific<Scratch> scratch;
  const bool charged = params_.deviation_weight > 0.0;
  // Some touched vertex may have fallen to kMaxCollapseDegree: its edges are options
  // again, which a stale neighbour's floor did not count.
  std::atomic<bool> degree_fell{false};
  // Touched vertices (the last collapses' first rings; only they can have lost a face):
  // compact their lists, update their border flags, and mark them and their second
  // ring dirty (edges to a touched vertex may have changed validity).
  parallel_over_with(nv, scratch, [&](size_t vi, Scratch& s) {
    if (!touched_[vi]) return;
    const uint32_t v = static_cast<uint32_t>(vi);
    // The cost resets below read v's faces' rows of corner_cost_, whose addresses need
    // no face read: start those loads now, under compact_list's and update_border's.
    if (charged)
      for (uint32_t c : corners_of(v)) {
        const double* row = &corner_cost_[c - c % 3];
        __builtin_prefetch(row);
        __builtin_prefetch(row + 2);
      }
    const bool was_above = adj_count_[v] > kMaxCollapseDegree;  // (dead faces counted too)
    compact_list(v);
    if (was_above && adj_count_[v] <= kMaxCollapseDegree && !degree_fell.load(std::memory_order_relaxed))
      degree_fell.store(true, std::memory_order_relaxed);
    // v's faces, or a vertex of one of them, changed (a collapse touches its kept
    // vertex's whole first ring): the area of v's faces is to be summed again.
    face_area_[v] = kUnknownCost;
    update_border(v, s);
    raise_flag(dirty_[v]);
    for (uint32_t c : corners_of(v)) {
      for (uint32_t x : fv_[c / 3]) raise_dirty(dirty_[x]);
      // v's faces changed, so did the validity of v's edges (and maybe of the face's
      // third edge: forgotten too, which only costs a check).
      forget_validity(falive_, c / 3);
      // v's faces changed, so did the deviation charge of every edge at v: reset its
      // corners v -> next and prev -> v in each face (both corners of v's edges lie in
      // faces of v). The face's third edge joins two other vertices; its charge changed
      // only if one of them is touched too, whose own pass resets it. Quadric parts
      // stay: v's quadric and position did not change unless v was a collapse's kept
      // vertex, whose corners collapse() reset already.
      if (charged)
        for (uint32_t k : {c, c - c % 3 + (c % 3 + 2) % 3})
          if (!is_lower_bound(load_cost(corner_cost_, k))) store_cost(corner_cost_, k, kUnknownCost);
    }
  });
  if (!verify_restored_.empty()) verify_restored_bests();
  // The touched vertices' lists are compact now: the rings below see live faces only.
  const std::vector<uint8_t> near = near_owned_only ? near_owned() : std::vector<uint8_t>();
  // A stale vertex was skipped by a round with a cut >= stale_floor_ because all its
  // edges cost more; while untouched its edge costs stay, so under a cut <= that
  // floor it would be skipped again.
  const bool keep_stale = cut && has_stale_ && !(stale_floor_ < *cut);
  const bool near_degree_fell = degree_fell.load();
  std::atomic<bool> deferred{false};
  // The dirty vertices: every vertex with dirty_ != 0 now (the loop below leaves it
  // non-zero, 1 or stale, at each of them, and writes no other vertex's).
  parallel_over_with(nv, scratch, [&](size_t vi, Scratch& s) {
    if (!dirty_[vi] || (near_owned_only && !near[vi])) return;
    const uint32_t v = static_cast<uint32_t>(vi);
    // A stale vertex has no cached best.
    const bool stale = dirty_[v] >= kDirtyStale;
    // With a deviation charge, an edge's cost also changes when a neighbour is touched:
    // only then do v's costs not stay while v is untouched.
    // So do they when a neighbour's degree fell to kMaxCollapseDegree (a new option).
    // Its smallest edge cost (or lower bound) when it was left stale, kept in
    // best_cost_, is another such floor, for this vertex alone.
    if (stale && cut && !touched_[v] && !((charged || near_degree_fell) && dirty_[v] == kDirtyStaleNearTouched) &&
        (keep_stale || cut->cost < best_cost_[v]))
      return;
    dirty_[v] = 1;
    if (frozen(v)) {
      // No exact decision reads v's best (see frozen()): none, so v is in no LME. Its
      // dirty_ stays set for update_partners, which undoes its old pair.
      best_[v] = kNone;
      ++s.frozen;
      return;
    }
    ++s.refreshed;
    refresh_best(v, s, !touched_[v] && !stale, cut);
    if (dirty_[v] == kDirtyStale && !deferred.load(std::memory_order_relaxed))
      deferred.store(true, std::memory_order_relaxed);
  }, 1024);  // over all vertices: late rounds have few dirty ones
  if (!cut) {
    has_stale_ = false;  // every stale vertex was refreshed
  } else if (deferred.load()) {
    stale_floor_ = keep_stale || !has_stale_ ? *cut : std::min(stale_floor_, *cut);
    has_stale_ = true;
  }
  for (const Scratch& s : scratch) {
    refreshes_ += s.refreshed;
    scanned_faces_ += s.scanned;
    frozen_refreshes_ += s.frozen;
    charges_ += s.charged;
    validity_checks_ += s.checked;
  }
  bests_exact_ = !cut;
  update_partners();
  // Candidates are marked (kCandidate at the LME's end with the smaller global id),
  // then gathered at their exact size in vertex order: per-thread lists grown by
  // push_back and then concatenated held about three times the candidates' memory at
  // the in-core peak. The gathered order does not matter (the sort below orders by
  // key, and keys of distinct edges differ).
  parallel_over(nv, [&](size_t vi) {
    const uint32_t v = static_cast<uint32_t>(vi);
    // The round's refreshes are done: clear v's flags (touched vertices are dirty too)
    // in this sweep rather than one of their own; nothing below reads them.
    if (dirty_[v]) {
      dirty_[v] = dirty_[v] >= kDirtyStale ? kDirtyStale : 0;
      touched_[v] = 0;
    }
    const uint32_t w = partner_[v];
    if (w == kNone || vgid_[v] > vgid_[w]) return;
    const EdgeKey key = lme_key(v);
    if (cut && *cut < key) return;  // not collapsed this round, whatever its status
    for (uint32_t end : {v, w}) {
      for (uint32_t c : corners_of(end)) {
        for (uint32_t u : fv_[c / 3]) {
          if (u == v || u == w || partner_[u] == kNone) continue;
          if (lme_key(u) < key) return;  // a smaller LME within one ring
        }
      }
    }
    vflag_[v] |= kCandidate;  // only v's own flag: no other iteration writes it
  }, 256);
  // In parallel (the two serial sweeps over every vertex were prepare's share of the
  // time one core idled: 345 of the 2,913 lone samples of 5M faces at 512M,
  // bench/serial_samples.py), in the same vertex order.
  release_memory(candidates_);
  parallel_select(
      nv, [&](size_t v) { return (vflag_[v] & kCandidate) != 0; }, [&](size_t total) { candidates_.resize(total); },
      [&](size_t vi, size_t rank) {
        const uint32_t v = static_cast<uint32_t>(vi);
        const uint32_t w = partner_[v];
        uint32_t shared = 0;
        for (uint32_t c : corners_of(v)) shared += contains(fv_[c / 3], w);
        candidates_[rank] = {lme_key(v), v, w, shared, (vflag_[v] & kOwned) != 0, true};
      });
  // Cleared after the selection, whose test must not change under it.
  parallel_over(candidates_.size(), [&](size_t i) { vflag_[candidates_[i].keep] &= ~kCandidate; }, 4096);
  trust_dist_.clear();
  if (untrusted_count_ > 0) {
    // Distances now, in the mesh the round's collapses start from: they decide which
    // candidates are exact and, in apply_cut, how far untrusted state spreads.
    untrusted_distances(kTrustSpread, trust_dist_);
    for (auto& c : candidates_)
      c.exact = trust_dist_[c.keep] > kDecisionRadius && trust_dist_[c.remove] > kDecisionRadius;
  }
  tbb::parallel_sort(candidates_.begin(), candidates_.end(),
                     [](const Candidate& x, const Candidate& y) { return x.key < y.key; });
}

void PatchDecimator::update_partners() {
  // partner_[v] = best_[v] when that edge is best at both ends, else kNone: a function
  // of best_ at v and at best_[v]. best_ changed only at the dirty vertices (dirty_ !=
  // 0: the refreshed ones, and stale ones left without a best; every other write to
  // best_ is followed by a refresh), so only pairs with
  // an end there can change: undo their old pairs (partner_ is symmetric), then pair
  // the ends of the mutual best edges among them. The result is the full recomputation's.
  auto store = [&](uint32_t v, uint32_t w) {
    std::atomic_ref<uint32_t>(partner_[v]).store(w, std::memory_order_relaxed);
  };
  parallel_over(partner_.size(), [&](size_t i) {
    if (!dirty_[i]) return;
    const uint32_t v = static_cast<uint32_t>(i);
    const uint32_t old = std::atomic_ref<uint32_t>(partner_[v]).load(std::memory_order_relaxed);
    if (old != kNone) store(old, kNone);
    store(v, kNone);
  });
  parallel_over(partner_.size(), [&](size_t i) {
    if (!dirty_[i]) return;
    const uint32_t v = static_cast<uint32_t>(i);
    const uint32_t w = best_[v];
    if (w != kNone && best_[w] == v) {
      store(v, w);
      store(w, v);
    }
  });
}

void PatchDecimator::set_params(const DecimateParams& params) {
  if (params.deviation_weight != params_.deviation_weight)
    std::fill(corner_cost_.begin(), corner_cost_.end(), kUnknownCost);
  params_ = params;
  for (uint8_t& f : falive_) f = f ? kFaceAlive : 0;  // the guards changed: validity unknown
  std::fill(dirty_.begin(), dirty_.end(), uint8_t{1});
  std::fill(touched_.begin(), touched_.end(), uint8_t{1});
  candidates_.clear();
  bests_exact_ = false;
  release_memory(verify_restored_);  // refreshed under the new params, not restored
}

RoundSummary PatchDecimator::summarize() const {
  RoundSummary s;
  for (const auto& c : candidates_) {
    if (!c.owned) continue;
    if (!c.exact) {
      ++s.inexact_candidates;
      continue;
    }
    s.faces_per_bin[cost_bin(c.key.cost)] += c.faces_removed;
    s.candidate_faces += c.faces_removed;
    ++s.candidates;
  }
  return s;
}

std::vector<Candidate> PatchDecimator::owned_candidates() const {
  std::vector<Candidate> out;
  for (const auto& c : candidates_)
    if (c.owned && c.exact) out.push_back(c);
  return out;
}

uint64_t PatchDecimator::owned_face_count() const {
  uint64_t n = 0;
  if (fowned_.empty()) {
    n = faces_alive_;
  } else {
    for (size_t f = 0; f < fv_.size(); ++f) n += falive_[f] && fowned_[f];
  }
  for (uint8_t o : passthrough_owned_) n += o != 0;
  return n;
}

void PatchDecimator::untrusted_distances(int radius, std::vector<uint8_t>& dist) const {
  dist.resize(pos_.size());
  parallel_over(pos_.size(), [&](size_t v) {
    dist[v] = (vflag_[v] & (kUntrusted | kDead)) == kUntrusted ? 0 : static_cast<uint8_t>(radius + 1);
  }, 4096);
  std::vector<uint32_t> frontier;
  for (uint32_t v = 0; v < pos_.size(); ++v)
    if (dist[v] == 0) frontier.push_back(v);
  spread_distances(radius, std::move(frontier), dist);
}

void PatchDecimator::spread_distances(int radius, std::vector<uint32_t> frontier, std::vector<uint8_t>& dist) const {
  // Level by level, each level's frontier in parallel: a vertex's distance is the
  // smallest level that reaches it, whichever thread or order does (the frontiers'
  // order is free; each vertex is claimed once, by a compare-exchange).
  tbb::enumerable_thread_specific<std::vector<uint32_t>> reached;
  for (uint8_t d = 1; d <= radius && !frontier.empty(); ++d) {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, frontier.size(), 256), [&](const tbb::blocked_range<size_t>& r) {
      std::vector<uint32_t>& next = reached.local();
      for (size_t i = r.begin(); i < r.end(); ++i)
        for (uint32_t c : corners_of(frontier[i])) {
          if (!falive_[c / 3]) continue;
          for (uint32_t u : fv_[c / 3]) {
            std::atomic_ref<uint8_t> at(dist[u]);
            uint8_t seen = at.load(std::memory_order_relaxed);
            while (seen > d)
              if (at.compare_exchange_weak(seen, d, std::memory_order_relaxed)) {
                next.push_back(u);
                break;
              }
          }
        }
    });
    frontier.clear();
    for (auto& next : reached) {
      frontier.insert(frontier.end(), next.begin(), next.end());
      next.clear();
    }
  }
}

void PatchDecimator::spread_untrusted(int radius) {
  std::vector<uint8_t> dist;
  untrusted_distances(radius, dist);
  for (uint32_t v = 0; v < pos_.size(); ++v)
    if (dist[v] <= radius) vflag_[v] |= kUntrusted;
}

void PatchDecimator::collapse(const Candidate& c, uint64_t list_at) {
  const uint32_t k = c.keep, r = c.remove;
  const Vec3 p = edge_position(k, r);
  for (uint32_t corner : corners_of(r)) {
    const uint32_t f = corner / 3;
    if (!falive_[f]) continue;
    if (contains(fv_[f], k))
      falive_[f] = 0;
    else
      fv_[f][corner % 3] = k;
  }
  // k's new list: its own corners, then r's (the removed faces too: apply_cut refreshes
  // their vertices; the next prepare_round drops them), in the space apply_cut reserved.
  uint32_t* list = adj_.data() + list_at;
  const std::span<const uint32_t> own = corners_of(k), taken = corners_of(r);
  std::copy(own.begin(), own.end(), list);
  std::copy(taken.begin(), taken.end(), list + own.size());
  adj_begin_[k] = static_cast<uint32_t>(list_at);  // < adj_.size() <= kMaxPool
  adj_count_[k] = static_cast<uint32_t>(own.size() + taken.size());
  adj_count_[r] = 0;
  pos_[k] = p;
  quadric_[k] += quadric_[r];
  // Every edge at k has a new cost: the corners of k (edge k -> next) and of the
  // vertex before k (edge prev -> k). The third edge of the face keeps its cost.
  for (uint32_t corner : corners_of(k)) {
    const uint32_t f = corner / 3, slot = corner % 3;
    corner_cost_[corner] = corner_cost_[3 * f + (slot + 2) % 3] = kUnknownCost;
  }
  vflag_[k] |= vflag_[r] & kUntrusted;
  vflag_[r] |= kDead;
  best_[r] = kNone;
}

uint64_t PatchDecimator::apply_cut(const RoundCut& cut) {
  if (final_) throw std::logic_error("PatchDecimator: apply_cut after prepare_owned_summary_round");
  // The chosen candidates, kept in place at the front of candidates_ (no copy).
  size_t chosen_count = 0;
  for (const auto& c : candidates_) {
    if (cut.key < c.key) break;
    if (cut.single_face_only && c.faces_removed != 1) continue;
    if (!c.owned && !c.exact && trust_dist_[c.keep] <= kDecisionRadius &&
        trust_dist_[c.remove] <= kDecisionRadius) {
      // Both ends within kDecisionRadius rings of untrusted state: the collapse would
      // change faces within kTrustSpread rings only, all untrusted (and, not owned,
      // frozen) from this round on. One end further out (an edge from ring 4 to ring
      // 5) still collapses: its decision reads the untrusted set's outer ring only by
      // position, which is the global one, and its collapse reaches ring 6, trusted.
      ++frozen_collapses_;
      continue;
    }
    candidates_[chosen_count++] = c;
  }
  candidates_.resize(chosen_count);
  const std::vector<Candidate>& chosen = candidates_;
  if (untrusted_count_ > 0) {
    // Decisions within kDecisionRadius rings of untrusted state may be wrong, and their
    // collapses change faces one ring further: all of that is untrusted from now on.
    if (trust_dist_.size() != pos_.size())
      throw std::logic_error("PatchDecimator::apply_cut without prepare_round");
    for (uint32_t v = 0; v < pos_.size(); ++v) {
      if (trust_dist_[v] > kTrustSpread) continue;
      // Newly frozen: the next prepare drops its best (and LME pair), even when nothing
      // near it changes.
      if ((vflag_[v] & (kUntrusted | kOwned | kDead)) == 0) raise_flag(dirty_[v]);
      vflag_[v] |= kUntrusted;
    }
    trust_dist_.clear();
  }
  // Each collapse writes the kept vertex's merged corner list to its own slice of the
  // list pool, placed by a prefix sum (so the pool never reallocates mid-loop).
  std::vector<uint64_t> list_at(chosen.size() + 1, 0);
  for (size_t i = 0; i < chosen.size(); ++i)
    list_at[i + 1] = list_at[i] + adj_count_[chosen[i].keep] + adj_count_[chosen[i].remove];
  if (adj_.size() + list_at.back() > std::min<uint64_t>(adj_.capacity(), kMaxPool))
    rebuild_adjacency(list_at.back());
  const uint64_t pool_end = adj_.size();
  adj_.resize(pool_end + list_at.back());
  // Candidates are >= 2 rings apart: their collapses touch disjoint faces and lists.
  parallel_over(chosen.size(), [&](size_t i) { collapse(chosen[i], pool_end + list_at[i]); }, 64);
  uint64_t removed = 0;
  for (const auto& c : chosen) removed += c.faces_removed;
  faces_alive_ -= removed;
  if (untrusted_count_ > 0) {
    untrusted_count_ = 0;
    for (uint8_t f : vflag_) untrusted_count_ += (f & (kUntrusted | kDead)) == kUntrusted;
  }
  // Everything whose best edge may have changed lies within 2 rings of a kept vertex.
  // Here the first ring becomes touched (its faces changed), including the vertices of
  // the faces this collapse removed, so they are refreshed even when no live face joins
  // them to k any more; the next prepare marks the second ring from the touched ones.
  parallel_over(chosen.size(), [&](size_t i) {
    const uint32_t k = chosen[i].keep;
    raise_flag(touched_[k]);
    for (uint32_t c1 : corners_of(k))
      for (uint32_t u : fv_[c1 / 3]) raise_flag(touched_[u]);
  }, 64);
  candidates_.clear();
  bests_exact_ = false;
  return removed;
}

PatchOutput PatchDecimator::extract(bool owned_only, OutputOrder order) const {
  // Every pass in parallel (the extract ran on one core): ordered selections
  // (parallel_select) and per-element writes give the serial loops' arrays.
  // Its scratch arrays are UninitializedVectors and the output's are sized by
  // parallel_resize: all are fresh pages in every patch (parallel_fill.hpp).
  PatchOutput out;
  UninitializedVector<std::pair<uint64_t, std::array<uint32_t, 3>>> faces;
  std::vector<uint32_t> passthrough_kept;
  for (uint32_t i = 0; i < passthrough_.size(); ++i)
    if (!owned_only || passthrough_owned_[i]) passthrough_kept.push_back(i);
  const size_t live = parallel_select(
      fv_.size(), [&](size_t f) { return falive_[f] && (!owned_only || fowned_.empty() || fowned_[f]); },
      [&](size_t total) { faces.resize(total + passthrough_kept.size()); },
      [&](size_t f, size_t i) { faces[i] = {fgid_[f], fv_[f]}; });
  for (size_t i = 0; i < passthrough_kept.size(); ++i)
    faces[live + i] = {passthrough_gids_[passthrough_kept[i]], passthrough_[passthrough_kept[i]]};
  // Face and vertex gids are unique: the radix sorts give the comparison sorts' order
  // (the vertices' one compared gids through vgid_, a cache miss per comparison).
  const bool sorted = order == OutputOrder::by_gid;
  if (sorted) radix_sort_by_key(faces, [](const auto& x) { return x.first; });
  UninitializedVector<uint8_t> used;
  parallel_assign(used, pos_.size(), uint8_t{0});
  parallel_over(faces.size(), [&](size_t f) {
    for (uint32_t v : faces[f].second) raise_flag(used[v]);
  }, 4096);
  // The output's vertices (local ids), in gid order (the pairs, 16 B a vertex, go
  // before the output arrays are made: the finish's lease, kInCoreBytesPerExtraVertex,
  // counts what the extract holds at its peak) or in local order.
  UninitializedVector<uint32_t> verts;
  auto used_vertex = [&](size_t v) { return used[v] != 0; };
  if (sorted) {
    UninitializedVector<std::pair<uint64_t, uint32_t>> by_gid;
    parallel_select(
        pos_.size(), used_vertex, [&](size_t total) { by_gid.resize(total); },
        [&](size_t v, size_t i) { by_gid[i] = {vgid_[v], uint32_t(v)}; });
    release_memory(used);
    radix_sort_by_key(by_gid, [](const auto& x) { return x.first; });
    verts.resize(by_gid.size());
    parallel_over(verts.size(), [&](size_t i) { verts[i] = by_gid[i].second; }, 4096);
  } else {
    parallel_select(
        pos_.size(), used_vertex, [&](size_t total) { verts.resize(total); },
        [&](size_t v, size_t i) { verts[i] = uint32_t(v); });
    release_memory(used);
  }
  const size_t kept = verts.size();
  UninitializedVector<uint32_t> remap;
  parallel_assign(remap, pos_.size(), kNone);
  auto size_each = [&](auto&... arrays) { (parallel_resize(arrays, kept), ...); };
  size_each(out.positions, out.vertex_gids, out.quadrics, out.locked, out.degrees, out.trusted);
  const bool bests = bests_exact_ && (owned_only || !final_);
  if (bests) size_each(out.best_gids, out.best_costs);
  parallel_over(kept, [&](size_t i) {
    const uint32_t v = verts[i];
    remap[v] = uint32_t(i);
    out.positions[i] = pos_[v];
    out.vertex_gids[i] = vgid_[v];
    out.quadrics[i] = quadric_[v];
    out.locked[i] = (vflag_[v] & kLocked) ? 1 : 0;
    uint32_t degree = 0;
    for (uint32_t c : corners_of(v)) degree += falive_[c / 3] != 0;
    out.degrees[i] = degree;
    out.trusted[i] = (vflag_[v] & kUntrusted) ? 0 : 1;
    if (bests) {
      // trust_dist_ is the last prepare's (rings to the untrusted set, capped above
      // kTrustSpread >= kBestRadius; empty: nothing untrusted).
      const bool exact = trust_dist_.empty() || trust_dist_[v] > kBestRadius;
      const uint32_t w = best_[v];
      out.best_gids[i] = !exact ? kBestUnknown : w == kNone ? kBestNone : vgid_[w];
      out.best_costs[i] = exact && w != kNone ? best_cost_[v] : 0.0;
    }
  }, 2048);
  out.untrusted_vertices = count_where(kept, [&](size_t i) { return out.trusted[i] == 0; });
  release_memory(verts);
  // Faces with a repeated vertex count once for each distinct vertex.
  for (const auto& t : passthrough_)
    for (int k = 0; k < 3; ++k)
      if (remap[t[k]] != kNone && (k == 0 || t[k] != t[0]) && (k < 2 || t[2] != t[1]))
        ++out.degrees[remap[t[k]]];
  parallel_resize(out.faces, faces.size());
  parallel_resize(out.face_gids, faces.size());
  parallel_over(faces.size(), [&](size_t i) {
    const auto& [gid, t] = faces[i];
    out.faces[i] = {remap[t[0]], remap[t[1]], remap[t[2]]};
    out.face_gids[i] = gid;
  }, 4096);
  return out;
}

}  // namespace qemflow::nodes
