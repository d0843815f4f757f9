// run_ooc_job: the out-of-core simplify wired in one function (as engine/reencode.cpp
// does for --ratio 1): reservation, job, scratch, load, epochs, write; and
// run_ooc_command, the CLI's process around it (allocator, governor, progress bar).
#include <unistd.h>

#include <cstdio>
#include <cstdlib>

#include "config/size.hpp"
#include "engine/process_memory.hpp"
#include "engine/progress_bar.hpp"
#include "engine/reencode.hpp"
#include "engine/report.hpp"
#include "io/indexed_mesh.hpp"
#include "nodes/decimate/report_fields.hpp"
#include "nodes/pipeline/epochs.hpp"
#include "util/error.hpp"

namespace qemflow::nodes::pipeline {

namespace {

// QEMFLOW_SCRATCH_FREE=BYTES (tests): the scratch disk's free bytes at the start,
// instead of statvfs, so that --scratch-codec auto's choices can be checked against a
// small disk without mounting one.
std::optional<uint64_t> assumed_scratch_free() { return config::env_byte_count("QEMFLOW_SCRATCH_FREE", true); }

}  // namespace

nlohmann::json run_ooc_job(engine::Governor& shared, const OocJob& command, const engine::JobHooks& hooks) {
  // "job 2" -> owners "job 2/...", as a re-encode's ReencodeOptions::job_name.
  const std::string prefix = command.job_name.empty() ? std::string() : command.job_name + "/";
  const std::unique_ptr<engine::Governor> own = engine::reserve_for_job(shared, prefix, command.job_budget, hooks);
  engine::Governor& governor = *own;
  engine::require_budget_for_load(governor.budget(), governor.baseline());
  engine::JobSettings settings;
  settings.threads = command.threads;
  settings.trace_events = command.trace_path.empty() ? 0 : (1 << 18);
  settings.owner_prefix = prefix;
  engine::Job job(governor, hooks, settings);
  nlohmann::json report;
  engine::run_then_write_trace(job, command.trace_path, [&] {
    std::error_code ec;
    const uint64_t input_bytes = std::filesystem::file_size(command.input, ec);
    if (ec) throw Error(ErrorKind::bad_input, command.input.string() + ": cannot read: " + ec.message());
    // State chunks carry quadrics: several times the block size at the first epochs.
    const bool zstd_input = command.input.extension() == ".zst";
    // Raw frames take up to ~30x a PLY's bytes (a shuffled blob) and 126x a compressible
    // .zst (a lattice heightfield, review15), so no factor of the file's size bounds
    // them; the record sizes do, given the counts (raw_scratch_peak_bound). Automatic
    // decides stage by stage: the load from the header's counts (raw only when they
    // bound the triangles: an uncompressed binary PLY), then the conversion and each
    // epoch from the state's exact face count, each against the free space then. Raw
    // was a sixth less CPU on the demo (24.7-25.3 CPU-s against 29.7-33.1; zstd -1 on
    // the state chunks is encoded in every export and decoded in every gather).
    const std::optional<engine::InputCountsBound> counts = engine::input_counts_bound(command.input);
    // The load chooses again (zstd) if its spills turn out to have small frames
    // (LoadedMesh::small_spill_frames), against the bound that counts them.
    // Forced raw without a bound is checked against the re-encode's estimate, as before.
    const uint64_t raw_load_bytes =
        counts ? engine::raw_load_scratch_bound(counts->triangles, counts->vertices, false)
        : command.scratch_codec == engine::ScratchCodec::raw ? engine::expected_raw_scratch_bytes(input_bytes, zstd_input)
                                                             : UINT64_MAX;
    engine::ScratchStore scratch(command.scratch_dir, 2 * engine::expected_scratch_bytes(input_bytes, zstd_input),
                                 raw_load_bytes, command.scratch_codec, command.scratch_free);
    // Every frame (blocks, vertex windows, state chunks) is encoded with this store's
    // codec, never a process-wide default: a job beside it with another codec must not
    // change what this one writes onto a disk checked for its own codec's bytes.
    struct DrainIo {
      engine::Job& job;
      ~DrainIo() { job.io().drain(); }
    } drain_before_scratch_goes{job};
    engine::LoadedMesh mesh;
    {
      // No stage timer here: the loader times its own stages (load, weld, degrees,
      // resolve, ...); one around them all, named "load" too, added their sum to the
      // read pass's seconds (session 20's 200M report: 176 s counted twice).
      job.progress_span(0, kLoadShare);
      engine::LoadOptions load_options;
      load_options.weld = command.weld;
      mesh = engine::load_into_blocks(job, scratch, command.input, load_options);
    }
    // Freed with the lease, not only emptied (util/memory.hpp): 572 MiB for the 50M
    // blob stayed resident through the epochs and the finish.
    release_memory(mesh.vertices.resident);
    mesh.resident_lease.release();
    OocResult result = simplify_blocks(job, scratch, mesh, command.options);
    {
      engine::StageTimer timer(job, "write");
      job.progress_span(kEpochsTo, 1);
      job.progress(0, "write");
      const uint64_t bytes = result.points.size() * 24 + result.triangles.size() * 24;
      engine::Lease lease = job.governor().acquire(job.owner("output"), std::min(bytes, job.capacity()),
                                                   std::min(bytes, job.capacity()));
      io::IndexedMesh out{std::move(result.points), std::move(result.triangles)};
      io::WriteOptions write_options;
      write_options.double_precision = command.double_precision;
      job.io().call("write output", [&] { io::write_mesh(command.output, out, write_options); });
      std::error_code size_ec;
      job.stage("write").bytes_written = std::filesystem::file_size(command.output, size_ec);
    }
    job.progress(1.0, "done");
    const OocStats& st = result.stats;
    report = engine::job_report(job, governor);
    report["command"] = "simplify";
    report["mode"] = "out-of-core";
    report["input"] = command.input.string();
    report["output"] = command.output.string();
    report["input_vertices"] = st.input_vertices;
    report["input_faces"] = st.input_faces;
    report["target_faces"] = st.target_faces;
    report["output_vertices"] = st.output_vertices;
    report["output_faces"] = st.output_faces;
    report["patches"] = st.patches;
    report["epochs"] = st.epochs;
    report["out_of_core_epochs"] = st.ooc_epochs;
    report["rounds"] = st.rounds;
    nodes::report_schedule(report, command.options.simplify.epochs);
    report["halo_redos"] = st.halo_redos;
    report["gather_reads"] = st.gather_reads;
    report["patch_splits"] = st.patch_splits;
    report["reused_buffers"] = st.reused_buffers;
    report["reused_buffer_bytes"] = st.reused_buffer_bytes;
    report["halo_rings"] = st.max_rings;
    report["in_core_faces"] = st.in_core_faces;
    report["in_core_vertices"] = st.in_core_vertices;
    report["in_core_start_rss_bytes"] = st.in_core_start_rss;
    report["in_core_peak_rss_bytes"] = st.in_core_peak_rss;
    report["in_core_lease_bytes_per_face"] = kInCoreBytesPerFace;
    report["in_core_lease_bytes_per_extra_vertex"] = kInCoreBytesPerExtraVertex;
    report["largest_patch_faces"] = st.patch_faces_max;
    report["scratch_epochs_start_bytes"] = st.scratch_epochs_start_bytes;
    report["gathered_faces_total"] = st.gathered_faces_total;
    report["patch_faces_total"] = st.patch_faces_total;
    report["owned_faces_total"] = st.owned_faces_total;
    report["carried_bests"] = st.carried_bests;
    report["in_core_carried_bests"] = st.in_core_carried_bests;
    report["first_round_refreshes"] = st.first_round_refreshes;
    nodes::report_work(report, "patch_", st.patch_work);
    nodes::report_work(report, "in_core_", st.in_core_work);
    report["frozen_refreshes"] = st.frozen_refreshes;
    report["frozen_collapses"] = st.frozen_collapses;
    for (size_t i = 0; i < OocStats::kPhases; ++i)
      report["patch_phases"][OocStats::kPhaseNames[i]] = {{"seconds", st.phase_wall[i]}, {"cpu_seconds", st.phase_cpu[i]}};
    engine::report_scratch(report, scratch);
    // The load files every input face, the weld's dropped ones too; with an envelope a
    // record where its spills could write frames that small (as its own choice did).
    const bool small = mesh.small_spill_frames;
    report["scratch_raw_peak_bound_bytes"] =
        std::max(raw_scratch_peak_bound(mesh.kept_faces(), mesh.vertex_count, small),
                 engine::raw_load_scratch_bound(mesh.face_count, mesh.vertex_count, small));
    report["input_bytes"] = input_bytes;
    report["out_of_core_dereference"] = mesh.out_of_core;
  });
  return report;
}

nlohmann::json run_ooc_command(const OocCommand& command) {
  engine::tune_allocator(8 << 20, 1, 2 << 20, true);  // see process_memory.hpp (measured on the demo)
  uint64_t budget = command.mem_budget;
  if (budget == 0) budget = uint64_t(::sysconf(_SC_PHYS_PAGES)) * uint64_t(::sysconf(_SC_PAGE_SIZE)) / 2;
  const uint64_t baseline = engine::command_baseline();
  engine::require_budget_for_load(budget, baseline);
  engine::Governor governor(budget, baseline);
  engine::ProgressBar bar(command.quiet);
  OocJob alone = command;
  alone.job_budget = 0;  // all of the capacity: the CLI's one job
  if (!alone.scratch_free) alone.scratch_free = assumed_scratch_free();
  const nlohmann::json report = run_ooc_job(governor, alone, {.progress = bar.callback(), .cancel = command.cancel});
  bar.finish();
  if (!command.report_path.empty()) engine::write_json(command.report_path, report);
  if (!command.quiet) {
    std::fprintf(stderr, "qemflow: %llu -> %llu faces, %u patches, %llu epochs (%llu out of core), %llu rounds, %llu halo redos | %s\n",
                 (unsigned long long)report.value("input_faces", uint64_t(0)),
                 (unsigned long long)report.value("output_faces", uint64_t(0)), report.value("patches", 0u),
                 (unsigned long long)report.value("epochs", uint64_t(0)),
                 (unsigned long long)report.value("out_of_core_epochs", uint64_t(0)),
                 (unsigned long long)report.value("rounds", uint64_t(0)),
                 (unsigned long long)report.value("halo_redos", uint64_t(0)), engine::format_summary(report).c_str());
  }
  return report;
}

}  // namespace qemflow::nodes::pipeline
