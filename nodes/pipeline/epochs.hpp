#pragma once
// The out-of-core simplification pipeline (DESIGN.md §2-5; README.md, "Out of core equals in core"):
//
//   input ──loader──► blocks ──convert (owner per face, degrees)──► mesh state (scratch)
//   mesh state ──epoch pass: per patch gather owned + BFS halo, PatchDecimator runs the
//     epoch's rounds with the global plan, trust check (redo with a deeper halo), export
//     owned faces + vertex states, summary──► next mesh state; plan_epoch(summed summaries)
//   once the state fits the budget ──finish in core (one patch, run_epochs)──► output
//
// Contract
// - Equal to the in-core reference (nodes/decimate/simplify.hpp, no weld difference once
//   the loader welds): the same epoch schedule of G, each epoch's global plan from the
//   patches' summed summaries (exact integer sums), every owned face's state checked
//   trusted (decimator.hpp: trust), so the owned outputs are the global mesh's. The
//   output (vertices sorted by global id, faces by face id) is written with the same
//   writer options as the in-core command, so the files are byte-identical.
// - The mesh state between epochs lives in scratch as chunks: one frame per chunk (raw, or zstd -1 where --scratch-codec auto finds no room for raw; README)
//   holding face records {fid, 3 vertex gids, owner} and the records of their vertices
//   {gid, position, quadric, degree, lock, best edge}; every chunk holds faces of one owner.
// - Best edges carried between passes: a pass's summary (a plain prepare_round) leaves
//   every vertex's best edge exact; the export writes it (other endpoint's gid and cost)
//   where the patch computed it with a trusted 2-ring, and the next pass's patches (and
//   the in-core finish) restore it where their own 2-ring is trusted, so their first
//   round refreshes only the other vertices (decimator.hpp, PatchInput::best_gids).
//   Nothing collapses between a summary and the next pass; when the guards relax in
//   between, nothing is carried (the bests were found under the old params).
// - A patch's halo: faces within `rings` rings of its owned faces, found by a BFS that
//   drives the gather. Each chunk's meta keeps the boxes of 8 runs of its faces (an
//   export's chunk is in Morton order, so a run is a compact piece of surface); a run's
//   box holds its faces' corners, so every face of a vertex lies in a run whose box
//   holds the vertex. The gather reads the runs that may hold owned faces, then runs
//   the BFS over what it read; where the BFS must expand a vertex whose fan is not
//   whole there (loaded faces < degree), it goes on around it, and one batch of reads
//   brings every run not yet read whose box holds such a vertex; then the BFS goes on
//   from those vertices over the new faces (its index and rings are kept across the
//   batches, not rebuilt; counted: gather_reads), until no vertex is blocked (at most
//   rings + 1 batches: each completes the fans that stopped the BFS). A run is read at
//   most once per gather, so no face is held twice; a frame read for some of its runs
//   leaves the others in a cache within the lease's room, so a later batch asking for
//   them reads no frame twice. What is read changes, never the patch.
// - 'Halo too small' (an owned inexact candidate or an owned face with an untrusted
//   vertex): the ring count grows and the patch is redone (counted: halo_redos).
// - Memory: a patch runs under one governor lease, at most 3/4 of the capacity (taken
//   whole before the gather, trimmed after it), measured by patch_bytes over the faces
//   and distinct vertices the gather holds. Both are known from the chunk metas before
//   a batch is read (faces per run, vertex share per run), so a batch that would take
//   the gather over its lease is not read: the gather stops there (over_limit), and
//   what it counted (gathered_faces_total, the refusal's "over N faces") is the same
//   on every run, whatever the I/O's timing left in its run cache. (A part's first
//   batch, its owned runs, is read and counted without being held, for its owned
//   faces.) Such a patch is split: its owner runs as parts (the
//   faces whose centroid lies in each half of a region, halved again as needed), a
//   finer partition with the same output; a part of at most 2048 owned faces that
//   still does not fit is refused with the minimum budget (Error resource; a lower
//   bound: the gather stopped where it went over). The counts are in the report
//   (patch_splits).
// - The finish holds at least the state's isolated faces (each face whose corners no
//   other face uses: nothing collapses them), counted by the conversion: a budget
//   whose finish cannot hold them beside the target's faces is refused before the
//   epochs (Error resource, naming the budget that holds them: the epochs then go on
//   until the state fits, at the latest once the rest is within the target).
// - All scratch and output I/O goes through the job's I/O thread.
// - Order independence: a gather's records arrive in completion order (the I/O's
//   timing), so a vertex's record may come several times, once per exporting patch, in
//   any order. Copies agree on everything but the carried best, which some may lack;
//   the gather keeps the first copy with a known best (two known ones are equal).
//   Nothing else depends on arrival order.
// - Checks for tests and diagnosis (environment, read once per process; off: no cost):
//   QEMFLOW_VERIFY_CARRIED=1: every restored best is recomputed in full and must be
//     bit-equal (decimator.hpp), and all copies of a repeated vertex record a gather
//     reads must agree as above; otherwise Error(internal) / a
//     logic_error naming the gid (exit 1).
//   QEMFLOW_BASELINE=BYTES (engine::command_baseline): the governor's baseline, instead of the
//     process's RSS at its start plus a margin, which moves by ~100 KB between runs and
//     every budget-derived size with it: with it fixed, two runs of a command split the
//     same parts and report the same counts.
//   QEMFLOW_FUZZ_ORDER=SEED: each gather reads its frames, and the first state holds its
//     chunks, in a seeded pseudo-random order (what the I/O's timing may do), and each
//     patch build drops a seeded third of the carried bests (as a copy without one
//     would). The output must not change.
#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <functional>
#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "engine/blocks.hpp"
#include "engine/governor.hpp"
#include "engine/job.hpp"
#include "engine/scratch.hpp"
#include "nodes/decimate/simplify.hpp"
#include "nodes/pipeline/partition_stage.hpp"

namespace qemflow::nodes::pipeline {

struct OocOptions {
  SimplifyOptions simplify;          // target, epoch options, decimator params (weld: loader's)
  // The paper's partition (partition_stage.hpp); clusters 0: from the budget (clusters_for).
  PartitionOptions partition;
  // Finish in core once the state has at most this many faces (at most what the budget
  // allows: 0.9 of the capacity at kInCoreBytesPerFace, and in_core_finish_bytes with
  // its vertices too); 0: from the budget.
  // Tests set 1 to keep the out-of-core epochs going to the end.
  uint64_t in_core_faces = 0;
  int initial_rings = 0;             // 0: kTrustSpread * E + kDecisionRadius + 2
  uint64_t chunk_faces = 8192;       // most faces per state chunk (fewer for small patches)
};

struct OocStats {
  uint64_t input_faces = 0, input_vertices = 0, target_faces = 0;
  uint64_t output_faces = 0, output_vertices = 0;
  uint32_t patches = 0;
  uint64_t epochs = 0;               // global plans (out of core + in core)
  uint64_t ooc_epochs = 0;           // passes over the patches
  uint64_t rounds = 0;
  uint64_t halo_redos = 0;
  // The patch gathers' batches of chunk reads: a part's first (its owned runs) and one
  // per stop of its BFS at vertices whose fans were not read yet (epochs.hpp).
  uint64_t gather_reads = 0;
  uint64_t patch_splits = 0;         // a patch part halved because it did not fit its lease
  // Big allocations of the passes served by buffers an earlier patch freed, and their
  // bytes (engine/retained_buffers.hpp; 0 without the CLI's operator new).
  uint64_t reused_buffers = 0, reused_buffer_bytes = 0;
  int max_rings = 0;
  uint64_t in_core_faces = 0;        // faces when the run finished in core (0: never)
  uint64_t in_core_vertices = 0;     // their distinct vertices (in_core_finish_bytes)
  // The process's RSS as the finish starts (before its lease) and its high-water mark
  // over the finish (gather, build, decimation, extract): what kInCoreBytesPerFace is
  // checked against. The peak is 0 (not measured) when another job shared the process
  // during the finish (engine::SoleJobPeakWindow): the mark is one per process.
  uint64_t in_core_start_rss = 0, in_core_peak_rss = 0;
  uint64_t patch_faces_max = 0;      // largest patch (owned + halo)
  // Scratch on disk as the epochs start: the first state alone, the blocks it was
  // converted from being removed by then.
  uint64_t scratch_epochs_start_bytes = 0;
  // Summed over the out-of-core patch builds (redos included): faces read by the gathers
  // (every face of the runs they read), faces of the built patches (owned + halo)
  // and owned faces; their ratios say what the halo and the gather cost.
  uint64_t gathered_faces_total = 0, patch_faces_total = 0, owned_faces_total = 0;
  // Best edges carried from the previous pass's summary (VertexRecord): vertices whose
  // best the patches restored (redos included) and the in-core finish restored, and the
  // best-edge refreshes the patches' first prepare still ran (the first round's, or the
  // summary's in a pass without rounds).
  uint64_t carried_bests = 0, in_core_carried_bests = 0, first_round_refreshes = 0;
  // Work skipped in the patches: best-edge refreshes at frozen (untrusted, not owned)
  // vertices and the collapses skipped there (PatchDecimator::frozen_refreshes).
  uint64_t frozen_refreshes = 0, frozen_collapses = 0;
  // The decimator's work in the patches (redos included) and in the in-core finish.
  DecimatorWork patch_work, in_core_work;
  // Where the out-of-core patch work goes (redos included): wall and process CPU seconds
  // per phase of run_part, in this order: gather (plan, read, filter), build (BFS halo,
  // PatchInput), setup (PatchDecimator's constructor), first_round (the epoch's first
  // cut: a fresh decimator evaluates every vertex's edges), rounds (the other cuts),
  // summary (prepare_round, summarize, candidates), extract, export (chunks, encode,
  // write). CPU includes the I/O thread's work while the phase ran.
  static constexpr size_t kPhases = 8;
  static constexpr std::array<const char*, kPhases> kPhaseNames{
      "gather", "build", "setup", "first_round", "rounds", "summary", "extract", "export"};
  std::array<double, kPhases> phase_wall{}, phase_cpu{};
};

struct OocResult {
  std::vector<Point> points;         // sorted by global id
  std::vector<Triangle> triangles;   // sorted by face id
  OocStats stats;
};

// The epoch loop and the finish on a loaded mesh (blocks in `scratch`). Once the blocks
// are converted to the first state, their scratch files (and an out-of-core load's
// vertex windows) are removed: `mesh`'s frames may not be read afterwards.
OocResult simplify_blocks(engine::Job& job, engine::ScratchStore& scratch, const engine::LoadedMesh& mesh,
                          const OocOptions& options);

// Bytes per gathered face of a patch while it is gathered and decimated, and per face of
// the in-core finish; the budget rules use them. A patch peaks while the gathered state
// (face record 40 B + vertex records ~68 B per face: one per gid, however many chunks
// hold it, for the first state of an input in random face order holds ~2.8 records per
// face), the BFS arrays and the built
// PatchInput (~88 B) are alive together: measured on 1M faces at 96M (VmHWM reset per
// phase, above the RSS before the gather, with 120-byte records and no carried bests),
// the gather peaks at 132-237 B and the build at 188-274 B per gathered face; the
// decimator phase holds ~300 B per patch face plus ~20 MB that does not scale with the
// patch (heap arenas), which the baseline's margin covers. The carried best edge (16 B
// per vertex record and per PatchInput vertex, ~8 B per face each) added 16.
// The finish (kInCoreBytesPerFace) peaks in the decimator: its arrays (~131 B per face:
// 147 B per vertex, 60 per face) while the constructor still holds the input's locks
// and carried bests, or in the rounds. build_whole_patch copies the gathered records
// block by block and gives their pages back as it goes, so it holds about what the
// gather held (~113 B per face: 40-byte face records, 136-byte vertex records, V = F/2,
// a few % repeated). Measured (VmHWM over the finish above the RSS at its start, report
// fields in_core_peak_rss_bytes / in_core_start_rss_bytes): 145 B per finish face on
// the 5M blob at 1G with --in-core-faces 4000000 (3.84M faces), 160 on a 400K blob at
// 128M with --clusters 2 --in-core-faces 350000 (345K faces; a few MiB of thread
// scratch and frame buffers that do not scale weigh more). 170 leaves 6% over the
// smaller, 17% over the larger. (It was 240: 175-221 B had been measured when the build
// held the records beside the whole input and the loader's vertex positions, 24 B per
// input vertex, stayed resident after their lease; both fixed.)
inline constexpr uint64_t kPatchBytesPerFace = 276;
// The job's progress (engine::Job::progress_span): the load reports into [0,
// kLoadShare], the partition and the conversion up to kEpochsFrom, the epochs and the
// finish (the first pass by its patches' share of the faces, then by the share of the
// faces to remove that are gone; Runner::removed_progress) up to kEpochsTo, the
// output's write the rest.
inline constexpr double kLoadShare = 0.04, kEpochsFrom = 0.1, kEpochsTo = 0.99;
// The first pass's share of the epochs' span (it collapses nothing, so the share of the
// faces removed cannot move the bar through it).
inline constexpr double kFirstPassShare = 0.05;
inline constexpr uint64_t kInCoreBytesPerFace = 170;
// The finish's vertices beyond half a vertex per face (the welded meshes 170 B per face
// was measured on) each cost this much more: an unwelded soup (3 vertices per face)
// collapses nothing, so its finish also extracts the whole input, and peaks there with
// the decimator's ~147 B per vertex, the PatchOutput's ~134 and the result's 24 alive
// together. Measured: the 300k-face soup (900k vertices, --no-weld) finished from
// 300k faces at 1047 B per face over the RSS at its start (314 MB), so 351 B per
// vertex beyond F/2; 380 leaves 8%.
inline constexpr uint64_t kInCoreBytesPerExtraVertex = 380;
// A patch's vertices beyond half a vertex per face (kPatchBytesPerFace's meshes): each
// is a gathered record (136 B), its PatchInput entries (~130) and the decimator's
// (~147) while a soup's patch is built and run.
inline constexpr uint64_t kPatchBytesPerExtraVertex = 400;
// What a gather of `faces` faces and `vertices` distinct vertices may hold: the patch
// lease's measure. Each gather counts its own faces and vertices (their chunks' run
// shares, ChunkMeta), so a soup-heavy patch of a partly welded mesh pays for its
// vertices where the state's average would not.
inline uint64_t patch_bytes(uint64_t faces, uint64_t vertices) {
  const uint64_t extra = vertices > faces / 2 ? vertices - faces / 2 : 0;
  return faces * kPatchBytesPerFace + extra * kPatchBytesPerExtraVertex;
}
// The finish's lease for a state of `faces` faces and at most `vertices` vertices.
inline uint64_t in_core_finish_bytes(uint64_t faces, uint64_t vertices) {
  const uint64_t extra = vertices > faces / 2 ? vertices - faces / 2 : 0;
  return faces * kInCoreBytesPerFace + extra * kInCoreBytesPerExtraVertex;
}

// One out-of-core simplify as a library job: input to output, on a governor shared by
// every job of the process (a daemon may run several at once, each in its own thread).
// - Memory: the job first reserves `job_budget` bytes of the governor's capacity (0: all
//   of it), waiting while other jobs hold them, and then runs on a governor of its own
//   made from that reservation (engine::reserve_for_job): its patch leases, the loader's
//   reservations and the in-core finish size themselves from the job's capacity
//   exactly as a lone run with that capacity does, and it waits only for its own
//   memory. So jobs never deadlock on each other, and together never hold more than the
//   governor's capacity. When the shared budget is tight, the jobs take turns: a job
//   whose reservation does not fit beside the others' waits, holding nothing, until
//   they finish (waiters are woken by every release, in no fixed order). A job_budget
//   larger than the governor's capacity fails up front (Error resource, naming the
//   budget); one too small for the job fails as a lone run at that budget would, the
//   budget named being the governor's baseline plus the job's reservation.
// - The output does not depend on the budget or on other jobs (out of core equals in
//   core): it is the bytes the CLI writes for the same input and options.
// - Owners in the governors are prefixed with job_name and "/" (job_name "job 2": "job 2/",
//   as ReencodeOptions::job_name): the reservation is "job 2/job" in the shared governor,
//   the stages' leases are in the job's own (the report's "nodes").
// - Process-wide state is the host's: allocator settings (engine::tune_allocator, which
//   the CLI calls once) are not touched; the finish resets the process's peak-RSS
//   mark only while it is the only job alive (OocStats::in_core_peak_rss).
// Returns the report (what --report writes; its budget, governor peak and nodes are the
// job's own, its peak RSS the process's). Throws qemflow::Error (bad_input, resource,
// cancelled); nothing is left in scratch and no output exists after a failure.
// Raw scratch bytes, bounded from the record sizes (epochs.cpp): a state of `faces`
// faces, and everything on disk at once in a run of an input of `faces` triangles and
// `vertices` vertices. --scratch-codec auto goes raw for a load stage only when the
// disk has room for that stage's bound; for a state stage (the conversion, an epoch)
// when it has room for the bound, or for twice an estimate of the state's raw bytes
// (from the counts; the exact bytes of the state the pass reads), the stage's raw
// bytes then capped at the estimate (ScratchStore::choose_codec): the bound is ~4.4x
// a welded mesh's states. `small_load_frames`: LoadedMesh::small_spill_frames.
uint64_t raw_state_bytes_bound(uint64_t faces);
uint64_t raw_scratch_peak_bound(uint64_t faces, uint64_t vertices, bool small_load_frames);

struct OocJob {
  std::filesystem::path input, output, scratch_dir, trace_path;
  int threads = 0;
  bool double_precision = false;  // as `--double`
  bool weld = true;               // --no-weld: false (the loader's weld, as in core)
  OocOptions options;
  std::string job_name;           // prefixes this job's governor owners ("job 2": "job 2/patch")
  uint64_t job_budget = 0;        // bytes of the governor's capacity to reserve; 0: all of it
  // --scratch-codec. automatic by default: raw frames (about a sixth less CPU than
  // zstd -1) for each stage whose raw bytes, bounded from the counts
  // (raw_state_bytes_bound, engine::raw_load_scratch_bound), fit the disk's free space
  // then, or for a state stage twice their estimate (raw up to it, zstd past it);
  // zstd (DESIGN §2) for the others.
  engine::ScratchCodec scratch_codec = engine::ScratchCodec::automatic;
  // Tests: the scratch disk's free bytes at the start, instead of statvfs
  // (QEMFLOW_SCRATCH_FREE for the CLI; ScratchStore's assumed_free).
  std::optional<uint64_t> scratch_free;
};
nlohmann::json run_ooc_job(engine::Governor& governor, const OocJob& job, const engine::JobHooks& hooks);

// The whole `qemflow simplify IN OUT` out-of-core command: the allocator tuned, a
// governor for the process (budget, measured baseline), the progress bar, run_ooc_job
// (alone: all of the capacity), the report file and the summary on stderr.
struct OocCommand : OocJob {
  std::filesystem::path report_path;
  uint64_t mem_budget = 0;  // 0: half the physical memory
  bool quiet = false;
  std::shared_ptr<engine::CancelToken> cancel;  // may be empty (the CLI's: interrupt.hpp)
};
nlohmann::json run_ooc_command(const OocCommand& command);

}  // namespace qemflow::nodes::pipeline
