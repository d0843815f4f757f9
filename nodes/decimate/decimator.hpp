#pragma once
// PatchDecimator: the local-minimal-edge (LME) round machinery of DESIGN.md §3, run on
// one patch (in core: one patch holding the whole mesh, everything owned and trusted).
//
// Contract
// - Input: vertices (position, global id; optional flags `incomplete`, `owned`,
//   `locked`; optional quadric) and triangles (local vertex refs, global face id,
//   optional `owned` flag). Vertex quadrics, when not given, are summed in ascending
//   global face id (area-weighted face planes first, then boundary/fold-edge planes in
//   face order and corner order), so any patch holding a vertex's whole 1-ring computes
//   the same bits.
// - Local ids (Candidate::keep / remove, vertex_gid(), trusted()) are the decimator's
//   own numbering, not the input's: vertices along a Z-order curve of their positions,
//   faces by their first vertex (cache locality). No result depends on it.
// - A round has three steps, each deterministic and independent of thread count:
//     prepare_round()  refresh every vertex's best (cheapest valid) edge where the mesh
//                      changed, find the LMEs and the independent set (candidates);
//     summarize()      a small summary (integer histogram of the owned, exact
//                      candidates' costs, weighted by faces each would remove) that
//                      sums exactly across patches;
//     apply_cut(cut)   collapse every candidate (owned or not) whose key <= cut.
//   The cut comes from plan_epoch()/exact_cut() in cut.hpp, from summed summaries; the
//   epoch schedule (one global decision per E rounds) is in cut.hpp / simplify.hpp.
// - Total order of edges: key = (cost, tie, smaller global id, larger global id), where
//   tie = a hash of the two global ids (EdgeKey), and
//   cost = (Q_a + Q_b)(p) + deviation_weight * collapse_deviation (quadric.hpp) at the
//   collapse position p.
// - best(v): the smallest-key valid edge at v. LME: an edge that is best at both ends.
//   Candidate: an LME smaller than every other LME with an endpoint within one ring
//   of its endpoints. Candidates are then >= 2 rings apart, so their collapses touch
//   disjoint face sets and the round's result does not depend on collapse order.
// - Decision radius (rings around an edge's endpoints; out-of-core halos are sized
//   from it): validity and cost of (a,b) read the faces of a and b and their vertices'
//   positions (1 ring; the cost's deviation charge, quadric.hpp); best(v) reads the validity of all edges at v (2 rings); LME
//   status of (a,b) reads best(a), best(b) (2 rings); candidate status reads LME status
//   of edges with an endpoint within one ring (1 + 1 + 2 = 4 rings).
//   kDecisionRadius = 4. Quadrics are per-vertex state carried with the vertex
//   (initially they read the vertex's own faces, fold test included).
// - A collapse keeps the vertex with the smaller global id at the collapse position,
//   with quadric Q_keep + Q_remove. Surviving faces keep their global ids.
// - Trust (out-of-core patches; in core nothing is untrusted and this costs nothing):
//   a vertex is UNTRUSTED when its state (position, quadric, lock, incident faces)
//   may differ from the global mesh's. Initially untrusted: `incomplete` vertices (fan
//   not whole in the patch) and, when quadrics are computed here (no `quadrics`
//   given), every vertex within kInitialQuadricRadius rings of them. Before a round's
//   collapses are applied, every vertex within kTrustSpread = kDecisionRadius + 1 rings
//   (current mesh) of an untrusted vertex becomes untrusted; the kept vertex of a
//   collapse is untrusted if either endpoint was. A candidate is EXACT when both
//   endpoints are more than kDecisionRadius rings from every untrusted vertex: its
//   decision then equals the global one.
// - Ownership: each candidate is counted (summaries, owned_candidates()) only by the
//   patch owning its kept vertex (`PatchInput::owned_vertex`), and only when exact;
//   an owned inexact candidate is counted in RoundSummary::inexact_candidates (the
//   pipeline reports 'halo too small'). apply_cut collapses every candidate under the
//   cut, owned or not, so the halo evolves like the global mesh while trusted, except
//   where nothing exact can see it: untrusted vertices that are not owned are FROZEN
//   (no best edge, so in no LME), and inexact candidates not owned with both ends
//   within kDecisionRadius rings of untrusted state are not collapsed (frozen()).
//   Owned untrusted vertices run as before.
// - extract() returns the owned faces with their vertices' (gid, position, quadric,
//   lock, degree); PatchOutput::untrusted_vertices counts output vertices that are not
//   trusted (must be 0 for the output to be exact).
// - Locked vertices never move: those on non-manifold edges, non-manifold (multi-fan)
//   vertices, endpoints of inconsistently oriented edges (computed at setup unless
//   `locked` is given); their faces pass through. Faces with a repeated vertex (zero
//   area) are dropped and counted (dropped_faces()); with drop_repeated_vertex_faces =
//   false they pass through and lock their vertices. No other input face is dropped.
// - Verification of carried bests (QEMFLOW_VERIFY_CARRIED=1 in the environment, read
//   once per process; off: one flag test per decimator): the first prepare_round
//   recomputes every best the constructor restored from PatchInput::best_gids by a
//   full, uncached evaluation of its edges (before any refresh may replace it) and
//   throws std::logic_error naming the vertex's global id when the restored (edge,
//   cost) differs from it in any bit. Costs one full evaluation per restored vertex;
//   the results are the same bits with it on or off.
// - Thread safety: a PatchDecimator is used by one caller at a time; its methods run
//   oneTBB parallel loops internally.
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "nodes/decimate/quadric.hpp"
#include "util/hash.hpp"
#include "util/memory.hpp"

namespace qemflow::nodes {

inline constexpr int kDecisionRadius = 4;
// Untrusted state spreads this many rings per round (wrong decisions within
// kDecisionRadius rings, whose collapses change faces one ring further).
inline constexpr int kTrustSpread = kDecisionRadius + 1;
// Rings around an incomplete vertex whose locally computed initial quadric is not
// trusted (the lead's conservative rule; a vertex's quadric reads only its own faces).
inline constexpr int kInitialQuadricRadius = 2;
// Rings best(v) reads (the validity and cost of every edge at v): a best edge computed
// where every vertex within this many rings is trusted is the global one.
inline constexpr int kBestRadius = 2;
// PatchDecimator::prepare_owned_summary_round's rings around the owned part: 3 are read
// (an owned candidate's endpoints' 1-ring neighbours' partners' bests), 2 to spare.
inline constexpr int kOwnedSummaryRadius = 5;
// An edge at a vertex with more live faces than this is no collapse option (as if the
// vertex were locked, for as long as its degree stays above). Its validity and
// deviation charge read all of that vertex's faces, and a hub's every neighbour
// re-reads them each round the hub is touched (always, as every collapse nearby
// changes one of its faces): a fan of n triangles around one vertex cost O(n^2) per
// round. Reads the vertex's own faces only (radius 0: no halo change); real meshes
// never come near it (the shared meshes' outputs are unchanged).
inline constexpr uint32_t kMaxCollapseDegree = 256;
// QEMFLOW_VERIFY_CARRIED=1 (see the contract): checks carried state (here: restored
// bests; the out-of-core pipeline also checks that every copy of a repeated vertex
// record agrees). Read once per process.
bool verify_carried_enabled();

// PatchInput / PatchOutput::best_gids values besides a neighbour's global id.
inline constexpr uint64_t kBestUnknown = ~uint64_t{0};    // not carried: refresh
inline constexpr uint64_t kBestNone = ~uint64_t{0} - 1;   // exact: no valid edge

struct DecimateParams {
  // A collapse is invalid when a face normal turns so that cos(angle) < this.
  double min_normal_cos = 0.2;
  // A collapse is invalid when two faces that share an edge at the kept vertex afterwards
  // fold onto each other (their normals' cosine is below this) where neither endpoint's
  // fan held such a pair before. -1 turns the check off. (A moved face and the unmoved
  // one across its outer edge are not compared: that reads two rings.)
  double new_fold_cos = -0.5;
  // A face is degenerate when |cross| / (longest edge)^2 (about the sine of its
  // smallest angle) is below this; collapses may not create one (nor make one worse).
  double min_face_quality = 1e-6;
  // Weight of boundary-preserving quadrics (times squared edge length).
  double boundary_weight = 10.0;
  // Fold edges (the two faces' unit normals have a dot product below this: the rim of
  // a thin sheet or a very sharp crease) get the same perpendicular-plane quadrics as
  // border edges; without them the two nearly parallel face planes leave the rim free
  // to slide inward and thin sheets shrink.
  double fold_cos = -0.7;
  // Faces with a repeated vertex (zero area; welding makes some) carry no surface:
  // drop them (counted in dropped_faces()) rather than pass them through with their
  // vertices locked, which would pin their neighbourhoods for good.
  bool drop_repeated_vertex_faces = true;
  // Weight of the deviation charge added to an edge's quadric cost (quadric.hpp,
  // collapse_deviation): the endpoints' share of area times their squared distance to
  // the collapsed fan. The quadric alone prices cutting off a tip or a thin rim by its
  // small original area, so greedy order removes such features early and the largest
  // error (Hausdorff) grows; 0 turns the charge off (pure quadric cost).
  double deviation_weight = 10.0;
  friend bool operator==(const DecimateParams&, const DecimateParams&) = default;
};

struct PatchInput {
  std::vector<Vec3> positions;
  std::vector<uint64_t> vertex_gids;
  std::vector<uint8_t> incomplete;    // per vertex; empty: every fan is whole
  std::vector<uint8_t> owned_vertex;  // per vertex; empty: all owned
  std::vector<uint8_t> locked;        // per vertex; empty: computed from the faces
  std::vector<Quadric> quadrics;      // per vertex; empty: computed from the faces
  std::vector<std::array<uint32_t, 3>> faces;  // local vertex refs
  std::vector<uint64_t> face_gids;
  std::vector<uint8_t> owned_face;    // per face; empty: all owned
  // Per vertex; empty: none carried. A vertex's best edge as the previous epoch's
  // summary found it (PatchOutput::best_gids: the other endpoint's global id, kBestNone
  // or kBestUnknown) and its cost. Valid only for the same mesh state and params (the
  // caller's duty: nothing may collapse, and the guards may not relax, in between).
  // Restored where it is what a refresh here would compute, bit for bit: at vertices
  // more than kBestRadius rings from every initially untrusted one (a vertex near the
  // halo's edge sees a different 2-ring); there the first round skips the refresh.
  std::vector<uint64_t> best_gids;
  std::vector<double> best_costs;
};

// The total order of edges: (cost, tie, smaller global id, larger global id), where
// tie = mix64 of the two global ids. Equal costs are common (every edge of a flat
// region costs exactly 0); ordered by ids alone, the smallest id of a region would win
// every neighbourhood, so a round finds a single LME per flat region where the ids
// increase across it (a generated terrain took 1,815 epochs to 1%). The hash scatters
// the winners like a random priority while staying a pure function of global ids, so
// every patch orders edges the same way.
struct EdgeKey {
  double cost = 0.0;
  uint64_t gid_lo = 0, gid_hi = 0;
  static EdgeKey of(double cost, uint64_t gid_a, uint64_t gid_b) {
    return {cost, gid_a < gid_b ? gid_a : gid_b, gid_a < gid_b ? gid_b : gid_a};
  }
  // Bounds that are no edge (gid_lo == gid_hi): the largest key of cost `cost`, a cut
  // taking every edge of that cost, and the smallest.
  static EdgeKey above_all_of(double cost) { return {cost, ~uint64_t{0}, ~uint64_t{0}}; }
  static EdgeKey below_all_of(double cost) { return {cost, 0, 0}; }
  // Computed only when two costs are equal, which keeps the key (and every
  // Candidate) as small as the order without a tie.
  uint64_t tie() const {
    if (gid_lo == gid_hi) return gid_lo == 0 ? 0 : ~uint64_t{0};
    return mix64(mix64(gid_lo) ^ gid_hi);
  }
  friend bool operator<(const EdgeKey& a, const EdgeKey& b) {
    if (a.cost != b.cost) return a.cost < b.cost;
    const uint64_t ta = a.tie(), tb = b.tie();
    if (ta != tb) return ta < tb;
    if (a.gid_lo != b.gid_lo) return a.gid_lo < b.gid_lo;
    return a.gid_hi < b.gid_hi;
  }
  friend bool operator<=(const EdgeKey& a, const EdgeKey& b) { return !(b < a); }
};

struct Candidate {
  EdgeKey key;
  uint32_t keep = 0, remove = 0;  // local vertex ids
  uint32_t faces_removed = 0;     // 1 (border edge) or 2
  bool owned = true;              // the kept vertex is owned by this patch
  bool exact = true;              // both endpoints > kDecisionRadius rings from untrusted
};

// Fixed log-scale bins of cost: the top 13 bits of the IEEE double (exponent and two
// mantissa bits), so bins are exact, scale-free and the same in every patch.
inline constexpr size_t kCostBins = 1u << 13;
size_t cost_bin(double cost);
double cost_bin_upper(size_t bin);  // largest double in the bin

struct RoundSummary {
  std::vector<uint64_t> faces_per_bin = std::vector<uint64_t>(kCostBins, 0);
  uint64_t candidate_faces = 0;  // sum over owned exact candidates of faces they remove
  uint64_t candidates = 0;
  uint64_t inexact_candidates = 0;  // owned but not exact: the halo is too small
  void add(const RoundSummary& other);
};

// Collapse owned candidates with key <= `key`; when `single_face_only`, only those
// removing exactly one face (used to hit an odd remaining count exactly).
struct RoundCut {
  EdgeKey key;
  bool single_face_only = false;
};

// The owned faces and their vertices' state (enough to rebuild a patch of the next
// epoch: PatchInput's quadrics / locked, and degrees to tell complete fans).
struct PatchOutput {
  std::vector<Vec3> positions;           // sorted by global id (extract's default order)
  std::vector<uint64_t> vertex_gids;
  std::vector<Quadric> quadrics;
  std::vector<uint8_t> locked;
  std::vector<uint32_t> degrees;         // alive faces around the vertex in this patch
  std::vector<uint8_t> trusted;          // the vertex's state is the global one
  // The vertex's best edge (PatchInput::best_gids), filled only when extract() follows a
  // plain prepare_round() (every best exact, nothing collapsed since): the other
  // endpoint's global id or kBestNone where every vertex within kBestRadius rings is
  // trusted (the global best), kBestUnknown elsewhere. Empty otherwise.
  std::vector<uint64_t> best_gids;
  std::vector<double> best_costs;
  std::vector<std::array<uint32_t, 3>> faces;  // sorted by global face id (as positions)
  std::vector<uint64_t> face_gids;
  uint64_t untrusted_vertices = 0;       // output vertices whose state may be wrong
};

// The decimator's work so far: best-edge refreshes (prepare's calls of refresh_best),
// deviation charges (edge costs computed in full) and validity checks. A round's cost is
// mostly these, so the reports give them to tell a schedule's cost from the machine's
// speed (report_work, nodes/decimate/report_fields.hpp).
struct DecimatorWork {
  uint64_t refreshes = 0, charges = 0, validity_checks = 0;
  DecimatorWork& operator+=(const DecimatorWork& w) {
    refreshes += w.refreshes;
    charges += w.charges;
    validity_checks += w.validity_checks;
    return *this;
  }
};

class PatchDecimator {
 public:
  PatchDecimator(PatchInput input, const DecimateParams& params);

  void prepare_round();
  // prepare_round for a round whose cut is known in advance (the blind rounds of an
  // epoch): candidates() then holds exactly prepare_round's candidates with key <=
  // cut.key (so apply_cut(cut) collapses the same edges), but candidates above the
  // cut may be missing, so summarize() / owned_candidates() mean nothing after it.
  // It skips the validity checks of vertices whose every edge costs more than the cut
  // (they are refreshed in full by the next round that needs them).
  void prepare_round(const RoundCut& cut);
  // prepare_round() for a patch's last step (out of core: its summary, owned candidates
  // and extract), when nothing collapses afterwards: refreshes only the vertices within
  // kOwnedSummaryRadius rings of the owned part (owned vertices and the corners of owned
  // faces). An owned candidate's status reads bests within 3 rings of its kept vertex
  // (partners of its endpoints' 1-ring neighbours), and extract() exports bests only for
  // owned faces' corners, so summarize(), owned_candidates() and extract() give exactly
  // prepare_round()'s results; the outer halo, which only kept untrusted state away,
  // is not evaluated again. Afterwards the decimator is final: a further prepare or
  // apply_cut throws std::logic_error, and extract(false) carries no bests.
  void prepare_owned_summary_round();
  RoundSummary summarize() const;
  // Owned candidates of the prepared round, sorted by key.
  // Every candidate of the prepared round (owned or not, exact or not), sorted by key.
  std::span<const Candidate> candidates() const { return candidates_; }
  // The owned, exact candidates sorted by key: this patch's list for exact_cut().
  std::vector<Candidate> owned_candidates() const;
  // Returns the number of faces removed.
  uint64_t apply_cut(const RoundCut& cut);

  // New parameters for the following rounds (every vertex is re-evaluated, and nothing
  // restored from PatchInput::best_gids stands). run_epochs uses it to relax the
  // geometric guards once no candidate is left and to weigh the deviation charge from
  // EpochOptions::charge_from on; an out-of-core patch, to switch the charge on between
  // its rounds and its summary.
  void set_params(const DecimateParams& params);
  const DecimateParams& params() const { return params_; }

  uint64_t face_count() const { return faces_alive_ + passthrough_gids_.size(); }
  uint64_t owned_face_count() const;
  bool trusted(uint32_t v) const { return !(vflag_[v] & kUntrusted); }
  uint64_t untrusted_count() const { return untrusted_count_; }
  size_t vertex_count() const { return pos_.size(); }
  uint64_t vertex_gid(uint32_t v) const { return vgid_[v]; }
  uint64_t locked_vertices() const { return locked_count_; }
  uint64_t dropped_faces() const { return dropped_faces_; }
  // Vertices whose best edge the constructor restored from PatchInput::best_gids, and
  // best-edge refreshes run so far (prepare's calls of refresh_best): counters for
  // reports and tests.
  uint64_t restored_bests() const { return restored_bests_; }
  uint64_t refreshes() const { return refreshes_; }
  // Faces read by validity checks and deviation charges so far (both endpoints'
  // lists): the work kMaxCollapseDegree bounds, for tests.
  uint64_t scanned_faces() const { return scanned_faces_; }
  DecimatorWork work() const { return {refreshes_, charges_, validity_checks_}; }
  // Work skipped at frozen vertices (see frozen()): refreshes of their best edge, and
  // inexact candidates not owned that were under the cut but not collapsed.
  uint64_t frozen_refreshes() const { return frozen_refreshes_; }
  uint64_t frozen_collapses() const { return frozen_collapses_; }
  // The owned faces (all faces with owned_only = false, for diagnostics) and their
  // vertices. `order` local: faces and vertices in this decimator's local order instead
  // of by global id (PatchOutput's order), for a caller that orders them itself (the
  // out-of-core export, by Morton code): the same arrays otherwise, without the two sorts.
  enum class OutputOrder { by_gid, local };
  PatchOutput extract(bool owned_only = true, OutputOrder order = OutputOrder::by_gid) const;

 private:
  struct Scratch;
  // An edge v -> other of v's fan: its corner, and the corner of its twin half-edge
  // (other -> v), or none on the border.
  struct FanEdge {
    uint32_t other, corner, twin;
  };
  // kCandidate: marked within prepare() only.
  enum : uint8_t { kDead = 1, kLocked = 2, kUntrusted = 4, kBorder = 8, kOwned = 16, kCandidate = 32 };

  // Rebuilds the corner lists from the live faces, with room for `extra` more entries.
  void rebuild_adjacency(size_t extra);
  std::span<const uint32_t> corners_of(uint32_t v) const {
    return {adj_.data() + adj_begin_[v], adj_count_[v]};
  }
  void lock_nonmanifold_vertices();
  void restore_bests(const std::vector<uint64_t>& gids, const std::vector<double>& costs);
  // QEMFLOW_VERIFY_CARRIED: v's best edge by evaluating every edge in full (no cached
  // cost or validity), and the check of the restored ones against it.
  std::pair<uint32_t, double> best_from_scratch(uint32_t v, Scratch& s) const;
  void verify_restored_bests();
  void compute_quadrics();
  void compact_storage();
  void prepare(const EdgeKey* cut, bool near_owned_only = false);
  // prepare_owned_summary_round's domain: 1 for vertices within kOwnedSummaryRadius rings
  // of an owned vertex or an owned face's corner.
  std::vector<uint8_t> near_owned() const;
  void refresh_best(uint32_t v, Scratch& s, bool near_touched_only, const EdgeKey* cut);
  void update_border(uint32_t v, Scratch& s);
  // s.fan: v's neighbours with their corners (s.next / s.prev from fan_links).
  void fan_neighbors(uint32_t v, std::span<const uint32_t> corners, Scratch& s) const;
  // s.next / s.prev: the vertex after / before the corner's vertex, for each corner.
  void fan_links(std::span<const uint32_t> corners, Scratch& s) const;
  // The cached cost of edge (v, w) at `corner` (v's) and `twin` (w's, or kNone):
  // `cost` is the full cost when `full`, else its quadric part (a lower bound) or NaN.
  struct CachedCost {
    double cost;
    bool full;
  };
  CachedCost cached_cost(uint32_t v, uint32_t w, uint32_t corner, uint32_t twin) const;
  // Quadric part of edge (v, w)'s cost (a lower bound of edge_cost, the charge being
  // >= 0) and the position; kSkipEdge, also cached, when either is not finite.
  double quadric_cost(uint32_t v, uint32_t w, uint32_t corner, uint32_t twin, Vec3& position);
  // The edge's cost, cached in both corners: quadric part (`quadric`, at `position`)
  // + deviation_weight * deviation.
  double edge_cost(uint32_t v, uint32_t w, uint32_t corner, uint32_t twin, double quadric,
                   const Vec3& position, Scratch& s);
  double deviation(uint32_t a, uint32_t b, const Vec3& p, Scratch& s) const;
  // fan_a: fan_neighbors(a, corners_a).
  bool collapse_valid(uint32_t a, std::span<const uint32_t> corners_a, std::span<const FanEdge> fan_a,
                      uint32_t b, const Vec3& p, Scratch& s) const;
  // collapse_valid of edge (v, w) at `corner` / `twin`, from falive_ when known
  // (`position`, which may be null, is then not needed), else checked and cached.
  bool edge_valid(uint32_t v, std::span<const uint32_t> corners_v, std::span<const FanEdge> fan_v,
                  uint32_t w, uint32_t corner, uint32_t twin, const Vec3* position, Scratch& s);
  void gather_faces(uint32_t v, std::vector<uint32_t>& out) const;
  Vec3 edge_position(uint32_t a, uint32_t b) const;
  EdgeKey lme_key(uint32_t v) const;
  // Brings partner_ up to date after best_ changed at the dirty vertices only.
  void update_partners();
  void collapse(const Candidate& c, uint64_t list_at);
  void compact_list(uint32_t v);
  // Rings (capped at `radius` + 1) from the untrusted set, in the current mesh.
  void untrusted_distances(int radius, std::vector<uint8_t>& dist) const;
  // Lowers `dist` (capped at `radius` + 1) to the rings from `frontier`, the vertices
  // at 0, over the live faces.
  void spread_distances(int radius, std::vector<uint32_t> frontier, std::vector<uint8_t>& dist) const;
  void spread_untrusted(int radius);
  // Untrusted and not owned: nothing exact reads the vertex's state. An exact candidate
  // reads kDecisionRadius rings around its endpoints, all trusted; untrusted state
  // spreads kTrustSpread rings before each round's collapses, which covers whatever
  // differs there (any decision within kDecisionRadius rings, its collapse one ring
  // further), so the trusted part evolves the same whether the frozen vertices
  // collapse or not. Such a vertex keeps no best edge (no refresh, no LME), and an
  // inexact candidate not owned is not collapsed. Owned untrusted vertices run as
  // before: their candidates are RoundSummary::inexact_candidates, the halo-too-small
  // signal.
  // No edge at v is a collapse option: locked, or above kMaxCollapseDegree (v's list
  // compact, as in prepare's refreshes).
  bool immovable(uint32_t v) const { return (vflag_[v] & kLocked) || adj_count_[v] > kMaxCollapseDegree; }
  bool frozen(uint32_t v) const { return (vflag_[v] & (kUntrusted | kOwned | kDead)) == kUntrusted; }

  DecimateParams params_;
  // The arrays made here rather than taken from the PatchInput are UninitializedVectors
  // filled in parallel (util/parallel_fill.hpp): every patch's are fresh pages, whose
  // faults and kernel zeroing a value-initialising std::vector ran on one core.
  // vertices
  std::vector<Vec3> pos_;
  std::vector<uint64_t> vgid_;
  std::vector<Quadric> quadric_;
  UninitializedVector<uint8_t> vflag_;
  UninitializedVector<uint8_t> dirty_;       // best edge may have changed (a neighbour's faces did);
                                     // 2: stale (skipped by a round with a known cut)
  bool has_stale_ = false;           // some vertex is stale, all with edges above:
  EdgeKey stale_floor_;              // (the smallest cut that skipped one)
  UninitializedVector<uint8_t> touched_;  // the vertex's own faces changed: full refresh
  // Corner lists (corner c = 3 * face + slot), one contiguous slice of adj_ per vertex.
  // A collapse appends the kept vertex's merged list at the end of the pool; dead faces
  // stay listed until prepare_round compacts the touched vertices' lists.
  UninitializedVector<uint32_t> adj_begin_;  // offsets < kMaxPool (decimator.cpp)
  UninitializedVector<uint32_t> adj_count_;
  UninitializedVector<uint32_t> adj_;
  UninitializedVector<uint32_t> best_;  // other endpoint of best edge, or kNone
  UninitializedVector<double> best_cost_;   // a stale vertex: the floor of its edge costs
  // Area of the vertex's faces as deviation() sums it (in ascending order of the face
  // areas); NaN: unknown (reset when the vertex is touched).
  UninitializedVector<double> face_area_;
  UninitializedVector<uint32_t> partner_;    // LME partner (best_ at both ends), or kNone
  // faces; corner c = 3 * face + slot
  std::vector<std::array<uint32_t, 3>> fv_;
  std::vector<uint64_t> fgid_;
  // Non-zero iff the face is alive; bits 1-6: the validity (collapse_valid) of the edge
  // at each corner as last checked, kept at the edge's smaller corner and forgotten
  // when a vertex of the face is touched (see edge_valid in decimator.cpp).
  UninitializedVector<uint8_t> falive_;
  // Cost of the edge (corner's vertex, next one); NaN: unknown. With a deviation charge
  // one corner of an edge holds the full cost, the other its quadric part (see
  // is_lower_bound in decimator.cpp).
  UninitializedVector<double> corner_cost_;
  uint64_t faces_alive_ = 0;
  // faces with a repeated vertex: passed through unchanged
  std::vector<std::array<uint32_t, 3>> passthrough_;
  std::vector<uint64_t> passthrough_gids_;
  uint64_t locked_count_ = 0;
  uint64_t dropped_faces_ = 0;
  uint64_t untrusted_count_ = 0;
  uint64_t restored_bests_ = 0, refreshes_ = 0, scanned_faces_ = 0, charges_ = 0, validity_checks_ = 0;
  uint64_t frozen_refreshes_ = 0, frozen_collapses_ = 0;
  // QEMFLOW_VERIFY_CARRIED: the vertices restore_bests restored, until the first
  // prepare checks them (empty otherwise).
  std::vector<uint8_t> verify_restored_;
  // The last step was a plain prepare_round: every best_ is exact (extract carries them).
  bool bests_exact_ = false;
  // prepare_owned_summary_round ran: bests are exact only near the owned part; nothing
  // may be prepared or collapsed any more.
  bool final_ = false;
  std::vector<uint8_t> fowned_;      // per face, empty when all owned
  std::vector<uint8_t> passthrough_owned_;
  std::vector<uint8_t> trust_dist_;  // round scratch: rings to the untrusted set

  std::vector<Candidate> candidates_;
};

}  // namespace qemflow::nodes
