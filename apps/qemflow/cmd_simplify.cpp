// `qemflow simplify IN OUT (--target-faces N | --ratio R) [--in-core] [--mem-budget SIZE]
//  [--clusters N|auto] [--scratch DIR] [--scratch-codec auto|raw|zstd] [--trace FILE]
//  [--threads N] [--no-weld]
//  [--report FILE.json] [--quiet]`: --in-core runs the in-core reference of the
// decimator (nodes/decimate/simplify.hpp); --ratio 1 re-encodes through the engine;
// everything else runs the out-of-core pipeline (nodes/pipeline/epochs.hpp), which
// finishes in core once the mesh fits the budget.
#include <sys/resource.h>
#include <tbb/global_control.h>
#include <tbb/info.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <cstdio>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "apps/qemflow/commands.hpp"
#include "engine/process_memory.hpp"
#include "config/size.hpp"
#include "engine/interrupt.hpp"
#include "engine/progress_bar.hpp"
#include "engine/reencode.hpp"
#include "engine/trace.hpp"
#include "nodes/pipeline/epochs.hpp"
#include "io/indexed_mesh.hpp"
#include "nodes/decimate/report_fields.hpp"
#include "nodes/decimate/simplify.hpp"
#include "util/error.hpp"

namespace qemflow::cli {
namespace {

struct SimplifyArgs {
  std::string input, output, report;
  std::string mem_budget, scratch, trace;
  std::string clusters = "auto";
  std::string scratch_codec = "auto";
  uint64_t in_core_faces = 0;
  std::optional<uint64_t> target_faces;
  std::optional<double> ratio;
  int threads = 0;
  bool in_core = false, no_weld = false, quiet = false, double_precision = false;
  nodes::EpochOptions epochs;
  nodes::DecimateParams params;
};

uint64_t peak_rss_bytes() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<uint64_t>(usage.ru_maxrss) * 1024;
}

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// The decimator's options, the same for the in-core and the out-of-core run (which
// welds in its loader, from OocCommand::weld, and ignores `weld` here).
nodes::SimplifyOptions simplify_options(const SimplifyArgs& args) {
  nodes::SimplifyOptions options;
  options.target_faces = args.target_faces;
  options.ratio = args.ratio;
  options.weld = !args.no_weld;
  options.epochs = args.epochs;
  options.params = args.params;
  return options;
}

// --clusters: "auto" (0: from the budget) or a patch count in [1, kMaxClusters]. Checked
// here rather than by std::stoul, which took "-3" as 2^64-3 and "x" as an internal error.
constexpr uint32_t kMaxClusters = 1u << 20;
uint32_t parse_clusters(const std::string& text) {
  if (text == "auto") return 0;
  uint64_t value = 0;
  const bool digits = !text.empty() && text.size() <= 7 &&
                      std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; });
  if (digits) value = std::stoull(text);
  if (!digits || value < 1 || value > kMaxClusters)
    throw Error(ErrorKind::usage, "--clusters must be auto or a patch count from 1 to " + std::to_string(kMaxClusters) +
                                      ", not '" + text + "'");
  return uint32_t(value);
}

// A tuning value must be a finite number in [lo, hi]: CLI::Range lets NaN through (both
// of its comparisons are false), and a NaN fraction or cosine would silently change the
// rule it sets.
CLI::Validator finite_in(double lo, double hi) {
  std::ostringstream description;
  description << "in [" << lo << ", " << hi << "]";
  return CLI::Validator(
      [lo, hi](std::string& text) -> std::string {
        double value = 0;
        const bool number = CLI::detail::lexical_cast(text, value);
        if (number && std::isfinite(value) && value >= lo && value <= hi) return {};
        std::ostringstream range;
        range << "must be a number from " << lo << " to " << hi << ", not '" << text << "'";
        return range.str();
      },
      description.str());
}

// The in-core run has no engine job; its trace holds one span per stage on the main
// thread, so --trace gives a file whatever the mode.
void write_in_core_trace(const std::string& path, const std::vector<std::pair<const char*, double>>& stage_ends) {
  engine::Trace trace(stage_ends.size() + 8);
  trace.name_thread("main");
  double start_us = 0;
  for (const auto& [name, end_seconds] : stage_ends) {
    trace.span(name, start_us, end_seconds * 1e6);
    start_us = end_seconds * 1e6;
  }
  trace.write(path);
}

void run_simplify(const SimplifyArgs& args) {
  if (args.ratio && !(*args.ratio > 0.0 && *args.ratio <= 1.0))
    throw Error(ErrorKind::usage, "--ratio must be in (0, 1]");
  // Parsed before any branch, so a bad count is refused whatever the run (--ratio 1 too).
  const uint32_t clusters = args.in_core ? 0 : parse_clusters(args.clusters);
  const uint64_t mem_budget = args.mem_budget.empty() ? 0 : config::parse_size(args.mem_budget);
  const std::optional<engine::ScratchCodec> codec = engine::parse_scratch_codec(args.scratch_codec);
  if (!codec) throw Error(ErrorKind::usage, "--scratch-codec must be auto, raw or zstd, not '" + args.scratch_codec + "'");
  if (args.ratio && *args.ratio == 1.0) {
    // --ratio 1 is the re-encode, with --in-core too (then under the machine's budget:
    // resident when it fits), so both give one file: every vertex and face as they are.
    engine::run_reencode_command({.input = args.input, .output = args.output, .scratch_dir = args.scratch,
                                  .trace_path = args.trace, .report_path = args.report,
                                  .mem_budget = args.in_core ? 0 : mem_budget, .threads = args.threads, .quiet = args.quiet,
                                  .scratch_codec = *codec, .cancel = engine::interrupt_token()});
    return;
  }
  if (!args.in_core) {
    nodes::pipeline::OocCommand command;
    command.input = args.input;
    command.output = args.output;
    command.scratch_dir = args.scratch;
    command.scratch_codec = *codec;
    command.trace_path = args.trace;
    command.report_path = args.report;
    command.mem_budget = mem_budget;
    command.threads = args.threads;
    command.quiet = args.quiet;
    command.double_precision = args.double_precision;
    command.cancel = engine::interrupt_token();
    auto& o = command.options;
    o.simplify = simplify_options(args);
    o.partition.clusters = clusters;
    command.weld = !args.no_weld;
    o.in_core_faces = args.in_core_faces;
    nodes::pipeline::run_ooc_command(command);
    return;
  }
  std::optional<tbb::global_control> limit;
  if (args.threads > 0) limit.emplace(tbb::global_control::max_allowed_parallelism, args.threads);
  const int threads = args.threads > 0 ? args.threads : tbb::info::default_concurrency();

  // A fixed mmap threshold: big arrays freed early (the input mesh) go back to the
  // system instead of staying in the heap under glibc's growing dynamic threshold.
  engine::tune_allocator();
  // A trace that cannot be written fails the run before any output exists.
  if (!args.trace.empty()) engine::Trace::check_writable(args.trace);
  // The bar follows the rounds by the share of the faces to remove that are gone (as
  // the out-of-core run's does); the read and the setup before them show as 0%.
  engine::ProgressBar bar(args.quiet);
  const engine::ProgressCallback progress = bar.callback();
  if (progress) progress(0, "read");
  const auto t0 = std::chrono::steady_clock::now();
  io::IndexedMesh mesh = io::read_mesh(args.input);
  const double seconds_read = seconds_since(t0);

  nodes::SimplifyOptions options = simplify_options(args);
  if (progress) {
    const uint64_t input_faces = mesh.triangles.size();
    const uint64_t target_faces = nodes::target_face_count(input_faces, options);
    progress(0, "simplify");
    options.on_round = [&progress, input_faces, target_faces](uint64_t, uint64_t faces) {
      progress(0.95 * nodes::removed_share(input_faces, target_faces, faces), "simplify");
    };
  }
  nodes::SimplifyResult result = nodes::simplify_in_core(std::move(mesh.vertices), std::move(mesh.triangles), options);
  const double seconds_simplified = seconds_since(t0);
  if (progress) progress(0.95, "write");

  const auto t1 = std::chrono::steady_clock::now();
  io::IndexedMesh out{std::move(result.points), std::move(result.triangles)};
  io::WriteOptions write_options;
  write_options.double_precision = args.double_precision;
  io::write_mesh(args.output, out, write_options);
  const double seconds_write = seconds_since(t1);
  const double seconds_total = seconds_since(t0);
  bar.finish();
  const auto& st = result.stats;
  if (!args.trace.empty())
    write_in_core_trace(args.trace, {{"read", seconds_read},
                                     {"simplify", seconds_simplified},
                                     {"write", seconds_total}});

  if (!args.report.empty()) {
    nlohmann::json report = {
        {"command", "simplify"},
        {"input", args.input},
        {"output", args.output},
        {"mode", "in-core"},
        {"threads", threads},
        {"input_vertices", st.input_vertices},
        {"input_faces", st.input_faces},
        {"target_faces", st.target_faces},
        {"output_vertices", st.output_vertices},
        {"output_faces", st.output_faces},
        {"welded_vertices", st.welded_vertices},
        {"locked_vertices", st.locked_vertices},
        {"dropped_zero_area_faces", st.dropped_faces},
        {"rounds", st.rounds},
        {"epochs", st.epochs},
        {"patches", 1},
        {"budget_bytes", 0},
        {"peak_rss_bytes", peak_rss_bytes()},
        {"wall_seconds", seconds_total},
        {"stage_seconds",
         {{"read", seconds_read},
          {"setup", st.seconds_setup},
          {"rounds", st.seconds_rounds},
          {"extract", st.seconds_extract},
          {"write", seconds_write}}},
    };
    nodes::report_schedule(report, args.epochs);
    nodes::report_work(report, "", st.work);
    std::ofstream file(args.report);
    file << report.dump(2) << "\n";
    if (!file) throw Error(ErrorKind::resource, args.report + ": cannot write report");
  }
  if (!args.quiet) {
    // The out-of-core run's line with its in-core fields: the same words and units.
    std::fprintf(stderr,
                 "qemflow: %llu -> %llu faces (target %llu), in core, %llu epochs, %llu rounds | wall %.2f s "
                 "(read %.2f, setup %.2f, rounds %.2f, write %.2f) | peak RSS %s\n",
                 static_cast<unsigned long long>(st.input_faces),
                 static_cast<unsigned long long>(st.output_faces),
                 static_cast<unsigned long long>(st.target_faces),
                 static_cast<unsigned long long>(st.epochs),
                 static_cast<unsigned long long>(st.rounds), seconds_total, seconds_read,
                 st.seconds_setup, st.seconds_rounds, seconds_write, config::format_size(peak_rss_bytes()).c_str());
  }
}

}  // namespace

void add_simplify_command(CLI::App& root, Run& run) {
  auto args = std::make_shared<SimplifyArgs>();
  auto* cmd = root.add_subcommand("simplify", "simplify a triangle mesh with QEM edge collapses");
  cmd->add_option("IN", args->input, "input mesh: .ply (ascii/binary), .obj, optionally .zst")->required();
  cmd->add_option("OUT", args->output, "output mesh: .ply (binary), .obj, optionally .zst")->required();
  auto* target = cmd->add_option("--target-faces", args->target_faces, "face count to reach");
  auto* ratio = cmd->add_option("--ratio", args->ratio, "target as a fraction of the input faces");
  // CLI11 2.1 reads a uint64 with strtoull, which takes "-5" as 2^64-5: check the text.
  target->check(CLI::Validator(
      [](std::string& text) -> std::string {
        const bool digits = !text.empty() && text.find_first_not_of("0123456789") == std::string::npos;
        if (digits && text.find_first_not_of('0') != std::string::npos) return {};
        return "must be a face count of at least 1, not '" + text + "'";
      },
      "N >= 1"));
  target->excludes(ratio);
  ratio->excludes(target);
  cmd->add_flag("--in-core", args->in_core, "simplify the whole mesh in memory (one patch)");
  cmd->add_option("--threads", args->threads, "worker threads (default: all cores)");
  cmd->add_option("--mem-budget", args->mem_budget,
                  "peak memory of the out-of-core run, e.g. 512M, 4G (default: half the RAM)");
  cmd->add_option("--scratch", args->scratch, "directory for scratch files (default: the system temp dir)");
  cmd->add_option("--scratch-codec", args->scratch_codec,
                  "scratch frames: auto (out of core, raw for each stage whose raw bytes, "
                  "bounded from the face and vertex counts, fit the free space then, else zstd; the "
                  "re-encode, raw when the disk has room for an estimate from the file size), raw (less "
                  "CPU, up to ~1 KB a face on disk out of core), zstd (the least disk)")
      ->capture_default_str();
  cmd->add_option("--trace", args->trace, "write a Chrome trace-event JSON of the run");
  cmd->add_option("--clusters", args->clusters, "patches of the out-of-core run (default: from the budget)");
  cmd->add_option("--in-core-faces", args->in_core_faces,
                  "testing: finish in core at this many faces, at most what the budget allows (default: when the mesh fits the budget)");
  cmd->add_flag("--no-weld", args->no_weld, "keep vertices at identical positions apart");
  cmd->add_option("--report", args->report, "write a JSON report to this file");
  cmd->add_flag("--quiet", args->quiet, "no progress bar and no summary line on stderr");
  cmd->add_flag("--double", args->double_precision, "write double-precision PLY vertices");
  cmd->add_option("--round-fraction", args->epochs.round_fraction,
                  "most faces a non-final round may remove, as a fraction of the current count")
      ->capture_default_str()
      ->check(finite_in(0.0, 1.0));
  cmd->add_option("--candidate-fraction", args->epochs.candidate_fraction,
                  "most of the round's candidates (by faces removed) a non-final round may collapse")
      ->capture_default_str()
      ->check(finite_in(0.0, 1.0));
  cmd->add_option("--epoch-rounds", args->epochs.epoch_rounds,
                  "rounds per global cut decision (an epoch; the out-of-core pipeline makes one "
                  "pass over the patches per epoch)")
      ->capture_default_str()
      ->check(CLI::Range(1u, 64u));
  cmd->add_option("--cut-rise", args->epochs.cut_rise,
                  "cost bins (4 per octave) the cut rises per round of an epoch where no candidate is "
                  "flat; 0: one cut per epoch")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 64.0));
  cmd->add_option("--flat-cut-rise", args->epochs.flat_cut_rise,
                  "the rise (at most --cut-rise) where 10% or more of the candidates' faces are flat "
                  "(cost 0), linear between; >= --cut-rise: the fixed rise --cut-rise")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 64.0));
  cmd->add_option("--charge-from", args->epochs.charge_from,
                  "weigh the deviation charge (--deviation-weight) from the summary after an epoch "
                  "that began with at most this many times the target faces; before, an edge costs its "
                  "quadric error alone (about half the CPU); 0: from the start")
      ->capture_default_str()
      ->check(finite_in(0.0, 1e12));
  cmd->add_option("--min-normal-cos", args->params.min_normal_cos,
                  "tuning: smallest allowed cosine between a face's normals before and after a collapse")
      ->capture_default_str()
      ->check(finite_in(-1.0, 1.0));
  cmd->add_option("--new-fold-cos", args->params.new_fold_cos,
                  "tuning: a collapse may not leave two faces that share an edge at the kept vertex with "
                  "normals' cosine below this where the faces around it had no such pair (-1: off)")
      ->capture_default_str()
      ->check(finite_in(-1.0, 1.0));
  cmd->add_option("--min-face-quality", args->params.min_face_quality,
                  "tuning: collapses may not create faces with |cross|/longest_edge^2 below this")
      ->capture_default_str()
      ->check(finite_in(0.0, 1.0));
  cmd->add_option("--fold-cos", args->params.fold_cos,
                  "tuning: edges whose face normals' dot product is below this keep their rim")
      ->capture_default_str()
      ->check(finite_in(-1.0, 1.0));
  cmd->add_option("--boundary-weight", args->params.boundary_weight,
                  "tuning: weight of the boundary-preserving quadrics")
      ->capture_default_str()
      ->check(finite_in(0.0, 1e12));
  cmd->add_option("--deviation-weight", args->params.deviation_weight,
                  "tuning: weight of the deviation charge (keeps thin tips and rims; 0 is plain "
                  "QEM, about half the CPU time)")
      ->capture_default_str()
      ->check(finite_in(0.0, 1e12));
  cmd->callback([&run, args, target, ratio] {
    if (target->count() + ratio->count() != 1)
      throw CLI::ValidationError("simplify", "give exactly one of --target-faces and --ratio");
    run = [args] { run_simplify(*args); };
  });
}

}  // namespace qemflow::cli
