// `qemflow compare ORIGINAL SIMPLIFIED [--json] [--samples N] [--seed S] [--threads N]
//  [--chunk-faces N] [--mem-cap SIZE]`: Metro-style two-sided distances and topology
// of SIMPLIFIED beside ORIGINAL (measure/distance.hpp, measure/topology.hpp).
// ORIGINAL is streamed (it may be far larger than memory); SIMPLIFIED is loaded.
#include <tbb/global_control.h>

#include <chrono>
#include <cstdio>
#include <iostream>
#include <memory>
#include <optional>
#include <string>

#include "apps/qemflow/commands.hpp"
#include "config/size.hpp"
#include "measure/distance.hpp"
#include "measure/report_json.hpp"
#include "measure/topology.hpp"

namespace qemflow::cli {
namespace {

struct CompareArgs {
  std::string original, simplified;
  bool json = false;
  uint64_t samples = 0;
  uint64_t seed = measure::CompareOptions{}.seed;
  uint64_t chunk_faces = measure::CompareOptions{}.chunk_faces;
  std::string mem_cap = "1G";
  unsigned threads = 0;
};

std::string count_or_dash(const std::optional<uint64_t>& v) { return v ? std::to_string(*v) : "-"; }

void print_table(const CompareArgs& args, const measure::DistanceReport& d, const measure::TopologyStats& a,
                 const measure::TopologyStats& b, double seconds) {
  std::printf("A = ORIGINAL   %s\nB = SIMPLIFIED %s\n\n", args.original.c_str(), args.simplified.c_str());
  std::printf("%-22s %15s %15s %15s\n", "distance", "A->B", "B->A", "symmetric");
  auto row = [&](const char* name, double ab, double ba, double sym) {
    std::printf("%-22s %15.6e %15.6e %15.6e\n", name, ab, ba, sym);
    std::printf("%-22s %15.6e %15.6e %15.6e\n", "  / bbox diagonal", d.relative(ab), d.relative(ba), d.relative(sym));
  };
  row("hausdorff", d.a_to_b.hausdorff, d.b_to_a.hausdorff, d.hausdorff);
  row("mean", d.a_to_b.mean, d.b_to_a.mean, d.mean);
  row("rms", d.a_to_b.rms, d.b_to_a.rms, d.rms);
  std::printf("%-22s %15llu %15llu\n", "vertex samples", static_cast<unsigned long long>(d.a_to_b.vertex_samples),
              static_cast<unsigned long long>(d.b_to_a.vertex_samples));
  std::printf("%-22s %15llu %15llu\n", "face samples", static_cast<unsigned long long>(d.a_to_b.face_samples),
              static_cast<unsigned long long>(d.b_to_a.face_samples));
  std::printf("bbox diagonal of A: %.6e\n\n", d.bbox_diagonal);

  std::printf("%-26s %15s %15s\n", "topology", "original", "simplified");
  auto line = [](const char* name, const std::string& x, const std::string& y) {
    std::printf("%-26s %15s %15s\n", name, x.c_str(), y.c_str());
  };
  auto num = [](uint64_t v) { return std::to_string(v); };
  line("vertices", num(a.vertices), num(b.vertices));
  line("unreferenced vertices", count_or_dash(a.unreferenced_vertices), count_or_dash(b.unreferenced_vertices));
  line("faces", num(a.faces), num(b.faces));
  line("edges", num(a.edges), num(b.edges));
  line("boundary edges", num(a.boundary_edges), num(b.boundary_edges));
  line("non-manifold edges", num(a.non_manifold_edges), num(b.non_manifold_edges));
  line("inconsistently wound edges", num(a.oriented_duplicate_edges), num(b.oriented_duplicate_edges));
  line("non-manifold vertices", count_or_dash(a.non_manifold_vertices), count_or_dash(b.non_manifold_vertices));
  line("degenerate faces", count_or_dash(a.degenerate_faces), count_or_dash(b.degenerate_faces));
  line("duplicate faces", count_or_dash(a.duplicate_faces), count_or_dash(b.duplicate_faces));
  line("connected components", count_or_dash(a.connected_components), count_or_dash(b.connected_components));
  line("flipped faces", "", num(d.flipped_faces));
  std::printf("\n%.2f s\n", seconds);
}

}  // namespace

void add_compare_command(CLI::App& root, Run& run) {
  auto args = std::make_shared<CompareArgs>();
  auto* cmd = root.add_subcommand(
      "compare", "Metro-style surface distances (Hausdorff, mean, RMS; both directions) and topology");
  cmd->add_option("ORIGINAL", args->original, "reference mesh (streamed; may exceed memory)")->required();
  cmd->add_option("SIMPLIFIED", args->simplified, "mesh to measure (loaded into memory)")->required();
  cmd->add_flag("--json", args->json, "print one JSON object instead of the table");
  cmd->add_option("--samples", args->samples,
                  "face samples on SIMPLIFIED; ORIGINAL is sampled at the same density "
                  "(default max(1M, 10 x faces of SIMPLIFIED)); every vertex is a sample too");
  cmd->add_option("--seed", args->seed, "sampling seed; results are a pure function of inputs and options")
      ->capture_default_str();
  cmd->add_option("--chunk-faces", args->chunk_faces, "ORIGINAL faces per BVH chunk (memory ~180 B per face)")
      ->capture_default_str();
  cmd->add_option("--mem-cap", args->mem_cap, "memory for ORIGINAL's edge/face records per topology pass")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "worker threads (default: all cores); results do not depend on it");
  cmd->callback([&run, args] {
    run = [args] {
      std::optional<tbb::global_control> threads;
      if (args->threads > 0) threads.emplace(tbb::global_control::max_allowed_parallelism, args->threads);
      const auto start = std::chrono::steady_clock::now();
      measure::CompareOptions options;
      options.samples = args->samples;
      options.seed = args->seed;
      options.chunk_faces = args->chunk_faces;
      const uint64_t mem_cap = config::parse_size(args->mem_cap);

      const auto original = measure::file_mesh_source(args->original);
      const measure::Mesh simplified = measure::load_mesh(*measure::file_mesh_source(args->simplified));
      const measure::DistanceReport distances =
          measure::compare_streamed(*original, simplified, options, args->simplified);
      const measure::TopologyStats original_topology =
          measure::topology(*original, {measure::TopologyOptions::Scope::full, mem_cap});
      const measure::TopologyStats simplified_topology = measure::topology(simplified.points, simplified.triangles);
      const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

      if (args->json) {
        nlohmann::json j = measure::to_json(distances);
        j["original"] = args->original;
        j["simplified"] = args->simplified;
        j["topology"] = {{"original", measure::to_json(original_topology)},
                         {"simplified", measure::to_json(simplified_topology)}};
        j["seconds"] = seconds;
        std::cout << j.dump(2) << std::endl;
      } else {
        print_table(*args, distances, original_topology, simplified_topology, seconds);
      }
    };
  });
}

}  // namespace qemflow::cli
