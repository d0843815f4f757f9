// `qemflow info IN [--json] [--full] [--mem-cap SIZE]`: format, counts, bounding box,
// boundary and non-manifold edges of a mesh file, streamed with memory bounded by
// --mem-cap (edge records are counted in hash-partitioned passes, measure/topology.hpp).
// --full adds the per-vertex counters (components, non-manifold vertices, ...), which
// keep about 16 B per vertex.
#include <cstdio>
#include <iostream>
#include <memory>
#include <string>

#include "apps/qemflow/commands.hpp"
#include "config/size.hpp"
#include "io/mesh_stream.hpp"
#include "measure/report_json.hpp"
#include "measure/topology.hpp"

namespace qemflow::cli {
namespace {

struct InfoArgs {
  std::string input;
  bool json = false;
  bool full = false;
  std::string mem_cap = "1G";
};

}  // namespace

void add_info_command(CLI::App& root, Run& run) {
  auto args = std::make_shared<InfoArgs>();
  auto* cmd = root.add_subcommand("info", "format, counts, bounding box, boundary and non-manifold edges");
  cmd->add_option("IN", args->input, "mesh file: .ply (ascii/binary), .obj, optionally .zst")->required();
  cmd->add_flag("--json", args->json, "print one JSON object");
  cmd->add_flag("--full", args->full, "also count components, non-manifold vertices, degenerate/duplicate faces");
  cmd->add_option("--mem-cap", args->mem_cap, "memory for edge records per pass (more passes when smaller)")
      ->capture_default_str();
  cmd->callback([&run, args] {
    run = [args] {
      const uint64_t mem_cap = config::parse_size(args->mem_cap);
      const auto source = measure::file_mesh_source(args->input);
      io::MeshInfo header = io::open_mesh_reader(args->input)->info();
      const auto scope = args->full ? measure::TopologyOptions::Scope::full : measure::TopologyOptions::Scope::edges;
      const measure::TopologyStats stats = measure::topology(*source, {scope, mem_cap});
      const std::string format = io::to_string(header.format) + (header.zstd ? " + zstd" : "");
      if (args->json) {
        nlohmann::json j = measure::to_json(stats);
        j["file"] = args->input;
        j["format"] = format;
        j["zstd"] = header.zstd;
        j["bbox"] = measure::to_json(stats.bbox);
        j["passes"] = stats.passes;
        std::cout << j.dump(2) << std::endl;
        return;
      }
      std::printf("file                 %s\n", args->input.c_str());
      std::printf("format               %s\n", format.c_str());
      std::printf("vertices             %llu\n", static_cast<unsigned long long>(stats.vertices));
      std::printf("faces                %llu\n", static_cast<unsigned long long>(stats.faces));
      if (!stats.bbox.empty)
        std::printf("bbox                 (%.6g, %.6g, %.6g) - (%.6g, %.6g, %.6g), diagonal %.6g\n", stats.bbox.lo[0],
                    stats.bbox.lo[1], stats.bbox.lo[2], stats.bbox.hi[0], stats.bbox.hi[1], stats.bbox.hi[2],
                    stats.bbox.diagonal());
      std::printf("edges                %llu\n", static_cast<unsigned long long>(stats.edges));
      std::printf("boundary edges       %llu\n", static_cast<unsigned long long>(stats.boundary_edges));
      std::printf("non-manifold edges   %llu\n", static_cast<unsigned long long>(stats.non_manifold_edges));
      std::printf("inconsistent winding %llu edges\n", static_cast<unsigned long long>(stats.oriented_duplicate_edges));
      auto optional_line = [](const char* name, const std::optional<uint64_t>& v) {
        if (v) std::printf("%-20s %llu\n", name, static_cast<unsigned long long>(*v));
      };
      optional_line("unreferenced verts", stats.unreferenced_vertices);
      optional_line("non-manifold verts", stats.non_manifold_vertices);
      optional_line("degenerate faces", stats.degenerate_faces);
      optional_line("duplicate faces", stats.duplicate_faces);
      optional_line("components", stats.connected_components);
      std::printf("passes               %u\n", stats.passes);
    };
  });
}

}  // namespace qemflow::cli
