#pragma once
// The first real pipeline on the engine: re-encode a mesh through blocks.
//
//   input ──loader (I/O thread reads, compute resolves)──► block chunks (scratch)
//   vertices (resident or scratch windows) ──► output writer (I/O thread)
//   block chunks ──block reader (I/O) ──decode (compute)──► output writer (I/O)
//
// The output holds the same vertices (same order, same positions to the bit; written
// as float when every input coordinate is a float, else as double) and the same
// triangles (same vertex indices), with faces in block order rather than input order:
// block by block (grid cells in index order), each block's faces in face-id order.
// That order, so the output's bytes, depends only on the input file (and
// LoadOptions::faces_per_block, which sets the grid), not on the budget, the memory the
// governor measured, the thread count, or whether the load went out of core (out of
// core, blocks carry face ids and are sorted by them as they are written).
// This is `qemflow simplify IN OUT --ratio 1`.
//
// Guarantees: peak resident memory stays under the governor's budget (every big
// buffer is leased; the process baseline is reserved by whoever made the governor);
// the scratch directory is gone and no output file exists after any failure or
// cancel; errors are qemflow::Error (bad_input for the input, resource for budget,
// disk and scratch, cancelled).
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "engine/blocks.hpp"
#include "engine/governor.hpp"
#include "engine/job.hpp"
#include "engine/scratch.hpp"

namespace qemflow::engine {

struct ReencodeOptions {
  std::filesystem::path input;
  std::filesystem::path output;
  std::filesystem::path scratch_dir;  // empty: the system temp dir
  std::filesystem::path trace_path;   // empty: no trace
  std::filesystem::path report_path;  // empty: no report file
  int threads = 0;                    // 0: all cores
  size_t trace_events = 1 << 18;      // cap of the trace buffer when tracing
  std::string job_name;               // prefixes this job's governor owners ("job 2/")
  LoadOptions load;
  ScratchCodec scratch_codec = ScratchCodec::automatic;  // --scratch-codec
  // Tests: out of core, put blocks in face-id order in groups of at most this many
  // faces (0: as many as half of the free memory holds).
  uint64_t group_faces = 0;
};

struct ReencodeResult {
  uint64_t vertices = 0;
  uint64_t faces = 0;
  nlohmann::json report;  // what --report writes
  std::string summary;    // format_summary(report)
};

ReencodeResult run_reencode(Governor& governor, const ReencodeOptions& options, const JobHooks& hooks);

// Scratch space to ask for up front, from the input's size on disk (vertex chunks,
// bucketed faces and blocks, compressed).
uint64_t expected_scratch_bytes(uint64_t input_file_bytes, bool zstd_input);
// The same for raw (uncompressed) frames.
uint64_t expected_raw_scratch_bytes(uint64_t input_file_bytes, bool zstd_input);

}  // namespace qemflow::engine

namespace qemflow::engine {

// The whole `simplify --ratio 1` command as the CLI runs it: a Governor for the
// process (budget from --mem-budget, baseline measured now, allocator tuned), a
// progress bar on stderr when it is a terminal and not quiet, the run, and the
// one-line summary on stderr unless quiet. Throws qemflow::Error like run_reencode.
struct ReencodeCommand {
  std::filesystem::path input, output, scratch_dir, trace_path, report_path;
  uint64_t mem_budget = 0;  // 0: half the machine's physical memory
  int threads = 0;
  bool quiet = false;
  ScratchCodec scratch_codec = ScratchCodec::automatic;
  std::shared_ptr<CancelToken> cancel;  // may be empty (the CLI's: interrupt.hpp)
};
ReencodeResult run_reencode_command(const ReencodeCommand& command);

}  // namespace qemflow::engine
